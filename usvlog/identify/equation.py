"""Equation-error identification: eq. (3) is linear in (m, m xg, Iz, d11, d22, d33).

Expanding M nu_dot + C(nu) nu + D nu = tau with (4)-(6) (see :mod:`usvlog.model.vessel`) and
collecting the unknowns theta = (m, m xg, Iz, d11, d22, d33):

    surge:  m (u_dot - v r) - (m xg) r^2               + d11 u = tau_u
    sway:   m (v_dot + u r) + (m xg) r_dot             + d22 v = 0
    yaw:    (m xg)(v_dot + u r) + Iz r_dot             + d33 r = tau_r

Least squares on smoothed states and their derivatives. Fast, but the regressors carry
the smoother's noise and lag, so the inertia terms come out biased (errors-in-variables).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import ConfigError, FitFailed
from ..model.vessel import PARAM_NAMES

LIN_NAMES = ("m", "mxg", "Iz", "d11", "d22", "d33")


def regressors(nu, nu_dot):
    """Rows of the three equations: (A (3, N, 6), y-without-tau) with A @ theta = (tau_u, 0, tau_r).

    Parameters
    ----------
    nu : array_like, shape (N, 3)
        Body velocity [u (m/s), v (m/s), r (rad/s)].
    nu_dot : array_like, shape (N, 3)
        Its time derivative [m/s^2, m/s^2, rad/s^2].

    Returns
    -------
    numpy.ndarray, shape (3, N, 6)
        Regressors of the surge, sway and yaw equations for theta = (m, m xg, Iz, d11,
        d22, d33) (``LIN_NAMES``).
    """
    nu, nu_dot = np.asarray(nu, float), np.asarray(nu_dot, float)
    u, v, r = nu[:, 0], nu[:, 1], nu[:, 2]
    ud, vd, rd = nu_dot[:, 0], nu_dot[:, 1], nu_dot[:, 2]
    z = np.zeros_like(u)
    a1 = np.stack([ud - v * r, -r * r, z, u, z, z], -1)
    a2 = np.stack([vd + u * r, rd, z, z, v, z], -1)
    a3 = np.stack([z, vd + u * r, rd, z, z, r], -1)
    return np.stack([a1, a2, a3], 0)


def lin_to_params(th):
    """(m, m xg, Iz, d11, d22, d33) -> (m, Iz, d11, d22, d33, xg)."""
    m, mxg, Iz, d11, d22, d33 = th
    return np.array([m, Iz, d11, d22, d33, mxg / m])


@dataclass(frozen=True, kw_only=True)
class EquationErrorResult:
    """Result of :func:`fit_equation_error`.

    ``theta``: m (kg), Iz (kg m^2), d11, d22 (kg/s), d33 (kg m^2/s), xg (m);
    ``stderr``: their least-squares standard errors by name (assuming white equation
    errors; 0 for fixed ones); ``rms``: residual RMS of the surge, sway and yaw equations
    (N, N, N m); ``n``: number of samples.
    """

    theta: np.ndarray            # (m, Iz, d11, d22, d33, xg)
    stderr: dict                 # by parameter name (least-squares, assumes white equation errors)
    rms: tuple[float, float, float]   # residual RMS of the three equations (N, N, N m)
    n: int

    @property
    def valid(self) -> bool:
        """True if the parameters are physical: finite, m, Iz > 0, damping >= 0, Iz - m xg^2 > 0."""
        th = self.theta
        return bool(np.all(np.isfinite(th)) and th[0] > 0 and th[1] > 0 and np.all(th[2:5] >= 0)
                    and th[1] - th[0] * th[5] ** 2 > 0)

    def to_dict(self) -> dict[str, float]:
        """Parameters by paper symbol, SI units."""
        return {k: float(v) for k, v in zip(PARAM_NAMES, self.theta)}


def fit_equation_error(nu, nu_dot, tau_u, tau_r, *, fix: dict | None = None,
                       weights=None) -> EquationErrorResult:
    """Least-squares fit of eq. (3) on velocities ``nu`` (N, 3) and accelerations ``nu_dot``.

    ``fix``: known parameters by name (m, Iz, d11, d22, d33, xg). Surge and yaw are fitted
    jointly, each weighted by the inverse of its residual scatter (two passes) unless
    ``weights`` (three numbers; the sway one is unused) is given; then d22 from sway.

    Parameters
    ----------
    nu : array_like, shape (N, 3)
        Smoothed body velocity [u (m/s), v (m/s), r (rad/s)] relative to the water.
    nu_dot : array_like, shape (N, 3)
        Its time derivative [m/s^2, m/s^2, rad/s^2].
    tau_u : float or array_like, shape (N,)
        Surge force in N.
    tau_r : float or array_like, shape (N,)
        Yaw moment in N m.
    fix : dict of str to float, optional
        Known parameters by paper symbol, SI units.
    weights : sequence of 3 float, optional
        Weights of the surge, sway and yaw equations (1/N, unused, 1/(N m)).

    Returns
    -------
    EquationErrorResult
        d22 is constrained to >= 0; the other parameters are unconstrained (check
        :attr:`EquationErrorResult.valid`).

    Raises
    ------
    usvlog.errors.ConfigError
        If ``fix`` names an unknown parameter.
    usvlog.errors.FitFailed
        If fewer samples than unknowns (plus one) are finite: nothing to fit.

    Samples with a non-finite velocity, acceleration or force are left out.
    """
    fix = dict(fix or {})
    for k in fix:
        if k not in PARAM_NAMES:
            raise ConfigError(f"cannot fix {k!r}: not one of {', '.join(PARAM_NAMES)}")
    A = regressors(nu, nu_dot)                      # (3, N, 6)
    y = np.stack([np.asarray(tau_u, float) + 0 * A[0, :, 0], 0 * A[0, :, 0],
                  np.asarray(tau_r, float) + 0 * A[0, :, 0]], 0)
    ok = np.isfinite(A).all(axis=(0, 2)) & np.isfinite(y).all(axis=0)
    if not ok.all():   # a gap in the smoothed states (NaN): those samples say nothing
        A, y = A[:, ok], y[:, ok]
    n = A.shape[1]
    if n < 2 * len(PARAM_NAMES):
        raise FitFailed(f"equation error: {n} finite sample(s) of the smoothed states: too few to fit "
                        f"{len(PARAM_NAMES)} parameters")
    # move fixed parameters to the right-hand side; (m, xg) enter as m and m xg
    cols = {name: A[..., i] for i, name in enumerate(LIN_NAMES)}
    known = {}
    if "m" in fix and "xg" in fix:
        known["m"], known["mxg"] = fix["m"], fix["m"] * fix["xg"]
    elif "m" in fix:
        known["m"] = fix["m"]
    elif "xg" in fix:   # m free: the m column absorbs xg * (m xg column)
        cols["m"] = cols["m"] + fix["xg"] * cols["mxg"]
        known["mxg"] = None
    for k in ("Iz", "d11", "d22", "d33"):
        if k in fix:
            known[k] = fix[k]
    rhs = y.copy()
    for k, v in known.items():
        if v is not None:
            rhs = rhs - v * cols[k]
    # Surge and yaw determine (m, m xg, Iz, d11, d33); sway then gives d22. (Fitting all
    # three at once lets the unforced sway equation pull m, m xg and d22 towards zero.)
    free = [k for k in LIN_NAMES if k not in known and k != "d22"]
    X = np.stack([cols[k][[0, 2]] for k in free], -1) if free else np.zeros((2, n, 0))
    y13 = rhs[[0, 2]]
    w = np.ones(2) if weights is None else np.asarray(weights, float)[[0, 2]]
    for _ in range(1 if weights is not None else 2):
        Xw = (X * w[:, None, None]).reshape(2 * n, -1)
        yw = (y13 * w[:, None]).reshape(-1)
        sol = np.linalg.lstsq(Xw, yw, rcond=None)[0] if free else np.zeros(0)
        res = y13 - X @ sol
        rms13 = np.sqrt(np.mean(res ** 2, axis=1))
        if weights is None:
            # each equation by its scatter (both fitted exactly, no scatter at all: weights 1)
            floor = 1e-12 * float(rms13.max())
            w = 1.0 / np.maximum(rms13, floor) if math.isfinite(floor) and floor > 0 else np.ones(2)
    Xw = (X * w[:, None, None]).reshape(2 * n, -1)
    resw = (res * w[:, None]).reshape(-1)
    s2 = float(resw @ resw) / max(2 * n - len(free), 1)
    cov = s2 * np.linalg.pinv(Xw.T @ Xw) if free else np.zeros((0, 0))
    lin = {k: v for k, v in known.items() if v is not None}
    lin.update(dict(zip(free, sol)))
    if "mxg" not in lin:      # xg fixed, m free
        lin["mxg"] = lin["m"] * fix["xg"]
    # sway: d22 v = -(m (v_dot + u r) + m xg r_dot)
    a2 = -(lin["m"] * A[1, :, 0] + lin["mxg"] * A[1, :, 1])
    vv = A[1, :, 4]
    if "d22" in fix:
        lin["d22"] = fix["d22"]
        se_d22 = 0.0
    else:
        # least squares under d22 >= 0 (one unknown: the clamped solution is the constrained one)
        lin["d22"] = max(float(vv @ a2 / max(vv @ vv, 1e-300)), 0.0)
        r2 = a2 - lin["d22"] * vv
        se_d22 = float(np.sqrt((r2 @ r2) / max(n - 1, 1) / max(vv @ vv, 1e-300)))
    r2 = a2 - lin["d22"] * vv
    rms = (float(rms13[0]), float(np.sqrt(np.mean(r2 ** 2))), float(rms13[1]))
    # m = 0 (no surge information at all): xg and its error are NaN (``valid`` is False), not an exception
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        theta = lin_to_params([np.float64(lin[k]) for k in LIN_NAMES])
        # standard errors (delta method for xg = mxg / m)
        se_lin = dict(zip(free, np.sqrt(np.maximum(np.diag(cov), 0))))
        stderr = {k: float(se_lin.get(k, 0.0)) for k in ("m", "Iz", "d11", "d33")}
        stderr["d22"] = se_d22
        if "xg" in fix:
            stderr["xg"] = 0.0
        else:
            i_m = free.index("m") if "m" in free else None
            i_x = free.index("mxg")
            g = np.zeros(len(free))
            g[i_x] = 1.0 / theta[0]
            if i_m is not None:
                g[i_m] = -lin["mxg"] / theta[0] ** 2
            stderr["xg"] = float(np.sqrt(max(float(g @ cov @ g), 0.0)))
    stderr = {k: stderr[k] for k in PARAM_NAMES}
    return EquationErrorResult(theta=theta, stderr=stderr, rms=rms, n=n)
