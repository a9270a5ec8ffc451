"""ArduPilot DataFlash .bin logs through pymavlink's DFReader.

Roles and the messages they come from (field paths ``MSG[.instance].Field``; the
instance is the value of the message's instance field, e.g. ``GPS.1.Lat``, ``IMU.0.GyrZ``):

* ``gnss``: ``GPS`` (instance 0; Status >= 3: 3-D fix, lower is "no fix", skipped and
  counted) -> ``/gnss/fix``, with the receiver's ``GPA.HAcc``/``VAcc`` (m, same TimeUS) as
  the diagonal of the position covariance (``cov_type`` 2, DIAGONAL_KNOWN). A log without
  GPS messages is noted "no GNSS in this log" and maps no ``gnss`` (``AHR2``/``POS`` carry
  the autopilot's estimated position, not a fix);
* ``speed_mps``: ``GPS.Spd`` with ``GPS.GCrs`` as course -> ``/gnss/velocity``;
* ``heading``: ``ATT.Yaw`` (or ``AHR2.Yaw`` when there is no ATT) -> ``/compass/heading``;
* ``yaw_rate``: ``IMU.GyrZ`` of instance 0 (rad/s about the body z axis, FRD) -> ``/imu/yaw_rate``;
* ``thrust_left``/``thrust_right``: ``RCOU`` channel n through the ``PARM`` values
  ``SERVOn_FUNCTION`` = 73 (throttle left) / 74 (throttle right); commands in ``pwm_us``.

``--topic ROLE=MSG[.instance].Field`` overrides any of them (e.g. ``--topic
thrust_left=RCOU.C1 --topic thrust_right=RCOU.C2``, ``--topic yaw_rate=RATE.Y``);
values are converted by the unit the log's FMTU declares (deg, rad, deg/s, rad/s,
us). A mapping that cannot be honoured is a one-line error listing what exists. Only
the mappings used are recorded in the report (and so in the log's provenance).

Time: ``TimeUS`` (boot time) shifted to UTC by the first GPS message with a week
number whose offset agrees (within 1 s) with the median over all fixes (GPS time =
GWk * 604800 + GMS / 1000 s after 1980-01-06, minus 18 leap seconds); without one, by
``--start-utc`` (else the Unix epoch, noted).
"""

from __future__ import annotations

import contextlib
import io
import math
import os
import sys
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np

from ...errors import FormatError, InputError
from .catalog import Catalog, FieldInfo, TopicInfo
from .core import clock_offset_fallback, foreign, listing
from .sniff import DATAFLASH_MAGIC, file_head
from .thrust_guess import guess_thrust_unit
from .ulog import spike_mask

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


def _open(path):
    """pymavlink's reader of ``path`` (its indexing pass done); a damaged or foreign file -> FormatError."""
    from pymavlink.DFReader import DFReader_binary

    if file_head(path, len(DATAFLASH_MAGIC)) != DATAFLASH_MAGIC:
        raise FormatError(f"{path}: not an ArduPilot DataFlash log (no FMT header at byte 0)")
    with foreign(path, "not a readable DataFlash log"), _quiet_fds(), _quiet():
        return DFReader_binary(str(path), zero_time_base=True)


def _messages(path, types):
    """pymavlink's messages of ``types``; its exceptions on a damaged file -> FormatError.

    Only the library calls are inside :func:`~usvlog.io.importers.core.foreign`; the
    caller's work on each message runs outside it.
    """
    log = _open(path)
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




# ----------------------------------------------------------------------------- formats
ROLES = ("gnss", "heading", "yaw_rate", "thrust_left", "thrust_right", "speed_mps", "velocity")
_TYPES = {"a": "int16[32]", "b": "int8", "B": "uint8", "h": "int16", "H": "uint16", "i": "int32", "I": "uint32",
          "f": "float", "d": "double", "n": "char[4]", "N": "char[16]", "Z": "char[64]", "c": "int16*0.01",
          "C": "uint16*0.01", "e": "int32*0.01", "E": "uint32*0.01", "L": "int32 deg*1e-7", "M": "uint8 mode",
          "q": "int64", "Q": "uint64"}


@dataclass(frozen=True)
class MsgFormat:
    """One DataFlash message type as its FMT/FMTU define it.

    Attributes
    ----------
    name : str
        Message name (``GPS``, ``RCOU``).
    columns : tuple of str
        Field names.
    types : tuple of str
        Field types (from the FMT format letters).
    units : tuple of str
        Field units from FMTU ("" when the log declares none).
    instance : str or None
        The instance field (``I``, ``C``) of a multi-instance message, else None.
    count : int
        Messages of this type in the log (pymavlink's index).
    """

    name: str
    columns: tuple
    types: tuple
    units: tuple
    instance: str | None
    count: int

    def unit(self, column: str) -> str:
        """The FMTU unit of ``column`` ("" when unknown)."""
        i = self.columns.index(column)
        return self.units[i] if i < len(self.units) else ""


def formats(log) -> dict[str, MsgFormat]:
    """Message name -> :class:`MsgFormat` for every type the log defines (count 0 when none was logged).

    Parameters
    ----------
    log : pymavlink.DFReader.DFReader_binary
        An opened log.

    Returns
    -------
    dict
        Keyed by message name.
    """
    out = {}
    for tid, f in log.formats.items():
        cols = tuple(f.columns)
        units = tuple("" if u is None else str(u).replace("µ", "u") for u in (getattr(f, "units", None) or ()))
        out[f.name] = MsgFormat(f.name, cols, tuple(_TYPES.get(c, c) for c in f.format), units,
                                getattr(f, "instance_field", None), int(log.counts[tid]) if tid < len(log.counts)
                                else 0)
    return out


def parse_path(spec: str) -> tuple[str, int | None, str]:
    """``MSG[.instance][.Field]`` -> (message, instance or None, field or "").

    Parameters
    ----------
    spec : str
        A DataFlash field path as ``--topic`` takes it, e.g. ``RCOU.C1``, ``GPS.1.Lat``.

    Returns
    -------
    tuple
        Message name, instance number (None: not given) and field name ("" when absent).
    """
    parts = spec.strip().lstrip("/").split(".")
    inst = None
    if len(parts) > 1 and parts[1].isdigit():
        inst = int(parts.pop(1))
    return parts[0], inst, ".".join(parts[1:])


def _angle_scale(unit: str, column: str) -> tuple[float, str]:
    """Factor to rad of an angle field and what was assumed."""
    u = unit.lower()
    if u.startswith("rad"):
        return 1.0, "rad"
    if u.startswith("cdeg") or u == "cd":
        return math.pi / 18000.0, "centidegrees"
    if u.startswith("deg") or u == "d":
        return math.pi / 180.0, "deg"
    return math.pi / 180.0, "deg (no unit in the log: ArduPilot logs angles in degrees)"


def _rate_scale(unit: str, column: str) -> tuple[float, str]:
    """Factor to rad/s of a rate field and what was assumed."""
    u = unit.lower()
    if u.startswith("rad"):
        return 1.0, "rad/s"
    if u.startswith("deg") or u.startswith("d/s"):
        return math.pi / 180.0, "deg/s"
    if column.startswith("Gyr"):
        return 1.0, "rad/s (no unit in the log: IMU gyros are logged in rad/s)"
    return math.pi / 180.0, "deg/s (no unit in the log: ArduPilot logs rates in deg/s)"


# ----------------------------------------------------------------------------- mapping
@dataclass
class Source:
    """Where one role is read: message, instance (None: the first seen), field(s), scale to SI."""

    msg: str
    inst: int | None
    fields: tuple
    scale: float = 1.0
    unit: str = ""


@dataclass
class Choice:
    """The role mapping of one DataFlash log.

    Attributes
    ----------
    plan : dict
        stream (``gnss``, ``velocity``, ``heading``, ``yaw_rate``, ``thrust``) -> :class:`Source`.
    mapping : dict
        role -> ``MSG[.N].Field`` read.
    reasons : dict
        role -> why that source (or why none).
    notes : list of str
        Anything the user should know.
    """

    plan: dict = field(default_factory=dict)
    mapping: dict = field(default_factory=dict)
    reasons: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)


def _resolve(fmts: dict, spec: str, path, role: str) -> tuple[MsgFormat, int | None, str]:
    msg, inst, fld = parse_path(spec)
    f = fmts.get(msg)
    if f is None or f.count == 0:
        have = sorted(n for n, x in fmts.items() if x.count)
        raise InputError(f"{path}: {role}={spec}: no {msg} messages in the log (messages: {listing(have, 1000)})")
    if inst is not None and f.instance is None:
        raise InputError(f"{path}: {role}={spec}: {msg} has no instance field: give {msg}.FIELD")
    if fld and fld not in f.columns:
        raise InputError(f"{path}: {role}={spec}: {msg} has no field {fld!r} (fields: {', '.join(f.columns)})")
    return f, inst, fld


def _name(f: MsgFormat, inst: int | None, fld: str = "") -> str:
    base = f.name if inst is None else f"{f.name}.{inst}"
    return f"{base}.{fld}" if fld else base


def choose_roles(fmts: dict, servo: dict, requested: dict, path) -> Choice:
    """The role mapping of a DataFlash log: ``--topic`` requests honoured, the rest chosen by message and PARM.

    Parameters
    ----------
    fmts : dict
        :func:`formats` of the log.
    servo : dict
        Servo output number -> ``SERVOn_FUNCTION`` value (from the PARM messages).
    requested : dict
        role -> ``MSG[.N].Field`` from ``--topic`` (roles: :data:`ROLES`).
    path : path-like
        The file (named in errors).

    Returns
    -------
    Choice

    Raises
    ------
    InputError
        A role this reader does not know, a message/instance/field not in the log
        (listing what is), or a request of the wrong shape for the role.
    """
    ch = Choice()
    req = dict(requested)
    for role in req:
        if role not in ROLES:
            raise InputError(f"{path}: role {role!r} cannot be read from a DataFlash log (roles: {', '.join(ROLES)})")
    # gnss
    if "gnss" in req:
        f, inst, fld = _resolve(fmts, req["gnss"], path, "gnss")
        if fld:
            raise InputError(f"{path}: gnss={req['gnss']}: give the message only (its Lat/Lng fields are used), "
                             f"e.g. gnss={_name(f, inst)}")
        if "Lat" not in f.columns or "Lng" not in f.columns:
            raise InputError(f"{path}: gnss={req['gnss']}: {f.name} has no Lat/Lng fields "
                             f"(fields: {', '.join(f.columns)})")
        ch.plan["gnss"] = Source(f.name, inst, ("Lat", "Lng", "Alt"))
        ch.reasons["gnss"] = "--topic"
    elif fmts.get("GPS") is not None and fmts["GPS"].count:
        f = fmts["GPS"]
        inst = 0 if f.instance else None
        ch.plan["gnss"] = Source("GPS", inst, ("Lat", "Lng", "Alt"))
        ch.reasons["gnss"] = f"GPS messages ({f.count}{', instance 0' if inst is not None else ''})"
    else:
        ch.reasons["gnss"] = "no GNSS in this log (no GPS messages)"
        ch.notes.append("no GNSS in this log (no GPS messages)")
    if "gnss" in ch.plan:
        s = ch.plan["gnss"]
        ch.mapping["gnss"] = _name(fmts[s.msg], s.inst)
    # velocity
    spec = req.get("speed_mps") or req.get("velocity")
    if spec is not None:
        f, inst, fld = _resolve(fmts, spec, path, "speed_mps")
        fld = fld or ("Spd" if "Spd" in f.columns else "")
        if not fld:
            raise InputError(f"{path}: speed_mps={spec}: name the speed field (fields: {', '.join(f.columns)})")
        crs = "GCrs" if fld == "Spd" and "GCrs" in f.columns else ""
        ch.plan["velocity"] = Source(f.name, inst, (fld, crs))
        ch.mapping["speed_mps"] = _name(f, inst, fld)
        ch.reasons["speed_mps"] = "--topic"
    elif "gnss" in ch.plan and {"Spd", "GCrs"} <= set(fmts[ch.plan["gnss"].msg].columns):
        s = ch.plan["gnss"]
        ch.plan["velocity"] = Source(s.msg, s.inst, ("Spd", "GCrs"))
        ch.mapping["speed_mps"] = _name(fmts[s.msg], s.inst, "Spd")
        ch.reasons["speed_mps"] = "the GNSS message's ground speed (m/s) and course (GCrs, deg)"
    # heading
    if "heading" in req:
        f, inst, fld = _resolve(fmts, req["heading"], path, "heading")
        fld = fld or ("Yaw" if "Yaw" in f.columns else "")
        if not fld:
            raise InputError(f"{path}: heading={req['heading']}: name the heading field "
                             f"(fields: {', '.join(f.columns)})")
        scale, what = _angle_scale(f.unit(fld), fld)
        ch.plan["heading"] = Source(f.name, inst, (fld,), scale, what)
        ch.mapping["heading"] = _name(f, inst, fld)
        ch.reasons["heading"] = f"--topic (unit {what})"
    else:
        for msg in ("ATT", "AHR2", "AHRS2"):
            f = fmts.get(msg)
            if f is not None and f.count and "Yaw" in f.columns:
                scale, what = _angle_scale(f.unit("Yaw"), "Yaw")
                ch.plan["heading"] = Source(msg, None, ("Yaw",), scale, what)
                ch.mapping["heading"] = f"{msg}.Yaw"
                ch.reasons["heading"] = f"the attitude's yaw ({what})"
                break
        else:
            ch.reasons["heading"] = "no ATT or AHR2 messages"
    # yaw rate
    if "yaw_rate" in req:
        f, inst, fld = _resolve(fmts, req["yaw_rate"], path, "yaw_rate")
        if not fld:
            raise InputError(f"{path}: yaw_rate={req['yaw_rate']}: name the rate field "
                             f"(fields: {', '.join(f.columns)})")
        scale, what = _rate_scale(f.unit(fld), fld)
        ch.plan["yaw_rate"] = Source(f.name, inst, (fld,), scale, what)
        ch.mapping["yaw_rate"] = _name(f, inst, fld)
        ch.reasons["yaw_rate"] = f"--topic (unit {what})"
    else:
        f = fmts.get("IMU")
        if f is not None and f.count and "GyrZ" in f.columns:
            inst = 0 if f.instance else None
            scale, what = _rate_scale(f.unit("GyrZ"), "GyrZ")
            ch.plan["yaw_rate"] = Source("IMU", inst, ("GyrZ",), scale, what)
            ch.mapping["yaw_rate"] = _name(f, inst, "GyrZ")
            ch.reasons["yaw_rate"] = f"body z gyro of the first IMU ({what})"
    # thrust
    tl, tr = req.get("thrust_left"), req.get("thrust_right")
    if (tl is None) != (tr is None):
        raise InputError(f"{path}: give both --topic thrust_left= and thrust_right=")
    if tl is not None:
        fl, il, kl = _resolve(fmts, tl, path, "thrust_left")
        fr, ir, kr = _resolve(fmts, tr, path, "thrust_right")
        if fl.name != fr.name or il != ir or not kl or not kr:
            raise InputError(f"{path}: thrust_left and thrust_right must be two fields of one message "
                             "(e.g. RCOU.C1 and RCOU.C2)")
        ch.plan["thrust"] = Source(fl.name, il, (kl, kr), 1.0, fl.unit(kl))
        ch.mapping["thrust_left"], ch.mapping["thrust_right"] = _name(fl, il, kl), _name(fl, il, kr)
        ch.reasons["thrust"] = "--topic"
    else:
        left = [n for n, fn in sorted(servo.items()) if fn == FN_THROTTLE_LEFT]
        right = [n for n, fn in sorted(servo.items()) if fn == FN_THROTTLE_RIGHT]
        rc = fmts.get("RCOU")
        if left and right and rc is not None and rc.count and f"C{left[0]}" in rc.columns and \
                f"C{right[0]}" in rc.columns:
            ch.plan["thrust"] = Source("RCOU", None, (f"C{left[0]}", f"C{right[0]}"), 1.0, rc.unit(f"C{left[0]}"))
            ch.mapping["thrust_left"], ch.mapping["thrust_right"] = f"RCOU.C{left[0]}", f"RCOU.C{right[0]}"
            ch.reasons["thrust"] = (f"SERVO{left[0]}_FUNCTION = 73 (throttle left), "
                                    f"SERVO{right[0]}_FUNCTION = 74 (throttle right)")
        else:
            used = ", ".join(f"SERVO{n}_FUNCTION={fn}" for n, fn in sorted(servo.items()) if fn)
            why = ("no SERVOn_FUNCTION = 73/74 parameters (throttle left/right)" if not (left and right)
                   else "no RCOU messages with those channels")
            ch.reasons["thrust"] = why + (f"; outputs set: {used}" if used else "")
            ch.notes.append(f"{why}: thruster outputs not imported (give --topic thrust_left=RCOU.Cn "
                            "--topic thrust_right=RCOU.Cm)" + (f"; outputs set: {used}" if used else ""))
    return ch


def _scan_parm_gps(path, report=None) -> tuple[dict, int | None]:
    """Pass 1: servo functions (PARM) and the UTC - boot offset (ns) of GPS fixes."""
    servo: dict[int, int] = {}
    offs: list[int] = []
    for m in _messages(path, ["PARM", "GPS"]):
        f = _fields(m)
        if f is None:
            continue   # counted in pass 2
        if f["mavpackettype"] == "PARM":
            name, value = str(f.get("Name", "")), _num(f, "Value")
            num = name[5:-9]
            if name.startswith("SERVO") and name.endswith("_FUNCTION") and num.isdigit() and value is not None \
                    and abs(value) < 1e6:
                servo[int(num)] = round(value)
        else:
            week, gms, status, boot = (_num(f, k) for k in ("GWk", "GMS", "Status", "TimeUS"))
            if None not in (week, gms, status, boot) and 0 < week < 1e5 and status >= 3 and 0 <= boot < 2**62:
                gps_s = GPS_EPOCH_UNIX_S + int(week) * 604800 + int(gms) / 1000.0 - LEAP_S
                offs.append(round(gps_s * 1e9) - int(boot) * 1000)
    offset = None
    if offs:
        a = np.asarray(offs, np.int64)
        med = np.sort(a)[(len(a) - 1) // 2]
        offset = int(a[np.flatnonzero(np.abs(a - med) <= 1_000_000_000)[0]])
    return servo, offset


# ----------------------------------------------------------------------------- catalog
def _sample(v):
    if isinstance(v, bytes):
        v = v.decode("utf-8", errors="replace")
    if isinstance(v, float):
        return round(v, 9) if math.isfinite(v) else str(v)
    if isinstance(v, str):
        return " ".join(v.split())[:64]
    return v.item() if hasattr(v, "item") else v


def catalog(path, opts=None) -> Catalog:
    """Every message (and instance) of a DataFlash log with its fields, and the role mapping chosen.

    Parameters
    ----------
    path : path-like
        The ``.bin`` file.
    opts : usvlog.io.importers.ImportOptions, optional
        ``topics`` (role -> ``MSG[.N].Field``) honoured in the mapping.

    Returns
    -------
    Catalog
        Topics named ``MSG`` (``MSG.N`` for each instance of a multi-instance message),
        type = the message name, counts, spans (ns; UTC when a GPS fix gives the offset,
        else since boot), fields with their FMT type and a sample; mapping, reasons and
        notes of :func:`choose_roles`. A message type pymavlink cannot decode is noted.

    Raises
    ------
    FormatError
        Not a DataFlash log, or pymavlink cannot read it.
    InputError
        A ``--topic`` mapping that cannot be honoured.
    """
    fmts = formats(_open(path))
    servo, offset = _scan_parm_gps(path)
    base = "utc" if offset is not None else "boot"
    stats: dict[tuple, list] = {}
    bad = 0
    for m in _messages(path, None):
        f = _fields(m)
        if f is None:
            bad += 1
            continue
        typ = f["mavpackettype"]
        mf = fmts.get(typ)
        inst = f.get(mf.instance) if mf is not None and mf.instance else None
        inst = int(inst) if isinstance(inst, (int, np.integer)) else None
        t = _num(f, "TimeUS")
        st = stats.setdefault((typ, inst), [0, None, None, f])
        st[0] += 1
        if t is not None and 0 <= t < 2**62:
            tn = int(t) * 1000 + (offset or 0)
            st[1] = tn if st[1] is None else min(st[1], tn)
            st[2] = tn if st[2] is None else max(st[2], tn)
    insts: dict[str, int] = {}
    for typ, _inst in stats:
        insts[typ] = insts.get(typ, 0) + 1
    cat = Catalog(source=str(path), format="dataflash", time_base=base)
    for (typ, inst), (n, t0, t1, first) in sorted(stats.items(), key=lambda kv: (kv[0][0], kv[0][1] or 0)):
        mf = fmts.get(typ)
        cols = mf.columns if mf is not None else tuple(k for k in first if k != "mavpackettype")
        types = mf.types if mf is not None else ()
        fields = tuple(FieldInfo(c, types[i] if i < len(types) else "", None, _sample(first.get(c)))
                       for i, c in enumerate(cols))
        name = typ if inst is None or (insts[typ] == 1 and inst == 0) else f"{typ}.{inst}"
        cat.topics.append(TopicInfo(name=name, type=typ, count=n, first_ns=t0, last_ns=t1, fields=fields))
    ch = choose_roles(fmts, servo, dict(getattr(opts, "topics", None) or {}), path)
    cat.mapping, cat.reasons, cat.notes = ch.mapping, ch.reasons, list(ch.notes)
    if bad:
        cat.notes.append(f"{bad} messages pymavlink cannot decode (skipped)")
    return cat


# ----------------------------------------------------------------------------- read
def _gpa_covariance(accs: list, keep: np.ndarray) -> dict:
    """Fix covariance columns (m^2, ENU) from GPA HAcc/VAcc (m) per fix; cov_type 2 (DIAGONAL_KNOWN), else 0."""
    h = np.asarray([np.nan if a[0] is None else a[0] for a in accs], float)[keep]
    v = np.asarray([np.nan if a[1] is None else a[1] for a in accs], float)[keep]
    with np.errstate(invalid="ignore"):
        okh = np.isfinite(h) & (h > 0) & (h < 1e4)
        okv = np.isfinite(v) & (v > 0) & (v < 1e4)
    zero = np.zeros(len(h))
    out = {c: zero for c in ("cov_en_m2", "cov_eu_m2", "cov_ne_m2", "cov_nu_m2", "cov_ue_m2", "cov_un_m2")}
    out["cov_ee_m2"] = out["cov_nn_m2"] = np.where(okh, h * h, 0.0)
    out["cov_uu_m2"] = np.where(okh & okv, v * v, 0.0)
    out["cov_type"] = np.where(okh, 2, 0).astype(np.int64)
    return out


def read(path, opts, report, *, fmt="dataflash", on_mapping=None) -> Iterator[dict]:
    """Role streams from an ArduPilot DataFlash log as one batch (see :mod:`usvlog.io.importers.core`).

    Two passes through pymavlink: PARM/GPS for the thruster channels and the UTC offset
    of the boot clock, then the messages of the mapped roles. Messages pymavlink cannot
    decode, without a usable TimeUS, with a value out of range (|yaw| > 360 deg) or with
    a time stamp that is a lone jump forward are skipped and counted; pymavlink failing
    on the file as a whole is a :class:`~usvlog.errors.FormatError` ``from`` its
    exception.

    Parameters
    ----------
    path : pathlib.Path
        The ``.bin`` file.
    opts : usvlog.io.importers.ImportOptions
        ``topics`` (role -> ``MSG[.N].Field``), ``thrust_unit`` (else from the field's
        unit: us -> pwm_us, else guessed from the range), ``start_utc_ns``.
    report : usvlog.io.importers.core.ImportReport
        Filled with records read, skipped, the mapping used, guesses and notes.
    fmt : str
        Unused (one signature for every reader).
    on_mapping : callable, optional
        Called with ``report`` once the mapping is known.

    Raises
    ------
    FormatError
        Not a DataFlash log, or pymavlink cannot read it.
    InputError
        A ``--topic`` mapping that cannot be honoured (one line listing what exists).
    """
    fmts = formats(_open(path))
    servo, offset_ns = _scan_parm_gps(path)
    ch = choose_roles(fmts, servo, dict(opts.topics), path)
    for role, src in ch.mapping.items():
        if not ch.reasons.get("thrust" if role.startswith("thrust_") else role, "").startswith("--topic"):
            report.guesses[f"topic {role}"] = src
    for note in ch.notes:
        report.note(note)
    if offset_ns is None:
        offset_ns = clock_offset_fallback(opts, report, "boot time")
        # with --start-utc the first sample read is placed at that time (below)
        place_first = bool(opts.start_utc_ns)
    else:
        place_first = False
    by_msg: dict[str, list] = {}
    for stream, src in ch.plan.items():
        by_msg.setdefault(src.msg, []).append(stream)
    cols = {"gnss": ("lat_deg", "lon_deg", "alt_m"), "velocity": ("sog_mps", "cog_rad"),
            "heading": ("heading_rad",), "yaw_rate": ("r_radps",), "thrust": ("left", "right")}
    acc = {s: {k: [] for k in ("t_ns",) + cols[s]} for s in ch.plan}
    # receiver accuracy: GPA (HAcc/VAcc, m) is written with the same TimeUS as its GPS message
    gpa = fmts.get("GPA")
    use_gpa = ("gnss" in ch.plan and ch.plan["gnss"].msg == "GPS" and gpa is not None and gpa.count > 0
               and {"HAcc", "VAcc"} <= set(gpa.columns))
    acc_by_boot: dict[tuple, tuple] = {}
    fix_boot: list[tuple] = []
    first_inst: dict[str, int | None] = {}
    for m in _messages(path, sorted(set(by_msg) | ({"GPA"} if use_gpa else set()))) if by_msg else ():
        report.records += 1
        f = _fields(m)
        if f is None:
            report.skip("dataflash_bad_message", 1, where=f"a {m.get_type()} message pymavlink cannot decode")
            continue
        typ = f["mavpackettype"]
        mf = fmts.get(typ)
        inst = None
        if mf is not None and mf.instance:
            inst = f.get(mf.instance)
            inst = int(inst) if isinstance(inst, (int, np.integer)) else -1
        boot = _num(f, "TimeUS")
        if boot is None:
            report.skip("dataflash_bad_message", 1, where=f"{typ} without TimeUS")
            continue
        if place_first and 0 <= boot < 2**62:
            offset_ns, place_first = int(opts.start_utc_ns) - int(boot) * 1000, False
        t = int(boot) * 1000 + offset_ns
        if not 0 <= t < _T_MAX_NS:   # a damaged TimeUS: not a time int64 ns can hold
            report.skip("dataflash_bad_time", 1, where=f"{typ} at TimeUS {int(boot)}")
            continue
        at = f"{typ} at TimeUS {int(boot)}"
        if typ == "GPA" and use_gpa:
            acc_by_boot[(inst, int(boot))] = (_num(f, "HAcc"), _num(f, "VAcc"))
        for stream in by_msg.get(typ, ()):
            src = ch.plan[stream]
            want = src.inst if src.inst is not None else first_inst.setdefault(typ, inst)
            if inst != want:
                continue
            a = acc[stream]
            if stream == "gnss":
                status = _num(f, "Status") if "Status" in f else 3.0
                if status is None or status < 3:
                    report.skip("gnss_no_fix", 1, where=f"{at}: status {f.get('Status')}")
                    continue
                lat, lon, alt = _num(f, "Lat"), _num(f, "Lng"), _num(f, "Alt")
                if lat is None or lon is None:
                    report.skip("dataflash_bad_message", 1, where=f"{at} without Lat/Lng")
                    continue
                vals = (lat, lon, np.nan if alt is None else alt)
                fix_boot.append((inst, int(boot)))
            elif stream == "velocity":
                spd = _num(f, src.fields[0])
                crs = _num(f, src.fields[1]) if src.fields[1] else None
                if spd is None:
                    report.skip("velocity_nan", 1, where=at)
                    continue
                vals = (spd, np.nan if crs is None or abs(crs) > 720 else math.radians(crs))
            elif stream in ("heading", "yaw_rate"):
                v = _num(f, src.fields[0])
                if v is None:
                    report.skip(f"{stream}_nan", 1, where=f"{at} without {src.fields[0]}")
                    continue
                v *= src.scale
                if stream == "heading" and abs(v) > 2 * math.pi + 1e-9:
                    report.skip("heading_out_of_range", 1, where=f"{at}: {src.fields[0]} {v / src.scale:g}")
                    continue
                vals = (v,)
            else:
                lv, rv = _num(f, src.fields[0]), _num(f, src.fields[1])
                if lv is None or rv is None:
                    report.skip("thrust_nan", 1, where=at)
                    continue
                vals = (lv, rv)
            a["t_ns"].append(t)
            for k, v in zip(cols[stream], vals, strict=True):
                a[k].append(v)
    batch = {}
    for stream, a in acc.items():
        if not a["t_ns"]:
            continue
        t = np.asarray(a["t_ns"], np.int64)
        spike = spike_mask(t)
        report.skip(f"{stream}_time_spike", int(spike.sum()))
        keep = ~spike
        batch[stream] = {k: np.asarray(v, np.int64 if k == "t_ns" else float)[keep] for k, v in a.items()}
        if stream == "gnss" and acc_by_boot:
            batch[stream].update(_gpa_covariance([acc_by_boot.get(b, (None, None)) for b in fix_boot], keep))
    if "thrust" in batch:
        th = batch["thrust"]
        unit = opts.thrust_unit
        if unit is None:
            src = ch.plan["thrust"]
            unit = "pwm_us" if src.unit.lower() in ("us", "pwm") else guess_thrust_unit(th["left"], th["right"])
            if src.unit.lower() not in ("us", "pwm"):
                report.guesses["thrust_unit"] = unit
        th["unit"] = np.full(len(th["t_ns"]), unit, dtype=object)
    streams = {"gnss": "gnss", "speed_mps": "velocity", "heading": "heading", "yaw_rate": "yaw_rate",
               "thrust_left": "thrust", "thrust_right": "thrust"}
    report.mapping.update({r: m for r, m in ch.mapping.items() if streams[r] in batch})
    if on_mapping is not None:
        on_mapping(report)
    yield batch
