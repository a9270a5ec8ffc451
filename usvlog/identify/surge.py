"""The surge mass and damping by output error of the surge equation alone.

The paper's model shares one mass m between surge, sway and the yaw coupling (m xg). On a boat
whose sway and yaw are not of the paper's form (sway added mass unlike surge's, quadratic yaw
damping) a fit of all equations to positions and heading lets m absorb the sway and yaw mismatch
through those couplings: the boat's surge response, which the positions barely see (a time
constant of a second moves the track by less than the GPS noise), is then lost. The surge
equation of (3),

    m u_dot = tau_u + m (v + xg r) r - d11 u,

is simulated here from the recorded thrust, with the smoothed sway and yaw rates as its known
inputs, and (m, d11) with a constant current per run fitted to the smoothed surge speed. Noise on
the smoothed u is noise on the output only, which output error does not turn into bias (equation
error, whose regressors carry it, does: its m comes out low).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from .._jit import njit
from ..errors import FitFailed
from .data import RunData
from .smooth import MIN_SAMPLES, KinStates, thrust_on_grid

SEGMENT_S = 20.0    # position segments of the surge fit (s): each starts where the GPS says
BAD_RESIDUAL_M = 1e6  # position residual (m) of a sample whose surge simulation left the finite range


@dataclass(frozen=True, kw_only=True)
class SurgeFit:
    """Result of :func:`fit_surge`.

    Attributes
    ----------
    m : float
        Surge mass (kg).
    d11 : float
        Linear surge damping (kg/s).
    stderr : dict of str to float
        One-sigma standard errors of ``m`` (kg) and ``d11`` (kg/s) from the residual scatter.
    currents : numpy.ndarray, shape (n_runs, 2)
        Current north, east per run (m/s; zeros when not fitted).
    rms_m : float
        RMS of the GPS position residual (m).
    """

    m: float
    d11: float
    stderr: dict
    currents: np.ndarray
    rms_m: float


@njit
def _lag(f, a):
    """y[0] = 0, y[k+1] = a y[k] + f[k]: the first-order recursion ``scipy.signal.lfilter([0, 1],
    [1, -a], f)`` computes (the same values), without importing ``scipy.signal``."""
    y = np.empty_like(f)
    acc = 0.0
    for k in range(len(f)):
        y[k] = acc
        acc = f[k] + a * acc
    return y


def _surge_sim(p_m: float, p_d: float, tau, w, u0: float, dt: float) -> np.ndarray:
    """u on the grid: exact discretisation of m u_dot + d11 u = tau + m w, inputs held per step."""
    b = p_d / p_m
    a = np.exp(-b * dt)
    f = (1 - a) * (tau / p_d + w / b)
    y = _lag(np.ascontiguousarray(f, dtype=np.float64), float(a))
    return y + u0 * a ** np.arange(len(f))


def fit_surge(runs: list[RunData], kin: list[KinStates], m0: float, d110: float, xg: float = 0.0, *,
              fit_current: bool = True, max_current_mps: float = np.inf, segment_s: float = SEGMENT_S) -> SurgeFit:
    """Fit m and d11 of the surge equation by output error to the GPS positions.

    The simulated surge speed, with the smoothed heading and sway speed, is integrated to a
    track and fitted to the raw GPS positions in segments of ``segment_s`` seconds, each with
    its own starting position (eliminated: the segment's mean residual). The smoothed speeds
    themselves lag fast changes (the smoother's bandwidth) and would make m too large.

    Parameters
    ----------
    runs : list of RunData
        The runs (their recorded thrust drives the surge equation, their GPS is fitted).
    kin : list of KinStates
        Their smoothed states (heading, sway speed, yaw rate on a uniform grid).
    m0, d110 : float
        Starting m (kg) and d11 (kg/s), > 0.
    xg : float, default 0.0
        Longitudinal centre of gravity (m) for the m xg r^2 term.
    fit_current : bool, default True
        Fit a constant current per run.
    max_current_mps : float, default inf
        Bound on each current component (m/s).
    segment_s : float, default 20.0
        Length of the position segments (s).

    Returns
    -------
    SurgeFit

    Raises
    ------
    usvlog.errors.FitFailed
        The start is not positive and finite, there are too few smoothed samples or GNSS
        fixes to fit, or the fitted surge model is not finite (its simulation diverged).
    """
    if not (math.isfinite(m0) and m0 > 0 and math.isfinite(d110) and d110 > 0 and math.isfinite(xg)):
        raise FitFailed(f"surge fit: the start m = {m0:.4g}, d11 = {d110:.4g}, xg = {xg:.4g} is not positive "
                        "and finite")
    data = []
    for run, ks in zip(runs, kin):
        if len(ks.t) < MIN_SAMPLES:
            raise FitFailed(f"surge fit: {run.source or 'run'} has {len(ks.t)} smoothed sample(s): too short")
        tau_u, _ = thrust_on_grid(run, ks.t)
        c, s = np.cos(ks.psi), np.sin(ks.psi)
        dt = float(np.median(np.diff(ks.t)))
        g = (run.t_gps >= ks.t[0]) & (run.t_gps <= ks.t[-1])
        tg = run.t_gps[g]
        seg = np.floor((tg - ks.t[0]) / segment_s).astype(int)
        counts = np.bincount(seg)
        data.append((ks, tau_u, c, s, dt, tg, run.n_gps[g], run.e_gps[g], seg, np.maximum(counts, 1)))
    n_cur = 2 * len(runs) if fit_current else 0
    n_fix = sum(len(d[5]) for d in data)
    if 2 * n_fix <= 2 + n_cur + 2 * len(data):
        raise FitFailed(f"surge fit: {n_fix} GNSS fix(es) inside the smoothed time: too few to fit m and d11")

    def residuals(p):
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            r = _residuals(p)
        # a simulation that left the finite range (an absurd m or d11 tried): far off, not NaN
        return r if np.isfinite(r.sum()) else np.where(np.isfinite(r), r, BAD_RESIDUAL_M)

    def _residuals(p):
        m, d11 = np.exp(p[0]), np.exp(p[1])
        out = []
        for i, (ks, tau_u, c, s, dt, tg, ng, eg, seg, counts) in enumerate(data):
            cn, ce = (p[2 + 2 * i], p[3 + 2 * i]) if fit_current else (0.0, 0.0)
            wn, we = ks.vn - cn, ks.ve - ce
            u_m, v = c * wn + s * we, -s * wn + c * we
            u = _surge_sim(m, d11, tau_u, (v + xg * ks.r) * ks.r, u_m[0], dt)
            vn, ve = c * u - s * v + cn, s * u + c * v + ce
            pos = [np.concatenate([[0.0], np.cumsum(0.5 * (x[1:] + x[:-1]) * dt)]) for x in (vn, ve)]
            for x, meas in zip(pos, (ng, eg)):
                res = np.interp(tg, ks.t, x) - meas
                out.append(res - (np.bincount(seg, res) / counts)[seg])
        return np.concatenate(out)

    p0 = np.concatenate([[np.log(m0), np.log(d110)], np.zeros(n_cur)])
    lo = np.concatenate([[-np.inf, -np.inf], np.full(n_cur, -max_current_mps)])
    hi = np.concatenate([[np.inf, np.inf], np.full(n_cur, max_current_mps)])
    sol = least_squares(residuals, p0, bounds=(lo, hi), x_scale=np.concatenate([[0.3, 0.3], np.full(n_cur, 0.1)]))
    r, J = sol.fun, sol.jac
    with np.errstate(over="ignore"):
        m, d11 = float(np.exp(sol.x[0])), float(np.exp(sol.x[1]))
    if not (math.isfinite(m) and math.isfinite(d11) and m > 0 and d11 > 0) or np.any(np.abs(r) >= BAD_RESIDUAL_M):
        raise FitFailed(f"surge fit diverged (m = {m:.4g} kg, d11 = {d11:.4g} kg/s: its simulation left the "
                        "finite range)")
    sigma2 = float(r @ r) / max(len(r) - len(p0), 1)
    JtJ = J.T @ J
    cov = sigma2 * np.linalg.pinv(JtJ) if np.all(np.isfinite(JtJ)) else np.full(JtJ.shape, np.nan)
    cur = sol.x[2:].reshape(-1, 2) if fit_current else np.zeros((len(runs), 2))
    se = np.sqrt(np.maximum(np.diag(cov)[:2], 0.0)) * np.array([m, d11])
    return SurgeFit(m=m, d11=d11, stderr={"m": float(se[0]), "d11": float(se[1])}, currents=np.asarray(cur, float),
                    rms_m=float(np.sqrt(np.mean(r ** 2))))
