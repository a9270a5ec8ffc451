"""Replay of recorded runs and what-if runs, with their metrics.

* :func:`replay_log` feeds a recorded run's estimated state (``/estimate/state``, or
  ``/truth/state`` for simulated logs) into guidance + controller at every controller tick
  (open loop) -> ``/replay/controller``, next to the recorded ``/thrust/command``; and
  simulates the given model with the chosen gains from the recorded initial state along the
  same path with the estimated current (what-if) -> ``/replay/whatif/state`` and
  ``/replay/whatif/controller``. Metrics: :class:`ReplayMetrics`.

Closed-loop scenarios and their simulation live in :mod:`usvlog.sim`.
Pure: no file I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

from .control.gains import Gains
from .control.law import COL, Controller, speed_at
from .errors import InputError, UnusableResultError
from .log.channels import channel_spec, frame_from_columns
from .log.fieldlog import FieldLog
from .log.summary import propulsion_from_provenance
from .model.frames import ssa
from .model.stats import rms
from .model.vessel import Vessel, default_vessel
from .sim.closed_loop import closed_loop, command_unit, controller_frame
from .sim.scenario import META_PATH, Scenario

# -----------------------------------------------------------------------------
# metrics
# -----------------------------------------------------------------------------

@dataclass(frozen=True)
class TrackingMetrics:
    """How well a run followed the path (over ticks from ``start_s`` on)."""

    n_ticks: int
    start_s: float            # metrics from this time on (the scenario's [metrics] start_s, or 0
    duration_s: float         # when the run is shorter than that)
    cross_track_rms_m: float
    cross_track_p95_m: float
    cross_track_max_m: float
    heading_error_rms_rad: float
    surge_error_rms_mps: float
    time_saturated_s: float

    @property
    def window(self) -> str:
        """The time window the metrics cover, as it is written after their names: ``t>60s`` or
        ``whole run``."""
        return f"t>{self.start_s:g}s" if self.start_s > 0 else "whole run"

    def named(self) -> dict[str, float]:
        """The metric values by name with their window: ``{"cross_track_rms_m[t>60s]": ...}``
        (units in the names: m, rad, m/s, s; ``n_ticks``, ``start_s`` and ``duration_s`` left out)."""
        return {f"{f.name}[{self.window}]": float(getattr(self, f.name)) for f in fields(self)
                if f.name not in ("n_ticks", "start_s", "duration_s")}

    def display(self) -> list[tuple[str, str, str]]:
        """[(name with window, value as text, unit)] for people: the console and the report
        print these same lines (heading error in degrees; stored values stay in radians)."""
        w = self.window
        return [(f"cross_track_rms_m[{w}]", f"{self.cross_track_rms_m:.4f}", "m"),
                (f"cross_track_p95_m[{w}]", f"{self.cross_track_p95_m:.4f}", "m"),
                (f"cross_track_max_m[{w}]", f"{self.cross_track_max_m:.4f}", "m"),
                (f"heading_error_rms_deg[{w}]", f"{math.degrees(self.heading_error_rms_rad):.3f}", "deg"),
                (f"surge_error_rms_mps[{w}]", f"{self.surge_error_rms_mps:.5f}", "m/s"),
                (f"time_saturated_s[{w}]", f"{self.time_saturated_s:.2f}", "s")]

    @classmethod
    def from_dict(cls, d: dict) -> TrackingMetrics:
        """The metrics back from :meth:`to_dict` (e.g. a provenance record; ``window`` ignored)."""
        return cls(**{f.name: d[f.name] for f in fields(cls)})

    def to_dict(self) -> dict:
        """The metrics as a JSON-ready dict, by field name (units in the names: m, rad, m/s, s),
        plus ``window`` (:attr:`window`)."""
        return {**{f.name: getattr(self, f.name) for f in fields(self)}, "window": self.window}


def tracking_metrics(rows: np.ndarray, t_s: np.ndarray, start_s: float = 0.0) -> TrackingMetrics:
    """Path-following metrics of controller output rows, from ``start_s`` after the first tick on.

    Each tick counts for its interval to the next one (the last for the interval before
    it). NaN is kept: a diverged closed loop gives NaN metrics rather than hiding.

    Parameters
    ----------
    rows : numpy.ndarray, shape (N, NOUT)
        Controller outputs per tick, columns as :data:`usvlog.control.law.COL`
        (``cross_track_m``, ``psi_e_rad``, ``u_e_mps``, ``saturated`` are used).
    t_s : numpy.ndarray, shape (N,)
        Tick times (s), increasing.
    start_s : float
        Ignore the first ``start_s`` seconds (s; the transient); when the run is not that
        long, the whole run is measured and ``start_s`` reported as 0.

    Returns
    -------
    TrackingMetrics
        Number of ticks and duration (s) measured; RMS, 95th percentile and maximum of
        the absolute cross-track error (m); RMS heading error (rad) and surge speed error
        (m/s); time with the thrusters saturated (s).
    """
    t_s = np.asarray(t_s, float)
    dt = np.diff(t_s, append=t_s[-1] + (t_s[-1] - t_s[-2] if len(t_s) > 1 else 0.0))
    sel = t_s - t_s[0] >= start_s
    if not sel.any():  # a run shorter than the transient: measure all of it
        start_s = 0.0
        sel = np.ones(len(t_s), bool)
    def col(name: str) -> np.ndarray:   # one column of the selected rows (not a copy of them all)
        return rows[sel, COL[name]]
    xt = np.abs(col("cross_track_m"))
    # NaN kept (omit_nonfinite=False): a diverged closed loop must show in the metrics
    return TrackingMetrics(n_ticks=int(sel.sum()), start_s=float(start_s), duration_s=float(dt[sel].sum()),
                           cross_track_rms_m=rms(xt), cross_track_p95_m=float(np.percentile(xt, 95)),
                           cross_track_max_m=float(xt.max()),
                           heading_error_rms_rad=rms(col("psi_e_rad")),
                           surge_error_rms_mps=rms(col("u_e_mps")),
                           time_saturated_s=float(dt[sel][col("saturated") != 0].sum()))


OFF_PATH = "the run does not follow the scenario's path"
OFF_PATH_CARROTS = 3.0   # median |cross-track| above this many carrot distances: not the scenario's path


def path_following_warning(cross_track_m: np.ndarray, t_s: np.ndarray, start_s: float,
                           carrot_m: float) -> str | None:
    """A warning when a run does not follow the path it is measured against, else None.

    Parameters
    ----------
    cross_track_m : numpy.ndarray
        Cross-track error per controller tick (m).
    t_s : numpy.ndarray
        Tick times (s).
    start_s : float
        Start of the metrics window (s after the first tick), as :func:`tracking_metrics`.
    carrot_m : float
        The largest carrot distance (look-ahead) of the scenario (m).

    Returns
    -------
    str or None
        ``"the run does not follow the scenario's path: median |cross-track| 57.1 m over
        t>60s is more than 3 carrot distances (3 x 1.63 m)..."`` when the median absolute
        cross-track error over the window exceeds :data:`OFF_PATH_CARROTS` carrot distances.
    """
    t_s = np.asarray(t_s, float)
    sel = t_s - t_s[0] >= start_s
    if not sel.any():
        sel, start_s = np.ones(len(t_s), bool), 0.0
    xt = np.abs(np.asarray(cross_track_m, float)[sel])
    xt = xt[np.isfinite(xt)]
    if not len(xt):
        return None
    med = float(np.median(xt))
    limit = OFF_PATH_CARROTS * carrot_m
    if med <= limit:
        return None
    window = f"t>{start_s:g}s" if start_s > 0 else "whole run"
    return (f"{OFF_PATH}: median |cross-track| {med:.3g} m over {window} is more than "
            f"{OFF_PATH_CARROTS:g} carrot distances ({OFF_PATH_CARROTS:g} x {carrot_m:.3g} m); "
            "its tracking metrics do not measure path following (was it replayed against the right scenario?)")


def tracking_metrics_of(frame, start_s: float = 0.0) -> TrackingMetrics:
    """:func:`tracking_metrics` of a controller channel (``/control/state``, ``/replay/controller``,
    ``/replay/whatif/controller``) as stored in a log.

    Parameters
    ----------
    frame : pandas.DataFrame
        The channel, indexed by ``t_ns``, with ``cross_track_m``, ``psi_e_rad``, ``u_e_mps`` and
        ``saturated`` columns (missing ones count as NaN, ``saturated`` as 0).
    start_s : float
        Start of the window (s after the first tick).

    Returns
    -------
    TrackingMetrics
        As :func:`tracking_metrics`.
    """
    n = len(frame)
    rows = np.zeros((n, max(COL.values()) + 1))
    for name in ("cross_track_m", "psi_e_rad", "u_e_mps", "saturated"):
        rows[:, COL[name]] = (np.asarray(frame[name].to_numpy(), dtype=float) if name in frame.columns
                              else (0.0 if name == "saturated" else np.nan))
    t_s = (np.asarray(frame.index, dtype=np.int64) - int(frame.index[0])) / 1e9
    return tracking_metrics(rows, t_s, start_s)


@dataclass(frozen=True)
class ReplayMetrics:
    """Open-loop replay vs what was recorded, and the what-if run."""

    state_source: str                 # "/estimate/state" or "/truth/state"
    controller: str                   # full / baseline (open-loop replay)
    replay: TrackingMetrics
    command_unit: str | None
    n_commands_compared: int
    command_rms: float | None         # replayed vs recorded left/right commands, in command_unit
    command_max_abs: float | None
    force_rms_n: float | None         # the same in newtons (when the log has forces)
    decisions_compared: int           # ticks matched with a recorded /control/state (closed-loop runs)
    decisions_max_abs: float | None   # max |replayed - recorded| of forces and moments there (N, N m)
    whatif_controller: str | None
    whatif: TrackingMetrics | None
    warnings: tuple[str, ...] = ()    # e.g. the run does not follow the scenario's path

    @property
    def follows_path(self) -> bool:
        """False when the replayed run does not follow the scenario's path (see ``warnings``)."""
        return not any(w.startswith(OFF_PATH) for w in self.warnings)

    def to_dict(self) -> dict:
        """The metrics as a JSON-ready dict, ``replay`` and ``whatif`` as nested dicts (or None)."""
        d = {f.name: getattr(self, f.name) for f in fields(self)}
        d["replay"] = self.replay.to_dict()
        d["whatif"] = None if self.whatif is None else self.whatif.to_dict()
        d["warnings"] = list(self.warnings)
        return d


# -----------------------------------------------------------------------------
# replay of a recorded run
# -----------------------------------------------------------------------------

@dataclass(frozen=True)
class ReplayResult:
    """What :func:`replay_log` returns.

    Attributes
    ----------
    log : FieldLog
        A copy of the input log with ``/replay/controller`` (and, with the what-if run,
        ``/replay/whatif/state`` and ``/replay/whatif/controller``), the path metadata
        record and a provenance entry added.
    metrics : ReplayMetrics
        Replayed vs recorded commands and the tracking metrics of both runs.
    """

    log: FieldLog
    metrics: ReplayMetrics


def _state_source(log: FieldLog) -> tuple[str, np.ndarray, np.ndarray]:
    for topic in ("/estimate/state", "/truth/state"):
        f = log.get(topic)
        if f is not None and len(f):
            cols = ["n_m", "e_m", "psi_rad", "u_mps", "v_mps", "r_radps"]
            missing = [c for c in cols if c not in f.columns]
            if missing:
                raise InputError(f"{log.source or 'log'}: channel {topic} lacks {', '.join(missing)}")
            X = f[cols].to_numpy(dtype=float, copy=True)
            ok = np.all(np.isfinite(X), axis=1)
            if not ok.any():
                raise InputError(f"{log.source or 'log'}: channel {topic} has no finite state row")
            return topic, np.asarray(f.index, dtype=np.int64)[ok], X[ok]
    raise InputError(f"{log.source or 'log'}: no /estimate/state or /truth/state to replay "
                     "(run usvlog estimate first)")


def _states_at(t_state: np.ndarray, X: np.ndarray, t_tick: np.ndarray) -> np.ndarray:
    """States at tick times: exact rows where times match, linear interpolation elsewhere."""
    idx = np.searchsorted(t_state, t_tick)
    idx_c = np.clip(idx, 0, len(t_state) - 1)
    exact = t_state[idx_c] == t_tick
    out = np.empty((len(t_tick), 6))
    out[exact] = X[idx_c[exact]]
    if not exact.all():
        ts = (t_state - t_state[0]) / 1e9
        tt = (t_tick[~exact] - t_state[0]) / 1e9
        for j in range(6):
            y = np.unwrap(X[:, j]) if j == 2 else X[:, j]
            out[~exact, j] = np.interp(tt, ts, y)
    return out


def _current_of(log: FieldLog, topic: str) -> tuple[float, float]:
    f = log[topic]
    if "current_n_mps" in f.columns and "current_e_mps" in f.columns:
        cn = f["current_n_mps"].to_numpy(dtype=float)
        ce = f["current_e_mps"].to_numpy(dtype=float)
        ok = np.isfinite(cn) & np.isfinite(ce)
        if ok.any():
            return float(np.mean(cn[ok])), float(np.mean(ce[ok]))
    return 0.0, 0.0


def replay_log(log: FieldLog, scen: Scenario, *, vessel: Vessel | None = None, gains: Gains | None = None,
               controller: str | None = None, whatif: bool = True,
               whatif_controller: str | None = None, release_inputs: bool = False) -> ReplayResult:
    """Open-loop replay of a recorded run plus a what-if simulation; returns the log with the results.

    The controller's model (and the what-if plant) is ``vessel``, else the scenario's
    ``[vessel]``, else the log's ``usvlog.vessel``; the gains are ``gains`` else the scenario's.
    With ``release_inputs`` (a log read from its file for this call alone, its frames
    unchanged) the channels it reads are left in the file again once used, in ``log`` and
    in the result (:meth:`usvlog.log.fieldlog.FieldLog.redefer`: decoded again if touched,
    copied undecoded when written), so their frames do not stay in memory with the results.

    Raises
    ------
    usvlog.errors.UnusableResultError
        The log's import found a propulsion the twin-thruster controller does not command
        (a propeller and rudder, or one thruster): refused with that reason.
    """
    src = log.source or "log"
    prop = propulsion_from_provenance(log.provenance)
    if prop is not None:   # the controller commands two thrusters: nothing to compare on a rudder boat
        err = UnusableResultError(f"{src}: replay refused: {prop['reason']}")
        err.reasons = [str(prop["reason"])]      # type: ignore[attr-defined]
        raise err
    ves = vessel or (scen.sim.vessel if "vessel" in scen.doc else None) or log.vessel or default_vessel()
    gains = gains or scen.gains
    ctl_name = controller or scen.controller
    wif_name = whatif_controller or ctl_name
    datum = log.datum or scen.sim.datum
    path = scen.path(datum)
    topic, t_state, X = _state_source(log)
    cur = _current_of(log, topic) if whatif else (0.0, 0.0)
    cmd = log.get("/thrust/command")
    rate = scen.guidance.rate_hz
    if cmd is not None and len(cmd):
        t_cmd = np.asarray(cmd.index, dtype=np.int64)
        sel = (t_cmd >= t_state[0]) & (t_cmd <= t_state[-1])
        t_tick = t_cmd[sel]
    else:
        sel = None
        t_tick = np.arange(t_state[0], t_state[-1] + 1, int(round(1e9 / rate)), dtype=np.int64)
    if len(t_tick) < 2:
        raise InputError(f"{src}: fewer than 2 controller ticks inside {topic}")
    Xt = _states_at(t_state, X, t_tick)
    del X, t_state   # memory: only the states at the ticks are used from here
    thr = ves.thrusters
    unit = command_unit(thr)
    # the recorded commands and decisions compared below, taken now: the input channels can
    # then go (memory: with release_inputs they are not held while the controller runs)
    rec_lr = rec_f = None
    if sel is not None:
        if "unit" in cmd.columns:
            units = cmd["unit"][sel].astype(str).unique().tolist()
            if len(units) == 1 and (units[0] == "newton" or thr.map != "identity"):
                unit = units[0]
        rec_lr = [cmd[c].to_numpy(dtype=float)[sel] for c in ("left", "right")]
        # a vessel identified in command units has no newtons to compare with
        if thr.scale != "command" and {"thrust_left_n", "thrust_right_n"} <= set(cmd.columns):
            rec_f = [cmd[c].to_numpy(dtype=float)[sel] for c in ("thrust_left_n", "thrust_right_n")]
    dec_cols = ["tau_u_n", "tau_r_nm", "thrust_left_n", "thrust_right_n"]
    hit, rec_dec = None, None
    rec_cs = log.get("/control/state")
    if rec_cs is not None and len(rec_cs):
        tr_ns = np.asarray(rec_cs.index, dtype=np.int64)
        j = np.clip(np.searchsorted(tr_ns, t_tick), 0, len(tr_ns) - 1)
        hit = tr_ns[j] == t_tick
        if hit.any():
            rec_dec = rec_cs[dec_cols].to_numpy(dtype=float)[j[hit]]
    cmd = rec_cs = None
    if release_inputs:
        log.redefer([topic, "/thrust/command", "/control/state"])
    t_rel = (t_tick - t_tick[0]) / 1e9
    dt = np.diff(t_rel, append=t_rel[-1] + (t_rel[-1] - t_rel[-2]))
    ctl = Controller(path, ves, gains, scen.guidance, full=ctl_name == "full")
    ctl.reset(Xt[0])
    # (the what-if closed loop below once ran on a second thread beside this replay: no faster
    # on a 1-hour log, so it runs after it; docs/performance.md)
    rows = ctl.run(Xt, speed_at(scen.schedule, t_rel), dt, speed_at(scen.schedule, t_rel, 2))
    m_replay = tracking_metrics(rows, t_rel, scen.metrics_start_s)
    carrot = float(np.max(scen.schedule[:, 2]))   # the largest look-ahead (m) of the speed schedule
    off = path_following_warning(rows[:, COL["cross_track_m"]], t_rel, scen.metrics_start_s, carrot)
    frame = controller_frame(rows, t_tick, "/replay/controller", thr, unit)
    del rows   # memory: the controller rows are in the frame now
    out = log.copy()   # (the inputs released above stay in the file in the copy too)
    out.set("/replay/controller", frame)
    n_cmp, c_rms, c_max, f_rms = 0, None, None, None
    if rec_lr is not None:
        d = np.concatenate([frame["cmd_left"].to_numpy() - rec_lr[0], frame["cmd_right"].to_numpy() - rec_lr[1]])
        ok = np.isfinite(d)
        n_cmp = int(ok.sum() // 2)
        if ok.any():
            c_rms = rms(d, omit_nonfinite=True)   # over the ticks both sides have
            c_max = float(np.max(np.abs(d[ok])))
        if rec_f is not None:
            df = np.concatenate([frame["thrust_left_n"].to_numpy() - rec_f[0],
                                 frame["thrust_right_n"].to_numpy() - rec_f[1]])
            okf = np.isfinite(df)
            if okf.any():
                f_rms = rms(df, omit_nonfinite=True)
    n_dec, dec_max = 0, None
    if hit is not None:
        n_dec = int(hit.sum())
        if n_dec:
            a = frame[dec_cols].to_numpy(dtype=float)[hit]
            dec_max = float(np.nanmax(np.abs(a - rec_dec)))
    del frame
    rec_lr = rec_f = rec_dec = None
    m_whatif = None
    if whatif:
        wctl = Controller(path, ves, gains, scen.guidance, full=wif_name == "full")
        run = closed_loop(path, ves, wctl, duration_s=float(t_rel[-1] + dt[-1]), dt_s=1.0 / rate,
                          integrator=scen.sim.integrator, current_ne=cur, eta0=Xt[0, :3], nu0=Xt[0, 3:],
                          schedule=scen.schedule, rate_hz=rate)
        tw = t_tick[0] + np.round(run.t * 1e9).astype(np.int64)
        m_whatif = tracking_metrics(run.ctrl, run.t[run.tick], scen.metrics_start_s)
        s = run.states
        st_cols = {"n_m": s[:, 0], "e_m": s[:, 1], "psi_rad": ssa(s[:, 2]), "u_mps": s[:, 3], "v_mps": s[:, 4],
                   "r_radps": s[:, 5], "current_n_mps": np.full(len(s), cur[0]),
                   "current_e_mps": np.full(len(s), cur[1]), "tau_u_n": run.tau[:, 0], "tau_r_nm": run.tau[:, 1]}
        out.set("/replay/whatif/state", frame_from_columns(st_cols, tw, channel_spec("/replay/whatif/state"),
                                                           copy=False))   # the run's own arrays, no 2-D copy
        del s, st_cols   # memory: the states are in the frame now
        ctrl, t_ctrl = run.ctrl, tw[run.tick]
        del run
        out.set("/replay/whatif/controller", controller_frame(ctrl, t_ctrl, "/replay/whatif/controller", thr, unit))
        del ctrl
    out.meta[META_PATH] = path.metadata()
    metrics = ReplayMetrics(state_source=topic, controller=ctl_name, replay=m_replay,
                            command_unit=unit if sel is not None else None, n_commands_compared=n_cmp,
                            command_rms=c_rms, command_max_abs=c_max, force_rms_n=f_rms,
                            decisions_compared=n_dec, decisions_max_abs=dec_max,
                            whatif_controller=wif_name if whatif else None, whatif=m_whatif,
                            warnings=(off,) if off else ())
    out.add_provenance(producer="usvlog replay", source=src,
                       settings={"scenario": scen.source or scen.name, "state_source": topic,
                                 "controller": ctl_name, "whatif_controller": wif_name if whatif else None,
                                 "gains": gains.to_dict(), "guidance": scen.guidance.to_dict(),
                                 "vessel": ves.to_dict(), "path": scen.path_spec},
                       metrics=metrics.to_dict())
    return ReplayResult(out, metrics)


__all__ = ["replay_log", "ReplayResult", "ReplayMetrics", "TrackingMetrics", "tracking_metrics",
           "path_following_warning", "OFF_PATH", "tracking_metrics_of"]
