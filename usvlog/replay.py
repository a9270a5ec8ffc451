"""Replay of recorded runs and what-if runs, with their metrics.

* :func:`replay_log` feeds a recorded run's estimated state (``/estimate/state``, or
  ``/truth/state`` for simulated logs) into guidance + controller at every controller tick
  (open loop) -> ``/replay/controller``, next to the recorded ``/thrust/command``; and
  simulates the given model with the chosen gains from the recorded initial state along the
  same path with the estimated current (what-if) -> ``/replay/whatif/state`` and
  ``/replay/whatif/controller``. Metrics: :class:`ReplayMetrics`.

Closed-loop scenarios and their simulation live in :mod:`usvlog.sim`. :func:`replay_log` is
pure (no file I/O); :func:`replay_file` runs the same replay from a file to a file a time
window at a time (memory flat in the run's length).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

from .control.gains import Gains
from .control.law import COL, Controller, speed_at
from .errors import InputError, StorageError, UnusableResultError, UsvlogError
from .io.atomic import check_output
from .io.mcap import read_log
from .io.mcap.stream import chunk_spans
from .io.mcap.windows import NotWindowed, iter_windows, topic_counts
from .io.mcap.writer import Spool, merged_ids, write_log_merged
from .log.channels import channel_spec, frame_from_columns
from .log.fieldlog import FieldLog
from .log.summary import propulsion_from_provenance
from .model.frames import ssa
from .model.stats import rms
from .model.vessel import Vessel, default_vessel
from .sim.closed_loop import closed_loop_windows, command_unit, controller_frame
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
    return _tracking({c: rows[:, COL[c]] for c in _METRIC_COLS}, t_s, start_s)


_METRIC_COLS = ("cross_track_m", "psi_e_rad", "u_e_mps", "saturated")   # the columns the metrics read


def _tracking(cols: dict[str, np.ndarray], t_s: np.ndarray, start_s: float) -> TrackingMetrics:
    """:func:`tracking_metrics` of the controller's columns ``cols`` (:data:`_METRIC_COLS`)."""
    t_s = np.asarray(t_s, float)
    n = len(t_s)
    dt = np.empty(n)   # np.diff(t_s, append=...) without joining a copy
    np.subtract(t_s[1:], t_s[:-1], out=dt[:-1])
    dt[-1] = (t_s[-1] + (t_s[-1] - t_s[-2] if n > 1 else 0.0)) - t_s[-1]
    sel = t_s - t_s[0] >= start_s
    if not sel.any():  # a run shorter than the transient: measure all of it
        start_s = 0.0
        sel = np.ones(n, bool)
    i0 = int(np.argmax(sel))
    part = slice(i0, None) if sel[i0:].all() else sel   # rising times: the window is the run's tail (views)
    del sel

    def col(name: str) -> np.ndarray:   # one column of the selected rows
        return cols[name][part]
    xt = np.abs(col("cross_track_m"))
    # NaN kept (omit_nonfinite=False): a diverged closed loop must show in the metrics
    xt_rms, xt_max = rms(xt), float(xt.max())
    p95 = float(np.percentile(xt, 95, overwrite_input=True))   # (xt reordered: used last)
    del xt
    dts = dt[part]
    return TrackingMetrics(n_ticks=len(dts), start_s=float(start_s), duration_s=float(dts.sum()),
                           cross_track_rms_m=xt_rms, cross_track_p95_m=p95, cross_track_max_m=xt_max,
                           heading_error_rms_rad=rms(col("psi_e_rad")),
                           surge_error_rms_mps=rms(col("u_e_mps")),
                           time_saturated_s=float(dts[col("saturated") != 0].sum()))


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


STATE_COLS = ["n_m", "e_m", "psi_rad", "u_mps", "v_mps", "r_radps"]
_DEC_COLS = ["tau_u_n", "tau_r_nm", "thrust_left_n", "thrust_right_n"]
_KEEP = ("t_rel", *_METRIC_COLS, "d_left", "d_right", "f_left", "f_right")


class _Buf:
    """A 1-D array filled part by part: room for ``hint`` values allocated once (pages not yet
    written take no memory), grown by doubling past it (no list of parts joined at the end)."""

    def __init__(self, hint: int, dtype=float):
        self.a = np.empty(max(int(hint), 16), dtype)
        self.n = 0

    def put(self, x: np.ndarray) -> None:
        m = self.n + len(x)
        if m > len(self.a):
            b = np.empty(max(m, 2 * len(self.a)), self.a.dtype)
            b[:self.n] = self.a[:self.n]
            self.a = b
        self.a[self.n:m] = x
        self.n = m

    def view(self) -> np.ndarray:
        return self.a[:self.n]
WHATIF_WINDOW_TICKS = 6000
"""Controller ticks of the what-if run simulated (and written) at a time: a minute at 100 Hz."""


def _state_topic(log: FieldLog, count) -> str:
    """The channel replayed: ``/estimate/state`` when it has rows, else ``/truth/state``."""
    for topic in ("/estimate/state", "/truth/state"):
        if topic in log.channels and count(topic):
            return topic
    raise InputError(f"{log.source or 'log'}: no /estimate/state or /truth/state to replay "
                     "(run usvlog estimate first)")


def _unwrap(p: np.ndarray, prev: float | None, carry: float) -> tuple[np.ndarray, float]:
    """``numpy.unwrap`` of a run's angles a window at a time: ``p`` the window's, ``prev`` the
    last angle before it (None: the first window) and ``carry`` the correction summed so far;
    returns the window unwrapped, number for number as the whole run's, and the new carry."""
    if not len(p):
        return p, carry
    q = p if prev is None else np.concatenate(([prev], p))
    dd = np.diff(q)
    ddmod = np.mod(dd + np.pi, 2 * np.pi) - np.pi
    np.copyto(ddmod, np.pi, where=(ddmod == -np.pi) & (dd > 0))
    corr = ddmod - dd
    np.copyto(corr, 0, where=np.abs(dd) < np.pi)
    cs = np.cumsum(np.concatenate(([carry], corr)))   # a sequential sum: the whole run's partial sums
    out = np.array(p, dtype=float)
    if prev is None:
        out[1:] = p[1:] + cs[1:]
    else:
        out[:] = p + cs[1:]
    return out, float(cs[-1])


def _states_at(t_state: np.ndarray, X: np.ndarray, psi_u: np.ndarray, t_tick: np.ndarray, t0: int) -> np.ndarray:
    """States at tick times: exact rows where times match, linear interpolation elsewhere
    (heading unwrapped: ``psi_u``; times relative to the first state's, ``t0``)."""
    idx = np.searchsorted(t_state, t_tick)
    idx_c = np.clip(idx, 0, len(t_state) - 1)
    exact = t_state[idx_c] == t_tick
    out = np.empty((len(t_tick), 6))
    out[exact] = X[idx_c[exact]]
    if not exact.all():
        ts = (t_state - t0) / 1e9
        tt = (t_tick[~exact] - t0) / 1e9
        for j in range(6):
            out[~exact, j] = np.interp(tt, ts, psi_u if j == 2 else X[:, j])
    return out


class _Replay:
    """The open-loop replay and the what-if run, fed the recorded channels a time window at a
    time (:meth:`feed`, :meth:`ticks`), the what-if run after (:meth:`whatif_frames`).

    Memory: the window, and per tick the few numbers the metrics need at the end (time, the
    four metric columns, the command differences: at most 10 doubles a tick), per state row
    the current estimate when there is a what-if run (2 doubles). The numbers are those of the
    whole run at once: each tick waits for the next one (its step) and for a state at or after
    it (its interpolation); the heading is unwrapped with the run's carry.
    """

    def __init__(self, src: str, topic: str, scen: Scenario, ves: Vessel, gains: Gains, ctl_name: str, path,
                 with_cmd: bool, whatif: bool, hints: tuple[int, int] = (0, 0)):
        self.src, self.topic, self.scen, self.ves, self.gains, self.path = src, topic, scen, ves, gains, path
        self.thr = ves.thrusters
        self.ctl = Controller(path, ves, gains, scen.guidance, full=ctl_name == "full")
        self.with_cmd, self.whatif = with_cmd, whatif
        self.step_ns = int(round(1e9 / scen.guidance.rate_hz))
        self.ts0: int | None = None           # time of the first finite state
        self.n_state_rows = 0
        self.st_t = np.zeros(0, np.int64)     # states not yet passed by the ticks: times, rows, heading unwrapped
        self.st_x = np.zeros((0, 6))
        self.st_u = np.zeros(0)
        self.psi_prev: float | None = None
        self.psi_carry = 0.0
        n_ticks, n_states = hints   # at most (about) this many ticks and state rows: room kept for them
        self.cur = (_Buf(n_states), _Buf(n_states)) if whatif else None
        self.tk_t = np.zeros(0, np.int64)     # ticks waiting, their recorded commands and units
        self.tk_rec: dict[str, np.ndarray] = {}
        self.tk_unit: np.ndarray | None = None
        self.rec_f = False                    # the commands have forces to compare
        self.has_unit = False
        self.k_next = 0                       # next tick number (ticks at the scenario's rate)
        self.cs_t = np.zeros(0, np.int64)     # recorded /control/state rows not yet passed
        self.cs_x = np.zeros((0, 4))
        self.any_cs = False
        self.t0: int | None = None            # the first tick
        self.x0: np.ndarray | None = None
        self.keep: dict[str, _Buf] = {k: _Buf(n_ticks, bool if k == "saturated" else float) for k in _KEEP}
        self.n_ticks = 0
        self.units: set[str] = set()
        self.unit: str | None = None
        self.n_dec, self.dec_max, self.dec_any = 0, -np.inf, False
        self.t_rel_last: tuple[float, float] | None = None

    # -- input -------------------------------------------------------------------------------
    def feed(self, window: dict) -> None:
        """Take one window of the recorded channels (topic -> frame; all rows before its end)."""
        f = window.get(self.topic)
        if f is not None and len(f):
            missing = [c for c in STATE_COLS if c not in f.columns]
            if missing:
                raise InputError(f"{self.src}: channel {self.topic} lacks {', '.join(missing)}")
            X = f[STATE_COLS].to_numpy(dtype=float, copy=True)
            self.n_state_rows += len(X)
            if self.whatif and "current_n_mps" in f.columns and "current_e_mps" in f.columns:
                cn = f["current_n_mps"].to_numpy(dtype=float)
                ce = f["current_e_mps"].to_numpy(dtype=float)
                ok = np.isfinite(cn) & np.isfinite(ce)
                self.cur[0].put(cn[ok])
                self.cur[1].put(ce[ok])
            ok = np.all(np.isfinite(X), axis=1)
            t, X = np.asarray(f.index, dtype=np.int64)[ok], X[ok]
            if len(t):
                if self.ts0 is None:
                    self.ts0 = int(t[0])
                psi_u, self.psi_carry = _unwrap(X[:, 2], self.psi_prev, self.psi_carry)
                self.psi_prev = float(X[-1, 2])
                self.st_t = np.concatenate((self.st_t, t))
                self.st_x = np.concatenate((self.st_x, X))
                self.st_u = np.concatenate((self.st_u, psi_u))
        c = window.get("/thrust/command")
        if self.with_cmd and c is not None and len(c) and self.ts0 is not None:
            t = np.asarray(c.index, dtype=np.int64)
            sel = t >= self.ts0
            self.rec_f = self.thr.scale != "command" and {"thrust_left_n", "thrust_right_n"} <= set(c.columns)
            self.has_unit = "unit" in c.columns
            self.tk_t = np.concatenate((self.tk_t, t[sel]))
            names = ("left", "right", *(("thrust_left_n", "thrust_right_n") if self.rec_f else ()))
            for k in names:
                self.tk_rec[k] = np.concatenate((self.tk_rec.get(k, np.zeros(0)), c[k].to_numpy(dtype=float)[sel]))
            if self.has_unit:
                u = c["unit"].astype(str).to_numpy()[sel]
                self.tk_unit = u if self.tk_unit is None else np.concatenate((self.tk_unit, u))
        r = window.get("/control/state")
        if r is not None and len(r):
            self.any_cs = True
            self.cs_t = np.concatenate((self.cs_t, np.asarray(r.index, dtype=np.int64)))
            self.cs_x = np.concatenate((self.cs_x, r[_DEC_COLS].to_numpy(dtype=float)))

    # -- the open-loop replay ----------------------------------------------------------------
    def ticks(self, final: bool) -> dict:
        """Replay the ticks the states read so far decide (``final``: all that are left);
        returns ``{"/replay/controller": frame}`` of them (empty when none)."""
        if self.ts0 is None:
            if final:
                raise InputError(f"{self.src}: channel {self.topic} has no finite state row")
            return {}
        t_last = int(self.st_t[-1])
        if not self.with_cmd:   # ticks at the scenario's rate from the first state to the last
            k_end = (t_last - self.ts0) // self.step_ns + 1
            if k_end > self.k_next:
                new = self.ts0 + np.arange(self.k_next, k_end, dtype=np.int64) * self.step_ns
                self.tk_t = np.concatenate((self.tk_t, new))
                self.k_next = k_end
        m = int(np.searchsorted(self.tk_t, t_last, side="right"))   # ticks with a state at or after them
        if final:
            if self.n_ticks + m < 2:
                raise InputError(f"{self.src}: fewer than 2 controller ticks inside {self.topic}")
            n, nxt = m, None
            if n == 0:
                return {}
        else:
            n = m - 1
            if n <= 0:
                return {}
            nxt = int(self.tk_t[n])
        tk = self.tk_t[:n]
        if self.t0 is None:
            self.t0 = int(tk[0])
        t_rel = (tk - self.t0) / 1e9
        if nxt is not None:
            dt = np.diff(t_rel, append=(nxt - self.t0) / 1e9)
        else:   # the last tick's step: the one before it, as np.diff(t_rel, append=...) of the whole run
            prev = t_rel[-2] if len(t_rel) > 1 else self.t_rel_last[1]
            dt = np.diff(t_rel, append=t_rel[-1] + (t_rel[-1] - prev))
        Xt = _states_at(self.st_t, self.st_x, self.st_u, tk, self.ts0)
        if self.x0 is None:
            self.x0 = Xt[0].copy()
            self.ctl.reset(Xt[0])
        sch = self.scen.schedule
        rows = self.ctl.run(Xt, speed_at(sch, t_rel), dt, speed_at(sch, t_rel, 2))
        del Xt
        unit = command_unit(self.thr)
        if self.with_cmd and self.has_unit:
            self.units.update(self.tk_unit[:n].tolist())
            if len(self.units) == 1:
                (u,) = self.units
                unit = u if (u == "newton" or self.thr.map != "identity") else unit
        if self.unit is not None and unit != self.unit:
            raise NotWindowed("the commands' unit changes along the run")
        self.unit = unit
        frame = controller_frame(rows, tk, "/replay/controller", self.thr, unit)
        keep = self.keep
        keep["t_rel"].put(t_rel)
        for c in _METRIC_COLS:   # (saturated kept as its test != 0: the same ticks)
            keep[c].put(rows[:, COL[c]] != 0 if c == "saturated" else rows[:, COL[c]])
        if self.with_cmd:
            for side in ("left", "right"):
                keep[f"d_{side}"].put(frame[f"cmd_{side}"].to_numpy() - self.tk_rec[side][:n])
                if self.rec_f:
                    keep[f"f_{side}"].put(frame[f"thrust_{side}_n"].to_numpy() - self.tk_rec[f"thrust_{side}_n"][:n])
        if len(self.cs_t):
            j = np.clip(np.searchsorted(self.cs_t, tk), 0, len(self.cs_t) - 1)
            hit = self.cs_t[j] == tk
            if hit.any():
                a = np.abs(frame[_DEC_COLS].to_numpy(dtype=float)[hit] - self.cs_x[j[hit]])
                self.n_dec += int(hit.sum())
                if not np.all(np.isnan(a)):
                    self.dec_max, self.dec_any = max(self.dec_max, float(np.nanmax(a))), True
        del rows
        self.n_ticks += n
        self.t_rel_last = (float(t_rel[-2]) if n > 1 else (self.t_rel_last or (0.0, 0.0))[1], float(t_rel[-1]))
        # what the ticks to come need: the states from the last one before them, the rest
        self.tk_t = self.tk_t[n:]
        self.tk_rec = {k: v[n:] for k, v in self.tk_rec.items()}
        if self.tk_unit is not None:
            self.tk_unit = self.tk_unit[n:]
        upto = int(tk[-1]) if nxt is None else nxt
        s = max(0, int(np.searchsorted(self.st_t, upto)) - 1)
        self.st_t, self.st_x, self.st_u = self.st_t[s:], self.st_x[s:], self.st_u[s:]
        c = int(np.searchsorted(self.cs_t, int(tk[-1])))
        self.cs_t, self.cs_x = self.cs_t[c:], self.cs_x[c:]
        return {"/replay/controller": frame}

    def end_replay(self) -> None:
        """After the last tick: the replay's metrics, the command comparison and the mean current
        (``replay_metrics``, ``off_path``, ``comparison``, ``current_ne``), the kept numbers let go
        one after another (memory: the peak is the kept numbers, not copies of them)."""
        self.st_x = self.st_u = self.st_t = self.cs_x = self.cs_t = None   # the states are used
        self.current_ne = (0.0, 0.0)
        if self.cur is not None:
            cn, ce = self.cur[0].view(), self.cur[1].view()
            if len(cn):
                self.current_ne = (float(np.mean(cn)), float(np.mean(ce)))
            self.cur = None
        keep = self.keep
        n_cmp, c_rms, c_max, f_rms = 0, None, None, None
        if self.with_cmd:
            d = np.concatenate([keep.pop("d_left").view(), keep.pop("d_right").view()])
            ok = np.isfinite(d)
            n_cmp = int(ok.sum() // 2)
            if ok.all():   # (the same numbers as over d[ok], without its copy)
                c_rms, c_max = rms(d), float(np.max(np.abs(d)))
            elif ok.any():
                c_rms = rms(d, omit_nonfinite=True)   # over the ticks both sides have
                c_max = float(np.max(np.abs(d[ok])))
            del d, ok
            if self.rec_f:
                df = np.concatenate([keep.pop("f_left").view(), keep.pop("f_right").view()])
                if np.isfinite(df).any():
                    f_rms = rms(df, omit_nonfinite=True)
                del df
        self.comparison = (n_cmp, c_rms, c_max, f_rms)
        self.keep = {}
        t_rel = keep.pop("t_rel").view()
        start = self.scen.metrics_start_s
        carrot = float(np.max(self.scen.schedule[:, 2]))   # the largest look-ahead (m) of the speed schedule
        self.off_path = path_following_warning(keep["cross_track_m"].view(), t_rel, start, carrot)
        self.replay_metrics = _tracking({c: keep[c].view() for c in _METRIC_COLS}, t_rel, start)

    def decisions(self) -> tuple[int, float | None]:
        """(ticks matched with a recorded /control/state, max |replayed - recorded| there)."""
        if not self.n_dec:
            return 0, None
        return self.n_dec, self.dec_max if self.dec_any else float("nan")

    # -- the what-if run ------------------------------------------------------------------
    def whatif_frames(self, wif_name: str, window_ticks: int | None):
        """Yield the what-if run's ``/replay/whatif/*`` frames a window at a time; its metrics
        are in :attr:`whatif_metrics` after."""
        scen, rate, thr, unit = self.scen, self.scen.guidance.rate_hz, self.thr, self.unit
        cur = self.current_ne
        t_rel_end = self.t_rel_last[1]
        dt_end = (t_rel_end + (t_rel_end - self.t_rel_last[0])) - t_rel_end
        wctl = Controller(self.path, self.ves, self.gains, scen.guidance, full=wif_name == "full")
        n = int(round(float(t_rel_end + dt_end) * rate))   # the run's ticks (about): room for their numbers
        t_tick, tc = _Buf(n + 2), {c: _Buf(n + 2, bool if c == "saturated" else float) for c in _METRIC_COLS}
        for _k0, run in closed_loop_windows(self.path, self.ves, wctl, duration_s=float(t_rel_end + dt_end),
                                            dt_s=1.0 / rate, integrator=scen.sim.integrator, current_ne=cur,
                                            eta0=self.x0[:3], nu0=self.x0[3:], schedule=scen.schedule, rate_hz=rate,
                                            window_ticks=window_ticks):
            tw = self.t0 + np.round(run.t * 1e9).astype(np.int64)
            t_tick.put(run.t[run.tick])
            for c in _METRIC_COLS:
                tc[c].put(run.ctrl[:, COL[c]] != 0 if c == "saturated" else run.ctrl[:, COL[c]])
            s = run.states
            st_cols = {"n_m": s[:, 0], "e_m": s[:, 1], "psi_rad": ssa(s[:, 2]), "u_mps": s[:, 3], "v_mps": s[:, 4],
                       "r_radps": s[:, 5], "current_n_mps": np.full(len(s), cur[0]),
                       "current_e_mps": np.full(len(s), cur[1]), "tau_u_n": run.tau[:, 0],
                       "tau_r_nm": run.tau[:, 1]}
            # the run's own arrays, no 2-D copy
            yield {"/replay/whatif/state": frame_from_columns(st_cols, tw, channel_spec("/replay/whatif/state"),
                                                              copy=False),
                   "/replay/whatif/controller": controller_frame(run.ctrl, tw[run.tick], "/replay/whatif/controller",
                                                                 thr, unit)}
            del s, st_cols, run
        self.whatif_metrics = _tracking({c: v.view() for c, v in tc.items()}, t_tick.view(), scen.metrics_start_s)


def _setup(log: FieldLog, scen: Scenario, vessel, gains, controller, whatif, whatif_controller, count, span):
    """What :func:`replay_log` and :func:`replay_file` decide before reading the run (``count``:
    topic -> its messages, ``span``: topic -> (first, last) time in ns or None)."""
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
    topic = _state_topic(log, count)
    with_cmd = "/thrust/command" in log.channels and bool(count("/thrust/command"))
    n_ticks = count("/thrust/command")
    if not with_cmd:
        sp = span(topic)
        n_ticks = 0 if sp is None else (sp[1] - sp[0]) // int(round(1e9 / scen.guidance.rate_hz)) + 2
    rep = _Replay(src, topic, scen, ves, gains, ctl_name, path, with_cmd, whatif, (n_ticks, count(topic)))
    return rep, ctl_name, wif_name


def _finish(rep: _Replay, out: FieldLog, scen: Scenario, ctl_name: str, wif_name: str, whatif: bool,
            m_whatif) -> ReplayMetrics:
    """The metrics, the path metadata and the provenance entry into ``out``."""
    m_replay, off, (n_cmp, c_rms, c_max, f_rms) = rep.replay_metrics, rep.off_path, rep.comparison
    n_dec, dec_max = rep.decisions()
    out.meta[META_PATH] = rep.path.metadata()
    metrics = ReplayMetrics(state_source=rep.topic, controller=ctl_name, replay=m_replay,
                            command_unit=rep.unit if rep.with_cmd else None, n_commands_compared=n_cmp,
                            command_rms=c_rms, command_max_abs=c_max, force_rms_n=f_rms,
                            decisions_compared=n_dec, decisions_max_abs=dec_max,
                            whatif_controller=wif_name if whatif else None, whatif=m_whatif,
                            warnings=(off,) if off else ())
    out.add_provenance(producer="usvlog replay", source=rep.src,
                       settings={"scenario": scen.source or scen.name, "state_source": rep.topic,
                                 "controller": ctl_name, "whatif_controller": wif_name if whatif else None,
                                 "gains": rep.gains.to_dict(), "guidance": scen.guidance.to_dict(),
                                 "vessel": rep.ves.to_dict(), "path": scen.path_spec},
                       metrics=metrics.to_dict())
    return metrics


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
    :func:`replay_file` does the same from a file to a file a time window at a time.

    Raises
    ------
    usvlog.errors.UnusableResultError
        The log's import found a propulsion the twin-thruster controller does not command
        (a propeller and rudder, or one thruster): refused with that reason.
    """
    def count(topic: str) -> int:
        f = log.get(topic)
        return 0 if f is None else len(f)

    def span(topic: str) -> tuple[int, int] | None:
        f = log.get(topic)
        return None if f is None or not len(f) else (int(f.index.min()), int(f.index.max()))

    rep, ctl_name, wif_name = _setup(log, scen, vessel, gains, controller, whatif, whatif_controller, count, span)
    rep.feed({t: log.get(t) for t in (rep.topic, "/thrust/command", "/control/state") if t in log.channels})
    if release_inputs:
        log.redefer([rep.topic, "/thrust/command", "/control/state"])
    out = log.copy()   # (the inputs released above stay in the file in the copy too)
    out.set("/replay/controller", rep.ticks(final=True)["/replay/controller"])
    rep.end_replay()
    m_whatif = None
    if whatif:
        for frames in rep.whatif_frames(wif_name, None):   # one window: the whole run
            for topic, frame in frames.items():
                out.set(topic, frame)
        m_whatif = rep.whatif_metrics
    return ReplayResult(out, _finish(rep, out, scen, ctl_name, wif_name, whatif, m_whatif))


def replay_file(path, scen: Scenario, out, *, vessel: Vessel | None = None, gains: Gains | None = None,
                controller: str | None = None, whatif: bool = True, whatif_controller: str | None = None,
                force: bool = False) -> ReplayResult | None:
    """:func:`replay_log` from a canonical MCAP file to another, a time window at a time.

    The channels replay reads are decoded window by window (:func:`usvlog.io.mcap.windows.iter_windows`)
    and the ticks replayed as their states come; the ``/replay/*`` channels go to spool files
    beside ``out`` as they are made (:class:`usvlog.io.mcap.writer.Spool`), then ``out`` is
    written from the input's channels and the spools', copied undecoded
    (:func:`usvlog.io.mcap.writer.write_log_merged`): memory does not grow with the run's
    length beyond a few numbers a tick (see :class:`_Replay`). The numbers and the file's
    bytes are those of :func:`replay_log` and :func:`usvlog.io.mcap.write_log`.

    Returns
    -------
    ReplayResult or None
        ``log`` is the file written, read with its channels deferred. None when the file cannot
        be read or written so (damaged, no summary, channels out of order, the commands' unit
        changing along the run...): nothing is written, and the caller replays it whole
        (:func:`replay_log`).
    """
    check_output(out, force, parent=True)
    log = read_log(path, topics=[], defer=True)
    if log.recovery is not None or log.deferred is None:
        return None
    counts = topic_counts(path)
    spans = chunk_spans(path) or []

    def span(topic: str) -> tuple[int, int] | None:
        mine = [(t0, t1) for t0, t1, topics in spans if topic in topics]
        return (min(a for a, _ in mine), max(b for _, b in mine)) if mine else None

    rep, ctl_name, wif_name = _setup(log, scen, vessel, gains, controller, whatif, whatif_controller,
                                     lambda t: counts.get(t, 0), span)
    wif_topics = ["/replay/whatif/state", "/replay/whatif/controller"] if whatif else []
    new = ["/replay/controller", *wif_topics]
    ids = merged_ids(log, new)
    out_p = Path(out)
    spool_paths = [out_p.parent / f".{out_p.name}.{k}.spool" for k in ("replay", "whatif")]
    spools = []
    try:
        sp = Spool(spool_paths[0], ["/replay/controller"], ids)
        for window in iter_windows(path, [rep.topic, "/thrust/command", "/control/state"]):
            rep.feed(window)
            frames = rep.ticks(final=False)
            if frames:
                sp.add(frames)
        sp.add(rep.ticks(final=True))
        spools.append(sp.close())
        rep.end_replay()
        m_whatif = None
        if whatif:
            sp = Spool(spool_paths[1], wif_topics, ids)
            for frames in rep.whatif_frames(wif_name, WHATIF_WINDOW_TICKS):
                sp.add(frames)
            spools.append(sp.close())
            m_whatif = rep.whatif_metrics
        metrics = _finish(rep, log, scen, ctl_name, wif_name, whatif, m_whatif)
        write_log_merged(log, out, spools, new, force=force)
    except NotWindowed:
        return None
    except UsvlogError:
        raise
    except OSError as err:   # a spool beside the output that cannot be written
        raise StorageError(f"{out_p}: cannot write beside it ({err.strerror or err})") from err
    finally:
        for p in spool_paths:
            p.unlink(missing_ok=True)
    return ReplayResult(read_log(out, topics=[], defer=True), metrics)


__all__ = ["replay_log", "replay_file", "ReplayResult", "ReplayMetrics", "TrackingMetrics", "tracking_metrics",
           "path_following_warning", "OFF_PATH", "tracking_metrics_of"]
