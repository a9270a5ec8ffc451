"""ROS 1 .bag and ROS 2 bags (sqlite3 or mcap storage) through rosbags: no ROS install.

Automatic topic guesses by message type (printed so the user can correct them):

* ``sensor_msgs/NavSatFix`` -> ``/gnss/fix`` (status < 0 is "no fix": skipped, counted;
  the ENU covariance is Foxglove's layout already);
* ``sensor_msgs/Imu`` -> ``/compass/heading`` from the orientation quaternion
  (REP-103 ENU yaw, counter-clockwise from east: psi_NED = pi/2 - yaw_ENU) and
  ``/imu/yaw_rate`` from ``angular_velocity.z`` (FLU z up: r_FRD = -omega_z);
* ``geometry_msgs/QuaternionStamped``, ``PoseStamped``, ``nav_msgs/Odometry``
  orientations (ENU, as the IMU) -> heading when there is no IMU;
* ``std_msgs/Float32|Float64`` on a topic named like a compass heading -> heading
  (clockwise from north; degrees when the values exceed 2 pi), on topics named
  like left/right thrusters -> ``/thrust/command`` (held at the left topic's times).

``--topic ROLE=/topic[.field.path]`` maps any topic, including custom message types
whose definitions are embedded in the bag, with a dotted path to the field: a number,
a quaternion (x, y, z, w: ENU yaw) or a message with latitude/longitude.
Header stamps (``header.stamp``) go to ``stamp_ns``; the bag's record time is ``t_ns``.
"""

from __future__ import annotations

import math
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from ...errors import FormatError, InputError
from .core import foreign, guarded, guess_thrust_unit, listing, yaw_from_quaternion_enu
from .sniff import MCAP_MAGIC, ROS1_MAGIC, SQLITE_MAGIC, file_head

_FLOATS = {"std_msgs/msg/Float32", "std_msgs/msg/Float64"}
_NAVSAT = "sensor_msgs/msg/NavSatFix"
_IMU = "sensor_msgs/msg/Imu"
_HEADING_NAMES = ("heading", "compass", "hdg")
_ORIENTATION_TYPES = {"geometry_msgs/msg/QuaternionStamped": "quaternion",
                      "geometry_msgs/msg/PoseStamped": "pose.orientation",
                      "nav_msgs/msg/Odometry": "pose.pose.orientation"}
_LEFT_NAMES = ("left", "port")
_RIGHT_NAMES = ("right", "starboard", "stbd")
_THRUST_NAMES = ("thrust", "motor", "cmd", "thruster", "pwm", "esc")


def _open_path(path: Path, fmt: str, stack) -> Path:
    """rosbags picks the reader from the name: give it one that matches the content."""
    if path.is_dir():
        return path
    want = ".bag" if fmt == "ros1" else None
    if fmt == "ros2":
        want = ".mcap" if file_head(path, len(MCAP_MAGIC)).startswith(MCAP_MAGIC) else ".db3"
    if path.suffix == want:
        return path
    tmp = Path(tempfile.mkdtemp(prefix="usvlog-bag-"))
    stack.append(tmp)
    link = tmp / (path.stem + want)
    os.symlink(path.resolve(), link)
    return link


def _check_kind(path: Path, fmt: str) -> None:
    """A forced format must match the content: ROS 1 is one file, ROS 2 a directory or .db3/.mcap file."""
    head = file_head(path, 16)
    if fmt == "ros1" and not head.startswith(ROS1_MAGIC):
        raise FormatError(f"{path}: not a ROS 1 bag (no '#ROSBAG V2.0' header)")
    if fmt == "ros2" and path.is_file() and not head.startswith((SQLITE_MAGIC, MCAP_MAGIC)):
        raise FormatError(f"{path}: not a ROS 2 bag (neither a bag directory nor a sqlite3/mcap file)")


def _field(msg, fpath: str, where: str):
    """The field at dotted path ``fpath`` of a message (``a.b.0.c``: index 0 of a sequence).

    ``where`` names the file and topic for the InputError raised when the path does
    not exist in the message.
    """
    obj = msg
    for part in [x for x in fpath.split(".") if x]:
        if isinstance(obj, (list, tuple, np.ndarray)) and part.isdigit():
            if int(part) >= len(obj):
                raise InputError(f"{where}: no field {fpath!r} (index {part} of {len(obj)} elements)")
            obj = obj[int(part)]
        elif part.startswith("_") or not hasattr(obj, part):
            raise InputError(f"{where}: no field {fpath!r} ({type(obj).__name__} has no {part!r})")
        else:
            obj = getattr(obj, part)
    return obj


def _number(obj, where: str) -> float:
    """A message field as a float; InputError when the mapped field is not a number."""
    if isinstance(obj, (bool, np.bool_)) or not isinstance(obj, (int, float, np.integer, np.floating)):
        raise InputError(f"{where}: the field is a {type(obj).__name__}, not a number "
                         "(map a numeric field with --topic ROLE=/topic.field)")
    return float(obj)


def _stamp(msg) -> int | None:
    h = getattr(msg, "header", None)
    st = getattr(h, "stamp", None)
    if st is None:
        return None
    return int(st.sec) * 1_000_000_000 + int(getattr(st, "nanosec", getattr(st, "nsec", 0)))


def _guess(conns, report) -> dict:
    """role -> (topic, field path or '', how) from message types and topic names."""
    by_topic = {c.topic: c.msgtype for c in conns}
    guess: dict = {}

    def first(pred, prefer=()):
        cands = [t for t, ty in sorted(by_topic.items()) if pred(t, ty)]
        for p in prefer:
            for t in cands:
                if p in t.lower():
                    return t
        return cands[0] if cands else None

    t = first(lambda t, ty: ty == _NAVSAT, ("fix", "gps", "gnss"))
    if t:
        guess["gnss"] = (t, "")
    t = first(lambda t, ty: ty in _FLOATS and any(n in t.lower() for n in _HEADING_NAMES))
    if t:
        guess["heading"] = (t, "data")
    imu = first(lambda t, ty: ty == _IMU, ("imu",))
    if imu:
        guess.setdefault("heading", (imu, ""))
        guess["yaw_rate"] = (imu, "")
    for typ, fpath in _ORIENTATION_TYPES.items():  # other common carriers of an ENU orientation
        t = first(lambda t, ty, typ=typ: ty == typ, _HEADING_NAMES + ("pose", "odom"))
        if t:
            guess.setdefault("heading", (t, fpath))
    for role, names in (("thrust_left", _LEFT_NAMES), ("thrust_right", _RIGHT_NAMES)):
        t = first(lambda t, ty, names=names: ty in _FLOATS and any(n in t.lower() for n in names)
                  and any(n in t.lower() for n in _THRUST_NAMES))
        if t:
            guess[role] = (t, "data")
    return guess


def _parse_spec(spec: str, topics: list[str], path, role: str) -> tuple[str, str]:
    """'/topic.field.path' -> (topic, field path): the longest topic that prefixes the spec."""
    for t in sorted(topics, key=len, reverse=True):
        if spec == t:
            return t, ""
        if spec.startswith(t + "."):
            return t, spec[len(t) + 1:]
    raise InputError(f"{path}: topic {spec.split('.')[0]!r} for role {role} is not in the bag "
                     f"(topics: {listing(sorted(topics)) or 'none'})")


def read(path, opts, report, *, fmt="ros2", on_mapping=None) -> Iterator[dict]:
    """Batches of role streams from a ROS 1 or ROS 2 bag (see :mod:`usvlog.io.importers.core`).

    Topics are mapped as this module's docstring says (``--topic`` mappings first, then
    guesses by message type and topic name). ``t_ns`` is the bag's record time and
    ``stamp_ns`` the message's ``header.stamp`` (the record time when it has none), both ns
    since the Unix epoch; headings are rad clockwise from north, yaw rates rad/s (FRD),
    speeds m/s. A file whose name does not match its content is read through a symbolic
    link in a temporary directory, removed at the end.

    Parameters
    ----------
    path : pathlib.Path
        The bag: a ROS 1 ``.bag`` file, a ROS 2 bag directory or its ``.db3``/``.mcap`` file.
    opts : usvlog.io.importers.ImportOptions
        ``topics`` (role -> ``/topic[.field.path]``), ``thrust_unit`` (guessed from the
        values when None), ``chunk_rows`` samples per batch.
    report : usvlog.io.importers.core.ImportReport
        Filled with messages read, messages skipped by reason, the mapping and guesses.
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
        No topic maps to a role, a given topic is not in the bag, or a mapped field is
        missing or not a number.
    """
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    _check_kind(Path(path), fmt)
    tmpdirs: list[Path] = []
    try:
        bag = _open_path(Path(path), fmt, tmpdirs)
        store = get_typestore(Stores.ROS1_NOETIC if fmt == "ros1" else Stores.ROS2_HUMBLE)
        with foreign(path, f"not a readable {'ROS 1' if fmt == 'ros1' else 'ROS 2'} bag"):
            reader = AnyReader([bag], default_typestore=store)
            reader.open()
        try:
            yield from _read_open(reader, path, opts, report, on_mapping)
        finally:
            reader.close()
    finally:
        for d in tmpdirs:
            for f in d.iterdir():
                f.unlink()
            d.rmdir()


def _read_open(reader, path, opts, report, on_mapping) -> Iterator[dict]:
    conns = reader.connections
    topics = sorted({c.topic for c in conns})
    given = {role: _parse_spec(spec, topics, path, role) for role, spec in opts.topics.items()}
    guessed = {r: v for r, v in _guess(conns, report).items() if r not in given}
    # an IMU picked for heading also gives the yaw rate unless that role was mapped
    roles = {**guessed, **given}
    for r, (t, f) in roles.items():
        report.mapping[r] = t + ("." + f if f else "")
    report.guesses.update({f"topic {r}": t + ("." + f if f else "") for r, (t, f) in guessed.items()})
    if not roles:
        raise InputError(f"{path}: no topic maps to a role (give --topic ROLE=/topic[.field]; topics: "
                         f"{listing(f'{c.topic} [{c.msgtype}]' for c in conns) or 'none'})")
    if on_mapping is not None:
        on_mapping(report)
    wanted = {t for t, _ in roles.values()}
    sel = [c for c in conns if c.topic in wanted]
    by_topic: dict[str, list[str]] = {}
    for r, (t, _f) in roles.items():
        by_topic.setdefault(t, []).append(r)
    buf = _Buf()
    held = {"thrust_left": math.nan, "thrust_right": math.nan}
    heading_deg: bool | None = None
    thrust_unit = opts.thrust_unit
    last_t = None

    def damaged() -> str:
        return "damaged bag" + (f" after t_ns {last_t}" if last_t is not None else "")

    for conn, t_ns, raw in guarded(reader.messages(connections=sel), path, damaged):
        report.records += 1
        last_t = t_ns
        try:
            msg = reader.deserialize(raw, conn.msgtype)
        except Exception:  # noqa: BLE001 -- rosbags' deserializer on one damaged message: skip it, count it
            report.skip("ros_bad_message", 1, where=f"topic {conn.topic} at t_ns {t_ns}")
            continue
        stamp = _stamp(msg)
        stamp = int(t_ns) if stamp is None else stamp
        where = f"{path}: topic {conn.topic} at t_ns {t_ns}"
        for role in by_topic[conn.topic]:
            fpath = roles[role][1]
            obj = _field(msg, fpath, f"{path}: topic {conn.topic} ({conn.msgtype})") if fpath else msg
            if role == "gnss":
                lat = getattr(obj, "latitude", getattr(obj, "lat", None))
                lon = getattr(obj, "longitude", getattr(obj, "lon", None))
                if lat is None or lon is None:
                    raise InputError(f"{path}: topic {conn.topic}: {conn.msgtype} field {fpath or '(message)'} "
                                     "has no latitude/longitude")
                st = getattr(getattr(obj, "status", None), "status", 0)
                if st is not None and int(st) < 0:
                    report.skip("gnss_no_fix", 1, where=f"topic {conn.topic} at t_ns {t_ns}: status {st}")
                    continue
                cov = getattr(obj, "position_covariance", None)
                ctype = int(getattr(obj, "position_covariance_type", 0))
                buf.gnss(t_ns, stamp, _number(lat, where), _number(lon, where),
                         _number(getattr(obj, "altitude", math.nan), where), cov, ctype, conn.topic)
            elif role == "heading":
                q = getattr(obj, "orientation", obj)
                if all(hasattr(q, a) for a in ("x", "y", "z", "w")):
                    cov = getattr(obj, "orientation_covariance", None)
                    if cov is not None and len(cov) and cov[0] == -1.0:
                        report.skip("heading_unknown", 1)
                        continue
                    buf.heading(t_ns, stamp, float(yaw_from_quaternion_enu(q.x, q.y, q.z, q.w)))
                else:
                    v = _number(obj, where)
                    if heading_deg is None and math.isfinite(v):
                        heading_deg = abs(v) > 2 * math.pi + 0.1
                        report.guesses["heading_unit"] = "deg" if heading_deg else "rad"
                    buf.heading(t_ns, stamp, math.radians(v) if heading_deg else v)
            elif role == "yaw_rate":
                w = getattr(obj, "angular_velocity", None)
                r = -_number(w.z, where) if w is not None else _number(obj, where)  # FLU z up -> FRD z down
                buf.yaw_rate(t_ns, stamp, r)
            elif role == "speed_mps":
                buf.velocity(t_ns, stamp, _number(obj, where))
            else:
                held[role] = _number(obj, where)
                if role == "thrust_left" and math.isfinite(held["thrust_right"]):
                    buf.thrust(t_ns, stamp, held["thrust_left"], held["thrust_right"])
                elif role == "thrust_left":
                    report.skip("thrust_incomplete", 1)
        if buf.n >= opts.chunk_rows:
            batch, thrust_unit = buf.batch(thrust_unit, report)
            yield batch
    batch, _ = buf.batch(thrust_unit, report)
    yield batch


class _Buf:
    def __init__(self):
        self.d = {k: {} for k in ("gnss", "heading", "yaw_rate", "velocity", "thrust")}
        self.n = 0

    def _add(self, stream, **vals):
        d = self.d[stream]
        for k, v in vals.items():
            d.setdefault(k, []).append(v)
        self.n += 1

    def gnss(self, t, stamp, lat, lon, alt, cov, ctype, topic):
        extra = {}
        if cov is not None and len(cov) == 9:
            for name, c in zip(("cov_ee_m2", "cov_en_m2", "cov_eu_m2", "cov_ne_m2", "cov_nn_m2", "cov_nu_m2",
                                "cov_ue_m2", "cov_un_m2", "cov_uu_m2"), cov):
                extra[name] = float(c)
        self._add("gnss", t_ns=t, stamp_ns=stamp, lat_deg=lat, lon_deg=lon, alt_m=alt, cov_type=ctype,
                  frame_id=topic.strip("/") or "gnss", **extra)

    def heading(self, t, stamp, psi):
        self._add("heading", t_ns=t, stamp_ns=stamp, heading_rad=psi, reference="true")

    def yaw_rate(self, t, stamp, r):
        self._add("yaw_rate", t_ns=t, stamp_ns=stamp, r_radps=r)

    def velocity(self, t, stamp, v):
        self._add("velocity", t_ns=t, stamp_ns=stamp, sog_mps=v)

    def thrust(self, t, stamp, left, right):
        self._add("thrust", t_ns=t, stamp_ns=stamp, left=left, right=right)

    def batch(self, thrust_unit, report):
        out = {}
        for stream, d in self.d.items():
            if not d:
                continue
            cols = {k: np.asarray(v, dtype=object if k in ("reference", "frame_id") else
                                  (np.int64 if k.endswith("_ns") or k == "cov_type" else float))
                    for k, v in d.items()}
            if stream == "thrust":
                if thrust_unit is None:
                    thrust_unit = guess_thrust_unit(cols["left"], cols["right"])
                    report.guesses["thrust_unit"] = thrust_unit
                cols["unit"] = np.full(len(cols["t_ns"]), thrust_unit, dtype=object)
            out[stream] = cols
        self.__init__()
        return out, thrust_unit
