"""First-order thruster lag: applied to a run's thrust, and identified from the data.

A thruster does not deliver a commanded force at once: its propeller spins up with a time
constant from a tenth of a second (a small electric thruster) to a second or more (a large
propeller, a slow ESC ramp). Model (3) takes the force as commanded, so a lag it is not told
of is absorbed by the inertia and damping: the paper's vessel simulated with a 0.8 s lag and
identified as if it had none gives Iz +79 %, d33 -40 %, d11 -31 %, and a verdict "usable"
(measured, 600 s excitation run).

* :func:`usvlog.identify.data.lag_thrust`: the run's force and moment through a first-order lag of time constant
  ``lag_s`` (the vessel file's ``[thrusters] lag_s``, which the simulator's plant uses too).
  The model holds its input over each thrust step, so each step gets the mean over the step
  of the lag's exact response to the command held there.
* :func:`fit_thruster_lag`: the lag as an identified parameter, in two steps.

  1. A profile on the smoothed velocities, robust from any start: for a lag, the paper
     model's velocity output error (:func:`usvlog.identify.velocity.fit_velocity_error`, 5 s
     windows: the lag is a fast effect) is fitted on the lagged thrust, each lag from the
     fit before; the lag is the one whose fit leaves the least u and r residual (the
     likelihood with an unknown noise level per channel, ``n_eff (log rms_u + log rms_r)``),
     found on a grid and refined between its neighbours. Its 95 % interval is where that
     profile rises by 1.92 (chi-square, one degree of freedom), with ``n_eff`` the number of
     independent residuals (lag-one autocorrelation rho: ``n (1 - rho) / (1 + rho)``):
     smoothed states predicted a few seconds ahead are strongly correlated, and counting
     every sample would make the interval far too narrow. The smoother rounds off the
     velocities' fastest changes, which this profile reads as lag: measured +0.16 s on a boat
     with none and +0.12 s on one with 0.8 s (the paper's vessel, 600 s excitation runs).
  2. A refinement on the raw fixes and headings, which carry no smoother: from 0 to that
     interval's upper end, the position output error
     (:func:`usvlog.identify.output.fit_output_error`, each fit from the velocity fit's
     parameters) is fitted at evenly spaced lags; the most likely (``n_gps log rms_gps +
     n_compass log rms_compass``, whitened residuals) is refined by a parabola through its
     neighbours. On the same runs: 0.000 s for none, 0.798 s for 0.8 s. Kept only where that
     best is inside the range (else the velocity profile's lag stands, e.g. a model so far
     from the boat that its position fits jump between solutions); the interval reported is
     the velocity profile's, widened to include it.

  On a hull the paper's model does not describe (the catamaran of the extended structure,
  0.6 s lag) the lag comes out 0.43 s (interval 0.31-0.60 s): a lag is then partly a stand-in
  for the missing terms.

Pure numpy and scipy: arrays in, a :class:`RunData` or a :class:`LagFit` out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize_scalar

from .data import RunData, lag_thrust
from .output import fit_output_error
from .smooth import KinStates
from .velocity import fit_velocity_error

LAG_GRID_S = (0.0, 0.1, 0.2, 0.4, 0.8, 1.6, 3.2)   # lags (s) the profile is first evaluated at
LAG_HORIZONS_S = (5.0,)   # window length of the fits for the profile: the lag is a fast effect
LAG_CHANNELS = ("u", "r")   # the channels the thrust drives directly
POSITION_SEGMENT_S = 60.0   # segment length (s) of the position output error refining the lag
POSITION_POINTS = 9         # lags it evaluates from 0 to the velocity profile's upper bound
CHI2_95_HALF = 1.92            # half the 95 % point of chi-square with one degree of freedom


@dataclass(frozen=True, kw_only=True)
class LagFit:
    """Result of :func:`fit_thruster_lag`.

    ``lag_s``: the identified time constant (s); ``ci95``: its 95 % profile interval (s; the
    upper end ``inf`` when the profile never rises enough inside the grid; widened to include
    ``lag_s``); ``at_bound``:
    the best lag is the grid's largest (the data ask for more: a lag alone may not be what
    is missing); ``profile``: ((lag s, profile value), ...) of every lag evaluated, the value
    relative to the best (0 there); ``n_eff``: independent residuals counted;
    ``velocity_lag_s``: the velocity profile's best lag (``lag_s`` is the position output
    error's refinement of it inside ``ci95`` when that has an interior best, else the same);
    ``other_lag_s``: a second minimum of the profile that fits about as well (inside the 95 %
    level, a lag between the two above it; NaN when there is none): in surge a thruster lag and
    the hull's time constant are interchangeable, so a profile can have two, and ``ci95`` then
    spans both.
    """

    lag_s: float
    ci95: tuple[float, float]
    at_bound: bool
    profile: tuple
    n_eff: float
    velocity_lag_s: float = math.nan
    other_lag_s: float = math.nan

    def to_dict(self) -> dict:
        """Plain numbers for JSON (an infinite bound as None)."""
        hi = self.ci95[1] if math.isfinite(self.ci95[1]) else None
        return {"lag_s": self.lag_s, "ci95": [self.ci95[0], hi], "at_bound": self.at_bound,
                "profile": [[a, b] for a, b in self.profile], "n_eff": self.n_eff,
                "velocity_lag_s": self.velocity_lag_s,
                "other_lag_s": self.other_lag_s if math.isfinite(self.other_lag_s) else None}


def _n_eff(res: np.ndarray) -> float:
    """Independent samples in residual series (columns): n (1 - rho) / (1 + rho) with rho the
    lag-one autocorrelation, the smallest over the columns."""
    out = []
    for col in np.asarray(res, float).T:
        col = col[np.isfinite(col)]
        if len(col) < 3:
            continue
        c = col - col.mean()
        den = float(c @ c)
        rho = float(c[1:] @ c[:-1]) / den if den > 0 else 0.0
        rho = min(max(rho, 0.0), 0.999)
        out.append(len(col) * (1 - rho) / (1 + rho))
    return max(min(out), 1.0) if out else 1.0


def fit_thruster_lag(runs: list[RunData], kin: list[KinStates], theta0, *, fit_current: bool = True,
                     max_current_mps: float = 0.5, grid_s=LAG_GRID_S) -> LagFit:
    """Identify a first-order thruster lag from the runs (see the module doc).

    Parameters
    ----------
    runs : list of RunData
        The runs as recorded (no lag applied).
    kin : list of KinStates
        Their smoothed states.
    theta0 : array_like, shape (6,)
        Start of the paper model's parameters (m, Iz, d11, d22, d33, xg) for the first lag;
        each further lag starts from the fit before.
    fit_current : bool, default True
        Fit a current per run with the parameters.
    max_current_mps : float, default 0.5
        Bound on each current component (m/s).
    grid_s : sequence of float, default LAG_GRID_S
        Lags (s, increasing) evaluated first.

    Returns
    -------
    LagFit
    """
    theta = np.asarray(theta0, float)
    cache: dict[float, tuple] = {}   # lag -> (value, residuals, theta, currents)

    def fit(lag: float):
        nonlocal theta
        lag = float(lag)
        if lag not in cache:
            res = fit_velocity_error([lag_thrust(r, lag) for r in runs], kin, theta, fit_current=fit_current,
                                     max_current_mps=max_current_mps, horizons_s=LAG_HORIZONS_S)
            rms = np.array([res.rms[c] for c in LAG_CHANNELS])
            value = float(np.sum(np.log(np.maximum(rms, 1e-12)))) if not res.diverged and np.all(np.isfinite(rms)) \
                else math.inf
            cache[lag] = (value, res.residuals, res.theta, res.currents)
            if math.isfinite(value):
                theta = res.theta
        return cache[lag][0]

    grid = [float(g) for g in grid_s]
    values = [fit(g) for g in grid]
    i = int(np.argmin(values))
    best = grid[i]
    if 0 < i < len(grid) - 1:   # refine between the neighbours, in the logarithm of the lag
        lo, hi = max(grid[i - 1], 0.5 * grid[i]), grid[i + 1]
        sol = minimize_scalar(lambda z: fit(math.exp(z)), bounds=(math.log(lo), math.log(hi)), method="bounded",
                              options={"xatol": 0.03, "maxiter": 10})
        if fit(math.exp(float(sol.x))) < fit(best):
            best = math.exp(float(sol.x))
    v0 = fit(best)
    n_eff = _n_eff(cache[best][1])
    lags = sorted(cache)
    prof = [(lag, n_eff * (cache[lag][0] - v0)) for lag in lags]
    ci = _interval(prof, best)
    on_positions = None
    if math.isfinite(ci[1]) and ci[1] > 0:
        on_positions = _refine_on_positions(runs, kin, ci, cache[best][2], cache[best][3], fit_current,
                                            max_current_mps)
    lag = float(best if on_positions is None else on_positions)
    return LagFit(lag_s=lag, ci95=(min(ci[0], lag), max(ci[1], lag)),
                  at_bound=bool(best >= grid[-1]), profile=tuple(prof), n_eff=float(n_eff),
                  velocity_lag_s=float(best), other_lag_s=_other_minimum(prof, best))


def _refine_on_positions(runs, kin, ci, theta, currents, fit_current: bool, max_current_mps: float) -> float | None:
    """The lag from 0 to the upper end of the velocity profile's interval ``ci`` whose position output error
    (:func:`~usvlog.identify.output.fit_output_error` on the raw fixes and headings, each fit
    from the velocity fit's parameters at its best lag) has the highest likelihood
    (``n_gps log rms_gps + n_compass log rms_compass``, whitened residuals); None when that
    best is that upper end or a fit fails (the velocity profile's lag stands)."""
    n_gps = sum(2 * len(r.t_gps) for r in runs)
    n_compass = sum(len(r.t_compass) for r in runs)

    def value(lag: float) -> float:
        oe = fit_output_error([lag_thrust(r, lag) for r in runs], theta, lambda i, t: kin[i].at(t),
                              currents0=currents, fit_current=fit_current, segment_s=POSITION_SEGMENT_S,
                              warm_segment_s=0.0, max_current_mps=max_current_mps)
        rms = np.array([oe.rms.get("gps", math.nan), oe.rms.get("compass", math.nan)])
        if oe.diverged or not np.all(np.isfinite(rms) & (rms > 0)):
            return math.inf
        return float(n_gps * math.log(rms[0]) + n_compass * math.log(rms[1]))

    lags = np.linspace(0.0, ci[1], POSITION_POINTS)
    vals = np.array([value(float(x)) for x in lags])
    i = int(np.argmin(vals))
    if np.isfinite(vals[i]) and i == 0:
        return 0.0   # no lag: the end of the lag's own range
    if not np.isfinite(vals[i]) or i == len(lags) - 1 or not np.all(np.isfinite(vals[i - 1:i + 2])):
        return None
    # the vertex of the parabola through the best and its neighbours (equally spaced)
    a, b, c = vals[i - 1], vals[i], vals[i + 1]
    den = a - 2 * b + c
    h = lags[1] - lags[0]
    shift = 0.5 * h * (a - c) / den if den > 0 else 0.0
    return float(np.clip(lags[i] + shift, lags[i - 1], lags[i + 1]))


def _interval(prof: list, best: float) -> tuple[float, float]:
    """The lags where the profile ((lag, value), ... increasing lags, 0 at ``best``) is within
    CHI2_95_HALF: from where it crosses that level below the lowest such lag to where it crosses
    it above the highest, linearly between the evaluated lags; 0 below and ``inf`` above when it
    never does. A second minimum inside the level widens it to span both."""
    lags = np.array([a for a, _ in prof])
    vals = np.array([b for _, b in prof])
    inside = np.flatnonzero(vals <= CHI2_95_HALF)
    if len(inside) == 0:   # only the best itself (a value of 0) can be: not a profile
        return float(best), float(best)

    def cross(j_in: int, j_out: int) -> float:
        a, b = vals[j_in], vals[j_out]
        if not math.isfinite(b):
            return float(lags[j_out])
        w = (CHI2_95_HALF - a) / (b - a) if b != a else 1.0
        return float(lags[j_in] + w * (lags[j_out] - lags[j_in]))

    j0, j1 = int(inside[0]), int(inside[-1])
    lo = cross(j0, j0 - 1) if j0 > 0 else 0.0
    hi = cross(j1, j1 + 1) if j1 < len(lags) - 1 else math.inf
    return lo, hi


def _other_minimum(prof: list, best: float) -> float:
    """The lowest other local minimum of the profile inside CHI2_95_HALF, with a lag above that
    level between it and ``best``; NaN when there is none."""
    lags = np.array([a for a, _ in prof])
    vals = np.array([b for _, b in prof])
    ib = int(np.argmin(np.abs(lags - best)))
    out, v_out = math.nan, math.inf
    for j in range(len(lags)):
        lo, hi = min(j, ib), max(j, ib)
        if vals[j] > CHI2_95_HALF or not np.any(vals[lo:hi + 1] > CHI2_95_HALF):
            continue
        local = (j == 0 or vals[j] <= vals[j - 1]) and (j == len(lags) - 1 or vals[j] <= vals[j + 1])
        if local and vals[j] < v_out:
            out, v_out = float(lags[j]), float(vals[j])
    return out


__all__ = ["LAG_GRID_S", "LagFit", "fit_thruster_lag"]
