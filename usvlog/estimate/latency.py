"""Sensor latency: how long after the time it describes a GNSS fix or a compass heading is
stamped, estimated from the data.

A measurement stamped t describes the boat at t - delay (``EstimateSettings.gnss_delay_s``,
``compass_delay_s``; :func:`usvlog.estimate.problem.build_problem` moves the stamps). The
delay is the maximiser of the forward filter's innovation log-likelihood over a window of
the run (a profile likelihood: every other setting held): a coarse grid over
:data:`SEARCH_RANGE_S` (:data:`SEARCH_GRID_S`), then parabolic refinement, whose curvature gives the one-sigma
uncertainty 1 / sqrt(-d2 loglik / d delay2).

What makes a delay observable is a model tying the sensor's timing to something else: the
dynamic model ties the track and heading to the recorded thrust (GNSS and compass delays
both observable), the kinematic model with sway damping ties the track's direction to the
heading only weakly and the plain kinematic model not at all (the GNSS delay is then
reported as not identifiable and not applied). A flat likelihood - no drop of
:data:`PROFILE_DROP` on both sides of the optimum inside the search range - is reported
as ``not identifiable`` and the given delay is kept.

The delays used are stored in the estimate's output log (metadata record
:data:`META_LATENCY`) so that identification applies the same GNSS delay
(:func:`stored_delays`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from ..errors import ConfigError
from ..log.fieldlog import FieldLog
from ..model.frames import ssa
from .settings import DELAY_SENSORS, EstimateSettings

SEARCH_RANGE_S = (-0.1, 0.5)
"""Delays searched, s: a fix may lag its stamp by up to 0.5 s (or the clocks be offset a little)."""
SEARCH_GRID_S = (-0.1, 0.0, 0.125, 0.25, 0.375, 0.5)
"""Delays of the first pass over :data:`SEARCH_RANGE_S`, s (0 among them: the usual given value)."""
FINE_STEP_S = 0.04
"""Half-width of the parabolic refinement, s."""
WINDOW_S = {"gnss": 600.0, "compass": 200.0}
"""Length of the part of the run the likelihood is evaluated on per sensor, s (keeps the
search's cost independent of the log's length; the compass delay, tied to the recorded yaw
moment, is about 10x sharper than the GNSS one and needs less)."""
PROFILE_DROP = 1.92
"""Log-likelihood drop bounding the 95 % profile-likelihood interval (chi-square(1) 0.95 / 2)."""
MAX_STD_S = 0.1
"""A delay with a larger one-sigma (s) is not applied: the data do not determine it."""
META_LATENCY = "usvlog.latency"
"""Metadata record of an estimate's output log holding the delays it applied (s, as text)."""

SEARCH_ORDER = ("compass", "gnss")
"""The compass first: its delay, tied to the recorded yaw moment, is the sharper one, and
the GNSS delay shows against the heading too."""

LoglikFn = Callable[[FieldLog, EstimateSettings], float]


@dataclass(frozen=True)
class DelayProfile:
    """The likelihood over the delay of one sensor (the numeric result of :func:`profile_delay`).

    ``optimum_s``: the maximiser (s); ``std_s``: one-sigma from the curvature there (s, NaN
    when the likelihood is not concave); ``loglik_max``; ``identifiable``: the likelihood
    drops by :data:`PROFILE_DROP` on both sides inside the search range and ``std_s`` <=
    :data:`MAX_STD_S`; ``reason``: why not, in words (empty when identifiable);
    ``delays_s``, ``loglik``: every evaluation, sorted by delay.
    """

    optimum_s: float
    std_s: float
    loglik_max: float
    identifiable: bool
    reason: str
    delays_s: np.ndarray
    loglik: np.ndarray

    @property
    def evaluations(self) -> int:
        """Number of likelihood evaluations."""
        return len(self.delays_s)


def _parabola(x, y) -> tuple[float, float, float]:
    """(second derivative, vertex, value at the vertex) of the parabola through three points."""
    a, b, c = np.polyfit(np.asarray(x, float) - x[1], np.asarray(y, float), 2)
    if a >= 0:
        return 2 * a, float("nan"), float("nan")
    v = -b / (2 * a)
    return 2 * a, float(x[1] + v), float(c - b * b / (4 * a))


def profile_delay(loglik: Callable[[float], float], grid=SEARCH_GRID_S, fine: float = FINE_STEP_S) -> DelayProfile:
    """Maximise ``loglik(delay)`` over the span of ``grid``: the grid, then parabolas through
    three points ``fine`` apart about the running optimum (at most three, while it moves by
    more than ``fine`` / 2).

    Parameters
    ----------
    loglik : callable
        Log-likelihood of a delay in s.
    grid : sequence of float
        Delays of the first pass (increasing), s; their span is the search range.
    fine : float
        Half-width of the refinement, s.

    Returns
    -------
    DelayProfile
    """
    seen: dict[float, float] = {}

    def f(d: float) -> float:
        d = round(float(d), 6)
        if d not in seen:
            v = float(loglik(d))
            seen[d] = v if math.isfinite(v) else -math.inf
        return seen[d]

    grid = np.round(np.asarray(grid, float), 6)
    lo, hi = float(grid[0]), float(grid[-1])
    ys = np.array([f(d) for d in grid])
    i = int(np.argmax(ys))
    opt, std, reason = float(grid[i]), float("nan"), ""
    if not np.isfinite(ys[i]):
        reason = "the likelihood is not finite at any delay"
    elif i in (0, len(grid) - 1):
        reason = f"the likelihood is largest at the edge of the search range ({lo:g} to {hi:g} s)"
    else:
        _, v, _ = _parabola(grid[i - 1:i + 2], ys[i - 1:i + 2])
        opt = min(max(v, grid[i - 1]), grid[i + 1]) if math.isfinite(v) else opt
        for _ in range(3):
            x3 = np.array([opt - fine, opt, opt + fine])
            d2, v, _ = _parabola(x3, [f(x) for x in x3])
            if not (d2 < 0):
                reason = "the likelihood is not concave about its maximum"
                break
            std = 1.0 / math.sqrt(-d2)
            step = min(max(v, opt - 2 * fine), opt + 2 * fine) - opt
            opt = float(np.clip(opt + step, lo, hi))
            if abs(step) <= 0.5 * fine:
                break
    xs = np.array(sorted(seen))
    ll = np.array([seen[x] for x in xs])
    top = max(float(ll.max()), f(opt))
    if not reason:
        drop = ll < top - PROFILE_DROP
        if not (drop[xs < opt].any() and drop[xs > opt].any()):
            reason = (f"the likelihood is flat: it does not drop by {PROFILE_DROP} on both sides of its "
                      f"maximum within {lo:g} to {hi:g} s")
        elif not std <= MAX_STD_S:
            reason = f"its uncertainty ({std:.2g} s) exceeds {MAX_STD_S:g} s"
    xs = np.array(sorted(seen))
    return DelayProfile(optimum_s=float(opt), std_s=float(std), loglik_max=top, identifiable=not reason,
                        reason=reason, delays_s=xs, loglik=np.array([seen[x] for x in xs]))


@dataclass(frozen=True)
class DelayEstimate:
    """The latency of one sensor as used by an estimate.

    Attributes
    ----------
    sensor : str
        ``gnss`` or ``compass``.
    delay_s : float
        The delay applied, s (a record stamped t describes the boat at t - delay_s).
    status : str
        ``estimated`` (from the data, applied), ``not identifiable`` (the given value kept).
    std_s : float
        One-sigma of the estimate, s (NaN when not identifiable).
    optimum_s : float
        The likelihood's maximiser in the search, s (applied only when ``estimated``).
    loglik_gain : float
        Log-likelihood at ``optimum_s`` minus at the given delay (on the search window).
    evaluations : int
        Filter runs the search took.
    window_s : float
        Length of the part of the run searched, s.
    reason : str
        Why it is not identifiable, and what would help (empty otherwise).
    """

    sensor: str
    delay_s: float
    status: str
    std_s: float = float("nan")
    optimum_s: float = float("nan")
    loglik_gain: float = float("nan")
    evaluations: int = 0
    window_s: float = float("nan")
    reason: str = ""

    def to_dict(self) -> dict:
        """The fields as a JSON-ready dict (NaN as None)."""
        def num(x):
            return None if isinstance(x, float) and not math.isfinite(x) else x
        return {k: num(getattr(self, k)) for k in ("sensor", "delay_s", "status", "std_s", "optimum_s",
                                                    "loglik_gain", "evaluations", "window_s", "reason")}

    def format(self) -> str:
        """One line for the estimate's report."""
        if self.status == "estimated":
            return (f"{self.sensor} delay {self.delay_s:.3f} s +- {self.std_s:.3f} s (estimated on "
                    f"{self.window_s:.0f} s of the run; log-likelihood +{self.loglik_gain:.1f})")
        return (f"{self.sensor} delay not identifiable ({self.reason}); {self.delay_s:.3f} s kept, "
                f"likelihood maximum at {self.optimum_s:.3f} s not applied")


def search_window(log: FieldLog, window_s: float = WINDOW_S["gnss"]) -> FieldLog:
    """The part of ``log`` (about ``window_s`` s) with the most turning, as a shallow log.

    Windows of ``window_s`` start every half window over the GNSS record; the one whose
    compass heading changes most (sum of absolute steps) wins; the thrust channel keeps
    1 s before it (the command in force at its start). The whole log when it is at most
    1.5 windows long.

    Parameters
    ----------
    log : FieldLog
    window_s : float
        Length, s.

    Returns
    -------
    FieldLog
        ``log`` itself, or a copy with each channel cut to the window.
    """
    gps = log.get("/gnss/fix")
    if gps is None or len(gps) < 2:
        return log
    tg = np.asarray(gps.index, dtype=np.int64)
    span = int(tg[-1] - tg[0])
    w = int(window_s * 1e9)
    if span <= 1.5 * w:
        return log
    starts = tg[0] + np.arange(0, span - w + 1, w // 2, dtype=np.int64)
    comp = log.get("/compass/heading")
    if comp is not None and len(comp) > 2 and "heading_rad" in comp.columns:
        tc = np.asarray(comp.index, dtype=np.int64)
        hd = comp["heading_rad"].to_numpy(float)
        step = np.abs(ssa(np.diff(hd)))
        cum = np.concatenate([[0.0], np.cumsum(np.where(np.isfinite(step), step, 0.0))])
        score = cum[np.searchsorted(tc, starts + w) - 1] - cum[np.searchsorted(tc, starts)]
        a = int(starts[int(np.argmax(score))])
    else:
        a = int(starts[0])
    out = log.copy()
    for topic, frame in log.channels.items():
        t = np.asarray(frame.index, dtype=np.int64)
        i0 = np.searchsorted(t, a - (1_000_000_000 if topic == "/thrust/command" else 0))
        out.channels[topic] = frame.iloc[i0:np.searchsorted(t, a + w, side="right")]
    return out


def _hint(settings: EstimateSettings, sensor: str) -> str:
    if settings.model == "kinematic" and sensor == "gnss":
        return ("; the kinematic model ties the track to neither the thrust nor (without sway damping) the "
                "heading: use the dynamic model with the recorded thrust")
    return ("; tuned process noise (--tune), a longer run or more manoeuvring (thrust steps, turns) would help"
            if not settings.tune and settings.q_uv is None
            else "; a longer run or more manoeuvring (thrust steps, turns) would help")


def find_delays(log: FieldLog, settings: EstimateSettings, loglik: LoglikFn, window_s: dict | None = None,
                given: dict[str, float] | None = None) -> tuple[tuple[DelayEstimate, ...], EstimateSettings]:
    """Estimate the latency of each sensor in ``settings.estimate_delays`` on
    :func:`search_window`, in :data:`SEARCH_ORDER` (a later search uses the delays found
    before it).

    Parameters
    ----------
    log : FieldLog
        The run.
    settings : EstimateSettings
        Everything but the delays searched (their values are the fallback).
    loglik : callable
        ``loglik(log, settings)``: the forward filter's innovation log-likelihood.
    window_s : dict, optional
        Length of the part of the run searched per sensor, s (default :data:`WINDOW_S`).
    given : dict, optional
        Delay (s) per sensor kept where the data do not determine it, and the reference of
        ``loglik_gain``; default the values in ``settings``.

    Returns
    -------
    delays : tuple of DelayEstimate
        One per sensor searched.
    settings : EstimateSettings
        ``settings`` with the identifiable delays applied.
    """
    out = []
    for sensor in sorted(settings.estimate_delays, key=SEARCH_ORDER.index):
        sub = search_window(log, (window_s or WINDOW_S)[sensor])
        tg = np.asarray(sub["/gnss/fix"].index, dtype=np.int64) if "/gnss/fix" in sub else np.zeros(1, np.int64)
        length = float(tg[-1] - tg[0]) * 1e-9
        keep = float((given or {}).get(sensor, getattr(settings, f"{sensor}_delay_s")))
        seen: dict[float, float] = {}

        def at(d: float, _st=settings, _name=sensor, _seen=seen, _sub=sub) -> float:
            d = round(float(d), 6)
            if d not in _seen:
                _seen[d] = loglik(_sub, with_settings_delays(_st, {_name: d}))
            return _seen[d]
        prof = profile_delay(at)
        gain = prof.loglik_max - float(at(keep))
        if prof.identifiable:
            est = DelayEstimate(sensor, prof.optimum_s, "estimated", prof.std_s, prof.optimum_s, gain,
                                len(seen), length)
            settings = with_settings_delays(settings, {sensor: prof.optimum_s})
        else:
            est = DelayEstimate(sensor, keep, "not identifiable", float("nan"), prof.optimum_s, gain,
                                len(seen), length, prof.reason + _hint(settings, sensor))
            settings = with_settings_delays(settings, {sensor: keep})
        out.append(est)
    return tuple(out), settings


def with_settings_delays(settings: EstimateSettings, delays_s: dict[str, float]) -> EstimateSettings:
    """``settings`` with the delays (s) of ``delays_s`` (``{"gnss": 0.2}``) replaced."""
    return replace(settings, gnss_delay_s=float(delays_s.get("gnss", settings.gnss_delay_s)),
                   compass_delay_s=float(delays_s.get("compass", settings.compass_delay_s)))


def latency_record(settings: EstimateSettings, delays: tuple[DelayEstimate, ...] = ()) -> dict[str, str]:
    """The :data:`META_LATENCY` metadata record of an estimate: per sensor the delay applied
    (``<sensor>_delay_s``), and for searched ones ``<sensor>_delay_std_s`` and
    ``<sensor>_delay_status``; values as text (s)."""
    rec = {f"{s}_delay_s": repr(float(getattr(settings, f"{s}_delay_s"))) for s in DELAY_SENSORS}
    for d in delays:
        rec[f"{d.sensor}_delay_std_s"] = repr(float(d.std_s))
        rec[f"{d.sensor}_delay_status"] = d.status
    return rec


def stored_delays(log: FieldLog) -> dict[str, float]:
    """The delays (s) an estimate stored in ``log`` (``{"gnss": ..., "compass": ...}``), empty
    when the log has no :data:`META_LATENCY` record; unreadable values are left out."""
    rec = log.meta.get(META_LATENCY) or {}
    out = {}
    for s in DELAY_SENSORS:
        try:
            v = float(rec[f"{s}_delay_s"])
        except (KeyError, TypeError, ValueError):
            continue
        if math.isfinite(v):
            out[s] = v
    return out


def with_delays(log: FieldLog, **delays_s: float) -> FieldLog:
    """A shallow copy of ``log`` whose :data:`META_LATENCY` record holds the given delays
    (``gnss=0.2``, ``compass=0.0``, s), e.g. to tell identification a known GNSS delay."""
    out = log.copy()
    rec = dict(out.meta.get(META_LATENCY) or {})
    for s, v in delays_s.items():
        if s not in DELAY_SENSORS:
            raise ConfigError(f"no delay of sensor {s!r} (known: {', '.join(DELAY_SENSORS)})")
        rec[f"{s}_delay_s"] = repr(float(v))
        rec[f"{s}_delay_status"] = "given"
        rec.pop(f"{s}_delay_std_s", None)
    out.meta[META_LATENCY] = rec
    return out
