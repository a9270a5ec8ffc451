"""Which topic and field feeds each role, chosen from a :class:`~.catalog.Catalog` by structure.

Format-independent: only the catalog's topic names, types, field paths, rates and sample
values are looked at, so ROS bags, ULog, DataFlash, NMEA and CSV sources are mapped the
same way:

* a message with latitude and longitude fields (any common spelling, degrees or degrees
  times 1e7) is a ``gnss`` candidate; the mapping names the message (or sub-message) that
  holds them;
* speed fields feed ``speed_mps`` and track/course fields ``course`` (``/gnss/velocity``);
* heading/yaw fields, orientation quaternions and scalar messages on topics named like a
  compass are ``heading`` candidates (a course over ground is listed, never taken);
* left/right field pairs (or 2-element arrays) on command-like topics, or two scalar
  topics named left/right, are ``thrust_left``/``thrust_right`` candidates;
* an angular velocity's z (or a yaw-rate field) is ``yaw_rate``.

Several candidates: the best by plausibility (sample values in range), kind (a standard
message beats a field found by name) and rate is taken and the reason says which and why;
candidates that tie on all of these are listed on one line.

``--topic ROLE=SOURCE.field.path[i]`` mappings (``requested``) are checked against the
catalog first: a topic or field that does not exist is a :class:`~usvlog.errors.InputError`
listing what exists. A scalar message (one numeric field, e.g. ``std_msgs/Float64``) maps
without naming its field.
"""

from __future__ import annotations

import re

import numpy as np

from ...errors import InputError
from .catalog import Catalog, FieldInfo, TopicInfo
from .probe import Series, angle_like, course_agreement

LAT_NAMES = ("latitude", "lat", "lat_deg", "latitude_deg", "lat_e7")
LON_NAMES = ("longitude", "lon", "lng", "long", "lon_deg", "longitude_deg", "lon_e7")
ALT_NAMES = ("altitude", "alt", "alt_m", "altitude_m", "height", "alt_msl")
SPEED_NAMES = ("speed", "sog", "speed_mps", "ground_speed", "groundspeed", "speed_over_ground", "vel_m_s",
               "spd", "gspd")
COURSE_NAMES = ("track", "course", "cog", "course_deg", "cog_deg", "cog_rad", "course_over_ground",
                "track_deg", "crs")
HEADING_NAMES = ("heading", "yaw", "hdg", "heading_deg", "heading_rad", "yaw_deg", "yaw_rad",
                 "true_heading", "compass", "cap")
YAW_RATE_NAMES = ("yaw_rate", "yawrate", "yawspeed", "yaw_speed", "r_radps", "yaw_rate_radps",
                  "yaw_rate_degps")
LEFT_NAMES = ("left", "port", "l", "left_cmd", "left_thrust", "thrust_left", "motor_left", "left_motor")
RIGHT_NAMES = ("right", "starboard", "stbd", "r", "right_cmd", "right_thrust", "thrust_right",
               "motor_right", "right_motor")
COMMAND_WORDS = ("thrust", "motor", "cmd", "command", "pwm", "esc", "actuator", "propul", "servo", "output",
                 "rcou", "throttle", "setpoint")
HEADING_TOPIC_WORDS = ("heading", "compass", "hdg", "cap", "yaw")
NOT_MEASURED_WORDS = frozenset({"desired", "target", "setpoint", "goal", "ref", "reference", "gain", "sigma", "error",
                                "err", "control", "controller", "guidance", "waypoint", "waypoints", "mission",
                                "obstacle", "obstacles", "plan", "planned", "input", "cmd", "command"})
"""Words of a topic name that make it a setpoint, gain or error signal, never a measurement."""
NOT_POSITION_WORDS = frozenset({"vel", "velocity", "twist", "accel", "acceleration", "rate", "speed", "wind",
                                "force", "wrench", "imu", "mag", "gyro", "current"})
POSE_WORDS = frozenset({"pose", "position", "odom", "odometry", "ins", "nav", "local", "mocap", "vicon",
                        "optitrack", "qualisys", "location", "xy", "ned", "enu"})
NUMERIC = ("float", "double", "int", "uint", "byte", "char", "bool", "number")

# roles a --topic may name: the streams above plus the two that expand to a pair
ROLES = ("gnss", "heading", "yaw_rate", "thrust", "thrust_left", "thrust_right", "velocity", "speed_mps",
         "course", "local", "local_n", "local_e")

_INDEX = re.compile(r"^(.*)\[(\d+)\]$")


def leaf(path: str) -> str:
    """Last name of a field path, lower case, without an index (``"pose.Lat[0]"`` -> ``"lat"``)."""
    name = path.rsplit(".", 1)[-1]
    return _INDEX.sub(r"\1", name).lower()


def parent(path: str) -> str:
    """The field path above a leaf (``"fix.latitude"`` -> ``"fix"``; ``"latitude"`` -> ``""``)."""
    return path.rsplit(".", 1)[0] if "." in path else ""


def is_numeric(f: FieldInfo) -> bool:
    """True for a number field (any int/float/bool type name of any format)."""
    t = f.type.lower().split("[")[0]
    return any(t.startswith(n) for n in NUMERIC) or t in ("f", "d", "i", "h", "b", "q", "e", "l", "n", "c")


def split_path(path: str) -> list:
    """``"pose.position[2].x"`` -> ``["pose", "position", 2, "x"]`` (``a.0.b`` is read as ``a[0].b``)."""
    out: list = []
    for tok in re.findall(r"\[\d+\]|[^.\[\]]+", path):
        out.append(int(tok[1:-1]) if tok.startswith("[") else int(tok) if tok.isdigit() else tok)
    return out


def words(name: str) -> set:
    """The lower-case words of a topic name (``"/capRaw"`` -> ``{"cap", "raw"}``)."""
    return {w.lower() for w in re.findall(r"[A-Z]?[a-z]+|[A-Z]+(?![a-z])|\d+", name)}


def _short(x) -> str:
    return " ".join(str(x).split())


def field_listing(topic: TopicInfo, limit: int = 40) -> str:
    """``a, b[3], c.d`` of a topic's field paths, on one line."""
    names = [f.path + (f"[{f.length}]" if f.length is not None else "") for f in topic.fields]
    text = ", ".join(_short(n) for n in names[:limit])
    return (text + (f", ... ({len(names)} in all)" if len(names) > limit else "")) or "none"


def topic_listing(cat: Catalog, limit: int = 40) -> str:
    """``name [type], ...`` of a catalog's topics, each once, on one line."""
    seen = []
    for t in cat.topics:
        item = f"{_short(t.name)} [{_short(t.type)}]"
        if item not in seen:
            seen.append(item)
    text = ", ".join(seen[:limit])
    return (text + (f", ... ({len(seen)} in all)" if len(seen) > limit else "")) or "none"


def _field_at(topic: TopicInfo, path: str) -> tuple[str, list[FieldInfo]]:
    """``("leaf"|"element"|"message", fields)`` for a path below a topic, or ``("", [])`` when absent."""
    norm = normalize(path)
    for f in topic.fields:
        if f.path == norm:
            return "leaf", [f]
    m = _INDEX.match(norm)
    if m:
        for f in topic.fields:
            if f.path == m.group(1) and f.length is not None and int(m.group(2)) < f.length:
                return "element", [f]
    below = [f for f in topic.fields if f.path.startswith(norm + ".") or f.path.startswith(norm + "[")]
    return ("message", below) if below else ("", [])


def normalize(path: str) -> str:
    """A field path in the canonical spelling (``a.0.b`` -> ``a[0].b``)."""
    return "".join(f"[{p}]" if isinstance(p, int) else ("." if i else "") + p
                   for i, p in enumerate(split_path(path)))


def resolve_spec(cat: Catalog, role: str, spec: str) -> tuple[str, str]:
    """``"/topic.field.path[i]"`` -> (topic name, field path) checked against the catalog.

    The longest topic name that prefixes ``spec`` is the topic (topic names may hold dots:
    ``actuator_outputs.1.output[0]``). For the numeric roles a message with a single numeric
    field maps to that field (``/capRaw`` -> ``/capRaw``, ``data``).

    Raises
    ------
    InputError
        The topic is not in the source (the topics are listed), its messages cannot be read,
        or the field does not exist or is not of the role's kind (the fields are listed).
    """
    src = cat.source
    for t in sorted(cat.topics, key=lambda t: len(t.name), reverse=True):
        if spec == t.name:
            topic, path = t, ""
            break
        if spec.startswith(t.name + ".") or spec.startswith(t.name + "["):
            topic, path = t, spec[len(t.name):].lstrip(".")
            break
    else:
        raise InputError(f"{src}: topic {_short(spec.split('.')[0])!r} for role {role} is not in the source "
                         f"(topics: {topic_listing(cat)}; see usvlog inspect)")
    if topic.note:
        raise InputError(f"{src}: topic {topic.name} for role {role} cannot be read ({topic.note})")
    if path:
        kind, found = _field_at(topic, path)
        if not kind:
            raise InputError(f"{src}: topic {topic.name} has no field {_short(path)!r} for role {role} "
                             f"(fields: {field_listing(topic)})")
        path = normalize(path)
    else:
        kind, found = "message", list(topic.fields)
    if role in ("gnss", "velocity", "thrust", "local"):
        if kind != "message":
            raise InputError(f"{src}: role {role} needs a message, {topic.name}.{path} is a single field "
                             f"(fields: {field_listing(topic)})")
        return topic.name, path
    if role == "heading" and kind == "message" and _quaternion(found, path):
        return topic.name, path
    if role == "yaw_rate" and kind == "message":
        az = [f for f in found if re.search(r"angular_velocity(\.z|\[2\])$", f.path)]
        if len(az) == 1:
            return topic.name, az[0].path
    if kind == "message":
        nums = [f for f in found if is_numeric(f) and f.length is None and not _is_stamp(f.path)]
        if len(nums) == 1:
            return topic.name, nums[0].path
        names = ", ".join(f.path for f in nums) or "none"
        raise InputError(f"{src}: {spec!r} for role {role} is a message with {len(nums)} numeric fields: "
                         f"name one (numeric fields: {names})")
    f = found[0]
    if not is_numeric(f) or (kind == "leaf" and f.length is not None):
        raise InputError(f"{src}: {topic.name}.{path} for role {role} is {f.type}"
                         f"{'[' + str(f.length) + ']' if f.length is not None else ''}, not a number "
                         f"(fields: {field_listing(topic)})")
    return topic.name, path


def _is_stamp(path: str) -> bool:
    return path.startswith("header.") or path in ("timestamp", "time_boot_ms", "TimeUS", "seq")


def _quaternion(fields: list[FieldInfo], prefix: str) -> bool:
    names = {f.path[len(prefix) + 1:] if prefix else f.path for f in fields}
    return {"x", "y", "z", "w"} <= names or {"orientation.x", "orientation.y", "orientation.z",
                                             "orientation.w"} <= names


def _num(x) -> float | None:
    try:
        v = float(x)
    except (TypeError, ValueError):
        return None
    return v if v == v else None


def _rate(t: TopicInfo) -> float:
    return t.rate_hz or 0.0


def _join(topic: str, path: str) -> str:
    if not path:
        return topic
    return topic + ("" if path.startswith("[") else ".") + path


class _Cand:
    """One candidate for a role: where, a kind score, plausibility and the rate."""

    def __init__(self, topic: TopicInfo, paths: dict, score: int, why: str, plausible: bool = True):
        self.topic, self.paths, self.score, self.why, self.plausible = topic, paths, score, why, plausible
        self.agree = 0   # heading vs course over ground: 1 agrees, -1 does not, 0 unknown

    def key(self):
        return (self.plausible, self.score, self.agree, round(_rate(self.topic), 1))

    def where(self) -> str:
        return ", ".join(_join(self.topic.name, p) for p in self.paths.values())


def _groups(t: TopicInfo) -> dict[str, dict[str, FieldInfo]]:
    """parent path -> {leaf name: field} of a topic's numeric scalar fields."""
    g: dict[str, dict[str, FieldInfo]] = {}
    for f in t.fields:
        if is_numeric(f) and f.length is None:
            g.setdefault(parent(f.path), {}).setdefault(leaf(f.path), f)
    return g


def _pick(name: str, group: dict[str, FieldInfo]) -> FieldInfo | None:
    for n in name:
        if n in group:
            return group[n]
    return None


def _gnss_candidates(cat: Catalog) -> list[_Cand]:
    out = []
    for t in cat.topics:
        if t.note:
            continue
        for par, g in _groups(t).items():
            lat, lon = _pick(LAT_NAMES, g), _pick(LON_NAMES, g)
            if lat is None or lon is None:
                continue
            la, lo = _num(lat.sample), _num(lon.sample)
            plaus = la is None or lo is None or (abs(la) <= 90 and abs(lo) <= 180) or (
                abs(la) <= 90e7 and abs(lo) <= 180e7 and "int" in lat.type.lower())
            std = "navsatfix" in t.type.lower()
            named = any(w in t.name.lower() for w in ("fix", "gps", "gnss", "gpos"))
            why = (f"{t.type} message" if std else f"fields {lat.path}/{lon.path}") + (
                "" if plaus else f" (sample {lat.sample}, {lon.sample} is not a position)")
            out.append(_Cand(t, {"gnss": par}, 3 if std else (2 if named else 1), why, plaus))
    return out


def _local_candidates(cat: Catalog) -> list[_Cand]:
    """Positions in metres: x/y of a pose (Pose2D, a pose's position, odometry) or of a topic named like one.

    ``paths`` holds ``local_n``/``local_e``: x north and y east when the topic or type is named NED,
    else ROS REP-103 ENU (x east, y north); ``frame`` says which, ``yaw`` names the message's own
    heading (a Pose2D ``theta`` or the pose's orientation quaternion) when it has one.
    """
    out = []
    for t in cat.topics:
        tw = words(t.name + " " + t.type)
        if t.note or _not_measured(t) or tw & NOT_POSITION_WORDS:
            continue
        paths = {f.path for f in t.fields}
        for par, g in _groups(t).items():
            if "x" not in g or "y" not in g or "[" in par or _pick(LAT_NAMES, g) is not None:
                continue
            pose2d = t.type.lower().endswith("pose2d") and par == ""
            posed = leaf(par) == "position" if par else False
            if not (pose2d or posed or tw & POSE_WORDS):
                continue
            ned = "ned" in tw
            x, y = _join(par, "x").lstrip("."), _join(par, "y").lstrip(".")
            c = _Cand(t, {"local_n": x, "local_e": y} if ned else {"local_n": y, "local_e": x},
                      3 if pose2d or posed else 2,
                      f"{t.type} {par or 'x/y'} in metres ("
                      + ("x north, y east: named NED" if ned else "x east, y north: ROS REP-103 ENU") + ")")
            c.frame = "ned" if ned else "enu"  # type: ignore[attr-defined]
            quat = _join(parent(par), "orientation").lstrip(".") if posed else ""
            c.yaw = ("theta" if pose2d and "theta" in g else  # type: ignore[attr-defined]
                     quat if quat and all(f"{quat}.{a}" in paths for a in "xyzw") else "")
            out.append(c)
    return out


def _velocity_candidates(cat: Catalog) -> list[_Cand]:
    out = []
    for t in cat.topics:
        if t.note or _commandlike(t):
            continue
        navlike = bool(words(t.name + " " + t.type) & {"gps", "gnss", "fix", "nav", "vel", "velocity", "sog", "vtg",
                                                       "rmc", "odom", "odometry"})
        for _par, g in _groups(t).items():
            sp = _pick(SPEED_NAMES, g)
            if sp is None:
                continue
            cs = _pick(COURSE_NAMES, g)
            has_pos = _pick(LAT_NAMES, g) is not None
            if not (has_pos or cs is not None or navlike):   # a motor's or a wind sensor's speed is not SOG
                continue
            paths = {"speed_mps": sp.path}
            if cs is not None:
                paths["course"] = cs.path
            v = _num(sp.sample)
            plaus = v is None or 0 <= v < 100
            out.append(_Cand(t, paths, (2 if cs is not None else 1) + (1 if has_pos else 0),
                             f"field {sp.path}" + (f" (course {cs.path})" if cs is not None else ""), plaus))
    return out


def _not_measured(t: TopicInfo) -> str:
    """Why a topic is a setpoint, gain or error signal rather than a measurement ("" when it may be one)."""
    if _commandlike(t):
        return "a command topic"
    hit = sorted(words(t.name) & NOT_MEASURED_WORDS)
    return f"named like a setpoint, gain or error ({hit[0]!r})" if hit else ""


def _heading_candidates(cat: Catalog) -> tuple[list[_Cand], list[str]]:
    out, courses = [], []
    for t in cat.topics:
        if t.note:
            continue
        nums = [f for f in t.fields if is_numeric(f) and f.length is None and not _is_stamp(f.path)]
        tw = words(t.name)
        scalar = len(nums) == 1 and tw & set(HEADING_TOPIC_WORDS) and not tw & {"rate", "speed", "vel"}
        nm = _not_measured(t)
        if nm:   # a heading setpoint, a controller's heading gain or error is not a measurement
            if scalar:
                out.append(_Cand(t, {"heading": nums[0].path}, 0, nm, plausible=False))
            continue
        if scalar:
            out.append(_Cand(t, {"heading": nums[0].path}, 4, "scalar message on a topic named like a heading"))
            continue
        paths = {f.path for f in t.fields}
        for pre in sorted({parent(p) for p in paths if leaf(p) == "w"}):
            if all(_join(pre, a).lstrip(".") in paths for a in ("x", "y", "z")):
                imu = any(p.startswith("angular_velocity") for p in paths) and leaf(pre) == "orientation"
                out.append(_Cand(t, {"heading": pre}, 3 if imu else 1,
                                 "IMU orientation" if imu else f"orientation quaternion {pre}"))
        for f in nums:
            lf = leaf(f.path)
            if lf in HEADING_NAMES or (lf.startswith(("heading", "yaw_")) and "rate" not in lf and "speed" not in lf):
                v = _num(f.sample)
                out.append(_Cand(t, {"heading": f.path}, 2, f"field {f.path}", v is None or abs(v) <= 360))
            elif lf in COURSE_NAMES:
                courses.append(_join(t.name, f.path))
    return out, courses


def _yaw_rate_candidates(cat: Catalog) -> list[_Cand]:
    out = []
    for t in cat.topics:
        if t.note or _commandlike(t):
            continue
        for f in t.fields:
            if f.length is not None:
                continue
            if re.search(r"angular_velocity(\.z|\[2\])$", f.path):
                out.append(_Cand(t, {"yaw_rate": f.path}, 3, "angular velocity z"))
            elif leaf(f.path) in YAW_RATE_NAMES and is_numeric(f):
                out.append(_Cand(t, {"yaw_rate": f.path}, 2, f"field {f.path}"))
    return out


def _commandlike(t: TopicInfo) -> bool:
    """A topic whose name or type has a word starting like a command (``/motors/cmd``, ``actuator_outputs``)."""
    return any(w.startswith(c) for w in words(t.name + " " + t.type) for c in COMMAND_WORDS)


def _thrust_candidates(cat: Catalog, any_topic: bool = False) -> list[_Cand]:
    out = []
    for t in cat.topics:
        if t.note or not (any_topic or _commandlike(t)):
            continue
        for _par, g in _groups(t).items():
            lf, rt = _pick(LEFT_NAMES, g), _pick(RIGHT_NAMES, g)
            if lf is not None and rt is not None:
                out.append(_Cand(t, {"thrust_left": lf.path, "thrust_right": rt.path}, 3,
                                 f"fields {lf.path}/{rt.path} on a command topic"))
        for f in t.fields:
            if f.length == 2 and is_numeric(f):
                out.append(_Cand(t, {"thrust_left": f.path + "[0]", "thrust_right": f.path + "[1]"}, 2,
                                 f"2-element array {f.path} on a command topic"))
    # two scalar topics named left/right (e.g. /thrust/left_cmd, /thrust/right_cmd)
    scal = {}
    for t in cat.topics:
        nums = [f for f in t.fields if is_numeric(f) and f.length is None and not _is_stamp(f.path)]
        if t.note or not _commandlike(t) or len(nums) != 1:
            continue
        words = set(re.split(r"[^a-z]+", t.name.lower()))
        for side, names in (("thrust_left", LEFT_NAMES), ("thrust_right", RIGHT_NAMES)):
            if words & set(names) or any(n in t.name.lower() for n in names if len(n) > 2):
                scal.setdefault(side, (t, nums[0].path))
    if len(scal) == 2:
        (lt, lp), (rt_, rp) = scal["thrust_left"], scal["thrust_right"]
        c = _Cand(lt, {"thrust_left": lp, "thrust_right": rp}, 2, "scalar topics named left/right")
        c.right_topic = rt_  # type: ignore[attr-defined]
        out.append(c)
    return out


RUDDER_WORDS = ("rudder", "steer", "steering")
RUDDER_NAMES = ("delta", "delta_rad", "delta_deg", "delta_cmd")   # the rudder angle's usual symbol
PROPELLER_WORDS = ("rpm", "propeller", "prop", "throttle")
THRUSTER_WORDS = ("thrust", "thruster", "motor", "esc")


def _propulsion_kind(t: TopicInfo, f: FieldInfo, single: bool) -> str | None:
    """``"rudder"``, ``"propeller"`` or None for one numeric field, from its name (and the
    topic's name when the field is the topic's only number)."""
    ws = set(re.split(r"[^a-z0-9]+", leaf(f.path))) | (words(t.name) if single else set())
    if ws & set(RUDDER_WORDS) or leaf(f.path) in RUDDER_NAMES or {"servo", "angle"} <= ws:
        return "rudder"
    if ws & set(PROPELLER_WORDS) or (_commandlike(t) and ws & set(THRUSTER_WORDS)):
        return "propeller"
    return None


def propulsion_outside_model(cat: Catalog, mapping: dict) -> dict | None:
    """Commands the paper's twin-thruster model (differential thrust) does not describe.

    Looked for only when no left/right thrust pair is mapped: numeric fields named like a
    rudder or steering angle (``rudder``, ``steer``, ``delta``, ``servo ... angle``) or a
    propeller speed (``rpm``, ``propeller``, ``prop``, ``throttle``; ``thrust``/``motor`` on a
    command-like topic). A rudder (with or without a propeller), or a single propeller/thruster
    command, is a vessel outside the model; two or more unpaired thruster commands say nothing.

    Parameters
    ----------
    cat : Catalog
        The source's topics and fields.
    mapping : dict
        The role mapping chosen (:func:`map_roles`).

    Returns
    -------
    dict or None
        ``kind`` (``"propeller and rudder"``, ``"rudder"`` or ``"one thruster"``),
        ``commands`` (``TOPIC.field`` of each command found), ``topics`` (their topics),
        ``reason`` (why identify and replay refuse) and ``why`` (one line for the import
        report); None when the vessel may be a twin-thruster boat.
    """
    if "thrust_left" in mapping or "thrust_right" in mapping:
        return None
    found: dict[str, list[str]] = {"rudder": [], "propeller": []}
    topics: list[str] = []
    for t in cat.topics:
        if t.note:
            continue
        nums = [f for f in t.fields if is_numeric(f) and f.length is None and "[" not in f.path
                and not _is_stamp(f.path)]
        for f in nums:
            kind = _propulsion_kind(t, f, len(nums) == 1)
            if kind is not None:
                found[kind].append(_join(t.name, f.path))
                topics.append(t.name)
    rud, prop = found["rudder"], found["propeller"]
    if not rud and len(prop) != 1:
        return None
    kind = "propeller and rudder" if rud and prop else "rudder" if rud else "one thruster"
    cmds = prop + rud
    reason = (f"the paper's twin-thruster model (differential thrust) does not apply to this vessel's "
              f"propulsion: {kind} ({', '.join(cmds)})")
    why = f"propulsion: {reason}; positions and heading are imported, the commands kept as raw data"
    return {"kind": kind, "commands": cmds, "topics": list(dict.fromkeys(topics)), "reason": reason, "why": why}


def _choose(role: str, cands: list[_Cand], reasons: dict, notes: list) -> _Cand | None:
    if not cands:
        return None
    cands = sorted(cands, key=lambda c: c.key(), reverse=True)
    best = cands[0]
    if not best.plausible:
        reasons[role] = "no plausible candidate (" + "; ".join(f"{c.where()}: {c.why}" for c in cands[:5]) + ")"
        return None
    tied = [c for c in cands if c.key() == best.key()]
    if len(tied) > 1:
        notes.append(f"{role}: {len(tied)} equally good candidates: " + "; ".join(c.where() for c in tied)
                     + f" -- took {best.where()} (give --topic {role}=... to choose)")
    why = best.why
    if len(cands) > 1:
        rate = _rate(best.topic)
        why += (f" at {rate:.3g} Hz" if rate else "") + f"; preferred to {cands[1].where()}"
    reasons[role] = why
    return best


# role given as a message -> (its candidates on one topic, what it must have, what to map instead)
_MESSAGE_ROLES = {
    "thrust": (lambda c: _thrust_candidates(c, any_topic=True), "left/right fields or 2-element array",
               "; map thrust_left and thrust_right"),
    "local": (lambda c: _local_candidates(c), "x/y pose fields", "; map local_n and local_e"),
    "velocity": (lambda c: _velocity_candidates(c), "speed field", ""),
}


def _requested_message(cat: Catalog, role: str, spec: str, topic: str, path: str) -> _Cand:
    """The candidate of a message role (``--topic thrust=/motors``) on the topic and below the path given."""
    t = cat.topic(topic)
    assert t is not None
    found, needs, instead = _MESSAGE_ROLES[role]
    cs = [c for c in found(Catalog(cat.source, cat.format, [t]))
          if c.topic is t and all(p.startswith(path) for p in c.paths.values())]
    if not cs:
        raise InputError(f"{cat.source}: {spec!r} for role {role} has no {needs} (fields: {field_listing(t)})"
                         + instead)
    return cs[0]


def map_roles(cat: Catalog, requested: dict | None = None, series=None) -> tuple[dict, dict, list]:
    """Choose the topic and field of every role from a catalog.

    Parameters
    ----------
    cat : Catalog
        The source's topics and field paths (``catalog(path, opts)`` of its reader).
    requested : dict, optional
        role -> ``"TOPIC.field.path[i]"`` given by the user (``--topic``); roles are
        :data:`ROLES` (``thrust`` names a message with a left/right pair or a 2-element
        array, ``velocity`` one with speed and course fields, ``local`` a pose whose x/y are
        metres; ``local_n``/``local_e`` numeric fields in metres north/east).
    series : callable, optional
        ``series(topic, path) -> Series | None``: a candidate's values, from readers that can
        give them (ROS bags). Heading candidates must then behave like an angle
        (:func:`usvlog.io.importers.probe.angle_like`) and are ranked by how often they agree
        with the course over ground; without it, by structure only.

    Returns
    -------
    mapping : dict
        role -> ``"TOPIC.field.path"``: ``gnss`` names the message holding latitude and
        longitude (the topic itself when they are top-level fields), the other roles a
        numeric field (``heading`` may name an orientation quaternion). Requested roles
        come first and are never overridden.
    reasons : dict
        role -> why that source was chosen (or why none was).
    notes : list of str
        One line per ambiguity or skipped topic.

    Raises
    ------
    InputError
        A requested mapping names a topic or field that does not exist, or one of the
        wrong kind (the message lists what exists).
    """
    requested = dict(requested or {})
    pose = None   # the position message in metres, when positions come from one (its frame, its own yaw)
    mapping: dict = {}
    reasons: dict = {}
    notes: list = [f"topic {t.name} skipped: {t.note}" for t in cat.topics if t.note]
    for role, spec in requested.items():
        if role not in ROLES:
            raise InputError(f"unknown role {role!r} (roles: {', '.join(ROLES)})")
        topic, path = resolve_spec(cat, role, spec)
        if role in _MESSAGE_ROLES:   # a message whose fields expand to a pair of roles
            c = _requested_message(cat, role, spec, topic, path)
            for r, p in c.paths.items():
                mapping[r] = _join(topic, p)
                reasons[r] = f"given (--topic {role})" + (f": {c.why}" if role == "local" else "")
            if role == "local":
                reasons["local_frame"] = c.frame  # type: ignore[attr-defined]
                pose = c
        else:
            if role == "gnss":
                t = cat.topic(topic)
                assert t is not None
                g = _groups(t).get(path, {})
                if _pick(LAT_NAMES, g) is None or _pick(LON_NAMES, g) is None:
                    raise InputError(f"{cat.source}: {spec!r} for role gnss has no latitude/longitude fields "
                                     f"(fields: {field_listing(t)})")
            mapping[role] = _join(topic, path)
            reasons[role] = "given (--topic)"
    if "gnss" not in mapping:
        c = _choose("gnss", _gnss_candidates(cat), reasons, notes)
        if c is not None:
            mapping["gnss"] = _join(c.topic.name, c.paths["gnss"])
        else:
            reasons.setdefault("gnss", "no message with latitude and longitude fields")
    if "gnss" not in mapping and not ({"local_n", "local_e"} & set(mapping)):
        pose = _choose("local", _local_candidates(cat), reasons, notes)
        if pose is not None:
            for r, p in pose.paths.items():
                mapping[r] = _join(pose.topic.name, p)
                reasons[r] = reasons["local"]
            reasons["local_frame"] = pose.frame  # type: ignore[attr-defined]
        reasons.pop("local", None)
    if ("local_n" in mapping) != ("local_e" in mapping):
        raise InputError(f"{cat.source}: local positions need both local_n and local_e (give --topic for both)")
    if "speed_mps" not in mapping:
        cands = _velocity_candidates(cat)
        gt = mapping.get("gnss", "\0").split(".")[0]
        for c in cands:  # the GNSS message's own speed first
            if c.topic.name == gt:
                c.score += 2
        c = _choose("speed_mps", cands, reasons, notes)
        if c is not None:
            for r, p in c.paths.items():
                if r not in mapping:
                    mapping[r] = _join(c.topic.name, p)
                    reasons[r] = reasons["speed_mps"]
    if "course" in mapping:   # a course is written with the speed of the same message (/gnss/velocity)
        ct = split_mapping(cat, mapping["course"])[0]
        st = split_mapping(cat, mapping["speed_mps"])[0] if "speed_mps" in mapping else None
        if st != ct:
            if "course" in requested:
                raise InputError(f"{cat.source}: course={requested['course']} needs speed_mps from the same message "
                                 f"(give --topic speed_mps={ct}.FIELD or --topic velocity={ct})")
            notes.append(f"course {mapping.pop('course')} not used: the speed comes from another message")
            reasons.pop("course", None)
    hc, courses = _heading_candidates(cat)
    if "heading" not in mapping:
        if pose is not None and pose.yaw:  # type: ignore[attr-defined]
            hc = [c for c in hc if not (c.topic is pose.topic and c.paths["heading"] == pose.yaw)]  # type: ignore
            hc.append(_Cand(pose.topic, {"heading": pose.yaw}, 5,  # type: ignore[attr-defined]
                            f"the position's own heading ({pose.yaw})"))  # type: ignore[attr-defined]
        if series is not None:
            _check_headings(cat, hc, mapping, series, pose)
        c = _choose("heading", hc, reasons, notes)
        if c is not None:
            mapping["heading"] = _join(c.topic.name, c.paths["heading"])
            if pose is not None and c.topic is pose.topic and pose.frame == "enu":  # type: ignore[attr-defined]
                reasons["heading_frame"] = "enu"   # a Pose2D theta in ENU: counter-clockwise from east
        else:
            reasons.setdefault("heading", "no heading, yaw or orientation field" + (
                f" (course over ground {', '.join(courses)} is not a heading: give --topic heading=... to use it)"
                if courses else ""))
    elif pose is not None and pose.frame == "enu" and mapping["heading"] == _join(pose.topic.name, "theta"):
        reasons["heading_frame"] = "enu"   # the given heading is the ENU pose's theta
    if "yaw_rate" not in mapping:
        c = _choose("yaw_rate", _yaw_rate_candidates(cat), reasons, notes)
        if c is not None:
            mapping["yaw_rate"] = _join(c.topic.name, c.paths["yaw_rate"])
        else:
            reasons.setdefault("yaw_rate", "no angular velocity or yaw-rate field")
    if "thrust_left" not in mapping and "thrust_right" not in mapping:
        c = _choose("thrust", _thrust_candidates(cat), reasons, notes)
        if c is not None:
            rt = getattr(c, "right_topic", c.topic)
            mapping["thrust_left"] = _join(c.topic.name, c.paths["thrust_left"])
            mapping["thrust_right"] = _join(rt.name, c.paths["thrust_right"])
            reasons["thrust_left"] = reasons["thrust_right"] = reasons.pop("thrust")
        else:
            reasons.pop("thrust", None)
            reasons.setdefault("thrust_left", "no left/right command pair on a command-like topic")
    return mapping, reasons, notes


def _positions(cat: Catalog, mapping: dict, series, pose) -> tuple | None:
    """(t_ns, north m, east m) of the mapped positions, for the course over ground (None: none)."""
    if pose is not None:
        sn = series(pose.topic.name, pose.paths["local_n"])
        se = series(pose.topic.name, pose.paths["local_e"])
        if sn is None or se is None or len(sn.v) != len(se.v):
            return None
        return sn.t_ns, sn.v, se.v
    if "gnss" not in mapping:
        return None
    topic, path = split_mapping(cat, mapping["gnss"])
    t = cat.topic(topic)
    g = _groups(t).get(path, {}) if t is not None else {}
    la, lo = _pick(LAT_NAMES, g), _pick(LON_NAMES, g)
    if la is None or lo is None:
        return None
    sa, so = series(topic, la.path), series(topic, lo.path)
    if sa is None or so is None or len(sa.v) != len(so.v) or not len(sa.v):
        return None
    lat0 = float(np.nanmedian(sa.v))
    k = 111_320.0   # m per degree of latitude (enough for a course)
    return sa.t_ns, (sa.v - lat0) * k, (so.v - float(np.nanmedian(so.v))) * k * np.cos(np.radians(lat0))


def _check_headings(cat: Catalog, cands: list, mapping: dict, series, pose) -> None:
    """Heading candidates that do not behave like an angle lose; agreement with the course ranks the rest."""
    pos = _positions(cat, mapping, series, pose)
    for c in cands:
        if not c.plausible:
            continue
        s = series(c.topic.name, c.paths["heading"])
        if s is None:
            continue
        chk = angle_like(s)
        if chk.constant:   # a dead compass is still the compass: the health audit judges it
            c.agree, c.why = -1, f"{c.why} ({chk.why})"
            continue
        if not chk.ok:
            c.plausible, c.why = False, f"{c.why}: not an angle ({chk.why})"
            continue
        if pose is not None and c.topic is pose.topic and pose.frame == "enu" and c.paths["heading"] == "theta":
            s = Series(s.t_ns, np.pi / 2 - (np.radians(s.v) if chk.unit == "deg" else s.v))
            chk = angle_like(s)
        if pos is not None:
            a = course_agreement(s, chk.unit, *pos)
            if a is not None:
                c.agree = 1 if a >= 0.5 else -1 if a < 0.2 else 0
                c.why += f"; within 45 deg of the course over ground {100 * a:.0f} % of the time"


def apply(cat: Catalog, requested: dict | None = None, series=None) -> Catalog:
    """Fill ``cat.mapping``, ``cat.reasons`` and ``cat.notes`` with :func:`map_roles` and return it."""
    mapping, reasons, notes = map_roles(cat, requested, series)
    cat.mapping, cat.reasons = mapping, reasons
    cat.notes = list(dict.fromkeys(list(cat.notes) + list(notes)))
    return cat


def split_mapping(cat: Catalog, spec: str) -> tuple[str, str]:
    """A mapping value ``"TOPIC.field.path"`` -> (topic, field path) by the catalog's topic names."""
    for t in sorted(cat.topics, key=lambda t: len(t.name), reverse=True):
        if spec == t.name:
            return t.name, ""
        if spec.startswith(t.name + ".") or spec.startswith(t.name + "["):
            return t.name, spec[len(t.name):].lstrip(".")
    raise InputError(f"{cat.source}: {spec!r} names no topic of the source")
