"""Output-error identification by multiple shooting.

The model (eqs. (1)+(3), constant current per run) is integrated from the recorded
thrust over segments of ``segment_s`` seconds, each from its own free initial state, and
fitted to the raw measurements: GPS north/east and compass heading (ssa residual), each
weighted by its noise. The segment initial states are nuisance parameters eliminated by
variable projection: for given model parameters and currents each segment's initial state
is solved by Gauss-Newton, and :func:`scipy.optimize.least_squares` sees the projected
Jacobian (so its normal matrix is the marginal information of the parameters of interest;
standard errors come from it scaled by the residual variance).

The pieces: :mod:`.problem` (the segments, residuals and sensitivities, in blocks of segments
of about half an hour of log: memory of a block, not of the run), :mod:`.projection`
(the initial states solved and projected out, block by block), :mod:`.free_run` (free runs of the fitted
model); here the fit driver :func:`fit_output_error` and its :class:`OutputErrorResult`.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import least_squares

from ..errors import FitFailed
from ..model.vessel import PARAM_NAMES
from .data import RunData
from .free_run import _state_at, fit_initial_state, predict_segments, simulate_run
from .problem import (
    BAD_RESIDUAL,
    DIVERGED,
    JAC_MAX,
    MAX_DT,
    MAX_STIFFNESS,
    R_E,
    R_N,
    R_PSI,
    R_R,
    R_VE,
    R_VN,
    SENSOR_OF_ROW,
    SENSORS,
    VEL_SIGMA,
    Problem,
    _fmt,
    coarse_run,
    max_step,
    problem_blocks,
    stiffness,
)
from .projection import _VP, compress_lsq

__all__ = [
    "BAD_RESIDUAL", "DIVERGED", "JAC_MAX", "MAX_DT", "MAX_STIFFNESS", "OUTLIER_SIGMA", "R_E", "R_N", "R_PSI",
    "R_R", "R_VE", "R_VN", "SENSORS", "SENSOR_OF_ROW", "VEL_SIGMA", "VEL_STEP_S", "OutputErrorResult", "Problem",
    "coarse_run", "compress_lsq", "fit_initial_state", "fit_output_error", "max_step", "predict_segments",
    "simulate_run", "stiffness", "velocity_samples",
]

OUTLIER_SIGMA = 5.0
VEL_STEP_S = 0.5        # spacing of the velocity measurements (s)


@dataclass(frozen=True, kw_only=True)
class OutputErrorResult:
    """Result of :func:`fit_output_error`.

    ``theta``: all six parameters m (kg), Iz (kg m^2), d11, d22 (kg/s), d33 (kg m^2/s),
    xg (m), fixed ones included; ``free``: names of the fitted ones; ``currents``
    (n_runs, 2): north, east in m/s (zeros when not fitted); ``cov``: covariance of
    [free parameters, currents] with row names ``names`` (``current_n_<i>``,
    ``current_e_<i>``); ``cond``: condition number of the column-scaled projected
    Jacobian; ``sigma2``: residual variance factor (1 when the noise model is right);
    ``rms``: RMS of the noise-weighted residuals per sensor (``gps``, ``compass``);
    ``n_residuals``; ``x0s`` (n_segments, 6): each segment's fitted initial state
    [n (m), e (m), psi (rad), u (m/s), v (m/s), r (rad/s)]; ``nfev``: model evaluations;
    ``outliers``: measurements dropped as outliers, per sensor; ``diverged``: the model's
    simulation left the finite range at the solution (a failed fit, not a number).
    """

    theta: np.ndarray          # all six model parameters (fixed ones included)
    free: tuple[str, ...]      # names of fitted model parameters
    currents: np.ndarray       # (n_runs, 2) north, east m/s (zeros when not fitted)
    cov: np.ndarray            # covariance of [free params, currents (if fitted)]
    names: tuple[str, ...]     # names of the covariance's rows
    cond: float                # condition number of the column-scaled projected Jacobian
    sigma2: float              # residual variance factor (1 when the noise model is right)
    rms: dict                  # whitened-residual RMS per sensor
    n_residuals: int
    x0s: np.ndarray            # per-segment initial states
    nfev: int
    outliers: dict | None = None  # measurements dropped as outliers, per sensor
    diverged: bool = False     # the simulation left the finite range at the solution



_PARAM_LO = np.array([1e-3, 1e-4, 1e-6, 1e-6, 1e-6, -np.inf])   # lower bounds of m, Iz, d11, d22, d33, xg


def _check_fit_input(runs: list[RunData], theta, currents) -> None:
    """FitFailed unless the start is finite and every run has thrust to integrate over."""
    if len(theta) != 6 or not np.all(np.isfinite(theta)):
        raise FitFailed(f"the start values {_fmt(theta)} are not six finite numbers")
    if not np.all(np.isfinite(currents)):
        raise FitFailed("the start currents are not finite")
    if not runs:
        raise FitFailed("no runs to fit")
    for i, r in enumerate(runs):
        if len(r.t_thrust) < 2 or not r.t_thrust[-1] > r.t_thrust[0]:
            raise FitFailed(f"run {i} ({r.source or 'log'}): less than two thrust samples in the fitted time: "
                            "nothing to integrate")



def _bounds(free_mask, n_cur, max_current=np.inf):
    """Box of [free params, currents]: inertias and damping positive, |current| per axis bounded."""
    lo = _PARAM_LO[free_mask]
    hi = np.full(len(lo), np.inf)
    return (np.concatenate([lo, np.full(n_cur, -max_current)]), np.concatenate([hi, np.full(n_cur, max_current)]))


def _group_scales(prob: _Blocks, robust, vel_weight: float) -> np.ndarray:
    """Noise scale per sensor group: the robust scatter, and for the velocity groups a factor
    that gives them ``vel_weight`` times the weight of the position rows in total."""
    out = np.asarray(robust, float).copy()
    n_pos = int(np.sum(prob.r_sensor <= 1))
    for k in (2, 3):
        n_k = int(np.sum(prob.r_sensor == k))
        if n_k and vel_weight > 0:
            out[k] /= np.sqrt(vel_weight * n_pos / (2 * n_k))
        elif n_k:
            out[k] = 1e12   # weight zero
    return out


def velocity_samples(t, vn, ve, r, step_s: float = VEL_STEP_S):
    """Every ``step_s`` of smoothed ground velocity (north, east, m/s) and yaw rate (rad/s) at
    times ``t`` (s), as the velocity measurements of :func:`fit_output_error`."""
    t = np.asarray(t, float)
    k = max(1, int(round(step_s / max(float(np.median(np.diff(t))), 1e-9)))) if len(t) > 1 else 1
    return t[::k], np.asarray(vn, float)[::k], np.asarray(ve, float)[::k], np.asarray(r, float)[::k]


def fit_output_error(runs: list[RunData], theta0, x0_fn, *, free_mask=None, fit_current=True,
                     currents0=None, segment_s=300.0, warm_segment_s=60.0, reweight=True,
                     max_nfev=60, verbose=0, warm_span_s=None, velocities=None, vel_weight=0.0,
                     max_current_mps=np.inf, drop_outliers=True) -> OutputErrorResult:
    """Fit the model parameters (and per-run currents) to GPS and compass by output error.

    ``theta0``: starting (m, Iz, d11, d22, d33, xg); ``x0_fn(run_index, t_s) -> (6,)``
    initial-state guesses (n, e, psi, u, v, r) for segment starts.

    Parameters
    ----------
    runs : list of RunData
    theta0 : array_like, shape (6,)
        Starting m (kg), Iz (kg m^2), d11, d22 (kg/s), d33 (kg m^2/s), xg (m); fixed
        parameters keep these values.
    x0_fn : callable
        ``x0_fn(run_index, t_s)`` -> initial-state guess [n (m), e (m), psi (rad),
        u (m/s), v (m/s), r (rad/s)] at ``t_s`` s of that run.
    free_mask : array_like of bool, shape (6,), optional
        Which parameters to fit (default all).
    fit_current : bool, default True
        Fit a constant current per run.
    currents0 : array_like, shape (n_runs, 2), optional
        Starting (or, unfitted, fixed) currents north, east in m/s (default zeros).
    segment_s : float, default 300.0
        Segment length in s of the final fit.
    warm_segment_s : float, default 60.0
        Segment length in s of a warm-up fit (used when 0 < warm_segment_s < segment_s).
    reweight : bool, default True
        After each stage weight each sensor by its robust residual scatter.
    max_nfev : int, default 60
        Evaluation limit of each least-squares stage.
    verbose : int, default 0
        Passed to :func:`scipy.optimize.least_squares`.
    warm_span_s : float, optional
        Fit the warm-up stage only on the first ``warm_span_s`` s of each run.
    velocities : list, optional
        Per run None or (t (s), vn, ve (m/s over ground), r (rad/s)) smoothed velocities
        (:func:`velocity_samples`), fitted too so that a wrong current cannot buy a better
        position fit with absurd dynamics.
    vel_weight : float, default 0.0
        Total weight of the velocity rows relative to the GPS and compass rows (0: not fitted).
    max_current_mps : float, default inf
        Bound on each current component, m/s.
    drop_outliers : bool, default True
        Drop GNSS fixes and compass headings beyond OUTLIER_SIGMA robust sigmas of the fit and
        solve again (off for noise-free measurements, whose robust sigma is nothing: the smoother-
        bias check's, :mod:`usvlog.identify.smoother_bias`).

    Returns
    -------
    OutputErrorResult
        Standard errors come from the GPS and compass rows only (the velocities are
        derived from them: counting them again would overstate the information).
        ``diverged`` is True when the model's simulation left the finite range at the end.

    Raises
    ------
    usvlog.errors.FitFailed
        The start is not finite, a run has less than two thrust samples, there is no GNSS
        fix or compass heading to fit, or the fit's numbers left the finite range. (A
        simulation that diverges at some trial parameters is not an error: the fit steps
        back; at the solution it is ``diverged``.)
    """
    free = np.ones(6, bool) if free_mask is None else np.asarray(free_mask, bool)
    cur = np.zeros((len(runs), 2)) if currents0 is None else np.asarray(currents0, float)
    cur = np.clip(cur, -max_current_mps, max_current_mps)
    theta = np.asarray(theta0, float).copy()
    _check_fit_input(runs, theta, cur)
    # a free start below its bound (a near-zero mass or damping from a poor equation-error fit)
    # starts at the bound: the warm-up's box about the start stays a box
    theta = np.where(free, np.maximum(theta, _PARAM_LO * 1.01), theta)
    nfev = 0
    stages = [warm_segment_s, segment_s] if warm_segment_s and warm_segment_s < segment_s else [segment_s]
    robust = np.ones(4)
    x0_kin = x0_fn

    def problem(rr, seg_s):
        return _Blocks(problem_blocks(rr, seg_s, velocities if vel_weight > 0 else None))

    for si, seg_s in enumerate(stages):
        last = si == len(stages) - 1
        runs_s = runs
        if not last and warm_span_s:
            # the warm-up only needs to get close: fit it on the first warm_span_s of each run
            runs_s = [r.window(r.t_thrust[0], r.t_thrust[0] + warm_span_s) for r in runs]
        prob = problem(runs_s, seg_s)
        if prob.n_res == 0:
            raise FitFailed("no GNSS fix or compass heading inside the fitted time: nothing to fit")
        prob.set_sensor_scale(_group_scales(prob, robust, vel_weight))
        x0s = prob.initial_states(x0_fn)
        vp = _VP(prob.blocks, theta, free, fit_current, x0s, cur)
        p0 = vp.pack(theta, cur)
        lo, hi = _bounds(free, len(p0) - int(free.sum()), max_current_mps)
        p0 = np.clip(p0, lo + 1e-9, hi)
        if not last:
            # keep the warm-up stage near the start: short segments leave slow modes weak
            th_lo = np.where(theta > 0, theta / 3, -1.0)
            th_hi = np.where(theta > 0, theta * 3, 1.0)
            th_lo[5], th_hi[5] = -abs(theta[5]) - 0.3, abs(theta[5]) + 0.3
            nf = int(free.sum())
            lo = lo.copy()
            hi = hi.copy()
            lo[:nf], hi[:nf] = np.maximum(th_lo[free], lo[:nf]), th_hi[free]
            p0 = np.clip(p0, lo + 1e-9, hi - 1e-9)
        sol = least_squares(vp.fun_small, p0, jac=vp.jac_small, bounds=(lo, hi), x_scale="jac", method="trf",
                            ftol=1e-8 if last else 1e-6, xtol=1e-8 if last else 1e-6,
                            gtol=1e-8 if last else 1e-6, max_nfev=max_nfev, verbose=verbose)
        nfev += vp.nfev
        theta, cur = vp.unpack(sol.x)
        vp._eval(sol.x)
        if reweight:   # each sensor weighted by its own (robust) residual scatter from here on
            robust = robust * np.asarray(_robust_scale(prob, vp._r))
        # capture initial states for the next stage
        x0_prev = (prob, vp.x0s.copy())

        theta_prev, cur_prev = theta.copy(), cur.copy()

        def x0_fn(run, t, _p=x0_prev, _theta=theta_prev, _cur=cur_prev):
            if t > _p[0].end_s(run) - 1.0:
                return x0_kin(run, t)
            return _p[0].state_at(_p[1], _theta, _cur, run, t)
    # outliers (GPS jumps, compass glitches): drop measurements beyond OUTLIER_SIGMA robust
    # sigmas and solve again from where it stands (same segments, warm initial states)
    outliers = {"gps": 0, "compass": 0}
    for _ in range(3 if drop_outliers else 0):
        sc = np.asarray(_robust_scale(prob, vp._r))
        bad = (np.abs(vp._r) > OUTLIER_SIGMA * sc[prob.r_sensor]) & (prob.r_sensor <= 1)
        if not bad.any():
            break
        runs, n_gps, n_comp = prob.without(runs, bad)
        outliers["gps"] += n_gps
        outliers["compass"] += n_comp
        prob = problem(runs, stages[-1])
        prob.set_sensor_scale(_group_scales(prob, robust, vel_weight))
        vp = _VP(prob.blocks, theta, free, fit_current, vp.x0s, cur)
        p0 = vp.pack(theta, cur)
        lo, hi = _bounds(free, len(p0) - int(free.sum()), max_current_mps)
        sol = least_squares(vp.fun_small, np.clip(p0, lo + 1e-9, hi), jac=vp.jac_small, bounds=(lo, hi), x_scale="jac",
                            method="trf", ftol=1e-8, xtol=1e-8, gtol=1e-8, max_nfev=max_nfev, verbose=verbose)
        nfev += vp.nfev
        theta, cur = vp.unpack(sol.x)
        vp._eval(sol.x)
    rms = {k: float(np.sqrt(np.mean(vp._r[prob.r_sensor == i] ** 2)))
           for i, k in enumerate(SENSORS) if np.any(prob.r_sensor == i)}
    diverged, x0s = bool(vp.diverged), vp.x0s
    pos = prob.r_sensor <= 1          # the raw measurements carry the information
    r = vp._r[pos]
    G = vp.jac_positions(sol.x)       # their rows of the projected Jacobian, as few (the same G^T G)
    n_res = len(r)
    n_par = G.shape[1] + 6 * prob.n_seg
    sigma2 = float(r @ r) / max(n_res - n_par, 1)
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        colnorm = np.linalg.norm(G, axis=0)
        colnorm[colnorm == 0] = 1.0
        Gs = G / colnorm
        ok = bool(np.all(np.isfinite(Gs)) and np.all(np.isfinite(colnorm)) and np.isfinite(sigma2) and n_res)
        cond = float(np.linalg.cond(Gs)) if ok else float("inf")
        cov = sigma2 * np.linalg.pinv(Gs.T @ Gs) / np.outer(colnorm, colnorm) if np.isfinite(cond) else \
            np.full((G.shape[1], G.shape[1]), np.nan)
    names = tuple(n for n, f in zip(PARAM_NAMES, free) if f)
    if fit_current:
        names += tuple(f"current_{ax}_{i}" for i in range(len(runs)) for ax in ("n", "e"))
    return OutputErrorResult(theta=theta, free=tuple(n for n, f in zip(PARAM_NAMES, free) if f),
                             currents=np.asarray(cur, float) if fit_current else np.zeros((len(runs), 2)),
                             cov=cov, names=names, cond=cond, sigma2=sigma2, rms=rms, n_residuals=n_res,
                             x0s=x0s, nfev=nfev, outliers=outliers, diverged=diverged)


def _robust_scale(prob: _Blocks, r) -> tuple[float, ...]:
    """Per-sensor-group scatter of whitened residuals, 1.4826 median |r| (sigma for Gaussian noise)."""
    out = []
    for k in range(4):
        a = np.abs(r[prob.r_sensor == k])
        out.append(float(1.4826 * np.median(a)) if len(a) else 1.0)
    return tuple(x or 1.0 for x in out)


class _Blocks:
    """The output-error problem in blocks of segments (:func:`~usvlog.identify.problem.problem_blocks`),
    as the fit asks of it: its residual rows' sensor groups, counts and weights, the initial
    states, the fitted model's state at a time, the measurements an outlier scan drops."""

    def __init__(self, blocks: list[tuple[Problem, int]]):
        self.blocks = blocks
        self.n_res = sum(b.n_res for b, _ in blocks)
        self.n_seg = sum(b.n_seg for b, _ in blocks)
        self.r_sensor = np.concatenate([b.r_sensor for b, _ in blocks]) if blocks else np.zeros(0, np.int8)
        self._seg0 = np.cumsum([0] + [b.n_seg for b, _ in blocks])
        self._res0 = np.cumsum([0] + [b.n_res for b, _ in blocks])

    def set_sensor_scale(self, scales) -> None:
        """:meth:`Problem.set_sensor_scale` of every block."""
        for b, _ in self.blocks:
            b.set_sensor_scale(scales)

    def initial_states(self, states_fn):
        """x0 per segment (all blocks') from a function (run index, t (s)) -> states (6,)."""
        return np.concatenate([b.initial_states(lambda _, t, ri=ri: states_fn(ri, t)) for b, ri in self.blocks])

    def end_s(self, run: int) -> float:
        """The last time (s) of a run's coarse thrust grid."""
        return max(float(b.tg[-1]) for b, ri in self.blocks if ri == run)

    def state_at(self, x0s, theta, cur, run: int, t: float):
        """State of the fitted multiple-shooting model at time t of a run (from its segment)."""
        mine = [i for i, (_, ri) in enumerate(self.blocks) if ri == run]
        i = next((i for i in reversed(mine) if self.blocks[i][0].tg[0] <= t + 1e-9), mine[0])
        return _state_at(self.blocks[i][0], x0s[self._seg0[i]:self._seg0[i + 1]], theta, cur[[run]], 0, t)

    def without(self, runs: list[RunData], bad_rows) -> tuple[list[RunData], int, int]:
        """Runs without the measurements behind the flagged residual rows; how many GPS fixes and
        compass headings that drops."""
        tg: list[list[np.ndarray]] = [[] for _ in runs]
        tc: list[list[np.ndarray]] = [[] for _ in runs]
        for i, (b, ri) in enumerate(self.blocks):
            m = np.unique(b.r_meas[bad_rows[self._res0[i]:self._res0[i + 1]]])
            tg[ri].append(b.meas_t[m[b.kind[m] == 0]])
            tc[ri].append(b.meas_t[m[b.kind[m] == 1]])
        out = []
        for run, g_drop, c_drop in zip(runs, tg, tc):
            g = ~np.isin(run.t_gps, np.concatenate(g_drop) if g_drop else [])
            c = ~np.isin(run.t_compass, np.concatenate(c_drop) if c_drop else [])
            out.append(replace(run, t_gps=run.t_gps[g], n_gps=run.n_gps[g], e_gps=run.e_gps[g],
                               sigma_gps=run.sigma_gps[g], t_compass=run.t_compass[c],
                               psi_compass=run.psi_compass[c], sigma_compass=run.sigma_compass[c]))
        n_gps = sum(len(np.concatenate(x)) for x in tg if x)
        n_comp = sum(len(np.concatenate(x)) for x in tc if x)
        return out, n_gps, n_comp
