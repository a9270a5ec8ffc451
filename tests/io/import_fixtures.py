"""Small field-log fixtures built byte by byte to each format's published layout.

ArduPilot DataFlash (.bin), per ArduPilot's "Log file format" (libraries/AP_Logger):
every message is ``0xA3 0x95 <type id>`` followed by the packed fields (little-endian,
no padding). Type 128 is FMT, whose own fields are ``Type:B Length:B Name:4s
Format:16s Columns:64s`` (89 bytes with the 3-byte header); a FMT message must come
before the first message of the type it defines. Format letters used here:
``Q`` uint64, ``B`` uint8, ``H`` uint16, ``I`` uint32, ``c`` int16 x 100,
``C`` uint16 x 100, ``e`` int32 x 100, ``L`` int32 latitude/longitude x 1e7,
``N`` char[16], ``f`` float32. ``build_dataflash`` writes FMT (of FMT, PARM, GPS, ATT,
RCOU), PARM SERVOn_FUNCTION values and then GPS / ATT / RCOU messages.

PX4 ULog (.ulg), per the ULog file format spec (docs.px4.io "ULog File Format"):
a 16-byte header ``"ULog" 0x01 0x12 0x35 <version u8> <timestamp u64 us>``, then
messages ``<msg_size u16> <msg_type u8> <payload>``: the definitions section
('B' flag bits: 8 compat + 8 incompat flag bytes + 3 u64 appended offsets;
'F' formats ``name:type field;type field;...``; 'I' info ``<key_len u8> "type key" value``),
then the data section ('A' subscribe ``<multi_id u8> <msg_id u16> name``,
'D' data ``<msg_id u16> <packed fields>``). ``build_ulog`` writes
vehicle_gps_position, vehicle_attitude and actuator_outputs.
"""

from __future__ import annotations

import math
import struct

import numpy as np

T0_NS = 1_714_557_600_000_000_000  # 2024-05-01T10:00:00Z
GPS_EPOCH_UNIX_S = 315_964_800
LEAP_S = 18

# ---------------------------------------------------------------------------- DataFlash

_DF_STRUCT = {"Q": "Q", "B": "B", "H": "H", "I": "I", "c": "h", "C": "H", "e": "i", "L": "i", "N": "16s",
              "f": "f", "n": "4s", "Z": "64s"}


def _df_struct(fmt: str) -> str:
    return "<" + "".join(_DF_STRUCT[c] for c in fmt)


def _df_fmt(type_id: int, name: str, fmt: str, columns: str) -> bytes:
    length = 3 + struct.calcsize(_df_struct(fmt))
    return b"\xa3\x95\x80" + struct.pack("<BB4s16s64s", type_id, length, name.encode(), fmt.encode(),
                                         columns.encode())


def _df_msg(type_id: int, fmt: str, *values) -> bytes:
    return bytes([0xA3, 0x95, type_id]) + struct.pack(_df_struct(fmt), *values)


DF_PARM = (64, "PARM", "QNf", "TimeUS,Name,Value")
DF_GPS = (65, "GPS", "QBIHBcLLe", "TimeUS,Status,GMS,GWk,NSats,HDop,Lat,Lng,Alt")
DF_ATT = (66, "ATT", "QccccCC", "TimeUS,DesRoll,Roll,DesPitch,Pitch,DesYaw,Yaw")
DF_RCOU = (67, "RCOU", "QHHHHHHHH", "TimeUS,C1,C2,C3,C4,C5,C6,C7,C8")


def dataflash_truth(n: int = 30):
    """The values build_dataflash encodes (already on the format's integer grids)."""
    k = np.arange(n)
    lat_e7 = 591234567 + 13 * k
    lon_e7 = 102345678 - 29 * k
    yaw_cd = (35000 + 250 * k) % 36000          # centidegrees, crosses north
    pwm_l = 1500 + 10 * k                          # RCOU C3 (SERVO3_FUNCTION = 73)
    pwm_r = 1500 - 7 * k                           # RCOU C1 (SERVO1_FUNCTION = 74)
    boot_us = 5_000_000 + 100_000 * k              # 10 Hz from 5 s after boot
    return dict(lat_e7=lat_e7, lon_e7=lon_e7, yaw_cd=yaw_cd, pwm_l=pwm_l, pwm_r=pwm_r, boot_us=boot_us)


def build_dataflash(nofix_first: int = 0, n: int = 30) -> tuple[bytes, dict]:
    """A .bin with GPS (UTC from GWk/GMS), ATT and RCOU; returns (bytes, truth)."""
    tr = dataflash_truth(n)
    out = [_df_fmt(128, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns")]
    for d in (DF_PARM, DF_GPS, DF_ATT, DF_RCOU):
        out.append(_df_fmt(*d))
    for name, val in (("SERVO1_FUNCTION", 74.0), ("SERVO2_FUNCTION", 0.0), ("SERVO3_FUNCTION", 73.0)):
        out.append(_df_msg(64, "QNf", 1000, name.encode(), val))
    # GPS time of boot_us[0] = T0: GPS seconds since 1980-01-06 + leap seconds
    gps_s0 = T0_NS / 1e9 - GPS_EPOCH_UNIX_S + LEAP_S
    for i in range(n):
        us = int(tr["boot_us"][i])
        gps_ms = int(round((gps_s0 + (us - tr["boot_us"][0]) / 1e6) * 1000))
        week, gms = divmod(gps_ms, 604_800_000)
        status = 1 if i < nofix_first else 3
        out.append(_df_msg(65, "QBIHBcLLe", us, status, gms, week, 12, 90, int(tr["lat_e7"][i]),
                           int(tr["lon_e7"][i]), 1250))
        out.append(_df_msg(66, "QccccCC", us + 20_000, 0, 0, 0, 0, 0, int(tr["yaw_cd"][i])))
        out.append(_df_msg(67, "QHHHHHHHH", us + 40_000, int(tr["pwm_r"][i]), 1500, int(tr["pwm_l"][i]),
                           1500, 0, 0, 0, 0))
    return b"".join(out), tr


# ---------------------------------------------------------------------------- ULog

def _ulog_msg(kind: str, payload: bytes) -> bytes:
    return struct.pack("<HB", len(payload), ord(kind)) + payload


def ulog_truth(n: int = 25):
    k = np.arange(n)
    return dict(ts_us=1_000_000 + 100_000 * k, lat_e7=-335551234 + 17 * k, lon_e7=1512345678 + 11 * k,
                psi=np.linspace(-3.1, 3.1, n), pwm_l=1500.0 + 8 * k, pwm_r=1500.0 - 5 * k,
                fix=np.where(k % 6 == 5, 0, 3))


def build_ulog(n: int = 25) -> tuple[bytes, dict]:
    tr = ulog_truth(n)
    out = [b"ULog\x01\x12\x35" + bytes([1]) + struct.pack("<Q", 0)]
    out.append(_ulog_msg("B", bytes(16) + struct.pack("<QQQ", 0, 0, 0)))
    formats = {
        "vehicle_gps_position": ("uint64_t timestamp;uint64_t time_utc_usec;int32_t lat;int32_t lon;"
                                 "int32_t alt;int32_t alt_ellipsoid;uint8_t fix_type;", "<QQiiiiB"),
        "vehicle_attitude": ("uint64_t timestamp;float[4] q;", "<Q4f"),
        "actuator_outputs": ("uint64_t timestamp;uint32_t noutputs;float[16] output;", "<QI16f"),
    }
    for name, (fields, _) in formats.items():
        out.append(_ulog_msg("F", f"{name}:{fields}".encode()))
    key = b"char[9] sys_name"
    out.append(_ulog_msg("I", bytes([len(key)]) + key + b"usvlogfix"))
    for mid, name in enumerate(formats):
        out.append(_ulog_msg("A", struct.pack("<BH", 0, mid) + name.encode()))
    utc0_us = T0_NS // 1000
    for i in range(n):
        ts = int(tr["ts_us"][i])
        out.append(_ulog_msg("D", struct.pack("<H", 0) + struct.pack(
            formats["vehicle_gps_position"][1], ts, utc0_us + ts - int(tr["ts_us"][0]), int(tr["lat_e7"][i]),
            int(tr["lon_e7"][i]), 12500, 12500 + 38000, int(tr["fix"][i]))))  # 12.5 m MSL, geoid 38 m
        half = float(tr["psi"][i]) / 2  # rotation about NED z: q = (cos, 0, 0, sin)
        out.append(_ulog_msg("D", struct.pack("<H", 1) + struct.pack(
            formats["vehicle_attitude"][1], ts + 10_000, math.cos(half), 0.0, 0.0, math.sin(half))))
        outputs = [1500.0] * 16
        outputs[2], outputs[3] = float(tr["pwm_l"][i]), float(tr["pwm_r"][i])
        outputs[0], outputs[1] = float(tr["pwm_l"][i]) + 1, float(tr["pwm_r"][i]) + 1
        out.append(_ulog_msg("D", struct.pack("<H", 2) + struct.pack(
            formats["actuator_outputs"][1], ts + 20_000, 4, *outputs)))
    return b"".join(out), tr
