"""ArduPilot DataFlash .bin logs through pymavlink's DFReader.

* ``GPS`` (Status >= 3: 3-D fix; lower is "no fix", skipped and counted) -> ``/gnss/fix``;
* ``ATT.Yaw`` (or ``AHRS2.Yaw`` when there is no ATT), degrees clockwise from north
  -> ``/compass/heading``;
* ``RCOU`` channel n -> left/right thruster through the ``PARM`` values
  ``SERVOn_FUNCTION`` = 73 (throttle left) / 74 (throttle right); commands in ``pwm_us``.

Time: ``TimeUS`` (boot time) shifted to UTC by the first GPS message with a week
number (GPS time = GWk * 604800 + GMS / 1000 s after 1980-01-06, minus 18 leap
seconds); without one, by ``--start-utc`` (else the Unix epoch, noted).
"""

from __future__ import annotations

import contextlib
import io
import math
import os
import sys
from collections.abc import Iterator

import numpy as np

from ...errors import FormatError, InputError
from .core import clock_offset_fallback, foreign
from .sniff import DATAFLASH_MAGIC, file_head

GPS_EPOCH_UNIX_S = 315_964_800
LEAP_S = 18
FN_THROTTLE_LEFT = 73
FN_THROTTLE_RIGHT = 74
_T_MAX_NS = 2**63


@contextlib.contextmanager
def _quiet():
    """DFReader prints progress and warnings; keep stdout/stderr for usvlog's own output."""
    sink = io.StringIO()
    with contextlib.redirect_stdout(sink), contextlib.redirect_stderr(sink):
        yield sink


@contextlib.contextmanager
def _quiet_fds():
    """The C indexer of pymavlink writes to file descriptor 2 itself: silence it at the fd level."""
    for s in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            s.flush()
    saved = [os.dup(1), os.dup(2)]
    null = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(null, 1)
        os.dup2(null, 2)
        yield
    finally:
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in saved + [null]:
            os.close(fd)


def _messages(path, types):
    """pymavlink's messages of ``types``; its exceptions on a damaged file -> FormatError.

    Only the library calls are inside :func:`~usvlog.io.importers.core.foreign`; the
    caller's work on each message runs outside it.
    """
    from pymavlink.DFReader import DFReader_binary

    with foreign(path, "not a readable DataFlash log"), _quiet_fds(), _quiet():
        log = DFReader_binary(str(path), zero_time_base=True)
    last = None

    def damaged() -> str:
        return "damaged DataFlash log" + (f" after {last.get_type()} at TimeUS {getattr(last, 'TimeUS', '?')}"
                                          if last is not None else "")

    try:
        while True:
            with foreign(path, damaged), _quiet():
                m = log.recv_match(type=types)
            if m is None:
                return
            last = m
            yield m
    finally:
        with contextlib.suppress(OSError):
            log.filehandle.close()


def _fields(m) -> dict | None:
    """A message's fields as a dict; None when pymavlink cannot decode them (damaged bytes).

    pymavlink decodes fields lazily, on attribute access, and raises whatever its
    decoder meets (``IndexError``, ``struct.error``, ...); this is the one place it does
    that, so the caller can skip and count the message and work on plain values.
    """
    try:
        return m.to_dict()
    except Exception:  # noqa: BLE001 -- pymavlink decoding one damaged message: skipped and counted
        return None


def _num(f: dict, name: str) -> float | None:
    """Field ``name`` as a finite float, None when the message has no such number."""
    v = f.get(name)
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, float, np.integer, np.floating)):
        return None
    v = float(v)
    return v if math.isfinite(v) else None


def read(path, opts, report, *, fmt="dataflash", on_mapping=None) -> Iterator[dict]:
    """Batches of role streams from an ArduPilot DataFlash log (see :mod:`usvlog.io.importers.core`).

    Two passes through pymavlink: PARM/GPS for the thruster channels and the UTC offset
    of the boot clock, then GPS/ATT/AHRS2/RCOU. Messages pymavlink cannot decode, or
    without a usable TimeUS, are skipped and counted; pymavlink failing on the file as a
    whole is a :class:`~usvlog.errors.FormatError` ``from`` its exception.
    """
    if file_head(path, len(DATAFLASH_MAGIC)) != DATAFLASH_MAGIC:
        raise FormatError(f"{path}: not an ArduPilot DataFlash log (no FMT header at byte 0)")
    # pass 1: servo functions and the UTC offset of the boot clock
    servo: dict[int, int] = {}
    offset_ns = None
    for m in _messages(path, ["PARM", "GPS"]):
        f = _fields(m)
        if f is None:
            continue   # counted in pass 2
        if f["mavpackettype"] == "PARM":
            name, value = str(f.get("Name", "")), _num(f, "Value")
            num = name[5:-9]
            if name.startswith("SERVO") and name.endswith("_FUNCTION") and num.isdigit() and value is not None:
                servo[int(num)] = round(value)
        elif offset_ns is None:
            week, gms, status, boot = (_num(f, k) for k in ("GWk", "GMS", "Status", "TimeUS"))
            if None not in (week, gms, status, boot) and week > 0 and status >= 3:
                gps_s = GPS_EPOCH_UNIX_S + int(week) * 604800 + int(gms) / 1000.0 - LEAP_S
                offset_ns = round(gps_s * 1e9) - int(boot) * 1000
    if offset_ns is None:
        offset_ns = clock_offset_fallback(opts, report, "boot time")
    left = [n for n, f in sorted(servo.items()) if f == FN_THROTTLE_LEFT]
    right = [n for n, f in sorted(servo.items()) if f == FN_THROTTLE_RIGHT]
    report.mapping["gnss"] = "GPS"
    report.mapping["heading"] = "ATT.Yaw"
    if left and right:
        report.mapping["thrust_left"] = f"RCOU.C{left[0]} (SERVO{left[0]}_FUNCTION=73)"
        report.mapping["thrust_right"] = f"RCOU.C{right[0]} (SERVO{right[0]}_FUNCTION=74)"
    else:
        report.note("no SERVOn_FUNCTION = 73/74 parameters: thruster outputs not imported")
    if on_mapping is not None:
        on_mapping(report)
    g = {k: [] for k in ("t_ns", "lat_deg", "lon_deg", "alt_m")}
    h = {k: [] for k in ("t_ns", "heading_rad")}
    h2 = {k: [] for k in ("t_ns", "heading_rad")}
    th = {k: [] for k in ("t_ns", "left", "right")}
    for m in _messages(path, ["GPS", "ATT", "AHRS2", "RCOU"]):
        report.records += 1
        f = _fields(m)
        if f is None:
            report.skip("dataflash_bad_message", 1, where=f"a {m.get_type()} message pymavlink cannot decode")
            continue
        typ = f["mavpackettype"]
        boot = _num(f, "TimeUS")
        if boot is None:
            report.skip("dataflash_bad_message", 1, where=f"{typ} without TimeUS")
            continue
        t = int(boot) * 1000 + offset_ns
        if not 0 <= t < _T_MAX_NS:   # a damaged TimeUS: not a time int64 ns can hold
            report.skip("dataflash_bad_time", 1, where=f"{typ} at TimeUS {int(boot)}")
            continue
        at = f"{typ} at TimeUS {int(boot)}"
        if typ == "GPS":
            status = _num(f, "Status")
            if status is None or status < 3:
                report.skip("gnss_no_fix", 1, where=f"{at}: status {f.get('Status')}")
                continue
            lat, lon, alt = _num(f, "Lat"), _num(f, "Lng"), _num(f, "Alt")
            if lat is None or lon is None:
                report.skip("dataflash_bad_message", 1, where=f"{at} without Lat/Lng")
                continue
            g["t_ns"].append(t)
            g["lat_deg"].append(lat)
            g["lon_deg"].append(lon)
            g["alt_m"].append(np.nan if alt is None else alt)
        elif typ in ("ATT", "AHRS2"):
            yaw = _num(f, "Yaw")
            if yaw is None:
                report.skip("dataflash_bad_message", 1, where=f"{at} without Yaw")
                continue
            d = h if typ == "ATT" else h2
            d["t_ns"].append(t)
            d["heading_rad"].append(np.radians(yaw))
        elif typ == "RCOU" and left and right:
            ch_l, ch_r = f"C{left[0]}", f"C{right[0]}"
            if ch_l not in f or ch_r not in f:
                raise InputError(f"{path}: {at} has no channel for SERVO{left[0]}/SERVO{right[0]}")
            lv, rv = _num(f, ch_l), _num(f, ch_r)
            if lv is None or rv is None:
                report.skip("thrust_nan", 1, where=at)
                continue
            th["t_ns"].append(t)
            th["left"].append(lv)
            th["right"].append(rv)
    heading = h if h["t_ns"] else h2
    if not h["t_ns"] and h2["t_ns"]:
        report.mapping["heading"] = "AHRS2.Yaw"
    batch = {}
    if g["t_ns"]:
        batch["gnss"] = {k: np.asarray(v, np.int64 if k == "t_ns" else float) for k, v in g.items()}
    if heading["t_ns"]:
        batch["heading"] = {k: np.asarray(v, np.int64 if k == "t_ns" else float) for k, v in heading.items()}
    if th["t_ns"]:
        unit = opts.thrust_unit or "pwm_us"
        batch["thrust"] = {k: np.asarray(v, np.int64 if k == "t_ns" else float) for k, v in th.items()}
        batch["thrust"]["unit"] = np.full(len(th["t_ns"]), unit, dtype=object)
    yield batch
