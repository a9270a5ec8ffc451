"""Identification of the extended 3-DOF model (:class:`usvlog.model.vessel.ExtendedParams`).

Equation error: the model is linear in its ten parameters
theta = (m11, m22, m26, m66, d11, d11q, d22, d22q, d33, d33q):

    surge:  m11 u_dot - m22 v r - m26 r^2 + d11 u + d11q |u| u                      = tau_u
    sway:   m22 v_dot + m26 r_dot + m11 u r + d22 v + d22q |v| v                      = 0
    yaw:    m26 (v_dot + u r) + m66 r_dot + (m22 - m11) u v + d33 r + d33q |r| r     = tau_r

The three equations are fitted jointly, each weighted by its residual scatter (sway, which
theta = 0 satisfies, never weighing more than surge); bounded least squares keeps inertia
> 0 and damping >= 0.

Free runs for validation: the water-relative body velocity obeys the model whatever the
heading (a constant current drops out), so three states simulated through the recorded
thrust (compiled) compare a model with the smoothed u, v, r.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import lsq_linear

from .._jit import njit
from ..choices import EXTENDED_PARAM_NAMES
from ..model.stats import fit_percent
from ..model.vessel import ExtendedParams, nu_dot_ext_terms
from .data import RunData
from .smooth import KinStates

NE = len(EXTENDED_PARAM_NAMES)
_IX = {k: i for i, k in enumerate(EXTENDED_PARAM_NAMES)}
_INERTIA = ("m11", "m22", "m66")
MAX_DT = 0.05


def ext_regressors(nu, nu_dot) -> np.ndarray:
    """Regressors of the surge, sway and yaw equations, shape (3, N, 10), EXTENDED_PARAM_NAMES order.

    Parameters
    ----------
    nu : array_like, shape (N, 3)
        Body velocity [u (m/s), v (m/s), r (rad/s)] relative to the water.
    nu_dot : array_like, shape (N, 3)
        Its time derivative [m/s^2, m/s^2, rad/s^2].

    Returns
    -------
    numpy.ndarray
        ``A`` with ``A[0] @ theta = tau_u``, ``A[1] @ theta = 0``, ``A[2] @ theta = tau_r``.
    """
    nu, nu_dot = np.asarray(nu, float), np.asarray(nu_dot, float)
    u, v, r = nu[:, 0], nu[:, 1], nu[:, 2]
    ud, vd, rd = nu_dot[:, 0], nu_dot[:, 1], nu_dot[:, 2]
    A = np.zeros((3, len(u), NE))
    i = _IX
    A[0, :, i["m11"]], A[0, :, i["m22"]], A[0, :, i["m26"]] = ud, -v * r, -r * r
    A[0, :, i["d11"]], A[0, :, i["d11q"]] = u, np.abs(u) * u
    A[1, :, i["m22"]], A[1, :, i["m26"]], A[1, :, i["m11"]] = vd, rd, u * r
    A[1, :, i["d22"]], A[1, :, i["d22q"]] = v, np.abs(v) * v
    A[2, :, i["m26"]], A[2, :, i["m66"]] = vd + u * r, rd
    A[2, :, i["m22"]], A[2, :, i["m11"]] = u * v, -u * v
    A[2, :, i["d33"]], A[2, :, i["d33q"]] = r, np.abs(r) * r
    return A


@dataclass(frozen=True, kw_only=True)
class ExtendedFit:
    """An identified extended model.

    Attributes
    ----------
    theta : numpy.ndarray, shape (10,)
        m11, m22 (kg), m26 (kg m), m66 (kg m^2), d11 (kg/s), d11q (kg/m), d22 (kg/s),
        d22q (kg/m), d33 (kg m^2/s), d33q (kg m^2) (EXTENDED_PARAM_NAMES order).
    stderr : dict of str to float
        One-sigma standard errors (least squares; 0 for fixed ones).
    method : str
        ``"equation-error"``.
    currents : numpy.ndarray, shape (n_runs, 2)
        Current north, east in m/s per run (empty: equation error fits none).
    rms : tuple of float
        Residual RMS of the surge, sway and yaw equations (N, N, N m).
    """

    theta: np.ndarray
    stderr: dict
    method: str
    currents: np.ndarray
    rms: tuple

    @property
    def params(self) -> ExtendedParams:
        """The fit as :class:`~usvlog.model.vessel.ExtendedParams` (ConfigError if not physical)."""
        return ExtendedParams(**{k: float(v) for k, v in zip(EXTENDED_PARAM_NAMES, self.theta)})

    def to_dict(self) -> dict[str, float]:
        """Parameters by name, SI units."""
        return {k: float(v) for k, v in zip(EXTENDED_PARAM_NAMES, self.theta)}


def _bounds(names):
    lo = np.array([1e-3 if k in _INERTIA else (-np.inf if k == "m26" else 0.0) for k in names])
    return lo, np.full(len(names), np.inf)


def _lsq(X, y, names):
    """Bounded least squares (inertia > 0, damping >= 0) with residual-scaled standard errors."""
    lo, hi = _bounds(names)
    sol = lsq_linear(X, y, bounds=(lo, hi), method="bvls").x
    res = y - X @ sol
    s2 = float(res @ res) / max(len(y) - len(names), 1)
    se = np.sqrt(np.maximum(np.diag(s2 * np.linalg.pinv(X.T @ X)), 0.0))
    return sol, se, res


def fit_extended_equation_error(nu, nu_dot, tau_u, tau_r, *, fix: dict | None = None) -> ExtendedFit:
    """Least-squares fit of the extended model on smoothed velocities and accelerations.

    Parameters
    ----------
    nu : array_like, shape (N, 3)
        Smoothed body velocity [u (m/s), v (m/s), r (rad/s)] relative to the water.
    nu_dot : array_like, shape (N, 3)
        Its time derivative [m/s^2, m/s^2, rad/s^2].
    tau_u : array_like, shape (N,)
        Surge force in N (smoothed alike).
    tau_r : array_like, shape (N,)
        Yaw moment in N m.
    fix : dict of str to float, optional
        Known parameters by name (EXTENDED_PARAM_NAMES), SI units.

    Returns
    -------
    ExtendedFit
        ``method = "equation-error"``, no current.
    """
    fix = dict(fix or {})
    A = ext_regressors(nu, nu_dot)
    n = A.shape[1]
    tau_u = np.asarray(tau_u, float) + 0 * A[0, :, 0]
    tau_r = np.asarray(tau_r, float) + 0 * A[0, :, 0]
    theta = np.zeros(NE)
    for k, v in fix.items():
        theta[_IX[k]] = v
    se = np.zeros(NE)
    names = [k for k in EXTENDED_PARAM_NAMES if k not in fix]
    cols = [_IX[k] for k in names]
    held = [j for j in range(NE) if j not in cols]
    y = np.stack([tau_u, 0 * tau_u, tau_r]) - A[..., held] @ theta[held]
    # equations weighted by their residual scatter; sway (unforced, satisfied by theta = 0)
    # never weighs more than surge, so it cannot pull the fit towards zero
    w = 1.0 / np.maximum(np.array([np.std(tau_u), np.std(tau_u), np.std(tau_r)]), 1e-12)
    for _ in range(3):
        X = (A[..., cols] * w[:, None, None]).reshape(3 * n, -1)
        sol, s, res = _lsq(X, (y * w[:, None]).reshape(-1), names)
        r3 = res.reshape(3, n) / w[:, None]
        w = 1.0 / np.maximum(np.sqrt(np.mean(r3 ** 2, axis=1)), 1e-12)
        w[1] = min(w[1], w[0])
    theta[cols], se[cols] = sol, s
    res = np.stack([A[0] @ theta - tau_u, A[1] @ theta, A[2] @ theta - tau_r])
    rms = tuple(float(x) for x in np.sqrt(np.mean(res ** 2, axis=1)))
    return ExtendedFit(theta=theta, stderr={k: float(0.0 if k in fix else se[i])
                                            for i, k in enumerate(EXTENDED_PARAM_NAMES)},
                       method="equation-error", currents=np.zeros((0, 2)), rms=rms)


# ---------------------------------------------------------------------------------------
# simulation of the velocity dynamics (compiled)
# ---------------------------------------------------------------------------------------

@njit
def _vel_rk4(u, v, r, tu, tr, th, h):
    """One RK4 step of (u, v, r) under the extended model."""
    a1, b1, c1 = nu_dot_ext_terms(u, v, r, tu, tr, th[0], th[1], th[2], th[3], th[4], th[5], th[6], th[7],
                                  th[8], th[9])
    a2, b2, c2 = nu_dot_ext_terms(u + 0.5 * h * a1, v + 0.5 * h * b1, r + 0.5 * h * c1, tu, tr, th[0], th[1],
                                  th[2], th[3], th[4], th[5], th[6], th[7], th[8], th[9])
    a3, b3, c3 = nu_dot_ext_terms(u + 0.5 * h * a2, v + 0.5 * h * b2, r + 0.5 * h * c2, tu, tr, th[0], th[1],
                                  th[2], th[3], th[4], th[5], th[6], th[7], th[8], th[9])
    a4, b4, c4 = nu_dot_ext_terms(u + h * a3, v + h * b3, r + h * c3, tu, tr, th[0], th[1], th[2], th[3],
                                  th[4], th[5], th[6], th[7], th[8], th[9])
    w = h / 6.0
    return (u + w * (a1 + 2 * a2 + 2 * a3 + a4), v + w * (b1 + 2 * b2 + 2 * b3 + b4),
            r + w * (c1 + 2 * c2 + 2 * c3 + c4))


@njit
def simulate_velocity(tg, tau_u, tau_r, seg_i0, seg_i1, x0s, theta, meas_t, meas_ptr, max_dt, out):
    """Velocity (u, v, r) of every segment k from ``x0s[k]`` at ``tg[seg_i0[k]]``, thrust held
    over each grid step (RK4 sub-stepped to <= ``max_dt`` s), written at the segment's
    sorted times ``meas_t[meas_ptr[k]:meas_ptr[k + 1]]`` into ``out`` (linear
    interpolation inside a step); NaN once the state is no longer finite (divergence)."""
    for k in range(len(seg_i0)):
        u, v, r = x0s[k, 0], x0s[k, 1], x0s[k, 2]
        j, jend = meas_ptr[k], meas_ptr[k + 1]
        while j < jend and meas_t[j] < tg[seg_i0[k]] - 1e-9:
            j += 1
        for i in range(seg_i0[k], seg_i1[k]):
            if j >= jend:
                break
            ta, tb = tg[i], tg[i + 1]
            dt = tb - ta
            ua, va, ra = u, v, r
            nsub = max(1, int(math.ceil(dt / max_dt - 1e-9)))
            h = dt / nsub
            for _ in range(nsub):
                u, v, r = _vel_rk4(u, v, r, tau_u[i], tau_r[i], theta, h)
            if not (math.isfinite(u) and math.isfinite(v) and math.isfinite(r)) or abs(u) + abs(v) > 1e3:
                u = v = r = np.nan
            while j < jend and meas_t[j] <= tb + 1e-9:
                w = min(max((meas_t[j] - ta) / dt, 0.0), 1.0)
                out[j, 0] = (1 - w) * ua + w * u
                out[j, 1] = (1 - w) * va + w * v
                out[j, 2] = (1 - w) * ra + w * r
                j += 1


def free_run(run: RunData, theta, x0, t0: float, times) -> np.ndarray:
    """Velocity of the extended model from ``x0`` (u, v, r) at ``t0`` through a run's thrust.

    Parameters
    ----------
    run : RunData
        Thrust grid and forces.
    theta : array_like, shape (10,)
        Extended parameters (EXTENDED_PARAM_NAMES order, SI).
    x0 : array_like, shape (3,)
        Initial u (m/s), v (m/s), r (rad/s), relative to the water.
    t0 : float
        Start, s from the run's start.
    times : array_like
        Sorted output times in s (>= t0).

    Returns
    -------
    numpy.ndarray, shape (len(times), 3)
        u, v, r; NaN outside the thrust record or after a divergence.
    """
    times = np.ascontiguousarray(times, float)
    i0 = run.thrust_index_at(t0)   # the command in force at t0: the free run starts between two commands
    out = np.full((len(times), 3), np.nan)
    simulate_velocity(run.t_thrust, run.tau_u, run.tau_r, np.array([i0]), np.array([len(run.t_thrust) - 1]),
                      np.asarray(x0, float)[None, :], np.asarray(theta, float), times,
                      np.array([0, len(times)], np.int64), MAX_DT, out)
    return out


def velocity_validation(run: RunData, ks: KinStates, theta, current=(0.0, 0.0), t_from: float | None = None):
    """Fit % of u, v, r of a free run of the extended model from the smoothed state at ``t_from``.

    Parameters
    ----------
    run : RunData
        The (held-out) run's thrust.
    ks : KinStates
        Its smoothed states.
    theta : array_like, shape (10,)
        Extended parameters (a paper model: :meth:`ExtendedParams.from_paper`).
    current : (float, float), default (0, 0)
        Current north, east, m/s.
    t_from : float, optional
        Start, s (default the later of the run's and the smoother's first time).

    Returns
    -------
    dict
        ``u``, ``v``, ``r``: fit % (100 perfect, NaN when the run diverged).
    """
    t0 = max(run.t_thrust[0], ks.t[0]) if t_from is None else t_from
    t = ks.free_run_times(t0, run.t_thrust[-1])
    meas = ks.at(t, tuple(current))[:, 3:]
    sim = free_run(run, theta, meas[0], t[0], t)
    if not np.all(np.isfinite(sim)):
        return {"u": float("nan"), "v": float("nan"), "r": float("nan")}
    return {k: float(fit_percent(meas[:, i], sim[:, i])) for i, k in enumerate(("u", "v", "r"))}


__all__ = ["ExtendedFit", "ext_regressors", "fit_extended_equation_error", "free_run", "simulate_velocity",
           "velocity_validation"]
