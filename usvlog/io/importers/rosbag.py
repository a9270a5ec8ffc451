"""ROS 1 .bag and ROS 2 bags (sqlite3 or mcap storage) through rosbags: no ROS install.

The message definitions embedded in the bag are read one topic at a time: a topic whose
definition cannot be parsed is skipped with a one-line note, the others are read. A bag that
stores none (ROS 2 before Jazzy; a ROS 1 connection with an empty definition) is read with
``--msg-dir DIR`` (:func:`msg_dir_types`: every ``<pkg>/msg/<Name>.msg`` under DIR); without
it its custom topics are skipped with that advice.
:func:`catalog` lists every topic with its type, count, time span and every leaf field path
(types, array lengths, a sample value from the first message); the roles are then chosen
from it by structure (:mod:`usvlog.io.importers.mapping`), so custom message types map
without ``--topic``:

* a message with latitude/longitude fields (``sensor_msgs/NavSatFix`` first) ->
  ``/gnss/fix`` (``status.status < 0`` is "no fix": skipped, counted; the ENU covariance
  is Foxglove's layout already); its speed/track fields -> ``/gnss/velocity``;
* an IMU orientation quaternion (REP-103 ENU yaw, counter-clockwise from east:
  psi_NED = pi/2 - yaw_ENU), another orientation (pose, odometry) or a heading/yaw field
  -> ``/compass/heading`` (a number is clockwise from north: degrees when the field name
  says so or the values exceed 2 pi);
* ``angular_velocity.z`` -> ``/imu/yaw_rate`` (FLU z up: r_FRD = -omega_z);
* left/right fields or a 2-element array on a command-like topic, or two scalar topics
  named left/right -> ``/thrust/command`` (a pair on two topics is held at the left
  topic's times).

``--topic ROLE=/topic[.field.path[i]]`` maps any topic, checked against the catalog first:
a scalar message (``std_msgs/Float64``) maps without ``.data``; a wrong field name is an
error that lists the fields. Header stamps (``header.stamp``) go to ``stamp_ns``; the
bag's record time is ``t_ns``; a GNSS message's own fix time (a ``time`` field in UTC seconds,
as ``gps_common/GPSFix`` has) goes to the batch column ``fix_time_ns`` (-1 when there is
none), so a fix republished with new header stamps can be recognised.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from ...errors import InputError
from .audit import RAW_PREFIX
from .catalog import Catalog, FieldInfo, TopicInfo
from .core import guarded, yaw_from_quaternion_enu
from .mapping import (
    ALT_NAMES,
    LAT_NAMES,
    LON_NAMES,
    apply,
    map_roles,
    propulsion_outside_model,
    split_mapping,
    split_path,
    topic_listing,
)
from .probe import Series
from .rosbag_open import msg_dir_types, opened, printable
from .sniff import ROS1_MAGIC, file_head
from .thrust_guess import guess_thrust_unit

_BASE, _NAME, _ARRAY, _SEQUENCE = 1, 2, 3, 4   # rosbags' Nodetype values
_MAX_EXPAND = 16                               # elements of a message array listed in the catalog
_UTC_MIN_NS = 946_684_800 * 10**9              # 2000-01-01: record times before this are not wall clock
_FIX_TIME_NAMES = ("time", "fix_time", "utc_time", "time_utc", "gps_time")   # a fix's own UTC time, s
_FIX_TIME_MIN_S = 946_684_800.0
PROBE_MESSAGES = 20_000                        # messages of a candidate topic the mapping looks at


def _sample(v):
    """A short JSON-ready sample of a field value."""
    if isinstance(v, (np.ndarray, list, tuple)):
        return [_sample(x) for x in list(v[:4])]
    if isinstance(v, (bool, np.bool_)):
        return bool(v)
    if isinstance(v, (int, np.integer)):
        return int(v)
    if isinstance(v, (float, np.floating)):
        return float(v) if math.isfinite(v) else str(float(v))
    if isinstance(v, str):
        return printable(v, 40)
    return None


def _fields(store, msgtype: str, msg, prefix: str, out: list, depth: int = 0) -> None:
    """Every leaf field path of ``msgtype`` (sample values from ``msg`` when given)."""
    if depth > 12:
        return
    _consts, fields = store.fielddefs[msgtype]
    for name, (node, det) in fields:
        path = f"{prefix}.{name}" if prefix else name
        val = getattr(msg, name, None) if msg is not None else None
        node = int(node)
        if node == _BASE:
            out.append(FieldInfo(path, str(det[0]), None, _sample(val)))
        elif node == _NAME:
            _fields(store, det, val, path, out, depth + 1)
        else:
            (enode, edet), n = det
            length = int(n) if node == _ARRAY else (len(val) if val is not None else None)
            if int(enode) == _BASE:
                typ = str(edet[0]) + ("" if node == _ARRAY else "[]")
                out.append(FieldInfo(path, typ, length if length is not None else 0, _sample(val)))
            else:
                for i in range(min(length or 0, _MAX_EXPAND)):
                    _fields(store, edet, val[i] if val is not None else None, f"{path}[{i}]", out, depth + 1)


def _scan(reader, path: Path, fmt: str) -> Catalog:
    """One pass over the bag: counts, spans and the first message of every topic -> Catalog."""
    conns = reader.connections
    bad = getattr(reader, "bad_types", {})
    by_topic: dict[str, list] = {}
    for c in conns:
        by_topic.setdefault(c.topic, []).append(c)
    counts = {t: 0 for t in by_topic}
    first: dict[str, int] = {}
    last: dict[str, int] = {}
    first_raw: dict = {}
    indexes = [getattr(getattr(c, "owner", None), "indexes", None) for c in conns]
    if conns and all(isinstance(ix, dict) and c.id in ix for c, ix in zip(conns, indexes)):
        # ROS 1: counts and spans from the bag's index; only the first message of each topic is read
        for c, ix in zip(conns, indexes):
            times = [int(x.time) for x in ix[c.id]]
            counts[c.topic] += len(times)
            if times:
                first[c.topic] = min(first.get(c.topic, times[0]), min(times))
                last[c.topic] = max(last.get(c.topic, times[-1]), max(times))
        for t, cs in by_topic.items():
            good = [c for c in cs if c.msgtype not in bad and counts[t]]
            if good:
                for conn, _t_ns, raw in guarded(reader.messages(connections=good), path,
                                                "damaged bag while listing its topics"):
                    first_raw[t] = (conn, raw)
                    break
    else:
        for conn, t_ns, raw in guarded(reader.messages(), path, "damaged bag while listing its topics"):
            t = conn.topic
            counts[t] += 1
            first.setdefault(t, int(t_ns))
            last[t] = int(t_ns)
            if t not in first_raw and conn.msgtype not in bad:
                first_raw[t] = (conn, raw)
    topics = []
    for name, cs in sorted(by_topic.items()):
        types = sorted({c.msgtype for c in cs})
        msgtype = types[0]
        note = ""
        fields: list = []
        if len(types) > 1:
            note = f"several message types ({', '.join(printable(x) for x in types)})"
        elif msgtype in bad:
            note = f"{bad[msgtype]} ({printable(msgtype)})"
        else:
            msg = None
            if name in first_raw:
                try:
                    msg = reader.deserialize(first_raw[name][1], msgtype)
                except Exception:  # noqa: BLE001 -- rosbags' deserializer on a message from the file
                    msg = None
            try:
                _fields(reader.typestore, msgtype, msg, "", fields)
            except KeyError:
                note, fields = (f"its message definition cannot be read ({printable(msgtype)}; give --msg-dir "
                                "DIR with the package's .msg files)"), []
        topics.append(TopicInfo(name=printable(name, 200), type=printable(msgtype, 200), count=counts[name],
                                first_ns=first.get(name), last_ns=last.get(name), fields=tuple(fields), note=note))
    starts = [v for v in first.values()]
    base = "utc" if starts and min(starts) >= _UTC_MIN_NS else "relative"
    return Catalog(source=str(path), format=fmt, topics=topics, time_base=base)


def _fmt_of(path: Path, fmt: str | None) -> str:
    if fmt in ("ros1", "ros2"):
        return fmt
    return "ros1" if file_head(path, 16).startswith(ROS1_MAGIC) else "ros2"


def catalog(path, opts=None, *, fmt: str | None = None) -> Catalog:
    """Every topic of a bag: type, count, time span and leaf field paths (one pass over the bag).

    Parameters
    ----------
    path : path-like
        A ROS 1 ``.bag`` file, a ROS 2 bag directory or its ``.db3``/``.mcap`` file.
    opts : usvlog.io.importers.ImportOptions, optional
        Not used (the mapping is filled by :func:`usvlog.io.importers.mapping.apply`).
    fmt : str, optional
        ``"ros1"`` or ``"ros2"``; from the content when None.

    Returns
    -------
    Catalog
        Topics sorted by name (times: the bag's record times, ns since the Unix epoch;
        ``time_base`` ``"utc"`` unless they start before 2000, then ``"relative"``). A topic
        whose message definition cannot be read has a ``note`` and no fields.

    Raises
    ------
    FormatError
        rosbags cannot open or read the bag.
    """
    p = Path(path)
    f = _fmt_of(p, fmt)
    types, registered = msg_dir_types(getattr(opts, "msg_dirs", ()) or ())
    with opened(p, f, types) as reader:
        cat = _scan(reader, p, f)
        apply(cat, getattr(opts, "topics", None), series=_Probe(reader, p))   # the values judge the candidates
    cat.msg_dirs = list(registered)
    cat.notes.extend(msg_dir_notes(registered, cat))
    return cat


def msg_dir_notes(registered: dict[str, list[str]], cat: Catalog) -> list[str]:
    """One line per ``--msg-dir``: the types registered from it and the topics read with them.

    Parameters
    ----------
    registered : dict
        directory -> type names, as :func:`msg_dir_types` returns.
    cat : Catalog
        The bag's topics (those whose type a directory gave, and that could be read, are named).

    Returns
    -------
    list of str
    """
    out = []
    for d, names in registered.items():
        used = [t.name for t in cat.topics if t.type in names and not t.note]
        out.append(f"--msg-dir {d}: {len(names)} message types registered ({', '.join(names[:12])}"
                   + (", ..." if len(names) > 12 else "") + ")"
                   + (f"; topics read with them: {', '.join(used)}" if used else "; no topic of the bag uses them"))
    return out


def _get(obj, parts):
    """The value at a split field path, or None when the message does not have it."""
    for part in parts:
        if isinstance(part, int):
            if not isinstance(obj, (list, tuple, np.ndarray)) or part >= len(obj):
                return None
            obj = obj[part]
        elif part.startswith("_") or not hasattr(obj, part):
            return None
        else:
            obj = getattr(obj, part)
    return obj


def _first_attr(obj, names):
    for n in names:
        for cand in (n, n.upper(), n.capitalize()):
            if hasattr(obj, cand):
                return getattr(obj, cand)
    return None


def _number(obj) -> float | None:
    """A message field as a float; None when it is not a number."""
    if isinstance(obj, (bool, np.bool_)) or not isinstance(obj, (int, float, np.integer, np.floating)):
        return None
    return float(obj)


def _stamp(msg) -> int | None:
    h = getattr(msg, "header", None)
    st = getattr(h, "stamp", None)
    if st is None:
        return None
    try:
        return int(st.sec) * 1_000_000_000 + int(getattr(st, "nanosec", getattr(st, "nsec", 0)))
    except (TypeError, ValueError, AttributeError):
        return None


def _angle_unit(path: str) -> str | None:
    low = path.lower()
    if "deg" in low:
        return "deg"
    if "rad" in low:
        return "rad"
    return None


def read(path, opts, report, *, fmt="ros2", on_mapping=None) -> Iterator[dict]:
    """Batches of role streams from a ROS 1 or ROS 2 bag (see :mod:`usvlog.io.importers.core`).

    The bag is listed first (:func:`catalog`), the roles chosen from the listing
    (:func:`usvlog.io.importers.mapping.map_roles`: ``--topic`` mappings first, then by
    structure), then the mapped topics are read. ``t_ns`` is the bag's record time and
    ``stamp_ns`` the message's ``header.stamp`` (the record time when it has none), both ns
    since the Unix epoch; headings are rad clockwise from north, yaw rates rad/s (FRD),
    speeds m/s, courses rad. A file whose name does not match its content is read through a
    symbolic link in a temporary directory, removed at the end.

    Parameters
    ----------
    path : pathlib.Path
        The bag: a ROS 1 ``.bag`` file, a ROS 2 bag directory or its ``.db3``/``.mcap`` file.
    opts : usvlog.io.importers.ImportOptions
        ``topics`` (role -> ``/topic[.field.path[i]]``), ``thrust_unit`` (guessed from the
        values when None), ``chunk_rows`` samples per batch, ``msg_dirs`` (``.msg`` files for
        types the bag does not store). Commands outside the twin-thruster model
        (:func:`usvlog.io.importers.mapping.propulsion_outside_model`) go to
        ``report.propulsion`` and their values, as recorded, to ``/raw/<topic>``.
    report : usvlog.io.importers.core.ImportReport
        Filled with messages read, messages skipped by reason, the mapping, guesses and notes
        (skipped topics, ambiguous candidates).
    fmt : str
        ``"ros1"`` or ``"ros2"``.
    on_mapping : callable, optional
        Called with ``report`` once the topic mapping is known.

    Raises
    ------
    FormatError
        The content is not a bag of kind ``fmt``, or rosbags cannot open or read it
        (``from`` its exception).
    InputError
        No topic maps to a role, or a ``--topic`` mapping names a topic or field that does
        not exist or is of the wrong kind (the message lists what exists).
    """
    p = Path(path)
    types, registered = msg_dir_types(getattr(opts, "msg_dirs", ()) or ())
    with opened(p, fmt, types) as reader:
        cat = _scan(reader, p, fmt)
        mapping, reasons, notes = map_roles(cat, opts.topics, series=_Probe(reader, p))
        report.guesses.update({k: reasons[k] for k in ("local_frame", "heading_frame") if k in reasons})
        for n in msg_dir_notes(registered, cat) + notes:
            report.note(n)
        prop = propulsion_outside_model(cat, mapping)
        if prop:
            report.propulsion = prop
            report.note(prop["why"])
        if not mapping:
            raise InputError(f"{p}: no topic maps to a role (give --topic ROLE=/topic[.field]; see usvlog inspect; "
                             f"topics: {topic_listing(cat)})")
        report.mapping.update(mapping)
        report.guesses.update({f"topic {r}": v for r, v in mapping.items() if r not in opts.topics})
        report.guesses.update({f"reason {r}": v for r, v in reasons.items() if r in mapping and r not in opts.topics})
        if on_mapping is not None:
            on_mapping(report)
        yield from _read_mapped(reader, p, cat, mapping, opts, report, prop["commands"] if prop else ())


class _Probe:
    """``probe(topic, path) -> Series``: the first :data:`PROBE_MESSAGES` values of a field (for the mapping).

    A path naming an orientation quaternion (or a quaternion message) gives the heading,
    rad clockwise from north (REP-103 ENU yaw converted). Each topic is read once.
    """

    def __init__(self, reader, path: Path):
        self.reader, self.path = reader, path
        self._msgs: dict[str, list] = {}

    def _messages(self, topic: str) -> list:
        if topic not in self._msgs:
            conns = [c for c in self.reader.connections if c.topic == topic]
            out: list = []
            for conn, t_ns, raw in guarded(self.reader.messages(connections=conns), self.path,
                                           f"damaged bag while reading {topic}"):
                with contextlib.suppress(Exception):   # one message rosbags cannot decode: left out
                    out.append((int(t_ns), self.reader.deserialize(raw, conn.msgtype)))
                if len(out) >= PROBE_MESSAGES:
                    break
            self._msgs[topic] = out
        return self._msgs[topic]

    def __call__(self, topic: str, path: str) -> Series | None:
        parts = split_path(path)
        t, v = [], []
        for t_ns, msg in self._messages(topic):
            obj = _get(msg, parts)
            if obj is not None and all(hasattr(obj, a) for a in ("x", "y", "z", "w")):
                x = float(yaw_from_quaternion_enu(obj.x, obj.y, obj.z, obj.w))
            else:
                n = _number(obj)
                x = math.nan if n is None else n
            t.append(t_ns)
            v.append(x)
        return Series(np.asarray(t, np.int64), np.asarray(v, float)) if t else None


_ORDER = ("gnss", "local_n", "local_e", "heading", "yaw_rate", "course", "speed_mps", "thrust_right", "thrust_left")


def _raw_fields(cat, specs) -> dict[str, list[tuple[str, list]]]:
    """topic -> [(column, split field path)] of the ``TOPIC.field`` specs kept under ``/raw/...``."""
    out: dict[str, list[tuple[str, list]]] = {}
    for spec in specs:
        topic, field = split_mapping(cat, spec)
        col = "_".join(str(x) for x in split_path(field)) or "data"
        out.setdefault(topic, []).append((col, split_path(field)))
    return out


def _read_mapped(reader, path, cat, mapping, opts, report, raw_specs=()) -> Iterator[dict]:
    roles = {r: split_mapping(cat, v) for r, v in mapping.items()}
    parts = {r: split_path(f) for r, (_t, f) in roles.items()}
    by_topic: dict[str, list[str]] = {}
    for r in sorted(roles, key=lambda r: _ORDER.index(r) if r in _ORDER else 99):
        by_topic.setdefault(roles[r][0], []).append(r)
    raw = _raw_fields(cat, raw_specs)
    sel = [c for c in reader.connections if c.topic in by_topic or c.topic in raw]
    buf = _Buf(report)
    for r in ("heading", "course"):
        if r in roles:
            buf.units[r] = _angle_unit(roles[r][1])
            if buf.units[r] is not None:   # the field's name says the unit
                report.guesses[f"{r}_unit"] = buf.units[r]
    held = {"thrust_left": math.nan, "thrust_right": math.nan, "local_n": math.nan}
    pair_same_topic = roles.get("thrust_left", ("a",))[0] == roles.get("thrust_right", ("b",))[0]
    local_same_topic = roles.get("local_n", ("a",))[0] == roles.get("local_e", ("b",))[0]
    buf.heading_enu = report.guesses.get("heading_frame") == "enu"
    local_frame = {"ned": "x north, y east", "enu": "x east, y north"}.get(report.guesses.get("local_frame", ""),
                                                                         "local_n/local_e as given")
    thrust_unit = opts.thrust_unit
    last_t = None
    last_local: tuple[float, float] | None = None

    def damaged() -> str:
        return "damaged bag" + (f" after t_ns {last_t}" if last_t is not None else "")

    for conn, t_ns, data in guarded(reader.messages(connections=sel), path, damaged):
        report.records += 1
        last_t = t_ns
        try:
            msg = reader.deserialize(data, conn.msgtype)
        except Exception:  # noqa: BLE001 -- rosbags' deserializer on one damaged message: skip it, count it
            report.skip("ros_bad_message", 1, where=f"topic {conn.topic} at t_ns {t_ns}")
            continue
        stamp = _stamp(msg)
        stamp = int(t_ns) if stamp is None else stamp
        course = math.nan
        if conn.topic in raw:
            buf.raw(conn.topic, t_ns, stamp, [(c, _number(_get(msg, fp))) for c, fp in raw[conn.topic]])
        for role in by_topic.get(conn.topic, ()):
            obj = _get(msg, parts[role])
            where = f"topic {conn.topic} at t_ns {t_ns}"
            if obj is None:
                report.skip("ros_missing_field", 1, where=f"{where}: no {roles[role][1]}")
                continue
            if role == "gnss":
                lat, lon = _number(_first_attr(obj, LAT_NAMES)), _number(_first_attr(obj, LON_NAMES))
                if lat is None or lon is None:
                    report.skip("gnss_bad_value", 1, where=where)
                    continue
                if "int" in type(_first_attr(obj, LAT_NAMES)).__name__ and (abs(lat) > 90 or abs(lon) > 180):
                    lat, lon = lat * 1e-7, lon * 1e-7   # degrees x 1e7 (MAVLink-style integers)
                st = getattr(getattr(obj, "status", None), "status", 0)
                if _number(st) is not None and int(st) < 0:
                    report.skip("gnss_no_fix", 1, where=f"{where}: status {st}")
                    continue
                alt = _number(_first_attr(obj, ALT_NAMES))
                cov = getattr(obj, "position_covariance", None)
                ctype = _number(getattr(obj, "position_covariance_type", 0)) or 0
                fix_s = _number(_first_attr(obj, _FIX_TIME_NAMES))
                fix_ns = int(round(fix_s * 1e9)) if fix_s is not None and _FIX_TIME_MIN_S < fix_s < 4e9 else -1
                buf.gnss(t_ns, stamp, lat, lon, math.nan if alt is None else alt, cov, int(ctype), conn.topic, fix_ns)
            elif role == "heading":
                q = getattr(obj, "orientation", obj)
                if all(hasattr(q, a) for a in ("x", "y", "z", "w")):
                    cov = getattr(obj, "orientation_covariance", None)
                    if cov is not None and len(cov) and cov[0] == -1.0:
                        report.skip("heading_unknown", 1)
                        continue
                    buf.heading(t_ns, stamp, float(yaw_from_quaternion_enu(q.x, q.y, q.z, q.w)), "rad")
                else:
                    v = _number(obj)
                    if v is None:
                        report.skip("heading_bad_value", 1, where=where)
                        continue
                    buf.heading(t_ns, stamp, v, None)
            elif role == "yaw_rate":
                v = _number(obj)
                if v is None:
                    report.skip("yaw_rate_bad_value", 1, where=where)
                    continue
                flu = "angular_velocity" in roles[role][1]   # REP-103: FLU z up -> FRD z down
                buf.yaw_rate(t_ns, stamp, -v if flu else v)
            elif role in ("local_n", "local_e"):
                v = _number(obj)
                if v is None:
                    report.skip("local_bad_value", 1, where=where)
                    continue
                if role == "local_n":
                    held["local_n"] = v
                    continue
                if math.isfinite(held["local_n"]) and (held["local_n"], v) == last_local:
                    # the same position again: a pose held between the navigation's updates (published
                    # faster than it is computed) is one measurement, not many (collapsed, counted)
                    report.skip("local_held_repeat", 1)
                elif math.isfinite(held["local_n"]):
                    last_local = (held["local_n"], v)
                    buf.local(t_ns, stamp, held["local_n"], v, f"{roles['local_n'][0].strip('/')} ({local_frame})")
                else:
                    report.skip("local_incomplete", 1, where=where)
                if local_same_topic:
                    held["local_n"] = math.nan
            elif role == "course":
                v = _number(obj)
                course = math.nan if v is None else v
            elif role == "speed_mps":
                v = _number(obj)
                if v is None:
                    report.skip("velocity_bad_value", 1, where=where)
                    continue
                same = roles.get("course", ("",))[0] == conn.topic
                buf.velocity(t_ns, stamp, v, course if same else math.nan)
            else:
                v = _number(obj)
                held[role] = math.nan if v is None else v
                if role == "thrust_left":
                    if math.isfinite(held["thrust_right"]) and v is not None:
                        buf.thrust(t_ns, stamp, held["thrust_left"], held["thrust_right"])
                    else:
                        report.skip("thrust_incomplete", 1, where=where)
                    if pair_same_topic:
                        held["thrust_right"] = math.nan
        if buf.n >= opts.chunk_rows:
            batch, thrust_unit = buf.batch(thrust_unit)
            yield batch
    batch, _ = buf.batch(thrust_unit)
    yield batch


class _Buf:
    def __init__(self, report):
        self.report = report
        self.units: dict = {}
        self.heading_enu = False
        self._reset()

    def _reset(self):
        self.d = {k: {} for k in ("gnss", "local", "heading", "yaw_rate", "velocity", "thrust")}
        self.rawd: dict[str, dict[str, list]] = {}   # source topic -> column -> values (kept as they are)
        self.n = 0

    def raw(self, topic, t, stamp, vals):
        d = self.rawd.setdefault(topic, {})
        for k, v in [("t_ns", t), ("stamp_ns", stamp)] + list(vals):
            d.setdefault(k, []).append(math.nan if v is None else v)
        self.n += 1

    def _add(self, stream, **vals):
        d = self.d[stream]
        for k, v in vals.items():
            d.setdefault(k, []).append(v)
        self.n += 1

    def gnss(self, t, stamp, lat, lon, alt, cov, ctype, topic, fix_ns=-1):
        extra = {}
        if cov is not None and len(cov) == 9:
            for name, c in zip(("cov_ee_m2", "cov_en_m2", "cov_eu_m2", "cov_ne_m2", "cov_nn_m2", "cov_nu_m2",
                                "cov_ue_m2", "cov_un_m2", "cov_uu_m2"), cov):
                extra[name] = float(c)
        self._add("gnss", t_ns=t, stamp_ns=stamp, lat_deg=lat, lon_deg=lon, alt_m=alt, cov_type=ctype,
                  frame_id=topic.strip("/") or "gnss", fix_time_ns=fix_ns, **extra)

    def heading(self, t, stamp, psi, unit):
        self._add("heading", t_ns=t, stamp_ns=stamp, heading_rad=psi, _unit=unit or "", reference="true")

    def local(self, t, stamp, n, e, frame):
        self._add("local", t_ns=t, stamp_ns=stamp, n_m=n, e_m=e, frame_id=frame)

    def yaw_rate(self, t, stamp, r):
        self._add("yaw_rate", t_ns=t, stamp_ns=stamp, r_radps=r)

    def velocity(self, t, stamp, v, course):
        self._add("velocity", t_ns=t, stamp_ns=stamp, sog_mps=v, cog_rad=course)

    def thrust(self, t, stamp, left, right):
        self._add("thrust", t_ns=t, stamp_ns=stamp, left=left, right=right)

    def _to_rad(self, role: str, v: np.ndarray, fixed: np.ndarray | None = None) -> np.ndarray:
        """Angles in rad: degrees when the field name says so, else when the values exceed 2 pi."""
        todo = np.ones(len(v), bool) if fixed is None else (fixed == "")
        if not todo.any():
            return v
        if self.units.get(role) is None:
            fin = v[todo & np.isfinite(v)]
            if len(fin) == 0:
                return v
            self.units[role] = "deg" if np.abs(fin).max() > 2 * math.pi + 0.1 else "rad"
            self.report.guesses[f"{role}_unit"] = self.units[role]
        if self.units[role] == "deg":
            v = np.where(todo, np.radians(v), v)
        return v

    def batch(self, thrust_unit):
        out = {}
        for stream, d in self.d.items():
            if not d:
                continue
            cols = {k: np.asarray(v, dtype=object if k in ("reference", "frame_id", "_unit") else
                                  (np.int64 if k.endswith("_ns") or k == "cov_type" else float))
                    for k, v in d.items()}
            if stream == "heading":
                fixed = cols.pop("_unit")
                cols["heading_rad"] = self._to_rad("heading", cols["heading_rad"], fixed)
                if self.heading_enu:   # a pose's theta in ENU: counter-clockwise from east -> from north
                    cols["heading_rad"] = np.where(fixed == "", np.pi / 2 - cols["heading_rad"], cols["heading_rad"])
            if stream == "velocity":
                cols["cog_rad"] = self._to_rad("course", cols["cog_rad"])
            if stream == "thrust":
                if thrust_unit is None:
                    thrust_unit = guess_thrust_unit(cols["left"], cols["right"])
                    self.report.guesses["thrust_unit"] = thrust_unit
                cols["unit"] = np.full(len(cols["t_ns"]), thrust_unit, dtype=object)
            out[stream] = cols
        if self.rawd:
            out["raw"] = {RAW_PREFIX + topic: {k: np.asarray(v, np.int64 if k.endswith("_ns") else float)
                                               for k, v in d.items()} for topic, d in self.rawd.items()}
        self._reset()
        return out, thrust_unit
