"""The reference path: a plain per-step loop over filterpy's ExtendedKalmanFilter and an
extended RTS smoother in numpy over the stored priors, posteriors and Jacobians.

Slow (tens of microseconds a step) but written straight from the textbook with the
vessel model of :mod:`usvlog.model.vessel`; the compiled kernels must agree with it to 1e-9.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from filterpy.kalman import ExtendedKalmanFilter

from ..model.frames import ssa
from ..model.vessel import VesselParams, eta_dot, plant_jacobian, plant_rhs
from .kernels import (
    COMPASS,
    GNSS,
    MAX_SPEED_MPS,
    MAX_YAW_RATE_RADPS,
    REINIT_COVARIANCE,
    REINIT_IMPLAUSIBLE,
    REINIT_NONFINITE,
    REINIT_RESIDUALS,
    SENSOR_DIM,
)

_SELECT = {GNSS: (0, 1), COMPASS: (2,), 2: (5,), 3: (3, 4)}   # 3: GNSS velocity, kinematic NED model


def rhs(x, tau_u, tau_r, params: VesselParams, dynamic: bool):
    """x_dot: dynamic (6 states, or 8 with a random-walk current) or kinematic (9 states:
    n, e, psi, v_n, v_e, r and random-walk accelerations a_n, a_e, r_dot; or 10 with sway
    damping: n, e, psi, u, v, r over ground, a_x, a_y, r_dot, k with eta_dot = R(psi) nu,
    u_dot = a_x + r v, v_dot = a_y - k v - r u)."""
    if not dynamic and len(x) == 10:   # with sway damping: body frame, over ground
        u, v, r = x[3:6]
        return np.r_[eta_dot(x[:3], x[3:6]), x[6] + r * v, x[7] - x[9] * v - r * u, x[8], np.zeros(4)]
    if not dynamic:
        return np.concatenate([x[3:9], np.zeros(3)])
    cur = (x[6], x[7]) if len(x) == 8 else (0.0, 0.0)
    return np.concatenate([plant_rhs(x[:6], tau_u, tau_r, params, cur), np.zeros(len(x) - 6)])


def jacobian(x, params: VesselParams, dynamic: bool):
    """d(rhs)/dx, shape (nx, nx); the same models and arguments as :func:`rhs`."""
    nx = len(x)
    J = np.zeros((nx, nx))
    if not dynamic and nx == 10:
        u, v, r, k = x[3], x[4], x[5], x[9]
        J[:3, :6] = plant_jacobian(x[:6], params)[:3]      # eta_dot = R(psi) nu
        J[3, 4], J[3, 5], J[3, 6] = r, v, 1.0               # u_dot = a_x + r v
        J[4, 3], J[4, 4], J[4, 5], J[4, 7], J[4, 9] = -r, -k, -u, 1.0, -v   # v_dot = a_y - k v - r u
        J[5, 8] = 1.0
        return J
    if not dynamic:
        J[:6, 3:9] = np.eye(6)
        return J
    J[:6, :6] = plant_jacobian(x[:6], params)
    if nx == 8:
        J[0, 6] = J[1, 7] = 1.0
    return J


def _residual_angle(a, b):
    return ssa(a - b)


class VesselEKF(ExtendedKalmanFilter):
    """filterpy EKF with the vessel's nonlinear prediction (Euler step over ``dt``)."""

    x: np.ndarray  # state column (nx, 1), set by filterpy

    def __init__(self, nx: int, params: VesselParams, dynamic: bool, q):
        super().__init__(dim_x=nx, dim_z=2)
        self.params, self.dynamic, self.q = params, dynamic, np.asarray(q, float)
        self._step = (0.0, 0.0, 0.0)

    def predict_step(self, dt: float, tau_u: float, tau_r: float, qj: float = 0.0) -> None:
        """Predict over ``dt`` with F = I + dt J(x) and Q = diag(q) dt.

        Parameters
        ----------
        dt : float
            Step in s.
        tau_u : float
            Surge force held over the step, N.
        tau_r : float
            Yaw moment held over the step, N m.
        qj : float, default 0.0
            Variance added to r_dot (state 8) of the kinematic model, rad^2/s^4.
        """
        x = self.x[:, 0]
        self.F = np.eye(self.dim_x) + dt * jacobian(x, self.params, self.dynamic)
        self.Q = np.diag(self.q * dt)
        if qj:  # a step of the yaw moment: the kinematic model's r_dot may jump
            self.Q[8, 8] += qj
        self._step = (dt, tau_u, tau_r)
        self.predict()

    def predict_x(self, u=0):
        """filterpy hook: Euler step of the state with the arguments of :meth:`predict_step`."""
        dt, tau_u, tau_r = self._step
        x = self.x[:, 0]
        xn = x + dt * rhs(x, tau_u, tau_r, self.params, self.dynamic)
        xn[2] = ssa(xn[2])
        self.x = xn.reshape(-1, 1)

    def gated_update(self, kind: int, z, R, gate: float, force: bool):
        """Gated update; returns (res_0, res_1, nis, loglik term, accepted).

        Parameters
        ----------
        kind : int
            ``GNSS`` (z = n, e in m), ``COMPASS`` (z = psi in rad), yaw rate
            (z = r in rad/s) or GNSS velocity (z = v_n, v_e in m/s, kinematic model).
        z : array_like
            Measurement; only the first ``SENSOR_DIM[kind]`` entries are used.
        R : numpy.ndarray
            Measurement covariance, (m, m) in the units of ``z`` squared.
        gate : float
            NIS threshold.
        force : bool
            Apply the measurement even when its NIS exceeds ``gate``.
        """
        idx = _SELECT[kind]
        m = SENSOR_DIM[kind]
        H = np.zeros((m, self.dim_x))
        for r, c in enumerate(idx):
            H[r, c] = 1.0
        z = np.asarray(z[:m], float).reshape(-1, 1)
        resid = _residual_angle if kind == COMPASS else np.subtract
        y = resid(z, H @ self.x)
        S = H @ self.P @ H.T + R
        try:
            nis = float(y[:, 0] @ np.linalg.solve(S, y[:, 0]))
        except np.linalg.LinAlgError:   # a diverged covariance: the guard restarts the filter
            nis = np.nan
        ll = -0.5 * (min(nis, gate) + np.log(np.linalg.det(S)) + m * np.log(2 * np.pi))
        res = (float(y[0, 0]), float(y[1, 0]) if m == 2 else np.nan, nis, ll)
        if nis > gate and not force:
            return (*res, False)
        self.update(z, lambda x: H, lambda x: H @ x, R=R, residual=resid)
        self.x[2, 0] = ssa(self.x[2, 0])
        return (*res, True)


def _health(x, P, pos_var_limit: float) -> int:
    """0 for a usable state, else REINIT_NONFINITE, REINIT_COVARIANCE or REINIT_IMPLAUSIBLE
    (see kernels.health)."""
    if not (np.isfinite(x).all() and np.isfinite(P).all()):
        return REINIT_NONFINITE
    if P[0, 0] > pos_var_limit or P[1, 1] > pos_var_limit:
        return REINIT_COVARIANCE
    if abs(x[3]) > MAX_SPEED_MPS or abs(x[4]) > MAX_SPEED_MPS or abs(x[5]) > MAX_YAW_RATE_RADPS:
        return REINIT_IMPLAUSIBLE
    return 0


def _restart(ekf, x0, P0, n, e, psi) -> None:
    """x0 with the position (n, e) and heading psi, P0 (see kernels.reinitialise)."""
    x = np.asarray(x0, float).copy()
    x[0], x[1], x[2] = n, e, ssa(psi)
    ekf.x = x.reshape(-1, 1)
    ekf.P = np.asarray(P0, float).copy()


def run_reference(x0, P0, dts, taus, qjump, mstep, mkind, mz, mR, params, dynamic, q, gates, max_rej,
                  smoother: bool, pos_var_limit: float = np.inf, reinit_nis: float = 0.0):
    """Forward pass with filterpy, then the RTS smoother. Same inputs and outputs as the
    compiled path: (X, SD_forward, PB_forward, XS, SD_smoothed, PB_smoothed, innov,
    accepted, loglik, resets), PB the covariance block of states 2..4, resets the
    re-initialisations of the divergence guard (as ``kernels.forward``)."""
    nx = len(x0)
    N, M = len(dts), len(mstep)
    ekf = VesselEKF(nx, params, dynamic, q)
    ekf.x = np.asarray(x0, float).reshape(-1, 1).copy()
    ekf.P = np.asarray(P0, float).copy()
    xs_prior: list[Any] = [None] * N
    Ps_prior: list[Any] = [None] * N
    Fs: list[Any] = [None] * N
    X = np.zeros((N, nx))
    Ppost = np.zeros((N, nx, nx))
    innov = np.zeros((M, 4))
    accepted = np.zeros(M, np.int8)
    rej = [0] * len(SENSOR_DIM)
    ll = 0.0
    j = 0
    resets = np.zeros(N, np.int8)
    fix_n, fix_e, psi_last = float(x0[0]), float(x0[1]), float(x0[2])   # latest measurements
    for k in range(N):
        if k > 0 and dts[k] > 0:
            with np.errstate(all="ignore"):   # a diverging state is caught by the guard below
                ekf.predict_step(float(dts[k]), float(taus[k, 0]), float(taus[k, 1]), float(qjump[k]))
            Fs[k] = ekf.F.copy()
        else:
            Fs[k] = np.eye(nx)
        xs_prior[k], Ps_prior[k] = ekf.x[:, 0].copy(), ekf.P.copy()
        while j < M and mstep[j] == k:
            kind = int(mkind[j])
            m = SENSOR_DIM[kind]
            R = np.array([[mR[j, 0], mR[j, 1]], [mR[j, 1], mR[j, 2]]])[:m, :m]
            force = rej[kind] >= max_rej
            with np.errstate(all="ignore"):
                r0, r1, nis, l, ok = ekf.gated_update(kind, mz[j], R, float(gates[kind]), force)
            innov[j] = (r0, r1, nis, l)
            ll += l
            if kind == GNSS:
                fix_n, fix_e = float(mz[j, 0]), float(mz[j, 1])
                if force and reinit_nis > 0 and not nis <= reinit_nis:
                    _restart(ekf, x0, P0, fix_n, fix_e, psi_last if np.isfinite(psi_last) else x0[2])
                    resets[k] = REINIT_RESIDUALS
                    ekf.gated_update(kind, mz[j], R, float(gates[kind]), True)
            elif kind == COMPASS and ok:
                psi_last = float(mz[j, 0])
            accepted[j] = (2 if force else 1) if ok else 0
            rej[kind] = 0 if ok else rej[kind] + 1
            j += 1
        why = _health(ekf.x[:, 0], ekf.P, pos_var_limit)
        if why:
            _restart(ekf, x0, P0, fix_n, fix_e, psi_last if np.isfinite(psi_last) else x0[2])
            resets[k] = why
        X[k] = ekf.x[:, 0]
        Ppost[k] = ekf.P
    return _smooth(X, Ppost, xs_prior, Ps_prior, Fs, resets, innov, accepted, ll, smoother)


def _smooth(X, Ppost, xs_prior, Ps_prior, Fs, resets, innov, accepted, ll, smoother):
    """The RTS smoother over the forward pass (not across a restart)."""
    N = len(X)
    sd_f = np.sqrt(np.maximum(np.einsum("kii->ki", Ppost), 0.0))
    pb_f = Ppost[:, 2:5, 2:5].copy()
    if not smoother:
        return X, sd_f, pb_f, X.copy(), sd_f.copy(), pb_f.copy(), innov, accepted, ll, resets
    XS = np.zeros_like(X)
    SD = np.zeros_like(X)
    PB = np.zeros((N, 3, 3))
    XS[-1], Ps = X[-1], Ppost[-1]
    SD[-1], PB[-1] = sd_f[-1], pb_f[-1]
    for k in range(N - 2, -1, -1):
        if resets[k + 1]:   # a restart: a new segment ends at k
            XS[k], Ps = X[k], Ppost[k]
            SD[k], PB[k] = sd_f[k], pb_f[k]
            continue
        C = Ppost[k] @ Fs[k + 1].T @ np.linalg.inv(Ps_prior[k + 1])
        d = XS[k + 1] - xs_prior[k + 1]
        d[2] = ssa(d[2])
        XS[k] = X[k] + C @ d
        XS[k, 2] = ssa(XS[k, 2])
        Ps = Ppost[k] + C @ (Ps - Ps_prior[k + 1]) @ C.T
        SD[k] = np.sqrt(np.maximum(np.diag(Ps), 0.0))
        PB[k] = Ps[2:5, 2:5]
    return X, sd_f, pb_f, XS, SD, PB, innov, accepted, ll, resets
