"""Offline state estimation of one run: :func:`estimate` and its :class:`EstimateResult`.

:func:`estimate` ties the parts together: the heading offset and mode
(:mod:`usvlog.estimate.modes`), the problem from the log (:mod:`usvlog.estimate.problem`),
process-noise tuning, the latency search and the filter and smoother runs
(:func:`_solve`, :mod:`usvlog.estimate.run`), a second run on GNSS alone when the compass
contradicts the track, and the result frames and report (:mod:`usvlog.estimate.report`).
The names other units import from here (the topics, :func:`state_size`, ...) are re-exported
from the modules that define them.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np
import pandas as pd

from ..log.channels import StrCodes, channel_spec, frame_from_columns
from ..log.fieldlog import FieldLog
from ..log.status import EstimateStatus, set_estimate_status
from ..model.heading_offset import HeadingOffset
from ..model.vessel import Vessel, default_vessel
from . import kernels
from .kernels import (
    DYNAMIC,
    KINEMATIC,
    SENSOR_DIM,
    SENSORS,
    YAW_RATE,
)
from .latency import META_LATENCY, DelayEstimate, find_delays, latency_record
from .layout import (
    COMPASS_TOPIC,
    GNSS_TOPIC,
    INNOVATION_TOPIC,
    INPUT_TOPICS,
    STATE_COLUMNS,
    STATE_TOPIC,
    THRUST_TOPIC,
    VELOCITY_TOPIC,
    YAW_RATE_TOPIC,
    Problem,
    gps_only_settings,
    head_problem,
    process_noise,
    state_size,
)
from .modes import COURSE_MIN_SPEED_MPS, _compass_disagrees, apply_heading_offset, course_as_heading, heading_offset_of
from .problem import ThrustFrames, build_problem
from .report import EstimateReport, SensorReport, _check_finite, _reinits, heading_blocking, sideslip_figures
from .run import RawRun, RowSink, forward_loglik, run_fast, run_reference_path, tune_process_noise
from .settings import Q_R_KINEMATIC_NO_JUMPS, EstimateSettings

# what other units import from here, defined in .layout (the channels and the state layout)
__all__ = ["COMPASS_TOPIC", "GNSS_TOPIC", "INPUT_TOPICS", "THRUST_TOPIC", "VELOCITY_TOPIC", "YAW_RATE_TOPIC",
           "state_size", "EstimateResult", "estimate"]


def gps_only_start(log: FieldLog, settings: EstimateSettings, vessel: Vessel, pb: Problem,
                   thrust: ThrustFrames | None = None) -> Problem:
    """``pb`` with a better start heading for the dynamic model run on GNSS alone.

    Without a compass the dynamic model's heading is observed only through the track, and
    a start heading far off (the course of the track's first 10 m leg, see
    :func:`initial_course`, is tens of degrees from the start heading of a boat that turns
    as it sets off) costs the forward pass a long transient the smoother does not fully
    undo. The start heading is instead the course over ground where the boat first moves,
    from the GNSS-only kinematic smoother (:func:`course_as_heading`) on the same
    measurements. Other problems are returned as they are.

    Parameters
    ----------
    log : FieldLog
        The run ``pb`` was built from.
    settings : EstimateSettings
        The settings ``pb`` was built with (latencies applied as they say).
    vessel : Vessel
    pb : Problem
    thrust : callable, optional
        The log's thrust in time windows, as :func:`build_problem` takes it.

    Returns
    -------
    Problem
        ``pb``, or a copy whose ``x0`` heading (rad) is that course.
    """
    if pb.mode != "gps-only" or pb.model != DYNAMIC:
        return pb
    ks = gps_only_settings(replace(settings, model="kinematic", current=None, sway_damping=False, tune=False,
                                   estimate_delays=(), gps_only=True, q_uv=None, q_r=None))
    kp = build_problem(log, ks, vessel, thrust)
    runner = run_fast if ks.fast else run_reference_path
    q = process_noise(ks)
    # smoothed over a head of the run reaching START_MARGIN_S beyond the first moving step
    # (doubled until it does): the whole run would cost as much as the estimate itself
    span = int(round(START_HEAD_S / ks.output_step_s))
    while True:
        k = min(span, len(kp.dts))
        raw = runner(head_problem(kp, k), q, ks.max_consecutive_rejects, True)
        vn, ve = raw.XS[:, kernels.X_VN], raw.XS[:, kernels.X_VE]
        moving = np.flatnonzero(vn * vn + ve * ve > COURSE_MIN_SPEED_MPS ** 2)
        t_left = (kp.t_ns[k - 1] - kp.t_ns[moving[0]]) * 1e-9 if len(moving) else 0.0
        if k == len(kp.dts) or t_left >= START_MARGIN_S:
            break
        span *= 2
    X, _, _ = course_as_heading(raw.XS, raw.SDs, raw.PBs, gyro=True)
    x0 = pb.x0.copy()
    x0[kernels.X_PSI] = X[0, kernels.X_PSI]
    return replace(pb, x0=x0)


START_HEAD_S = 120.0
"""First length (s) of the run smoothed for a GNSS-only dynamic start heading (:func:`gps_only_start`)."""
START_MARGIN_S = 30.0
"""That head reaches at least this far (s) beyond the boat's first moving step."""



def _state_frame(X: np.ndarray, SD: np.ndarray, PB: np.ndarray, t_ns: np.ndarray,
                 model: int) -> pd.DataFrame:
    """The /estimate/state frame (STATE_COLUMNS and their ``_std``) of states X, one-sigma SD
    (and, kinematic, the covariance block PB), built as one block of columns (one copy)."""
    n_out = 8 if (model == DYNAMIC and X.shape[1] == 8) else 6
    spec = channel_spec(STATE_TOPIC)
    names = spec.columns if spec is not None else [*STATE_COLUMNS, *(c + "_std" for c in STATE_COLUMNS)]
    row = {c: k for k, c in enumerate(names)}
    block = np.empty((len(names), len(X)))   # rows: the frame's columns
    for c in STATE_COLUMNS[n_out:]:
        block[row[c]] = block[row[c + "_std"]] = np.nan
    if model == KINEMATIC:  # NED velocity -> over-ground body velocity
        X, SD = X[:, :6].copy(), SD[:, :6].copy()
        X[:, 3], X[:, 4], SD[:, 3], SD[:, 4] = kernels.body_velocity(X[:, 2], X[:, 3], X[:, 4], PB)
    for i, c in enumerate(STATE_COLUMNS[:n_out]):
        block[row[c]] = X[:, i]
        block[row[c + "_std"]] = SD[:, i]
    return pd.DataFrame(block.T, index=pd.Index(np.asarray(t_ns, np.int64), name="t_ns"), columns=names, copy=False)


@dataclass(frozen=True)
class EstimateResult:
    """State estimate of a run.

    ``state``: smoothed (or forward, with the smoother off) state on the output grid,
    indexed by ``t_ns``; ``forward``: the forward filter alone, same columns (made when
    first asked for, see :attr:`forward`); ``innovations``: one row per measurement;
    ``report``: counts and consistency. For the kinematic model u, v are body velocities
    over ground; for the dynamic model they are the model's nu, relative to the water when
    current states are estimated. (An estimate written to a file a time window at a time
    holds neither frame: they are decoded from the file when first asked for.)
    """

    report: EstimateReport
    settings: EstimateSettings
    vessel: Vessel | None = None
    _frames: Mapping[str, pd.DataFrame] = field(default_factory=dict, repr=False, compare=False)
    _make_forward: Callable[[], pd.DataFrame] | None = field(default=None, repr=False, compare=False)

    @property
    def state(self) -> pd.DataFrame:
        """The state frame (see the class): columns as :meth:`to_dataframe`, indexed by ``t_ns``."""
        return self._frames[STATE_TOPIC]

    @property
    def innovations(self) -> pd.DataFrame:
        """One row per measurement: sensor, res_0, res_1, nis, accepted, indexed by ``t_ns``."""
        return self._frames[INNOVATION_TOPIC]

    @cached_property
    def forward(self) -> pd.DataFrame:
        """The forward filter's state alone, the columns of ``state`` on the same grid.

        Made on first access (then kept): with the smoother on, by running the forward pass
        again over the same problem (the very same numbers as the pass the smoother
        started from; about a third of the estimate's filter time), so that an estimate
        whose forward frame is never looked at (``usvlog estimate``) neither builds nor holds
        it; with the smoother off, a copy of ``state``.

        Returns
        -------
        pandas.DataFrame
            Columns as ``state`` (positions m, heading rad, velocities m/s and rad/s and
            their ``_std``), indexed by ``t_ns`` (ns since the Unix epoch).
        """
        make = self._make_forward
        if make is None:
            raise AttributeError("this EstimateResult was made without its forward filter")
        frame = make()
        object.__setattr__(self, "_make_forward", None)   # its problem arrays are let go
        return frame

    def to_dataframe(self) -> pd.DataFrame:
        """The state estimate ``state`` (not a copy): columns n_m, e_m, psi_rad, u_mps,
        v_mps, r_radps, current_n_mps, current_e_mps (NaN without current states) and a
        ``*_std`` one-sigma for each, indexed by t_ns (ns since the Unix epoch)."""
        return self.state

    def to_log(self, log: FieldLog) -> FieldLog:
        """A copy of ``log`` plus /estimate/state, /estimate/innovations and the records of
        :meth:`add_records`."""
        out = log.copy()
        out.set(STATE_TOPIC, self.state)
        out.set(INNOVATION_TOPIC, self.innovations)
        self.add_records(out, log.source or "")
        return out

    def add_records(self, out: FieldLog, source: str) -> None:
        """Add to ``out`` (the log estimated from ``source``) the estimate's provenance, its
        status record (:mod:`usvlog.log.status`: ok or degraded, with reasons) and the sensor
        delays applied (metadata record ``usvlog.latency``, see
        :func:`usvlog.estimate.latency.stored_delays`)."""
        out.add_provenance(producer="usvlog estimate", source=source,
                           settings=self.report.settings,
                           vessel=self.vessel.name if self.vessel else "",
                           report={k: v for k, v in self.report.to_dict().items() if k != "settings"})
        set_estimate_status(out, EstimateStatus(status=self.report.status, mode=self.report.mode,
                                                reasons=tuple(self.report.status_reasons())))
        out.meta[META_LATENCY] = latency_record(self.settings, self.report.latency)


def _grid_frame(pb: Problem, X: np.ndarray, SD: np.ndarray, PB: np.ndarray, steps: slice = slice(None)) -> pd.DataFrame:
    """The state frame of a run's output rows (the grid's: X, SD, PB hold those rows only; of the
    steps ``steps``, default all); a GNSS-only kinematic run's heading is its course
    (:func:`course_as_heading`: of all the rows at once, it holds the course from row to row)."""
    if course_held(pb):
        X, SD, PB = course_as_heading(X, SD, PB, bool((pb.mkind == YAW_RATE).any()))
    return _state_frame(X, SD, PB, pb.t_ns[steps][pb.is_grid[steps]], pb.model)


def course_held(pb: Problem) -> bool:
    """A GNSS-only kinematic run: its heading is its course, held where the boat is still."""
    return pb.mode == "gps-only" and pb.model == KINEMATIC


@dataclass(frozen=True)
class _ForwardFrame:
    """Makes the forward filter's frame of a run when called (for :attr:`EstimateResult.forward`):
    the forward pass over ``pb`` with process noise ``q`` again (picklable, unlike a closure)."""

    pb: Problem
    q: np.ndarray
    settings: EstimateSettings

    def __call__(self) -> pd.DataFrame:
        fwd = _output_run(self.pb, self.q, self.settings, smoother=False)
        return _grid_frame(self.pb, fwd.X, fwd.SDf, fwd.PBf)


def _solve(pb: Problem, settings: EstimateSettings, log: FieldLog, vessel: Vessel, thrust: ThrustFrames | None,
           sink: RowSink | None) -> tuple[EstimateSettings, RawRun, dict | None, tuple[DelayEstimate, ...], Problem,
                                          np.ndarray]:
    """Settings in effect, the filter (and smoother) run, the tuning result, the sensor delays
    searched, the problem they give and the process noise, for one run (``pb`` built from
    ``log`` (its thrust ``thrust``) with ``settings``). With the smoother the run holds no forward
    posteriors (:func:`_output_run` makes them again when asked for); with a ``sink`` its output
    rows went there (:func:`_output_run`)."""
    if pb.mode == "gps-only":
        settings = gps_only_settings(settings)
    if settings.model == "kinematic" and settings.q_r is None and not pb.qjump.any():
        settings = replace(settings, q_r=Q_R_KINEMATIC_NO_JUMPS)   # no thrust record
    latency: tuple[DelayEstimate, ...] = ()
    given = {"gnss": settings.gnss_delay_s, "compass": settings.compass_delay_s}

    def search_delays(st: EstimateSettings, q: np.ndarray):
        lat, st = find_delays(log, st, lambda lg, s_: forward_loglik(build_problem(lg, s_, vessel), q,
                                                                       s_.max_consecutive_rejects), given=given)
        return lat, st, gps_only_start(log, st, vessel, build_problem(log, st, vessel, thrust), thrust)

    pb = gps_only_start(log, settings, vessel, pb, thrust)
    tuned = None
    if settings.tune:
        if settings.estimate_delays:   # first the delays, so that the tuned noise does not absorb them
            latency, settings, pb = search_delays(settings, process_noise(settings))
        tuned = tune_process_noise(pb, settings)
        settings = replace(settings, q_uv=tuned["q_uv"], q_r=tuned["q_r"],
                           q_current=tuned.get("q_current", settings.q_current), tune=False)
    q = process_noise(settings)
    if settings.estimate_delays:   # (again) with the noise in effect
        latency, settings, pb = search_delays(settings, q)
    raw = _output_run(pb, q, settings, smoother=settings.smoother, sink=sink)
    return settings, raw, tuned, latency, pb, q


def _output_run(pb: Problem, q: np.ndarray, settings: EstimateSettings, smoother: bool,
                sink: RowSink | None = None) -> RawRun:
    """The run of the output frames: with the smoother, the smoothed states only (the forward
    posteriors not stored); without it, the forward ones. With a ``sink`` the output rows go
    there (:func:`run_fast`; the forward ones at once) and the run returned has none."""
    runner = run_fast if settings.fast else run_reference_path
    # only what the output needs (memory): the grid's rows, the frame's states (the kinematic
    # model's accelerations too, for course_as_heading) and the covariance block of the NED model
    kinematic = pb.model == KINEMATIC
    raw = runner(pb, q, settings.max_consecutive_rejects, smoother, rows=pb.is_grid, covariance_block=kinematic,
                 columns=8 if kinematic or pb.nx == kernels.NX_DYNAMIC_CURRENT else 6, forward=not smoother,
                 sink=sink if smoother else None)
    if sink is not None and not smoother:
        sink(0, raw.XS, raw.SDs, raw.PBs)
        raw = _without_rows(raw)
    return raw


def _without_rows(raw: RawRun) -> RawRun:
    """``raw`` without its state rows (memory: they are in a frame or a sink already)."""
    gone = np.zeros((0, 0))
    return replace(raw, X=gone, SDf=gone, PBf=gone, XS=gone, SDs=gone, PBs=gone)


def estimate(log: FieldLog, settings: EstimateSettings = EstimateSettings(),
             vessel: Vessel | None = None) -> EstimateResult:
    """Estimate the state of a run (forward EKF, then the extended RTS smoother).

    ``vessel`` (dynamic model): defaults to the log's own vessel, else the built-in one.

    Parameters
    ----------
    log : FieldLog
        The run. Needs ``/gnss/fix`` (lat_deg, lon_deg, optional cov_*_m2); uses
        ``/compass/heading`` (heading_rad, optional std_rad and reference) unless it is
        missing, judged dead, still while the track turns or ``settings.gps_only`` (then
        GNSS only, see :func:`build_problem`); the dynamic model also needs
        ``/thrust/command`` (thrust_left_n / thrust_right_n in N, or commands through the
        vessel's thruster map). A compass the gate rejects more than
        :data:`COMPASS_REJECT_LIMIT` of the time is dropped and the run made again from
        GNSS alone; a filter that diverges is re-initialised from the measurements
        (counted in ``report.reinits``).
    settings : EstimateSettings, optional
        Model, noise, gating, smoother and tuning (default ``EstimateSettings()``: the
        kinematic model with the smoother on).
    vessel : Vessel, optional
        Model parameters and thruster map; not used by the kinematic model except to
        convert thrust commands for the yaw-jump term.

    Returns
    -------
    EstimateResult
        ``state`` on a grid of ``settings.output_step_s`` s from the first to the last
        measurement (positions in m about the log's datum or its first fix, heading in
        rad, velocities in m/s and rad/s), the forward filter, the innovations and a
        report. ``result.to_log(log)`` adds them to a copy of the log.

    Raises
    ------
    usvlog.errors.InputError
        If a needed channel is missing or empty, time goes backwards in one, it has no
        valid record, or thrust commands cannot be converted to forces.
    usvlog.errors.UnusableResultError
        If the filter kept diverging (more than :data:`REINIT_LIMIT` re-initialisations) or
        a state is still not finite or has a position one-sigma beyond
        :data:`POSITION_STD_LIMIT_M`: no estimate is returned rather than garbage.

    Examples
    --------
    >>> res = estimate(log, EstimateSettings(model="dynamic"))     # doctest: +SKIP
    >>> res.state[["n_m", "e_m", "psi_rad"]].head()                # doctest: +SKIP
    """
    if vessel is None:
        vessel = log.vessel or default_vessel()
    run = solve_log(log, settings, vessel)
    pb, raw = run.pb, run.raw
    state = _grid_frame(pb, raw.XS, raw.SDs, raw.PBs)
    run = replace(run, raw=_without_rows(raw))   # the step arrays already in a frame are let go (memory)
    # the forward frame when first asked for: the forward pass made again, or (no smoother) the state's
    make_forward = _ForwardFrame(pb, run.q, run.settings) if run.settings.smoother else state.copy
    slip = sideslip_figures(state) if pb.mode == "gnss+compass" else None
    return EstimateResult(report=run.report(slip), settings=run.settings, vessel=vessel,
                          _frames={STATE_TOPIC: state, INNOVATION_TOPIC: run.innovations()},
                          _make_forward=make_forward)


@dataclass(frozen=True)
class SolvedRun:
    """An estimate's filter and smoother run, before its frames (:func:`solve_log`).

    ``pb`` the problem run, ``raw`` the run (its state rows in a frame or handed on),
    ``settings`` those in effect, ``q`` the process noise, ``vessel``, ``tuned`` and ``latency``
    the tuning and delay search results, ``found`` the heading offset detected and
    ``offset_source`` where the one applied came from, ``reinits`` the divergence guard's restarts.
    """

    pb: Problem
    raw: RawRun
    settings: EstimateSettings
    q: np.ndarray
    vessel: Vessel
    tuned: dict | None
    latency: tuple[DelayEstimate, ...]
    found: HeadingOffset | None
    offset_source: str
    reinits: tuple[tuple[int, str], ...]

    def innovations(self, j0: int = 0, j1: int | None = None) -> pd.DataFrame:
        """The /estimate/innovations frame of measurements ``j0`` .. ``j1`` (default all)."""
        pb, raw, sel = self.pb, self.raw, slice(j0, j1)
        return frame_from_columns(
            {"sensor": StrCodes.of(SENSORS, pb.mkind[sel]),
             "res_0": raw.innov[sel, 0].copy(), "res_1": raw.innov[sel, 1].copy(), "nis": raw.innov[sel, 2].copy(),
             "accepted": raw.accepted[sel] > 0},
            pb.m_t_ns[sel], channel_spec(INNOVATION_TOPIC), copy=False)   # (fresh arrays: taken as they are)

    def report(self, sideslip: dict | None) -> EstimateReport:
        """The estimate's report, with the sideslip figures of its state (:func:`sideslip_figures`)."""
        pb, raw, settings, vessel, found = self.pb, self.raw, self.settings, self.vessel, self.found
        reps = []
        for k in range(len(SENSORS)):
            sel = pb.mkind == k
            if not sel.any():
                continue
            acc = raw.accepted[sel] > 0
            nis = raw.innov[sel, 2][acc]
            reps.append(SensorReport(sensor=SENSORS[k], dim=SENSOR_DIM[k], accepted=int(acc.sum()),
                                     rejected=int((~acc).sum()), forced=int((raw.accepted[sel] == 2).sum()),
                                     mean_nis=float(nis.mean()) if len(nis) else float("nan"),
                                     skipped=pb.skipped.get(SENSORS[k], 0)))
        sd = settings.to_dict()
        sd["vessel"] = vessel.name if settings.model == "dynamic" else None
        if settings.model == "dynamic":
            sd["vessel_params"] = vessel.params.to_dict()
        offset = {"detected": found.to_dict() if found is not None else None,
                  "text": found.describe() if found is not None else "",
                  "applied_deg": math.degrees(settings.compass_offset_rad), "source": self.offset_source}
        return EstimateReport(model=settings.model, states=pb.nx, steps=len(pb.t_ns),
                              duration_s=float((pb.t_ns[-1] - pb.t_ns[0]) * 1e-9), sensors=tuple(reps),
                              dropouts=pb.dropouts, loglik=raw.loglik,
                              thrust_skipped=pb.skipped.get("thrust", 0), settings=sd, tuned=self.tuned,
                              mode=pb.mode, mode_reason=pb.mode_reason, reinits=self.reinits, latency=self.latency,
                              heading_offset=offset, sideslip=sideslip, gnss_noise=pb.gnss_noise,
                              blocking=heading_blocking(found, settings.compass_offset_rad, pb.mode, sideslip))


def solve_log(log: FieldLog, settings: EstimateSettings, vessel: Vessel, thrust: ThrustFrames | None = None,
              sink: RowSink | None = None) -> SolvedRun:
    """The run of :func:`estimate` up to its frames: the heading offset and mode, the problem,
    tuning and delays, the filter and smoother (again from GNSS alone when the compass
    contradicts the track), the divergence checks.

    ``thrust``: the log's thrust in time windows (:func:`build_problem`); ``sink``: takes the
    output rows a block at a time instead of the run (:func:`run_fast`). Raises as :func:`estimate`.
    """
    found = heading_offset_of(log, settings) if not settings.gps_only else None
    settings, offset_source = apply_heading_offset(settings, found, vessel)
    pb = build_problem(log, settings, vessel, thrust)
    run_settings, raw, tuned, latency, pb, q = _solve(pb, settings, log, vessel, thrust, sink)
    why = _compass_disagrees(pb, raw)
    if why:   # a heading source the track contradicts: GNSS only
        settings = replace(settings, gps_only=True)
        pb = build_problem(log, settings, vessel, thrust)
        run_settings, raw, tuned, latency, pb, q = _solve(pb, settings, log, vessel, thrust, sink)
        pb = replace(pb, mode_reason=why)
    settings = run_settings
    reinits = _reinits(raw, pb, settings, log.source or "log")
    _check_finite(raw, pb, settings, log.source or "log")
    return SolvedRun(pb=pb, raw=raw, settings=settings, q=q, vessel=vessel, tuned=tuned, latency=latency,
                     found=found, offset_source=offset_source, reinits=reinits)
