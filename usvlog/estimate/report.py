"""The status of an estimate and its report: :class:`EstimateReport`, :class:`SensorReport`.

The report says what the estimate is worth: per sensor the measurements accepted, rejected
and forced in and the mean NIS (:meth:`EstimateReport.consistency` turns them into plain
words), the mode, the divergence guard's restarts (:func:`_reinits`, which refuses a run that
kept diverging, as :func:`_check_finite` refuses one that is not finite), the sideslip while
moving (:func:`sideslip_figures`) and what blocks its use (:func:`heading_blocking`). Its
:attr:`~EstimateReport.status` (ok, degraded, failed) is what ``usvlog estimate`` exits on.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pandas as pd

from ..errors import UnusableResultError
from ..log.fieldlog import format_time
from ..model.frames import ssa
from ..model.heading_offset import MIN_OFFSET_DEG, MIN_OFFSET_SIGMAS, HeadingOffset
from . import kernels
from .latency import DelayEstimate
from .layout import POSITION_STD_LIMIT_M, Problem
from .modes import COURSE_MIN_SPEED_MPS
from .run import RawRun
from .settings import EstimateSettings


@dataclass(frozen=True)
class SensorReport:
    """Measurement counts and consistency of one sensor in an estimate.

    ``sensor`` is ``gnss``, ``compass``, ``yaw_rate`` or ``gnss_velocity`` and ``dim`` its measurement
    dimension; ``forced`` counts measurements accepted after ``max_consecutive_rejects``
    rejections in a row (they are also in ``accepted``); ``mean_nis`` is the mean
    normalised innovation squared over the accepted ones (near ``dim`` for a consistent
    filter); ``skipped`` counts unusable records (non-finite or out of range), which are
    in neither count.
    """

    sensor: str
    dim: int
    accepted: int
    rejected: int
    forced: int        # accepted after max_consecutive_rejects rejections in a row
    mean_nis: float    # over accepted measurements (near ``dim`` for a consistent filter)
    skipped: int = 0   # records not usable (non-finite or out of range), not counted above

    def to_dict(self) -> dict:
        """The fields as a JSON-ready dict."""
        return {"sensor": self.sensor, "dim": self.dim, "accepted": self.accepted,
                "rejected": self.rejected, "forced": self.forced, "mean_nis": self.mean_nis,
                "skipped": self.skipped}


@dataclass(frozen=True)
class EstimateReport:
    """Summary of an estimate: model, size, sensors, GNSS dropouts, likelihood.

    Attributes
    ----------
    model : str
        ``kinematic`` or ``dynamic``.
    states : int
        Number of filter states.
    steps : int
        Filter steps (output grid plus measurement times).
    duration_s : float
        First to last measurement, s.
    sensors : tuple of SensorReport
        One per sensor present in the log.
    dropouts : tuple of (int, float)
        GNSS gaps bridged by prediction: (start in ns since the Unix epoch, duration in s).
    loglik : float
        Innovation log-likelihood of the forward pass.
    thrust_skipped : int
        Thrust records that could not be used.
    settings : dict
        The settings in effect (:meth:`EstimateSettings.to_dict` plus the vessel).
    tuned : dict or None
        Result of process-noise tuning (``q_uv``, ``q_r``, maybe ``q_current``,
        ``loglik``, ``evaluations``), None without tuning.
    mode : str
        ``gnss+compass``, or ``gps-only`` when no heading was fused.
    mode_reason : str
        Why GNSS only (empty with a compass).
    reinits : tuple of (int, str)
        Re-initialisations of the divergence guard: (time in ns since the Unix epoch, why).
    latency : tuple of DelayEstimate
        The sensor delays searched (``settings.estimate_delays``), empty without a search.
    heading_offset : dict or None
        The heading mounting offset: ``detected`` (:meth:`HeadingOffset.to_dict`, None
        without a heading to test), ``text`` (it in words), ``applied_deg`` (subtracted from
        the heading before fusion) and ``source`` (``auto``, ``given``, ``vessel file``, ``none``).
    sideslip : dict or None
        Over the moving parts of the estimate (speed > :data:`SIDESLIP_MIN_SPEED_MPS`):
        ``median_abs_deg`` (|atan2(v, u)|), ``median_u_mps``, ``median_abs_v_mps``,
        ``moving_s``; None when the boat never moves or no heading was fused.
    blocking : tuple of str
        Why the estimate must not be used (status ``failed``): an implausible sideslip, a
        mounting offset detected and not applied.
    gnss_noise : str
        Where the GNSS noise came from, in words (covariance, fix quality or the default).
    """

    model: str
    states: int
    steps: int
    duration_s: float
    sensors: tuple[SensorReport, ...]
    dropouts: tuple[tuple[int, float], ...]    # GNSS gaps bridged: (start t_ns, duration s)
    loglik: float
    thrust_skipped: int
    settings: dict
    tuned: dict | None = None
    mode: str = "gnss+compass"
    mode_reason: str = ""
    reinits: tuple[tuple[int, str], ...] = ()
    latency: tuple[DelayEstimate, ...] = ()
    heading_offset: dict | None = None
    sideslip: dict | None = None
    blocking: tuple[str, ...] = ()
    gnss_noise: str = ""

    @property
    def dropouts_bridged(self) -> int:
        """Number of GNSS gaps bridged by prediction."""
        return len(self.dropouts)

    def sensor(self, name: str) -> SensorReport:
        """The report of sensor ``name`` (``gnss``, ``compass``, ``yaw_rate``, ``gnss_velocity``).

        Raises
        ------
        KeyError
            If that sensor had no measurements.
        """
        for r in self.sensors:
            if r.sensor == name:
                return r
        raise KeyError(name)

    def consistency(self) -> list[str]:
        """Plain-word warnings from each sensor's NIS and gate (empty for a consistent run).

        The mean NIS of a sensor whose noise is stated right is its dimension; below a tenth
        of it the stated noise is far too large or the sensor does not move (a dead compass
        fused with a large sigma), above five times it the noise is understated, the sensor
        lags (latency) or the model does not fit; more than 20 % rejected by the gate says
        the sensor and the track disagree.

        Returns
        -------
        list of str
            One line per finding.
        """
        out = []
        for r in self.sensors:
            n = r.accepted + r.rejected
            if r.accepted and np.isfinite(r.mean_nis):
                if r.mean_nis < 0.1 * r.dim:
                    out.append(f"{r.sensor} NIS {r.mean_nis:.3f} (expected about {r.dim}): its noise is overstated "
                               "or it does not move - check the sensor")
                elif r.mean_nis > 5.0 * r.dim:
                    out.append(f"{r.sensor} NIS {r.mean_nis:.3g} (expected about {r.dim}): its noise is understated, "
                               "it lags (a latency), or the model does not fit")
            if n and r.rejected > 0.2 * n:
                out.append(f"{r.sensor}: {100.0 * r.rejected / n:.0f} % of its measurements rejected by the gate - "
                           "the sensor and the track disagree")
        sl = self.sideslip
        if (self.mode == "gnss+compass" and sl and sl["median_abs_deg"] > SIDESLIP_MAX_DEG
                and sl["moving_s"] < SIDESLIP_MIN_MOVING_S):   # (over that time it blocks: heading_blocking)
            out.append(f"sideslip: median |beta| {sl['median_abs_deg']:.0f} deg while moving, but over only "
                       f"{sl['moving_s']:.1f} s of motion (too short to judge; over {SIDESLIP_MIN_MOVING_S:g} s it "
                       "refuses the estimate): if it holds, the heading is wrong (a mounting offset or a wrong "
                       "heading source) or the boat went backwards")
        return out

    def mode_notes(self) -> list[str]:
        """What the mode means for the estimate, in plain words (empty with a compass)."""
        if self.mode != "gps-only":
            return []
        if self.model == "kinematic":
            what = ("heading = course over ground while the boat moves (held below "
                    f"{COURSE_MIN_SPEED_MPS:g} m/s); sideslip is not observable without a heading (v = 0)")
        else:
            what = ("heading estimated through the vessel model from the thrust and the track (sideslip included), "
                    "starting from the course over ground where the boat first moves")
        return [f"GNSS only: {self.mode_reason}; {what}"]

    @property
    def status(self) -> str:
        """``failed`` with a :attr:`blocking` reason (not to be used: ``usvlog estimate`` exits 1),
        else ``degraded`` when GNSS only, re-initialised or a sensor is inconsistent, else ``ok``."""
        if self.blocking:
            return "failed"
        return "degraded" if self.status_reasons() else "ok"

    def status_reasons(self) -> list[str]:
        """Why the estimate failed or is degraded, in plain words (empty when ``ok``)."""
        out = list(self.blocking)
        if self.mode == "gps-only":
            out.append(f"gps-only: {self.mode_reason}")
        if self.reinits:
            first = self.reinits[0]
            out.append(f"{len(self.reinits)} re-initialisation{'s' if len(self.reinits) > 1 else ''} "
                       f"after divergence (first at {format_time(first[0])}: {first[1]})")
        return out + self.consistency()

    def to_dict(self) -> dict:
        """JSON-ready dict; dropouts carry ``start_ns``, a readable ``start`` and ``duration_s``;
        ``warnings`` are :meth:`consistency`'s plain-word findings, ``status`` and
        ``status_reasons`` as :attr:`status`, ``reinitialisations`` the guard's restarts
        (``t_ns``, ``time``, ``reason``)."""
        return {"status": self.status, "status_reasons": self.status_reasons(), "mode": self.mode,
                "mode_reason": self.mode_reason, "notes": self.mode_notes(),
                "reinitialisations": [{"t_ns": t, "time": format_time(t), "reason": r} for t, r in self.reinits],
                "warnings": self.consistency(), "model": self.model, "states": self.states, "steps": self.steps,
                "duration_s": self.duration_s, "sensors": {r.sensor: r.to_dict() for r in self.sensors},
                "dropouts_bridged": self.dropouts_bridged, "thrust_skipped": self.thrust_skipped,
                "dropouts": [{"start_ns": a, "start": format_time(a), "duration_s": d} for a, d in self.dropouts],
                "loglik": self.loglik, "settings": self.settings, "tuned": self.tuned,
                "latency": [d.to_dict() for d in self.latency], "heading_offset": self.heading_offset,
                "sideslip": self.sideslip, "gnss_noise": self.gnss_noise}

    def format(self) -> str:
        """Human-readable multi-line summary (what ``usvlog estimate`` prints)."""
        lines = [f"estimate ({self.model}, {self.states} states, {self.mode}): {self.steps} steps over "
                 f"{self.duration_s:.1f} s; status {self.status}"]
        lines += [f"  note: {x}" for x in self.mode_notes()]
        lines += [f"  FAILED: {x}" for x in self.blocking]
        if self.gnss_noise:
            lines.append(f"  {self.gnss_noise}")
        ho = self.heading_offset or {}
        if ho.get("text"):
            lines.append(f"  heading: {ho['text']}; applied {ho.get('applied_deg', 0.0):+.1f} deg "
                         f"({ho.get('source', 'none')})")
        if self.sideslip:
            sl = self.sideslip
            lines.append(f"  sideslip while moving: median |beta| {sl['median_abs_deg']:.1f} deg, median u "
                         f"{sl['median_u_mps']:.2f} m/s, |v| {sl['median_abs_v_mps']:.2f} m/s")
        for r in self.sensors:
            lines.append(f"  {r.sensor:8s} accepted {r.accepted:7d}  rejected {r.rejected:5d}"
                         f"  mean NIS {r.mean_nis:6.3f} (dim {r.dim})"
                         + (f"  forced {r.forced}" if r.forced else "")
                         + (f"  skipped {r.skipped}" if r.skipped else ""))
        if self.thrust_skipped:
            lines.append(f"  thrust records skipped: {self.thrust_skipped}")
        lines.append(f"  GNSS dropouts bridged: {self.dropouts_bridged}"
                     + "".join(f"\n    {format_time(a)}  {d:.1f} s" for a, d in self.dropouts))
        if self.tuned:
            lines.append("  tuned process noise: " + ", ".join(
                f"{k} {v:.3g}" for k, v in self.tuned.items() if k.startswith("q_")))
        if self.reinits:
            lines.append(f"  re-initialisations after divergence: {len(self.reinits)}"
                         + "".join(f"\n    {format_time(t)}  {r}" for t, r in self.reinits[:20])
                         + (f"\n    ... {len(self.reinits) - 20} more" if len(self.reinits) > 20 else ""))
        lines += [f"  {d.format()}" for d in self.latency]
        lines += [f"  warning: {w}" for w in self.consistency()]
        return "\n".join(lines)


def _divergence_hint(settings: EstimateSettings) -> str:
    """What to check after a divergence, by model."""
    if settings.model == "dynamic":
        return "check the thrust units and the sensors' noise, or use the kinematic model"
    return "check the process noise (q_uv, q_r) and the sensors' noise"


REINIT_LIMIT = 20
"""More re-initialisations than this in one run: the filter cannot recover (exit 1)."""


def _reinits(raw: RawRun, pb: Problem, settings: EstimateSettings, src: str) -> tuple[tuple[int, str], ...]:
    """The divergence guard's restarts as (t_ns, why); refuses a run that kept diverging.

    Raises
    ------
    usvlog.errors.UnusableResultError
        With more than :data:`REINIT_LIMIT` restarts, naming the first one and its reason.
    """
    k = np.flatnonzero(raw.resets)
    out = tuple((int(pb.t_ns[i]), kernels.REINIT_REASONS[int(raw.resets[i])]) for i in k[:1000])
    if len(k) > REINIT_LIMIT:
        t_s = (int(pb.t_ns[k[0]]) - int(pb.t_ns[0])) * 1e-9
        raise UnusableResultError(
            f"{src}: the {settings.model} estimate diverged and could not recover: re-initialised from the "
            f"measurements {len(k)} times (more than {REINIT_LIMIT}), first at t = {t_s:.1f} s from the start "
            f"({out[0][1]}); nothing written: " + _divergence_hint(settings))
    return out


def _check_finite(raw: RawRun, pb: Problem, settings: EstimateSettings, src: str) -> None:
    """Refuse a run whose states or one-sigmas are not finite, or whose position one-sigma
    exceeds :data:`POSITION_STD_LIMIT_M`: an estimate is finite or it is not returned.

    Raises
    ------
    usvlog.errors.UnusableResultError
        Naming the model, the first bad time (s from the start) and the largest
        innovation NIS before it.
    """
    if raw.first_bad < 0:
        return
    i = raw.first_bad
    t_s = (int(pb.t_ns[i]) - int(pb.t_ns[0])) * 1e-9
    before = pb.m_t_ns <= pb.t_ns[i]
    nis = raw.innov[before, 2] if before.any() else np.zeros(0)
    worst = f"; largest NIS before it {float(np.nanmax(np.abs(nis))):.3g}" if np.isfinite(nis).any() else ""
    raise UnusableResultError(
        f"{src}: the {settings.model} estimate diverged at t = {t_s:.1f} s from the start (state not finite or "
        f"position uncertainty beyond {POSITION_STD_LIMIT_M:g} m{worst}); nothing written: check the thrust "
        "units and the sensors' noise, or use the kinematic model")


SIDESLIP_MIN_SPEED_MPS = 0.5
"""Sideslip is judged where the estimated speed exceeds this (m/s)."""
SIDESLIP_MAX_DEG = 30.0
"""A median |sideslip| beyond this (deg) while moving is no boat's: a wrong heading."""
SIDESLIP_MIN_MOVING_S = 10.0
"""...judged only when the boat moved at least this long (s)."""


def sideslip_figures(state: pd.DataFrame) -> dict | None:
    """Median |atan2(v, u)| (deg), u and |v| (m/s) where the speed exceeds
    :data:`SIDESLIP_MIN_SPEED_MPS`, and how long that was (s); None when never."""
    slip = Sideslip()
    slip.add(state)
    return slip.figures()


class Sideslip:
    """:func:`sideslip_figures` of a state frame given in consecutive time windows (:meth:`add`
    each, then :meth:`figures`): the same numbers, keeping only the moving rows' u and v and
    the counts of the time steps."""

    def __init__(self):
        self._u: list[np.ndarray] = []
        self._v: list[np.ndarray] = []
        self._steps: dict[int, int] = {}   # time step (ns) -> how often
        self._last: int | None = None

    def add(self, state: pd.DataFrame) -> None:
        """The next rows of the state frame (columns u_mps, v_mps; index t_ns)."""
        u, v = state["u_mps"].to_numpy(), state["v_mps"].to_numpy()
        moving = np.hypot(u, v) > SIDESLIP_MIN_SPEED_MPS
        self._u.append(u[moving])
        self._v.append(v[moving])
        t = np.asarray(state.index, np.int64)
        if len(t):
            steps, counts = np.unique(np.diff(t, prepend=t[:1] if self._last is None else self._last),
                                      return_counts=True)
            if self._last is None:   # (the first row has no step before it)
                counts[np.searchsorted(steps, 0)] -= 1
            for d, c in zip(steps.tolist(), counts.tolist()):
                self._steps[d] = self._steps.get(d, 0) + c
            self._last = int(t[-1])

    def figures(self) -> dict | None:
        """The figures of every row added (as :func:`sideslip_figures`)."""
        u, v = np.concatenate(self._u), np.concatenate(self._v)
        if not len(u):
            return None
        dt = _median_of_counts(self._steps) * 1e-9
        beta = np.degrees(np.abs(np.arctan2(v, u)))
        return {"median_abs_deg": float(np.median(beta)), "median_u_mps": float(np.median(u)),
                "median_abs_v_mps": float(np.median(np.abs(v))), "moving_s": float(len(u) * dt)}


def _median_of_counts(counts: dict[int, int]) -> float:
    """``numpy.median`` of integers given as value -> how often (0.0 for none)."""
    values = sorted(v for v, c in counts.items() if c > 0)
    n = sum(counts[v] for v in values)
    if not n:
        return 0.0
    ends = np.cumsum([counts[v] for v in values])
    lo, hi = values[int(np.searchsorted(ends, (n - 1) // 2, side="right"))], \
        values[int(np.searchsorted(ends, n // 2, side="right"))]
    return float(np.median(np.array([lo, hi], dtype=np.int64)))   # (the mean of the middle two, as numpy takes it)


def heading_blocking(found: HeadingOffset | None, applied_rad: float, mode: str,
                     sideslip: dict | None) -> tuple[str, ...]:
    """Why an estimate whose heading was fused must not be used: a mounting offset detected
    and not applied (its heading-based velocities are wrong), a median sideslip beyond
    :data:`SIDESLIP_MAX_DEG` while moving; each with the likely fix."""
    if mode != "gnss+compass":
        return ()
    out = []
    missed = found is not None and found.decided and abs(
        math.degrees(float(ssa(found.offset_rad - applied_rad)))) > max(MIN_OFFSET_DEG,
                                                                       MIN_OFFSET_SIGMAS * found.std_deg)
    fix = (f"heading {found.describe()} (applied {math.degrees(applied_rad):+.1f} deg): rerun with "
           f"`usvlog estimate --heading-offset auto` (or --heading-offset {found.offset_deg:.1f}, or "
           "heading_offset_deg in the vessel file's [sensors])" if missed and found is not None else "")
    if missed:
        out.append(fix)
    if sideslip and sideslip["moving_s"] >= SIDESLIP_MIN_MOVING_S and sideslip["median_abs_deg"] > SIDESLIP_MAX_DEG:
        cause = ("the heading mounting offset above" if missed else
                 "a heading mounting offset or a wrong heading source (check --heading-offset, or --gps-only)")
        out.append(f"implausible sideslip: median |beta| {sideslip['median_abs_deg']:.0f} deg while moving (u "
                   f"{sideslip['median_u_mps']:.2f} m/s, |v| {sideslip['median_abs_v_mps']:.2f} m/s), no boat's; "
                   f"likely cause: {cause}")
    return tuple(out)
