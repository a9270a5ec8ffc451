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
import os
import sys
from collections.abc import Iterator

import numpy as np

from ...errors import FormatError, InputError

GPS_EPOCH_UNIX_S = 315_964_800
LEAP_S = 18
FN_THROTTLE_LEFT = 73
FN_THROTTLE_RIGHT = 74


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
    from pymavlink.DFReader import DFReader_binary

    with _quiet_fds(), _quiet():
        log = DFReader_binary(str(path), zero_time_base=True)
    try:
        while True:
            with _quiet():
                m = log.recv_match(type=types)
            if m is None:
                return
            yield m
    finally:
        with contextlib.suppress(Exception):
            log.filehandle.close()


def read(path, opts, report, *, fmt="dataflash", on_mapping=None) -> Iterator[dict]:
    with open(path, "rb") as fh:
        head = fh.read(3)
    if head != b"\xa3\x95\x80":
        raise FormatError(f"{path}: not an ArduPilot DataFlash log (no FMT header at byte 0)")
    # pass 1: servo functions and the UTC offset of the boot clock
    servo: dict[int, int] = {}
    offset_ns = None
    for m in _messages(path, ["PARM", "GPS"]):
        if m.get_type() == "PARM":
            name = str(m.Name)
            if name.startswith("SERVO") and name.endswith("_FUNCTION"):
                try:
                    servo[int(name[5:-9])] = int(round(float(m.Value)))
                except ValueError:
                    pass
        elif offset_ns is None and int(getattr(m, "GWk", 0) or 0) > 0 and int(getattr(m, "Status", 0)) >= 3:
            gps_s = GPS_EPOCH_UNIX_S + int(m.GWk) * 604800 + int(m.GMS) / 1000.0 - LEAP_S
            offset_ns = int(round(gps_s * 1e9)) - int(m.TimeUS) * 1000
    if offset_ns is None:
        offset_ns = opts.start_utc_ns or 0
        report.guesses["time_base"] = "--start-utc" if opts.start_utc_ns else "1970-01-01T00:00:00Z"
        report.note("no GPS time in the log: boot time counted from " + report.guesses["time_base"])
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
        typ = m.get_type()
        try:
            t = int(m.TimeUS) * 1000 + offset_ns
        except (AttributeError, TypeError, ValueError):
            report.skip("dataflash_bad_message", 1, where=f"{typ} without TimeUS")
            continue
        if typ == "GPS":
            if int(getattr(m, "Status", 0)) < 3:
                report.skip("gnss_no_fix", 1, where=f"GPS at TimeUS {m.TimeUS}: status {m.Status}")
                continue
            g["t_ns"].append(t)
            g["lat_deg"].append(float(m.Lat))
            g["lon_deg"].append(float(m.Lng))
            g["alt_m"].append(float(getattr(m, "Alt", np.nan)))
        elif typ in ("ATT", "AHRS2"):
            d = h if typ == "ATT" else h2
            d["t_ns"].append(t)
            d["heading_rad"].append(np.radians(float(m.Yaw)))
        elif typ == "RCOU" and left and right:
            try:
                lv = float(getattr(m, f"C{left[0]}"))
                rv = float(getattr(m, f"C{right[0]}"))
            except AttributeError as err:
                raise InputError(f"{path}: RCOU has no channel for SERVO{left[0]}/SERVO{right[0]}") from err
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
