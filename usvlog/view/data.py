"""What the viewer and the report draw, pulled out of a FieldLog (pure numpy, no I/O).

Both :mod:`usvlog.view.rrd` (Rerun) and :mod:`usvlog.view.report` (matplotlib) read a log
through these helpers, so they show the same tracks, errors and events. Every
helper returns ``None`` (or an empty list) when the log lacks the channel: a raw
field log draws GPS and compass only, a replayed one draws everything.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, replace

import numpy as np

from ..errors import UnusableResultError
from ..log.fieldlog import FieldLog
from ..log.positions import local_positions, uses_local
from ..log.status import estimate_status
from ..model.frames import Datum, geodetic_to_ned, ned_to_geodetic, ssa, unwrap
from ..model.stats import fit_percent, rms

META_PATH = "usvlog.path"

# controller channel -> (label, state channel it steers, what it is)
CONTROLLERS = (
    ("/control/state", "control", "/truth/state", "closed-loop controller"),
    ("/replay/controller", "replay", "/estimate/state", "replayed controller"),
    ("/replay/whatif/controller", "whatif", "/replay/whatif/state", "what-if controller"),
)
# state channels, in the order they are drawn; the first present is "the boat"
STATES = (
    ("/estimate/state", "estimate", "smoothed estimate"),
    ("/truth/state", "truth", "simulated truth"),
    ("/replay/whatif/state", "whatif", "what-if run"),
)

OVERLAY_HZ = 10.0             # the view's tracks and per-tick overlays are thinned to this rate (Hz)
SPEED_STEP_MIN_MPS = 0.05      # a change of u_d at least this big is a "speed step" event
DROPOUT_FACTOR = 3.0           # a GPS gap longer than this many nominal periods is a dropout


@dataclass(frozen=True)
class Track:
    """Positions of one source over time, local NED metres about the log's datum."""

    name: str
    t_ns: np.ndarray
    n_m: np.ndarray
    e_m: np.ndarray


def thin_indices(t_ns: np.ndarray, max_hz: float) -> np.ndarray:
    """Indices keeping at most ``max_hz`` samples per second of a series stamped ``t_ns`` (int64
    ns): every k-th sample, k from the median step, and the last one.

    Parameters
    ----------
    t_ns : numpy.ndarray
        Time stamps, ns, rising.
    max_hz : float
        Samples per second to keep at most, Hz.

    Returns
    -------
    numpy.ndarray
        Row indices (int).
    """
    if len(t_ns) < 3:
        return np.arange(len(t_ns))
    step = thin_step(float(np.median(np.diff(t_ns))), max_hz)
    k = np.arange(0, len(t_ns), step)
    if k[-1] != len(t_ns) - 1:
        k = np.append(k, len(t_ns) - 1)
    return k


def thin_step(median_dt_ns: float, max_hz: float) -> int:
    """Every how many samples :func:`thin_indices` keeps one, for a series whose median time step is
    ``median_dt_ns`` (ns): at most ``max_hz`` samples per second, at least every sample."""
    dt = median_dt_ns / 1e9
    return max(1, int(round((1.0 / max_hz) / dt))) if dt > 0 else 1


def _col(frame, name):
    if frame is None or name not in frame.columns:
        return None
    a = np.asarray(frame[name].to_numpy(), dtype=float)
    return a


def _times(frame) -> np.ndarray:
    return np.asarray(frame.index.to_numpy(), dtype=np.int64)


def nonempty(log: FieldLog, topic: str):
    """The channel's DataFrame (indexed by t_ns), or None if it is missing or empty."""
    f = log.get(topic)
    return f if f is not None and len(f) else None


def gps(log: FieldLog):
    """(t_ns, lat, lon, n, e) of every GPS fix, or None. n, e are NaN without a datum.

    A log whose positions are in metres (``/local/position``, no fixes) gives those; their
    latitude/longitude are NaN unless the log's datum geo-references them (then there is
    no map, only the local view)."""
    if uses_local(log):
        lp = local_positions(log)
        assert lp is not None
        if lp.geo and log.datum is not None:
            lat, lon, _ = ned_to_geodetic(lp.n_m, lp.e_m, 0.0, datum=log.datum)
        else:
            lat = lon = np.full(len(lp.t_ns), np.nan)
        return lp.t_ns, np.asarray(lat, float), np.asarray(lon, float), lp.n_m, lp.e_m
    f = nonempty(log, "/gnss/fix")
    if f is None:
        return None
    lat, lon = _col(f, "lat_deg"), _col(f, "lon_deg")
    ok = np.isfinite(lat) & np.isfinite(lon)
    t, lat, lon = _times(f)[ok], lat[ok], lon[ok]
    datum = log.datum
    if datum is None and len(lat):
        datum = Datum(lat_deg=float(lat[0]), lon_deg=float(lon[0]))
    n, e, _ = geodetic_to_ned(lat, lon, 0.0, datum=datum) if len(lat) else (lat, lon, None)
    return t, lat, lon, np.asarray(n), np.asarray(e)


def fixes_name(log: FieldLog) -> str:
    """What the log's measured positions are, for labels: ``GPS fixes``, or ``positions`` when they
    are metres from a local channel (an INS pose, motion capture)."""
    return "positions" if uses_local(log) else "GPS fixes"


def path_polyline(log: FieldLog) -> np.ndarray | None:
    """The desired path as an (k, 2) array of [n, e] metres, from the ``usvlog.path`` record."""
    rec = log.meta.get(META_PATH)
    if not rec or "polyline_ne" not in rec:
        return None
    try:
        pts = np.asarray(json.loads(rec["polyline_ne"]), dtype=float).reshape(-1, 2)
    except (ValueError, TypeError):
        return None
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    return pts if len(pts) >= 2 else None


def state_tracks(log: FieldLog) -> list[tuple[str, str, object]]:
    """[(topic, label, frame)] of the state channels present."""
    out = []
    for topic, label, _ in STATES:
        f = nonempty(log, topic)
        if f is not None and "n_m" in f.columns:
            out.append((topic, label, f))
    return out


def boat_state(log: FieldLog):
    """(topic, frame) of the best estimate of where the boat was: estimate, else truth."""
    for topic in ("/estimate/state", "/truth/state"):
        f = nonempty(log, topic)
        if f is not None and "n_m" in f.columns:
            return topic, f
    return None


def controllers(log: FieldLog) -> list[tuple[str, str, object, object, str]]:
    """[(topic, label, controller frame, state frame or None, description)] present in the log."""
    out = []
    for topic, label, state_topic, desc in CONTROLLERS:
        f = nonempty(log, topic)
        if f is None:
            continue
        sf = nonempty(log, state_topic)
        if sf is None and label != "whatif":
            b = boat_state(log)
            sf = b[1] if b else None
        out.append((topic, label, f, sf, desc))
    return out


def interp(t_ns: np.ndarray, frame, column: str, *, angle: bool = False) -> np.ndarray | None:
    """Value of ``column`` of ``frame`` at times ``t_ns`` (linear; angles through unwrap)."""
    y = _col(frame, column)
    if y is None:
        return None
    tf = _times(frame)
    base = tf[0]
    x = (tf - base).astype(float)
    q = (np.asarray(t_ns, dtype=np.int64) - base).astype(float)
    if angle:
        return ssa(np.interp(q, x, unwrap(y)))
    return np.interp(q, x, y)


def heading_pair(t_act, psi_act, t_des, psi_des):
    """Actual and desired heading for display: the actual unwrapped, the desired placed
    within +-pi of the actual at the same time, so the two curves never jump apart by 2 pi."""
    a = unwrap(psi_act)
    at_des = np.interp((t_des - t_act[0]).astype(float), (t_act - t_act[0]).astype(float), a)
    d = at_des + ssa(np.asarray(psi_des, float) - at_des)
    return a, d


def course_over_ground(frame) -> np.ndarray:
    """Course over ground from R(psi) nu + current, rad clockwise from north."""
    psi, u, v = _col(frame, "psi_rad"), _col(frame, "u_mps"), _col(frame, "v_mps")
    cn = _col(frame, "current_n_mps")
    ce = _col(frame, "current_e_mps")
    cn = np.nan_to_num(cn) if cn is not None else 0.0
    ce = np.nan_to_num(ce) if ce is not None else 0.0
    c, s = np.cos(psi), np.sin(psi)
    return np.arctan2(s * u + c * v + ce, c * u - s * v + cn)


def mean_current(frame) -> tuple[float, float] | None:
    """(north, east) m/s: the mean estimated water current over the rows where both are finite
    (the report's current arrow); None without a finite one."""
    cn, ce = _col(frame, "current_n_mps"), _col(frame, "current_e_mps")
    if cn is None or ce is None:
        return None
    ok = np.isfinite(cn) & np.isfinite(ce)
    if not ok.any():
        return None
    return float(cn[ok].mean()), float(ce[ok].mean())


def recorded_tau(log: FieldLog, *, unit: str | None = None, forces: bool | None = None):
    """(t_ns, tau_u, tau_r) from the recorded thrust commands and the vessel's geometry: from the
    forces when any is recorded, else from the commands in the unit of the first row.

    ``unit`` and ``forces`` (whether any force is finite) are the whole channel's when ``log``
    holds a block of its rows (default: the frame's own)."""
    f = nonempty(log, "/thrust/command")
    if f is None:
        return None
    fl, fr = _col(f, "thrust_left_n"), _col(f, "thrust_right_n")
    vessel = log.vessel
    if fl is None or fr is None:
        return None
    if forces is None:
        forces = bool(np.isfinite(fl).any() or np.isfinite(fr).any())
    if vessel is None or not forces:
        if vessel is None:
            return None
        if unit is None:
            unit = str(f["unit"].iloc[0]) if "unit" in f.columns else "newton"
        fl = vessel.thrusters.command_to_force(_col(f, "left"), unit, side="left")
        fr = vessel.thrusters.command_to_force(_col(f, "right"), unit, side="right")
    tu, tr = vessel.thrusters.tau_from_forces(fl, fr)
    return _times(f), np.asarray(tu), np.asarray(tr)


# -----------------------------------------------------------------------------
# events
# -----------------------------------------------------------------------------

@dataclass(frozen=True)
class Event:
    """One line of the event log.

    ``t_ns``: ns since the Unix epoch; ``level``: ``INFO`` or ``WARN``; ``kind``:
    ``warning``, ``estimate_reinit``, ``gps_rejected``, ``<sensor>_rejected``, ``gps_dropout``,
    ``saturation_start``, ``saturation_end`` or ``speed_step``; ``text``: the message.
    """

    t_ns: int
    level: str   # "INFO" | "WARN"
    kind: str    # "gps_rejected" | "<sensor>_rejected" | "gps_dropout" | "saturation_start" | ... | "speed_step"
    text: str


def rejections(log: FieldLog, sensor: str | None = "gnss"):
    """(t_ns, nis, sensor) of measurements the estimator rejected (of one sensor, or all), or None."""
    f = nonempty(log, "/estimate/innovations")
    if f is None or "accepted" not in f.columns or "sensor" not in f.columns:
        return None
    sens = f["sensor"].astype(str).to_numpy()
    acc = np.asarray(f["accepted"].to_numpy(), dtype=bool)
    m = ~acc if sensor is None else (sens == sensor) & ~acc
    nis = _col(f, "nis")
    return _times(f)[m], (nis[m] if nis is not None else np.full(m.sum(), np.nan)), sens[m]


def gps_rejections(log: FieldLog):
    """(t_ns, nis) of GPS fixes the estimator rejected, or None."""
    r = rejections(log, "gnss")
    return None if r is None else r[:2]


def gps_dropouts(log: FieldLog) -> list[tuple[int, int]]:
    """[(start_ns, end_ns)] of gaps between fixes longer than 3 nominal periods (a fix repeated at
    the same position, e.g. republished by several nodes, counts once)."""
    f = nonempty(log, "/gnss/fix")
    if f is None or len(f) < 3:
        return []
    t = _times(f)
    lat, lon = _col(f, "lat_deg"), _col(f, "lon_deg")
    if lat is not None and lon is not None:   # a fix republished (same position again) is not a new fix
        new = np.r_[True, (np.diff(lat) != 0) | (np.diff(lon) != 0)]
        t = t[new]
    if len(t) < 3:
        return []
    dt = np.diff(t)
    period = float(np.median(dt))
    if period <= 0:
        return []
    k = np.nonzero(dt > DROPOUT_FACTOR * period)[0]
    return [(int(t[i]), int(t[i + 1])) for i in k]


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[(first, last)] index ranges where mask is True."""
    m = np.concatenate([[False], mask.astype(bool), [False]])
    d = np.diff(m.astype(np.int8))
    starts, ends = np.nonzero(d == 1)[0], np.nonzero(d == -1)[0] - 1
    return list(zip(starts.tolist(), ends.tolist()))


def saturation_spans(frame) -> list[tuple[int, int]]:
    """[(first_ns, last_ns)] of runs of ``saturated`` controller ticks."""
    if frame is None or "saturated" not in frame.columns:
        return []
    t = _times(frame)
    return [(int(t[a]), int(t[b])) for a, b in _runs(np.asarray(frame["saturated"].to_numpy(), bool))]


def speed_steps(frame) -> list[tuple[int, float, float]]:
    """[(t_ns, from, to)] where the desired speed u_d changes by >= 0.05 m/s.

    A step (one jump) and a prefiltered step (a ramp of small changes) both count once,
    at the tick where u_d starts to move.
    """
    ud = _col(frame, "u_d_mps")
    if ud is None or len(ud) < 2:
        return []
    t = _times(frame)
    moving = np.abs(np.diff(ud)) > 1e-6
    out = []
    for a, b in _runs(moving):
        u0, u1 = float(ud[a]), float(ud[b + 1])
        if abs(u1 - u0) >= SPEED_STEP_MIN_MPS:
            out.append((int(t[a + 1]), u0, u1))
    return out


def _estimate_report(log: FieldLog) -> dict:
    """The report of the latest estimate, from its provenance record ({} without one)."""
    est = None
    for rec in log.provenance:
        if rec.get("producer") == "usvlog estimate":
            est = rec
    if est is None:
        return {}
    try:
        rep = json.loads(est.get("report") or "{}")
    except json.JSONDecodeError:
        return {}
    return rep if isinstance(rep, dict) else {}


def refuse_failed_estimate(log: FieldLog) -> None:
    """Refuse a log whose stored estimate status is ``failed`` (:mod:`usvlog.log.status`):
    nothing is drawn from an estimate its maker disowned.

    Raises
    ------
    usvlog.errors.UnusableResultError
        Naming the log and the status's reasons.
    """
    st = estimate_status(log)
    if st is not None and st.status == "failed":
        raise UnusableResultError(f"{log.source or 'log'}: {st.headline()}; not drawn - estimate it again")


def warnings(log: FieldLog) -> list[str]:
    """What the stages that made this log could not vouch for, in plain words: a degraded
    estimate first (``estimate DEGRADED (gps-only): ...``, from its stored status), then a
    damaged input (``input damaged: ...``) and the estimate's consistency findings
    (``estimate: compass NIS 0.000 ...``), read from the provenance records (the latest
    estimate's only).

    Returns
    -------
    list of str
        One line each; empty for a log whose stages had nothing to say.
    """
    out: list[str] = []
    for rec in log.provenance:
        note = rec.get("input_damage")
        if note and note not in out:
            out.append(note)
    found = [w for w in _estimate_report(log).get("warnings", []) if isinstance(w, str)]
    st = estimate_status(log)
    if st is not None and st.status != "ok":   # first: the figures below rest on it
        own = tuple(r for r in st.reasons if r not in found)   # the findings follow on their own lines
        out.insert(0, replace(st, reasons=own).headline() + (" (sensor findings below)" if len(own) < len(st.reasons)
                                                             else ""))
    return out + [f"estimate: {w}" for w in found]


def events(log: FieldLog) -> list[Event]:
    """Everything worth a line in the event log, sorted by time (the :func:`warnings` first,
    at the start of the log)."""
    ev: list[Event] = []
    tr = log.time_range()
    for w in warnings(log):
        ev.append(Event(tr[0] if tr else 0, "WARN", "warning", w))
    for r in _estimate_report(log).get("reinitialisations", []):
        if isinstance(r, dict) and isinstance(r.get("t_ns"), int):
            ev.append(Event(r["t_ns"], "WARN", "estimate_reinit",
                            f"estimate re-initialised from the measurements after divergence ({r.get('reason', '')})"))
    rej = rejections(log, None)
    if rej is not None:
        for t, nis, s in zip(*rej):
            if s == "gnss":
                ev.append(Event(int(t), "WARN", "gps_rejected", f"GPS fix rejected (NIS {nis:.1f})"))
            else:
                ev.append(Event(int(t), "WARN", f"{s}_rejected", f"{s} measurement rejected (NIS {nis:.1f})"))
    for a, b in gps_dropouts(log):
        ev.append(Event(a, "WARN", "gps_dropout", f"GPS dropout: no fix for {(b - a) / 1e9:.1f} s"))
    for _topic, _label, f, _, desc in controllers(log):
        for a, b in saturation_spans(f):
            ev.append(Event(a, "WARN", "saturation_start", f"{desc}: thrusters saturated"))
            ev.append(Event(b, "INFO", "saturation_end",
                            f"{desc}: saturation ended after {(b - a) / 1e9:.2f} s"))
        for t, u0, u1 in speed_steps(f):
            ev.append(Event(t, "INFO", "speed_step", f"{desc}: speed step u_d {u0:.2f} -> {u1:.2f} m/s"))
    ev.sort(key=lambda e: e.t_ns)
    return ev


def events_once(log: FieldLog) -> list[Event]:
    """:func:`events`, each said once: the same speed step seen by several controllers at the same
    tick (the closed loop, its replay and the what-if run follow one schedule) is one event whose
    text names them all (``closed-loop controller, replayed controller: speed step ...``)."""
    groups: dict[tuple, list[Event]] = {}
    for x in events(log):
        who, sep, what = x.text.partition(": ")
        key = (x.kind, x.t_ns // 10_000_000, what) if x.kind == "speed_step" and sep else (x.kind, x.t_ns, x.text)
        groups.setdefault(key, []).append(x)
    out = []
    for key, items in groups.items():
        x = items[0]
        if len(items) > 1 and x.kind == "speed_step":
            who = ", ".join(dict.fromkeys(i.text.partition(": ")[0] for i in items))
            x = Event(x.t_ns, x.level, x.kind, f"{who}: {key[2]}")
        out.append(x)
    return sorted(out, key=lambda e: e.t_ns)


# -----------------------------------------------------------------------------
# metrics
# -----------------------------------------------------------------------------

def _rms(a) -> float:
    """RMS over the finite samples: report channels have gaps (sparse rows, dropouts)."""
    return rms(a, omit_nonfinite=True)


def metrics(log: FieldLog) -> list[tuple[str, str, str]]:
    """[(name, value, unit)] for the report's table: only what the log supports."""
    rows: list[tuple[str, str, str]] = []
    tr = log.time_range()
    if tr:
        rows.append(("duration", f"{(tr[1] - tr[0]) / 1e9:.1f}", "s"))
    g = gps(log)
    if g is not None:
        rows.append((fixes_name(log), str(len(g[0])), ""))
        rows.append(("GPS dropouts (> 3 periods)", str(len(gps_dropouts(log))), ""))
    rej = gps_rejections(log)
    if rej is not None:
        rows.append(("GPS fixes rejected by the estimator", str(len(rej[0])), ""))
    inn = nonempty(log, "/estimate/innovations")
    if inn is not None and "nis" in inn.columns:
        sens, nis_all = inn["sensor"].astype(str).to_numpy(), _col(inn, "nis")
        for sensor in sorted(set(sens.tolist())):   # over the array: iterating the Series is 20x slower
            nis = nis_all[sens == sensor]
            nis = nis[np.isfinite(nis)]
            if len(nis):
                rows.append((f"mean NIS, {sensor}", f"{nis.mean():.2f}", ""))
    for _topic, _label, f, _sf, desc in controllers(log):
        ct = _col(f, "cross_track_m")
        if ct is not None:
            rows.append((f"{desc}: RMS cross-track error", f"{_rms(ct):.3f}", "m"))
            rows.append((f"{desc}: max |cross-track error|", f"{np.nanmax(np.abs(ct)):.3f}", "m"))
        ue = _col(f, "u_e_mps")
        if ue is not None:
            rows.append((f"{desc}: RMS surge speed error u_e", f"{_rms(ue):.3f}", "m/s"))
        pe = _col(f, "psi_e_rad")
        if pe is not None:
            rows.append((f"{desc}: RMS yaw error psi_e", f"{math.degrees(_rms(ssa(pe))):.2f}", "deg"))
        if "saturated" in f.columns:
            sat = np.asarray(f["saturated"].to_numpy(), bool)
            rows.append((f"{desc}: time saturated", f"{100 * sat.mean():.1f}", "%"))
    fit = nonempty(log, "/identify/fit")
    if fit is not None:
        for q, unit in (("u_mps", "m/s"), ("v_mps", "m/s"), ("r_radps", "rad/s")):
            y, ys = _col(fit, q), _col(fit, q.replace("_", "_sim_", 1))
            if y is not None and ys is not None:
                name = q.split("_")[0]
                rows.append((f"identification fit: RMS {name} error", f"{_rms(y - ys):.4f}", unit))
                rows.append((f"identification fit: {name} fit (100 (1 - |y - y_sim| / |y - mean y|))",
                             f"{fit_percent(y, ys):.1f}", "%"))
    return rows
