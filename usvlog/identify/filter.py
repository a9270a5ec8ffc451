"""Filter-error identification: the estimator's dynamic EKF (eqs. (1)+(3) driven by the
recorded thrust, with the water current as states) run with candidate parameters; the
parameters maximise the innovation log-likelihood of the forward pass. Standard errors from
the inverse of the finite-difference Hessian of the negative log-likelihood."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import minimize

from ..errors import FitFailed
from ..estimate import EstimateSettings, build_problem
from ..estimate.latency import stored_delays, with_settings_delays
from ..estimate.layout import process_noise
from ..estimate.run import forward_loglik
from ..log.fieldlog import FieldLog
from ..model.vessel import PARAM_NAMES, Vessel

BAD_NLL = 1e12   # negative log-likelihood of parameters that are no boat or whose filter diverged


@dataclass(frozen=True, kw_only=True)
class FilterErrorResult:
    """Result of :func:`fit_filter_error`.

    ``theta``: all six parameters m (kg), Iz (kg m^2), d11, d22 (kg/s), d33 (kg m^2/s),
    xg (m), fixed ones included; ``cov``: covariance of the free ones (order ``free``),
    from the inverse Hessian of the negative log-likelihood; ``loglik``: the innovation
    log-likelihood at ``theta``, summed over the runs; ``nfev``: likelihood evaluations.
    """

    theta: np.ndarray     # (m, Iz, d11, d22, d33, xg)
    cov: np.ndarray       # covariance of the free parameters
    free: tuple[str, ...]
    loglik: float
    nfev: int


def fit_filter_error(logs: list[FieldLog], vessel: Vessel, theta0, *, free_mask=None,
                     current: bool = True, max_iter: int = 200) -> FilterErrorResult:
    """Fit the model parameters by maximising the dynamic EKF's innovation likelihood.

    Parameters
    ----------
    logs : list of FieldLog
        The runs (thrust, GNSS and compass channels).
    vessel : Vessel
        Thruster map and geometry turning the recorded commands into forces.
    theta0 : array_like, shape (6,)
        Starting m (kg), Iz (kg m^2), d11, d22 (kg/s), d33 (kg m^2/s), xg (m); fixed
        parameters keep these values.
    free_mask : array_like of bool, shape (6,), optional
        Which parameters to fit (default all).
    current : bool, default True
        Estimate the water current as EKF states.
    max_iter : int, default 200
        Iteration limit of the BFGS search (positive parameters searched in log space).

    Returns
    -------
    FilterErrorResult

    Raises
    ------
    usvlog.errors.InputError
        If a log lacks a channel the estimator needs.
    usvlog.errors.FitFailed
        If the start is not finite, or the likelihood is not finite at the fitted parameters
        (the filter diverged there).
    """
    free = np.ones(6, bool) if free_mask is None else np.asarray(free_mask, bool)
    s = EstimateSettings(model="dynamic", current=current, gate_probability=1.0)
    pbs = [build_problem(log, with_settings_delays(s, stored_delays(log)), vessel) for log in logs]
    q = process_noise(s)
    theta0 = np.asarray(theta0, float)
    if theta0.shape != (6,) or not np.all(np.isfinite(theta0)):
        raise FitFailed("filter error: the start values are not six finite numbers")
    pos = np.array([True, True, True, True, True, False])   # searched in log space
    nfev = [0]

    def theta_of(z):
        th = theta0.copy()
        with np.errstate(over="ignore"):
            zz = np.where(pos[free], np.exp(z), z)
        th[free] = zz
        return th

    def neg_loglik(th) -> float:
        """-log-likelihood of ``th`` summed over the runs; BAD_NLL where it is not a boat or not finite."""
        if (not np.all(np.isfinite(th)) or th[0] <= 0 or th[1] <= 0 or np.any(th[2:5] < 0)
                or th[1] - th[0] * th[5] ** 2 <= 1e-3 * th[1]):
            return BAD_NLL
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            v = -sum(forward_loglik(replace(pb, prm=th), q, s.max_consecutive_rejects) for pb in pbs)
        return float(v) if np.isfinite(v) and v < BAD_NLL else BAD_NLL

    def nll(z):
        nfev[0] += 1
        return neg_loglik(theta_of(z))

    z0 = np.where(pos[free], np.log(np.maximum(theta0[free], 1e-6)), theta0[free])
    sol = minimize(nll, z0, method="BFGS", options={"gtol": 1e-2, "maxiter": max_iter})
    z = sol.x if np.all(np.isfinite(sol.x)) else z0
    th = theta_of(z)
    # Hessian in theta (not log) space by central differences
    x = th[free].astype(float)
    k = len(x)
    h = 1e-3 * np.maximum(np.abs(x), 1e-2)

    bad_point = [False]   # a point of the difference stencil where the filter diverged

    def f(xx):
        t = th.copy()
        t[free] = xx
        nfev[0] += 1
        v = BAD_NLL if t[1] - t[0] * t[5] ** 2 <= 0 else neg_loglik(t)
        bad_point[0] |= v >= BAD_NLL
        return v

    f0 = f(x)
    if f0 >= BAD_NLL:
        raise FitFailed("filter error: the dynamic EKF's likelihood is not finite at the fitted parameters "
                        "(the filter diverged, or the values are no boat)")
    H = np.zeros((k, k))
    for i in range(k):
        for j in range(i, k):
            ei, ej = np.eye(k)[i] * h[i], np.eye(k)[j] * h[j]
            if i == j:
                H[i, i] = (f(x + ei) - 2 * f0 + f(x - ei)) / h[i] ** 2
            else:
                H[i, j] = H[j, i] = ((f(x + ei + ej) - f(x + ei - ej) - f(x - ei + ej) + f(x - ei - ej))
                                     / (4 * h[i] * h[j]))
    if bad_point[0] or not np.all(np.isfinite(H)):   # a neighbour's filter diverged: no curvature to read
        cov = np.full((k, k), np.nan)
    else:
        try:
            cov = np.linalg.inv(H)
        except np.linalg.LinAlgError:
            cov = np.linalg.pinv(H)
    return FilterErrorResult(theta=th, cov=cov, free=tuple(n for n, fr in zip(PARAM_NAMES, free) if fr),
                             loglik=float(-f0), nfev=nfev[0])
