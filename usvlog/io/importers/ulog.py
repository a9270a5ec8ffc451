"""PX4 .ulg logs through pyulog.

Roles and the topics they come from (PX4 topic names; every multi-instance copy of a
topic is considered, ``topic.N`` in field paths):

* ``gnss``: ``vehicle_gps_position`` or ``sensor_gps`` (``fix_type`` < 3 is "no fix":
  skipped, counted; ``lat``/``lon`` in 1e-7 deg or ``latitude_deg``/``longitude_deg``)
  -> ``/gnss/fix``, with ``eph``/``epv`` (m) as the diagonal of the position covariance
  (``cov_type`` 2, DIAGONAL_KNOWN in foxglove.LocationFix);
* ``speed_mps``: the GNSS topic's ``vel_m_s`` and ``cog_rad`` (where ``vel_ned_valid``)
  -> ``/gnss/velocity``;
* ``heading``: ``vehicle_attitude.q`` (w, x, y, z; PX4 is NED/FRD already) ->
  ``/compass/heading``; a scalar field given with ``--topic`` is read in rad (deg when
  its name ends in ``_deg``);
* ``yaw_rate``: ``vehicle_angular_velocity.xyz[2]`` (else ``sensor_combined.gyro_rad[2]``),
  rad/s about FRD z -> ``/imu/yaw_rate``;
* ``thrust_left``/``thrust_right``: ``actuator_motors.control[0|1]`` (normalized), else
  ``actuator_outputs.output[0|1]`` (pwm_us) of the instance whose outputs move (every
  instance is compared; the choice and why is noted).

``--topic ROLE=topic[.instance].field[i]`` overrides any of them; a mapping that cannot
be honoured is a one-line error listing what exists. Only the mappings used are
recorded in the report (and so in the log's provenance).

Time: the log's microsecond ``timestamp`` shifted to UTC by the first GPS message whose
``time_utc_usec - timestamp`` agrees (within 1 s) with the median over all fixes;
without one, by ``--start-utc`` (else the Unix epoch, noted).
"""

from __future__ import annotations

import contextlib
import io
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np

from ...errors import FormatError, InputError
from .catalog import Catalog, FieldInfo, TopicInfo
from .core import clock_offset_fallback, foreign, listing
from .sniff import ULOG_MAGIC, file_head
from .thrust_guess import guess_thrust_unit

GNSS_TOPICS = ("vehicle_gps_position", "sensor_gps")
HEADING_TOPICS = ("vehicle_attitude",)
YAW_RATE_FIELDS = (("vehicle_angular_velocity", "xyz[2]"), ("sensor_combined", "gyro_rad[2]"))
THRUST_TOPICS = (("actuator_motors", "control", "normalized"), ("actuator_outputs", "output", "pwm_us"))
ROLES = ("gnss", "heading", "yaw_rate", "thrust", "thrust_left", "thrust_right", "speed_mps", "velocity")
_US_MAX = 2**62 // 1000   # microsecond times beyond this (146 years) are damaged: no int64 ns holds them with an offset


# ----------------------------------------------------------------------------- loading
def _load(path, topics=None):
    """pyulog's ULog of ``path`` (only ``topics`` when given), its console output swallowed."""
    from pyulog import ULog

    if file_head(path, len(ULOG_MAGIC)) != ULOG_MAGIC:
        raise FormatError(f"{path}: not a PX4 ULog file (bad magic bytes)")
    sink = io.StringIO()
    with foreign(path, "not a readable ULog file"), contextlib.redirect_stdout(sink), \
            contextlib.redirect_stderr(sink):
        return ULog(str(path), topics)


def _names(ulog) -> dict:
    """pyulog dataset -> the name field paths use: ``topic``, or ``topic.N`` for a multi-instance topic."""
    multi = {d.name for d in ulog.data_list if d.multi_id > 0}
    return {id(d): (f"{d.name}.{d.multi_id}" if d.name in multi else d.name) for d in ulog.data_list}


def parse_path(spec: str) -> tuple[str, int | None, str]:
    """``topic[.instance][.field[i]]`` -> (topic, instance or None, field path or "").

    Parameters
    ----------
    spec : str
        A ULog field path as ``--topic`` takes it (a leading ``/`` is ignored), e.g.
        ``actuator_outputs.1.output[0]``.

    Returns
    -------
    tuple
        The topic name, the multi-instance number (None: not given) and the field path
        below the topic (``""`` when only a topic is named).
    """
    parts = spec.strip().lstrip("/").split(".")
    inst = None
    if len(parts) > 1 and parts[1].isdigit():
        inst = int(parts.pop(1))
    return parts[0], inst, ".".join(parts[1:])


def _sample(v):
    v = v.item() if hasattr(v, "item") else v
    if isinstance(v, float):
        return round(v, 9)
    return v


def _fields(d) -> tuple[FieldInfo, ...]:
    """Leaf fields of a pyulog dataset; ``x[0]..x[n-1]`` become one array field ``x`` of length n."""
    out: list[FieldInfo] = []
    arrays: dict[str, list] = {}
    for f in d.field_data:
        name = f.field_name
        if name.endswith("]") and "[" in name and "." not in name.rsplit("]", 2)[-2]:
            base = name[:name.rindex("[")]
            if base not in arrays:
                arrays[base] = [f.type_str, []]
                out.append(FieldInfo(base, f.type_str))    # placeholder, replaced below
            arrays[base][1].append(d.data[name][0] if len(d.data[name]) else None)
            continue
        col = d.data.get(name)
        out.append(FieldInfo(name, f.type_str, None, _sample(col[0]) if col is not None and len(col) else None))
    res = []
    for fi in out:
        if fi.path in arrays:
            typ, vals = arrays[fi.path]
            res.append(FieldInfo(fi.path, typ, len(vals), [_sample(v) for v in vals[:16]]))
        else:
            res.append(fi)
    return tuple(res)


# ----------------------------------------------------------------------------- time
def _utc_offset_ns(gps) -> int | None:
    """UTC - boot offset (ns) from a GNSS dataset's ``time_utc_usec``: the first fix agreeing with the median."""
    if gps is None or "time_utc_usec" not in gps.data:
        return None
    tu = np.asarray(gps.data["time_utc_usec"]).astype(np.int64, copy=False)
    ts = np.asarray(gps.data["timestamp"]).astype(np.int64, copy=False)
    ok = np.flatnonzero((tu > 0) & (tu < _US_MAX) & (ts >= 0) & (ts < _US_MAX))
    if not len(ok):
        return None
    off = tu[ok] - ts[ok]
    med = np.sort(off)[(len(off) - 1) // 2]
    first = int(np.flatnonzero(np.abs(off - med) <= 1_000_000)[0])
    return int(off[first]) * 1000


def _time_ns(d, offset_ns: int) -> np.ndarray:
    """The dataset's ``timestamp`` (us since boot) as UTC ns; -1 (dropped, counted) where it is damaged."""
    us = np.asarray(d.data["timestamp"])
    ok = (us >= 0) & (us < _US_MAX)
    t = np.where(ok, us, 0).astype(np.int64) * 1000 + offset_ns
    return np.where(ok & (t >= 0), t, -1)


def spike_mask(t: np.ndarray) -> np.ndarray:
    """Samples whose time is a lone jump forward (later than the two next ones while its
    neighbours are in order): a damaged time stamp that would otherwise make every later
    sample look like it goes backwards.

    Parameters
    ----------
    t : numpy.ndarray
        Sample times (int64 ns), in record order.

    Returns
    -------
    numpy.ndarray
        Boolean mask, True for the samples to drop.
    """
    n = len(t)
    bad = np.zeros(n, bool)
    if n < 3:
        return bad
    i = np.arange(n - 2)
    cand = (t[i] > t[i + 1]) & (t[i] > t[i + 2])
    prev_ok = np.ones(n - 2, bool)
    prev_ok[1:] = t[i[1:] - 1] <= t[i[1:] + 1]
    bad[:-2] = cand & prev_ok
    bad[-2] = t[-2] > t[-1] and t[-3] <= t[-1]
    return bad


# ----------------------------------------------------------------------------- mapping
@dataclass
class Choice:
    """The role mapping of one ULog: for each role the dataset and field(s) read, and why.

    Attributes
    ----------
    plan : dict
        role -> (pyulog dataset, field path(s), unit or kind).
    mapping : dict
        role -> ``topic[.N].field`` path read.
    reasons : dict
        role -> why that source (or why none).
    notes : list of str
        Anything the user should know (candidates passed over).
    """

    plan: dict = field(default_factory=dict)
    mapping: dict = field(default_factory=dict)
    reasons: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)


def _has(d, key: str) -> bool:
    return key in d.data


def _fields_listing(d, name) -> str:
    return f"fields of {name}: {listing(sorted(x.field_name for x in d.field_data), 1000)}"


def _array_len(d, base: str) -> int:
    n = 0
    while f"{base}[{n}]" in d.data:
        n += 1
    return n


class _NotInLog(InputError):
    """A requested topic that the (filtered) load does not hold; the message is rebuilt with every topic."""

    def __init__(self, path, spec, topic, inst):
        super().__init__(f"{path}: topic {topic}{'' if inst is None else f'.{inst}'} is not in the log")
        self.path, self.spec, self.topic, self.inst = path, spec, topic, inst


def _resolve(ulog, names, spec: str, path):
    """``topic[.N][.field]`` -> (dataset, field); errors list the instances or fields that exist."""
    topic, inst, fld = parse_path(spec)
    same = [d for d in ulog.data_list if d.name == topic]
    if not same:
        raise _NotInLog(path, spec, topic, inst)
    if inst is None:
        d = min(same, key=lambda x: x.multi_id)
    else:
        d = next((x for x in same if x.multi_id == inst), None)
        if d is None:
            raise InputError(f"{path}: {spec}: topic {topic} has no instance {inst} "
                             f"(instances: {', '.join(str(x.multi_id) for x in same)})")
    if fld and fld not in d.data and _array_len(d, fld) == 0:
        raise InputError(f"{path}: topic {names[id(d)]} has no field {fld!r} ({_fields_listing(d, names[id(d)])})")
    return d, fld


def _need_scalar(d, names, spec, fld, path, what):
    if not fld:
        raise InputError(f"{path}: {spec}: name the {what} field ({_fields_listing(d, names[id(d)])})")
    if fld not in d.data:
        n = _array_len(d, fld)
        raise InputError(f"{path}: {spec}: {fld} is an array of {n}: give {fld}[i] (i < {n})")


def _activity(d, base: str) -> tuple[int, int]:
    """(channels in use, channels that move) of a command array ``base[i]`` of dataset ``d``."""
    n = _array_len(d, base)
    if "noutputs" in d.data and len(d.data["noutputs"]):
        n = min(n, int(np.max(d.data["noutputs"])))
    moving = 0
    for i in range(n):
        v = np.asarray(d.data[f"{base}[{i}]"], float)
        v = v[np.isfinite(v)]
        if len(v) and float(v.max()) > float(v.min()):
            moving += 1
    return n, moving


def choose_roles(ulog, requested: dict, path) -> Choice:
    """The role mapping of a loaded ULog: ``--topic`` requests honoured, the rest chosen by PX4 topic and structure.

    Parameters
    ----------
    ulog : pyulog.ULog
        The log (loaded with at least the candidate and requested topics).
    requested : dict
        role -> ``topic[.N][.field[i]]`` from ``--topic`` (roles: :data:`ROLES`).
    path : path-like
        The file (named in errors).

    Returns
    -------
    Choice
        The plan, the mapping, the reasons and notes.

    Raises
    ------
    InputError
        A requested role this reader does not know, a topic/instance/field that is not in
        the log (listing what is), or a field of the wrong shape for the role.
    """
    names = _names(ulog)
    ch = Choice()
    req = dict(requested)
    for role in req:
        if role not in ROLES:
            raise InputError(f"{path}: role {role!r} cannot be read from a ULog (roles: {', '.join(ROLES)})")

    def nm(d):
        return names[id(d)]

    # gnss
    gps = None
    if "gnss" in req:
        gps, fld = _resolve(ulog, names, req["gnss"], path)
        if fld:
            raise InputError(f"{path}: gnss={req['gnss']}: give the topic only (its lat/lon fields are found by "
                             f"name), e.g. gnss={nm(gps)}")
        if not ((_has(gps, "lat") and _has(gps, "lon")) or (_has(gps, "latitude_deg") and _has(gps, "longitude_deg"))):
            raise InputError(f"{path}: gnss={req['gnss']}: topic {nm(gps)} has no lat/lon fields "
                             f"({_fields_listing(gps, nm(gps))})")
        ch.reasons["gnss"] = "--topic"
    else:
        cands = [d for d in ulog.data_list if d.name in GNSS_TOPICS]
        if cands:
            gps = max(cands, key=lambda d: (-GNSS_TOPICS.index(d.name), len(d.data["timestamp"]), -d.multi_id))
            ch.reasons["gnss"] = f"{nm(gps)}: the receiver's fixes ({len(gps.data['timestamp'])} messages)"
            others = [nm(d) for d in cands if d is not gps]
            if others:
                ch.notes.append(f"gnss: {nm(gps)} chosen (most messages); also in the log: {', '.join(others)}")
        else:
            ch.reasons["gnss"] = "no GNSS in this log (no vehicle_gps_position or sensor_gps)"
            ch.notes.append("no GNSS in this log")
    if gps is not None:
        ch.plan["gnss"] = (gps, "", "")
        ch.mapping["gnss"] = nm(gps)
    # velocity (speed and course over ground)
    spec = req.get("speed_mps") or req.get("velocity")
    if spec is not None:
        d, fld = _resolve(ulog, names, spec, path)
        if not fld:
            if not _has(d, "vel_m_s"):
                raise InputError(f"{path}: {spec}: no vel_m_s field: name the speed field "
                                 f"({_fields_listing(d, nm(d))})")
            fld = "vel_m_s"
        _need_scalar(d, names, spec, fld, path, "speed")
        ch.plan["speed_mps"] = (d, fld, "")
        ch.mapping["speed_mps"] = f"{nm(d)}.{fld}"
        ch.reasons["speed_mps"] = "--topic"
    elif gps is not None and _has(gps, "vel_m_s"):
        ch.plan["speed_mps"] = (gps, "vel_m_s", "")
        ch.mapping["speed_mps"] = f"{nm(gps)}.vel_m_s"
        ch.reasons["speed_mps"] = f"the GNSS topic's speed (course from {nm(gps)}.cog_rad)"
    # heading
    if "heading" in req:
        d, fld = _resolve(ulog, names, req["heading"], path)
        if fld in ("", "q") and _array_len(d, "q") == 4:
            ch.plan["heading"] = (d, "q", "quaternion")
            ch.mapping["heading"] = f"{nm(d)}.q"
        else:
            _need_scalar(d, names, req["heading"], fld, path, "heading")
            unit = "deg" if fld.endswith("_deg") else "rad"
            ch.plan["heading"] = (d, fld, unit)
            ch.mapping["heading"] = f"{nm(d)}.{fld}"
        ch.reasons["heading"] = "--topic"
    else:
        d = next((x for x in sorted(ulog.data_list, key=lambda x: x.multi_id)
                  if x.name in HEADING_TOPICS and _array_len(x, "q") == 4), None)
        if d is not None:
            ch.plan["heading"] = (d, "q", "quaternion")
            ch.mapping["heading"] = f"{nm(d)}.q"
            ch.reasons["heading"] = "yaw of the attitude quaternion (NED/FRD)"
        else:
            ch.reasons["heading"] = "no vehicle_attitude.q in this log"
    # yaw rate
    if "yaw_rate" in req:
        d, fld = _resolve(ulog, names, req["yaw_rate"], path)
        if fld in ("", "xyz") and _array_len(d, "xyz") >= 3:
            fld = "xyz[2]"
        _need_scalar(d, names, req["yaw_rate"], fld, path, "yaw rate")
        unit = "deg" if "deg" in fld else "rad"
        ch.plan["yaw_rate"] = (d, fld, unit)
        ch.mapping["yaw_rate"] = f"{nm(d)}.{fld}"
        ch.reasons["yaw_rate"] = "--topic"
    else:
        for topic, fld in YAW_RATE_FIELDS:
            d = next((x for x in sorted(ulog.data_list, key=lambda x: x.multi_id)
                      if x.name == topic and _has(x, fld)), None)
            if d is not None:
                ch.plan["yaw_rate"] = (d, fld, "rad")
                ch.mapping["yaw_rate"] = f"{nm(d)}.{fld}"
                ch.reasons["yaw_rate"] = "angular velocity about the body z axis (FRD, rad/s)"
                break
    # thrust
    tl, tr, tb = req.get("thrust_left"), req.get("thrust_right"), req.get("thrust")
    if tb is not None and (tl or tr):
        raise InputError(f"{path}: give either --topic thrust= or thrust_left=/thrust_right=, not both")
    if (tl is None) != (tr is None):
        raise InputError(f"{path}: give both --topic thrust_left= and thrust_right=")
    if tb is not None:
        d, fld = _resolve(ulog, names, tb, path)
        base = fld or next((b for t, b, _ in THRUST_TOPICS if t == d.name), "")
        if _array_len(d, base) < 2:
            raise InputError(f"{path}: thrust={tb}: give a command array of at least 2 ({_fields_listing(d, nm(d))})")
        kl, kr = f"{base}[0]", f"{base}[1]"
        unit = next((u for t, _, u in THRUST_TOPICS if t == d.name), None)
        ch.plan["thrust"] = (d, (kl, kr), unit)
        ch.reasons["thrust"] = "--topic"
    elif tl is not None:
        dl, kl = _resolve(ulog, names, tl, path)
        dr, kr = _resolve(ulog, names, tr, path)
        if dl is not dr:
            raise InputError(f"{path}: thrust_left and thrust_right must be fields of one topic instance "
                             f"(e.g. actuator_outputs.output[2] and actuator_outputs.output[3])")
        _need_scalar(dl, names, tl, kl, path, "thrust")
        _need_scalar(dr, names, tr, kr, path, "thrust")
        unit = next((u for t, _, u in THRUST_TOPICS if t == dl.name), None)
        ch.plan["thrust"] = (dl, (kl, kr), unit)
        ch.reasons["thrust"] = "--topic"
    else:
        for topic, base, unit in THRUST_TOPICS:
            cands = [d for d in sorted(ulog.data_list, key=lambda x: x.multi_id)
                     if d.name == topic and _array_len(d, base) >= 2]
            if not cands:
                continue
            act = {id(d): _activity(d, base) for d in cands}
            best = max(cands, key=lambda d: (act[id(d)][1], act[id(d)][0], len(d.data["timestamp"]), -d.multi_id))
            why = "; ".join(f"{nm(d)}: {act[id(d)][0]} outputs in use, {act[id(d)][1]} moving" for d in cands)
            ch.plan["thrust"] = (best, (f"{base}[0]", f"{base}[1]"), unit)
            ch.reasons["thrust"] = (f"{nm(best)} chosen (the instance whose outputs move most: {why}); "
                                    f"left/right = {base}[0]/{base}[1]")
            if len(cands) > 1:
                ch.notes.append(f"thrust: {ch.reasons['thrust']}")
            break
        else:
            ch.reasons["thrust"] = "no actuator_motors or actuator_outputs in this log"
    if "thrust" in ch.plan:
        d, (kl, kr), _ = ch.plan["thrust"]
        ch.mapping["thrust_left"] = f"{nm(d)}.{kl}"
        ch.mapping["thrust_right"] = f"{nm(d)}.{kr}"
    return ch


def _wanted(requested: dict) -> list[str]:
    return sorted(set(GNSS_TOPICS + HEADING_TOPICS) | {t for t, _ in YAW_RATE_FIELDS}
                  | {t for t, _, _ in THRUST_TOPICS} | {parse_path(s)[0] for s in requested.values()})


def _all_topics_error(err: _NotInLog) -> InputError:
    """The not-in-log error again, listing every topic instance of the file."""
    ulog = _load(err.path)
    names = sorted(_names(ulog).values())
    return InputError(f"{err} (topics: {listing(names, 1000)})")


# ----------------------------------------------------------------------------- catalog
def catalog(path, opts=None) -> Catalog:
    """Every topic instance of a ULog with its fields, and the role mapping chosen.

    Parameters
    ----------
    path : path-like
        The ``.ulg`` file.
    opts : usvlog.io.importers.ImportOptions, optional
        ``topics`` (role -> ``topic[.N].field``) honoured in the mapping.

    Returns
    -------
    Catalog
        Topics named ``topic`` or ``topic.N`` (multi-instance), type = the topic name,
        counts, spans (ns, UTC when the GPS gives it, else since boot), fields (arrays
        with their length and first values); mapping, reasons and notes of
        :func:`choose_roles`.

    Raises
    ------
    FormatError
        Not a ULog file, or pyulog cannot read it.
    InputError
        A ``--topic`` mapping that cannot be honoured.
    """
    ulog = _load(path)
    names = _names(ulog)
    gps = next((d for d in ulog.data_list if d.name in GNSS_TOPICS), None)
    off = _utc_offset_ns(gps)
    base = "utc" if off is not None else "boot"
    cat = Catalog(source=str(path), format="ulog", time_base=base)
    for d in sorted(ulog.data_list, key=lambda x: (x.name, x.multi_id)):
        t = np.asarray(d.data["timestamp"]).astype(np.int64, copy=False)
        t = t[(t >= 0) & (t < _US_MAX)] * 1000 + (off or 0)
        cat.topics.append(TopicInfo(name=names[id(d)], type=d.name, count=len(d.data["timestamp"]),
                                    first_ns=int(t.min()) if len(t) else None,
                                    last_ns=int(t.max()) if len(t) else None, fields=_fields(d)))
    ch = choose_roles(ulog, dict(getattr(opts, "topics", None) or {}), path)
    cat.mapping, cat.reasons, cat.notes = ch.mapping, ch.reasons, ch.notes
    return cat


# ----------------------------------------------------------------------------- read
def _float(d, key) -> np.ndarray:
    with np.errstate(invalid="ignore", over="ignore"):   # damaged values: NaN/inf, dropped and counted later
        return np.asarray(d.data[key], float)


def read(path, opts, report, *, fmt="ulog", on_mapping=None) -> Iterator[dict]:
    """The role streams of a PX4 ULog file as one batch (see :mod:`usvlog.io.importers.core`).

    pyulog loads the whole file (only the candidate and requested topics), so there is a
    single batch: ``gnss`` (deg, m, covariance m^2 from eph/epv), ``velocity`` (m/s,
    rad), ``heading`` (rad), ``yaw_rate`` (rad/s) and ``thrust`` (commands with their
    unit), as this module's docstring describes. Times are the log's microsecond
    ``timestamp`` shifted to ns since the Unix epoch; ``stamp_ns`` equals ``t_ns``.
    Samples whose time stamp is a lone jump forward are skipped and counted
    (``{stream}_time_spike``). pyulog's own console output is swallowed.

    Parameters
    ----------
    path : pathlib.Path
        The ``.ulg`` file.
    opts : usvlog.io.importers.ImportOptions
        ``topics`` (role -> ``topic[.N].field[i]``, any role of :data:`ROLES`),
        ``thrust_unit`` (else normalized for ``actuator_motors``, pwm_us for
        ``actuator_outputs``, else guessed from the range), ``start_utc_ns`` when the log
        has no GPS UTC time.
    report : usvlog.io.importers.core.ImportReport
        Filled with samples read, fixes skipped (no fix), the mapping used, guesses, notes.
    fmt : str
        Unused (one signature for every reader).
    on_mapping : callable, optional
        Called with ``report`` once the mapping is known.

    Raises
    ------
    FormatError
        Not a ULog file, or pyulog cannot read it (``from`` its exception).
    InputError
        A ``--topic`` mapping that cannot be honoured (one line listing what exists).
    """
    requested = dict(opts.topics)
    ulog = _load(path, _wanted(requested))
    try:
        ch = choose_roles(ulog, requested, path)
    except _NotInLog as err:
        raise _all_topics_error(err) from None
    for role, src in ch.mapping.items():
        if ch.reasons.get("thrust" if role.startswith("thrust_") else role) != "--topic":
            report.guesses[f"topic {role}"] = src
    for note in ch.notes:
        report.note(note)
    gps = ch.plan.get("gnss", (None,))[0]
    offset_ns = _utc_offset_ns(gps)
    if offset_ns is None:
        firsts = [int(us[(us >= 0) & (us < _US_MAX)].min()) * 1000 for us in
                  (np.asarray(p[0].data["timestamp"]) for p in ch.plan.values())
                  if ((us >= 0) & (us < _US_MAX)).any()]
        offset_ns = clock_offset_fallback(opts, report, "log time", min(firsts) if firsts else None)
    batch = {}

    def times(d, stream):
        t = _time_ns(d, offset_ns)
        spike = spike_mask(t)
        report.skip(f"{stream}_time_spike", int(spike.sum()))
        return t, ~spike

    if gps is not None:
        t, k = times(gps, "gnss")
        n = len(t)
        if _has(gps, "latitude_deg"):
            lat, lon = _float(gps, "latitude_deg"), _float(gps, "longitude_deg")
            alt = next((_float(gps, a) for a in ("altitude_ellipsoid_m", "altitude_msl_m") if _has(gps, a)),
                       np.full(n, np.nan))
        else:
            lat = np.asarray(gps.data["lat"]).astype(np.int64) * 1e-7
            lon = np.asarray(gps.data["lon"]).astype(np.int64) * 1e-7
            alt = next((np.asarray(gps.data[a]).astype(float) * 1e-3 for a in ("alt_ellipsoid", "alt") if _has(gps, a)),
                       np.full(n, np.nan))
        fix = np.asarray(gps.data["fix_type"]) if _has(gps, "fix_type") else np.full(n, 3)
        nofix = fix < 3
        report.skip("gnss_no_fix", int((nofix & k).sum()))
        report.records += n
        k &= ~nofix
        g = {"t_ns": t[k], "lat_deg": lat[k], "lon_deg": lon[k], "alt_m": alt[k]}
        if _has(gps, "eph"):
            eph = _float(gps, "eph")[k]
            epv = _float(gps, "epv")[k] if _has(gps, "epv") else np.full(len(eph), np.nan)
            with np.errstate(invalid="ignore"):
                okh = np.isfinite(eph) & (eph > 0) & (eph < 1e4)
                okv = np.isfinite(epv) & (epv > 0) & (epv < 1e4)
            zero = np.zeros(len(eph))
            g["cov_ee_m2"] = g["cov_nn_m2"] = np.where(okh, eph * eph, 0.0)
            g["cov_uu_m2"] = np.where(okh & okv, epv * epv, 0.0)
            for c in ("cov_en_m2", "cov_eu_m2", "cov_ne_m2", "cov_nu_m2", "cov_ue_m2", "cov_un_m2"):
                g[c] = zero
            g["cov_type"] = np.where(okh, 2, 0).astype(np.int64)   # 2 = DIAGONAL_KNOWN
        batch["gnss"] = g
    if "speed_mps" in ch.plan:
        d, fld, _ = ch.plan["speed_mps"]
        t, k = times(d, "velocity")
        sog = _float(d, fld)
        cog = _float(d, "cog_rad") if fld == "vel_m_s" and _has(d, "cog_rad") else np.full(len(t), np.nan)
        if fld == "vel_m_s" and _has(d, "vel_ned_valid"):
            valid = np.asarray(d.data["vel_ned_valid"]).astype(bool)
            report.skip("velocity_invalid", int((~valid & k).sum()))
            k &= valid
        if d is not gps:
            report.records += len(t)
        batch["velocity"] = {"t_ns": t[k], "sog_mps": sog[k], "cog_rad": cog[k]}
    if "heading" in ch.plan:
        d, fld, kind = ch.plan["heading"]
        t, k = times(d, "heading")
        if kind == "quaternion":
            w, x, y, z = (_float(d, f"q[{i}]") for i in range(4))
            with np.errstate(invalid="ignore", over="ignore"):
                norm = np.sqrt(w * w + x * x + y * y + z * z)
                badq = ~(np.abs(norm - 1.0) < 0.1)
                psi = np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
            report.skip("heading_bad_quaternion", int((badq & k).sum()))
            k &= ~badq
        else:
            psi = _float(d, fld)
            psi = np.radians(psi) if kind == "deg" else psi
            with np.errstate(invalid="ignore"):
                rng = np.abs(psi) > 2 * np.pi
            report.skip("heading_out_of_range", int((rng & k).sum()))
            k &= ~rng
        report.records += len(t)
        batch["heading"] = {"t_ns": t[k], "heading_rad": psi[k]}
    if "yaw_rate" in ch.plan:
        d, fld, unit = ch.plan["yaw_rate"]
        t, k = times(d, "yaw_rate")
        r = _float(d, fld)
        r = np.radians(r) if unit == "deg" else r
        report.records += len(t)
        batch["yaw_rate"] = {"t_ns": t[k], "r_radps": r[k]}
    if "thrust" in ch.plan:
        d, (kl, kr), unit = ch.plan["thrust"]
        t, k = times(d, "thrust")
        left, right = _float(d, kl), _float(d, kr)
        unit = opts.thrust_unit or unit
        if unit is None:
            unit = guess_thrust_unit(left, right)
            report.guesses["thrust_unit"] = unit
        report.records += len(t)
        batch["thrust"] = {"t_ns": t[k], "left": left[k], "right": right[k],
                           "unit": np.full(int(k.sum()), unit, dtype=object)}
    report.mapping.update({r: m for r, m in ch.mapping.items()
                           if (r.startswith("thrust_") and "thrust" in batch)
                           or {"gnss": "gnss", "speed_mps": "velocity", "heading": "heading",
                               "yaw_rate": "yaw_rate"}.get(r) in batch})
    if on_mapping is not None:
        on_mapping(report)
    yield batch
