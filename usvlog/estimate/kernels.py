"""Compiled (numba) kernels of the EKF and the extended RTS smoother.

One implementation of the process model, the prediction, the gated measurement update,
the forward pass and the smoother; the offline fast path and :class:`OnlineEKF` both run
these. The dynamics come from :mod:`usvlog.model.vessel` (``nu_dot_terms`` and
``nu_dot_jacobian_terms`` are plain arithmetic, compiled here as they are); the
filterpy reference path (:mod:`.reference`) uses ``plant_rhs``/``plant_jacobian`` and
a test holds both to each other and to finite differences.

State, dynamic model: x = [n, e, psi, u, v, r] (+ [c_n, c_e] water current, NED), with
nu = [u, v, r] relative to the water. Kinematic model: x = [n, e, psi, v_n, v_e, r, a_n,
a_e, r_dot], over-ground velocity in NED driven by random-walk accelerations (over
ground, a boat's velocity turns far more smoothly in NED than its body-frame sway does
in a zig-zag); body u, v are R(psi)^T [v_n, v_e] (see :func:`body_velocity`). Kinematic
model with sway damping (KINEMATIC_SWAY): x = [n, e, psi, u, v, r, a_x, a_y, r_dot, k],
over-ground body velocity with u_dot = a_x + r v, v_dot = a_y - k v - r u (a_x, a_y the
over-ground acceleration in the body frame, random walks; -k v the sway damping, k a
constant the filter estimates: a boat's lateral acceleration is mostly its sway damping,
so the sway follows the yaw rate). Discretisation: Euler
step x+ = x + dt f(x, tau) with Phi = I + dt F, Q = diag(q) dt on the velocity and
current states (the kinematic accelerations carry the noise), plus, kinematic, a
variance on r_dot at steps of the recorded yaw moment (``qjump``, see ``layout.yaw_jump_variance``).
Measurements select state entries (GNSS: n, e; compass: psi, with the
residual wrapped; yaw rate: r; GNSS velocity: v_n, v_e of the kinematic model in NED).
"""

from __future__ import annotations

import math

import numpy as np

from .._jit import njit
from ..model.frames import wrap_angle
from ..model.vessel import nu_dot_jacobian_terms, nu_dot_terms

KINEMATIC, DYNAMIC, KINEMATIC_SWAY = 0, 1, 2
GNSS, COMPASS, YAW_RATE, VELOCITY = 0, 1, 2, 3
SENSORS = ("gnss", "compass", "yaw_rate", "gnss_velocity")
SENSOR_DIM = (2, 1, 1, 2)

# State positions. Every model starts with position and heading, and has the yaw rate at X_R.
X_N, X_E, X_PSI = 0, 1, 2
X_U, X_V, X_R = 3, 4, 5          # dynamic (water-relative) and kinematic-sway (over ground) body velocities
X_CUR_N, X_CUR_E = 6, 7          # dynamic model with current: water current, NED (m/s)
X_VN, X_VE = 3, 4                # kinematic: over-ground velocity, NED (m/s)
X_AN, X_AE = 6, 7                # kinematic: its random-walk acceleration, NED (m/s^2)
X_AX, X_AY = 6, 7                # kinematic-sway: over-ground acceleration, body frame (m/s^2)
X_RDOT = 8                       # both kinematic models: yaw acceleration (rad/s^2)
X_K = 9                          # kinematic-sway: sway damping constant k (1/s)
NX_DYNAMIC_CURRENT = 8
# covariance block stored per step (PB): psi and the two velocity states after it
PB_FIRST, PB_SIZE = X_PSI, 3

# columns of the per-step and per-measurement inputs
TAU_U, TAU_R = 0, 1              # taus (N, 2): N, N m
Z_0, Z_1 = 0, 1                  # mz (M, 2): measured value(s)
R_00, R_01, R_11 = 0, 1, 2       # mR (M, 3): measurement covariance entries
# measurement result (res, innov rows)
RES_Y0, RES_Y1, RES_NIS, RES_LOGLIK = range(4)
NRES = 4
# why the forward pass re-initialised the state from the measurements at a step (resets)
REINIT_NONFINITE, REINIT_COVARIANCE, REINIT_RESIDUALS, REINIT_IMPLAUSIBLE = 1, 2, 3, 4
REINIT_REASONS = ("", "state not finite", "position covariance blow-up",
                  "GNSS residuals far beyond the gate for a long stretch",
                  "speed or yaw rate beyond any boat")
MAX_SPEED_MPS = 50.0             # |velocity state| above this is a filter that lost the track
MAX_YAW_RATE_RADPS = 2.0 * math.pi   # |r| above this (one turn a second) likewise

_nu_dot = njit(nu_dot_terms)
_nu_jac = njit(nu_dot_jacobian_terms)

_TWO_PI = 2.0 * math.pi


@njit
def process(x, tau_u, tau_r, prm, model, f, F):
    """x_dot = f(x, tau) and F = df/dx into ``f``, ``F`` (eqs. (1)+(3), current in NED)."""
    nx = x.shape[0]
    for i in range(nx):
        f[i] = 0.0
        for j in range(nx):
            F[i, j] = 0.0
    if model == KINEMATIC:
        # [n, e, psi, v_n, v_e, r] driven by random-walk accelerations [a_n, a_e, r_dot]:
        # each of the first six states integrates the one three places later
        for i in (X_N, X_E, X_PSI, X_VN, X_VE, X_R):
            f[i] = x[i + 3]
            F[i, i + 3] = 1.0
        return
    psi, u, v, r = x[X_PSI], x[X_U], x[X_V], x[X_R]
    c, s = math.cos(psi), math.sin(psi)
    f[X_N] = c * u - s * v
    f[X_E] = s * u + c * v
    f[X_PSI] = r
    F[X_N, X_PSI] = -s * u - c * v
    F[X_E, X_PSI] = c * u - s * v
    F[X_N, X_U], F[X_N, X_V] = c, -s
    F[X_E, X_U], F[X_E, X_V] = s, c
    F[X_PSI, X_R] = 1.0
    if model == KINEMATIC_SWAY:  # body frame, over ground (see the module docstring)
        k = x[X_K]
        f[X_U] = x[X_AX] + r * v
        f[X_V] = x[X_AY] - k * v - r * u
        f[X_R] = x[X_RDOT]
        F[X_U, X_V], F[X_U, X_R], F[X_U, X_AX] = r, v, 1.0
        F[X_V, X_U], F[X_V, X_V], F[X_V, X_R], F[X_V, X_AY], F[X_V, X_K] = -r, -k, -u, 1.0, -v
        F[X_R, X_RDOT] = 1.0
        return
    if nx == NX_DYNAMIC_CURRENT:  # water current, NED
        f[X_N] += x[X_CUR_N]
        f[X_E] += x[X_CUR_E]
        F[X_N, X_CUR_N] = 1.0
        F[X_E, X_CUR_E] = 1.0
    if model == DYNAMIC:
        m, Iz, d11, d22, d33, xg = prm  # PARAM_NAMES order
        ud, vd, rd = _nu_dot(u, v, r, tau_u, tau_r, m, Iz, d11, d22, d33, xg)
        f[X_U], f[X_V], f[X_R] = ud, vd, rd
        J = _nu_jac(u, v, r, m, Iz, d11, d22, d33, xg)  # d(u, v, r)_dot / d(u, v, r), row-major
        for i in range(3):
            for j in range(3):
                F[X_U + i, X_U + j] = J[3 * i + j]


def body_velocity(psi, vn, ve, P_psi_vn_ve=None):
    """Over-ground body velocities u, v from NED velocity and heading (arrays), and, given
    the (..., 3, 3) covariance of (psi, v_n, v_e), their one-sigma (first order)."""
    c, s = np.cos(psi), np.sin(psi)
    u, v = c * vn + s * ve, -s * vn + c * ve
    if P_psi_vn_ve is None:
        return u, v
    Ju = np.stack([v, c, s], -1)            # du/d(psi, vn, ve)
    Jv = np.stack([-u, -s, c], -1)
    su = np.einsum("...i,...ij,...j->...", Ju, P_psi_vn_ve, Ju)
    sv = np.einsum("...i,...ij,...j->...", Jv, P_psi_vn_ve, Jv)
    return u, v, np.sqrt(np.maximum(su, 0.0)), np.sqrt(np.maximum(sv, 0.0))


@njit
def sparse_matmul(A, B, out):
    """out = A B, skipping the zero entries of A (the model Jacobians have a few a row)."""
    n = A.shape[0]
    for i in range(n):
        for j in range(B.shape[1]):
            out[i, j] = 0.0
        for k in range(A.shape[1]):
            a = A[i, k]
            if a != 0.0:
                for j in range(B.shape[1]):
                    out[i, j] += a * B[k, j]


@njit
def predict(x, P, tau_u, tau_r, dt, prm, model, q, qj, xo, Po, Phi, f, F, tmp):
    """One prediction over ``dt``: xo, Po (and Phi = I + dt F) from x, P; ``qj`` is a
    variance added to the yaw acceleration of the kinematic model (a step of the yaw moment).

    Po = Phi P Phi^T + Q dt is formed as P + dt (F P + P F^T) + dt^2 F P F^T over the
    non-zero entries of the sparse F (a few per row), upper triangle mirrored."""
    nx = x.shape[0]
    process(x, tau_u, tau_r, prm, model, f, F)
    for i in range(nx):
        xo[i] = x[i] + dt * f[i]
        for j in range(nx):
            Phi[i, j] = dt * F[i, j]
        Phi[i, i] += 1.0
    xo[X_PSI] = wrap_angle(xo[X_PSI])
    sparse_matmul(F, P, tmp)
    dt2 = dt * dt
    # (F P F^T)[i, j], i <= j, summed over the non-zero F[j, k] (k upwards) into Po[j, i]
    for j in range(nx):
        for i in range(j + 1):
            Po[j, i] = 0.0
        for k in range(nx):
            a = F[j, k]
            if a != 0.0:
                for i in range(j + 1):
                    Po[j, i] += tmp[i, k] * a
    for i in range(nx):
        for j in range(i, nx):
            v = P[i, j] + dt * (tmp[i, j] + tmp[j, i]) + dt2 * Po[j, i]
            Po[i, j] = v
            Po[j, i] = v
        Po[i, i] += q[i] * dt
    if qj != 0.0:  # r_dot, in both kinematic models
        Po[X_RDOT, X_RDOT] += qj


@njit
def update(x, P, kind, z0, z1, R00, R01, R11, gate, force, res, K, P2):
    """Gated measurement update in place (Joseph form).

    Writes [res_0, res_1, nis, log-likelihood term] into ``res`` (RES_* positions); returns
    True when the measurement was applied (NIS within ``gate`` or ``force``).
    """
    nx = x.shape[0]
    m = 2 if kind == GNSS or kind == VELOCITY else 1
    if kind == GNSS:
        i0, i1 = X_N, X_E
    elif kind == VELOCITY:   # the kinematic model's NED velocity
        i0, i1 = X_VN, X_VE
    elif kind == COMPASS:
        i0, i1 = X_PSI, X_PSI
    else:
        i0, i1 = X_R, X_R
    S01 = S10 = S11 = 0.0
    I01 = I10 = I11 = 0.0
    y0 = z0 - x[i0]
    if kind == COMPASS:
        y0 = wrap_angle(y0)
    if m == 2:
        y1 = z1 - x[i1]
        S00 = P[i0, i0] + R00
        S01 = P[i0, i1] + R01
        S10 = P[i1, i0] + R01
        S11 = P[i1, i1] + R11
        det = S00 * S11 - S01 * S10
        I00, I01, I10, I11 = S11 / det, -S01 / det, -S10 / det, S00 / det
        nis = y0 * (I00 * y0 + I01 * y1) + y1 * (I10 * y0 + I11 * y1)
        logdet = math.log(det)
    else:
        y1 = math.nan
        S00 = P[i0, i0] + R00
        I00 = 1.0 / S00
        nis = y0 * y0 * I00
        logdet = math.log(S00)
    res[RES_Y0], res[RES_Y1], res[RES_NIS] = y0, y1, nis
    res[RES_LOGLIK] = -0.5 * (min(nis, gate) + logdet + m * math.log(_TWO_PI))
    if nis > gate and not force:
        return False
    # K = P H^T S^-1
    for i in range(nx):
        if m == 2:
            K[i, 0] = P[i, i0] * I00 + P[i, i1] * I10
            K[i, 1] = P[i, i0] * I01 + P[i, i1] * I11
        else:
            K[i, 0] = P[i, i0] * I00
            K[i, 1] = 0.0
    for i in range(nx):
        if m == 2:
            x[i] += K[i, 0] * y0 + K[i, 1] * y1
        else:
            x[i] += K[i, 0] * y0
    x[X_PSI] = wrap_angle(x[X_PSI])
    # Joseph form (I - K H) P (I - K H)^T + K R K^T, expanded for a selector H:
    # P - K (H P) - (H P)^T K^T + K (H P H^T + R) K^T, upper triangle mirrored
    for i in range(nx):
        for j in range(i, nx):
            if m == 2:
                kpk = (K[i, 0] * (S00 * K[j, 0] + S01 * K[j, 1])
                       + K[i, 1] * (S10 * K[j, 0] + S11 * K[j, 1]))
                v = (P[i, j] - K[i, 0] * P[i0, j] - K[i, 1] * P[i1, j]
                     - P[i, i0] * K[j, 0] - P[i, i1] * K[j, 1] + kpk)
            else:
                v = P[i, j] - K[i, 0] * P[i0, j] - P[i, i0] * K[j, 0] + K[i, 0] * S00 * K[j, 0]
            P2[i, j] = v
            P2[j, i] = v
    for i in range(nx):
        for j in range(nx):
            P[i, j] = P2[i, j]
    return True


class Work:
    """Scratch arrays for one state dimension (allocated once)."""

    def __init__(self, nx: int):
        self.f = np.zeros(nx)
        self.F = np.zeros((nx, nx))
        self.Phi = np.zeros((nx, nx))
        self.tmp = np.zeros((nx, nx))
        self.tmp2 = np.zeros((nx, nx))
        self.K = np.zeros((nx, 2))
        self.xo = np.zeros(nx)
        self.Po = np.zeros((nx, nx))
        self.res = np.zeros(NRES)


@njit
def health(x, P, pos_var_limit):
    """0 for a usable state, else why not: REINIT_NONFINITE (a state or covariance entry
    not finite), REINIT_COVARIANCE (a position variance beyond ``pos_var_limit``, m^2) or
    REINIT_IMPLAUSIBLE (a velocity state beyond MAX_SPEED_MPS or r beyond MAX_YAW_RATE_RADPS:
    states 3, 4 are velocities and 5 the yaw rate in every model)."""
    nx = x.shape[0]
    for a in range(nx):
        if not math.isfinite(x[a]):
            return REINIT_NONFINITE
        for b in range(nx):
            if not math.isfinite(P[a, b]):
                return REINIT_NONFINITE
    if P[X_N, X_N] > pos_var_limit or P[X_E, X_E] > pos_var_limit:
        return REINIT_COVARIANCE
    if abs(x[X_U]) > MAX_SPEED_MPS or abs(x[X_V]) > MAX_SPEED_MPS or abs(x[X_R]) > MAX_YAW_RATE_RADPS:
        return REINIT_IMPLAUSIBLE
    return 0


@njit
def reinitialise(x, P, x0, P0, n, e, psi):
    """Restart from the measurements: x0 with position (n, e) and heading psi, P = P0."""
    nx = x.shape[0]
    for a in range(nx):
        x[a] = x0[a]
        for b in range(nx):
            P[a, b] = P0[a, b]
    x[X_N], x[X_E], x[X_PSI] = n, e, wrap_angle(psi)


# Forward-pass state carried between blocks (a checkpoint): x, P and these.
# fst: the latest fix, the latest accepted heading, the sum of the log-likelihood terms
FS_FIX_N, FS_FIX_E, FS_PSI_LAST, FS_LOGLIK = range(4)
NFS = 4
# ist: the next measurement, then the rejections in a row of each sensor
IS_J = 0
N_IST = 1 + len(SENSORS)
SMOOTH_BLOCK = 2048
"""Steps between the forward pass's checkpoints: the smoother re-runs the forward pass one
block at a time from them (memory bounded by a block, not by the run)."""


@njit
def _bad_step(x, P, sd_limit):
    """The state or a one-sigma not finite, or a position one-sigma beyond ``sd_limit`` (m)."""
    for a in range(x.shape[0]):
        s = math.sqrt(max(P[a, a], 0.0))
        if not (math.isfinite(x[a]) and math.isfinite(s)):
            return True
        if a < 2 and s > sd_limit:
            return True
    return False


@njit
def _store_row(r, x, P, X, SD, PB):
    """The first X.shape[1] states of ``x``, their one-sigma and the covariance block
    PB_FIRST.. into row ``r`` of X, SD (and PB unless it has no rows)."""
    for a in range(X.shape[1]):
        X[r, a] = x[a]
        SD[r, a] = math.sqrt(max(P[a, a], 0.0))
    if PB.shape[0]:
        for a in range(PB_SIZE):
            for b in range(PB_SIZE):
                PB[r, a, b] = P[PB_FIRST + a, PB_FIRST + b]


@njit
def _forward_steps(k0, k1, x, P, ist, fst, x0, P0, dts, taus, qjump, mstep, mkind, mz, mR, prm, model, q, gates,
                   max_rej, pos_var_limit, reinit_nis, innov, accepted, resets, row, X, SD, PB, BX, BP, BXp, BPp, BC,
                   bad):
    """Steps k0 .. k1 - 1 of the forward pass from the state x, P, ist, fst (updated in place).

    Writes each step's posterior into row ``row[k]`` of X, SD, PB (none when ``row`` is
    empty or ``row[k] < 0``) and, when BX has rows, the state and the upper triangle of P
    (row by row) into BX[k - k0], BP[k - k0], the step's prior (the state and P before its
    measurements) into BXp[k - k0], BPp[k - k0] and, for a step the smoother smooths the
    one before across (k > 0, not re-initialised), the transposed RTS gain of the step
    before, C^T = Pp^-1 Phi P_{k-1} (Pp the prior, P_{k-1} the posterior before it, Phi = I
    without a prediction), into BC[k - k0]: all of it only the forward pass's numbers, made
    here for the smoother; ``bad[0]`` gets the first step whose state is unusable
    (:func:`_bad_step`), if none did yet."""
    nx = x.shape[0]
    M = mstep.shape[0]
    xo = np.zeros(nx)
    Po = np.zeros((nx, nx))
    Phi = np.zeros((nx, nx))
    f = np.zeros(nx)
    F = np.zeros((nx, nx))
    tmp = np.zeros((nx, nx))
    P2 = np.zeros((nx, nx))
    K = np.zeros((nx, 2))
    res = np.zeros(NRES)
    store = BX.shape[0] > 0
    PhiP = np.zeros((nx, nx))   # Phi P of the posterior before the step (for the smoother's gain)
    L = np.zeros((nx, nx))
    inv = np.zeros(nx)
    sd_limit = math.sqrt(pos_var_limit)
    j = ist[IS_J]
    for k in range(k0, k1):
        resets[k] = 0
        if k > 0 and dts[k] > 0.0:
            predict(x, P, taus[k, TAU_U], taus[k, TAU_R], dts[k], prm, model, q, qjump[k], xo, Po, Phi, f, F, tmp)
            if store:
                sparse_matmul(Phi, P, PhiP)
            for a in range(nx):
                x[a] = xo[a]
                for b in range(nx):
                    P[a, b] = Po[a, b]
        elif store:   # no prediction: Phi = I
            for a in range(nx):
                for b in range(nx):
                    PhiP[a, b] = P[a, b]
        if store:
            for a in range(nx):
                BXp[k - k0, a] = x[a]
                for b in range(nx):
                    BPp[k - k0, a, b] = P[a, b]
        while j < M and mstep[j] == k:
            kind = mkind[j]
            force = ist[1 + kind] >= max_rej
            ok = update(x, P, kind, mz[j, Z_0], mz[j, Z_1], mR[j, R_00], mR[j, R_01], mR[j, R_11],
                        gates[kind], force, res, K, P2)
            for a in range(NRES):
                innov[j, a] = res[a]
            fst[FS_LOGLIK] += res[RES_LOGLIK]
            if kind == GNSS:
                fst[FS_FIX_N], fst[FS_FIX_E] = mz[j, Z_0], mz[j, Z_1]
                if force and reinit_nis > 0.0 and not res[RES_NIS] <= reinit_nis:
                    keep = fst[FS_PSI_LAST] if math.isfinite(fst[FS_PSI_LAST]) else x0[X_PSI]
                    reinitialise(x, P, x0, P0, fst[FS_FIX_N], fst[FS_FIX_E], keep)
                    resets[k] = REINIT_RESIDUALS
                    update(x, P, kind, mz[j, Z_0], mz[j, Z_1], mR[j, R_00], mR[j, R_01], mR[j, R_11],
                           gates[kind], True, res, K, P2)
            elif kind == COMPASS and ok:
                fst[FS_PSI_LAST] = mz[j, Z_0]
            if ok:
                accepted[j] = 2 if force else 1
                ist[1 + kind] = 0
            else:
                accepted[j] = 0
                ist[1 + kind] += 1
            j += 1
        why = health(x, P, pos_var_limit)
        if why:
            psi = fst[FS_PSI_LAST] if math.isfinite(fst[FS_PSI_LAST]) else x0[X_PSI]
            reinitialise(x, P, x0, P0, fst[FS_FIX_N], fst[FS_FIX_E], psi)
            resets[k] = why
        if bad[0] < 0 and _bad_step(x, P, sd_limit):
            bad[0] = k
        if store and k > 0 and resets[k] == 0:   # C^T of step k - 1: Pp C^T = Phi P_{k-1}
            _chol_solve(L, inv, BPp[k - k0], PhiP, BC[k - k0])
        if row.shape[0] and row[k] >= 0:
            _store_row(row[k], x, P, X, SD, PB)
        if BX.shape[0]:   # P is symmetric (predict and update write both halves): its upper triangle
            i = 0
            for a in range(nx):
                BX[k - k0, a] = x[a]
                for b in range(a, nx):
                    BP[k - k0, i] = P[a, b]
                    i += 1
    ist[IS_J] = j


@njit
def forward(x0, P0, dts, taus, qjump, mstep, mkind, mz, mR, prm, model, q, gates, max_rej,
            pos_var_limit, reinit_nis, row, X, SD, PB, innov, accepted, resets, CX, CP, CI, CF, bad):
    """Forward EKF pass over N steps; measurements j are applied at step mstep[j].

    Stores the posterior of step k in row ``row[k]`` of X (its first X.shape[1] states), their
    one-sigma in SD and the
    covariance block of states PB_FIRST.. (PB_SIZE) in PB (steps with ``row[k] < 0``, or
    all when ``row`` is empty, are not stored; PB may have no rows: not stored),
    per-measurement [res_0, res_1, nis, loglik] in innov and the decision in accepted
    (0 rejected, 1 accepted, 2 accepted after too many rejections). When CX has rows, the
    filter's state entering every SMOOTH_BLOCK-th step is kept there and in CP, CI, CF
    (checkpoints, for :func:`smooth_rerun`). ``bad[0]``: the first step whose state or
    one-sigma is not finite or whose position one-sigma exceeds sqrt(pos_var_limit), -1
    for none. Returns the sum of the log-likelihood terms.

    Divergence guard: a GNSS fix forced in (after ``max_rej`` rejections in a row) with
    a NIS above ``reinit_nis`` (0: off), or a step ending with a state that is not finite
    or a position variance above ``pos_var_limit`` (m^2, see :func:`health`),
    re-initialises the filter from the measurements (:func:`reinitialise`: the latest
    fix, the latest accepted compass heading, P0); ``resets[k]`` records why
    (REINIT_*, 0 for none) and the smoother does not smooth across it.
    """
    nx = x0.shape[0]
    N = dts.shape[0]
    x = x0.copy()
    P = P0.copy()
    ist = np.zeros(N_IST, np.int64)
    fst = np.zeros(NFS)
    fst[FS_FIX_N], fst[FS_FIX_E], fst[FS_PSI_LAST] = x0[X_N], x0[X_E], x0[X_PSI]
    bad[0] = -1
    none = np.zeros((0, nx))
    none_tri = np.zeros((0, 1))
    none_sq = np.zeros((0, nx, nx))
    for c in range((N + SMOOTH_BLOCK - 1) // SMOOTH_BLOCK):
        if CX.shape[0]:
            for a in range(nx):
                CX[c, a] = x[a]
                for b in range(nx):
                    CP[c, a, b] = P[a, b]
            # element loops: an array slice assignment compiles numba's shape-mismatch error (its message
            # formatting: 2.4 s of the kernel's first compile)
            for a in range(N_IST):
                CI[c, a] = ist[a]
            for a in range(NFS):
                CF[c, a] = fst[a]
        _forward_steps(c * SMOOTH_BLOCK, min(N, (c + 1) * SMOOTH_BLOCK), x, P, ist, fst, x0, P0, dts, taus, qjump,
                       mstep, mkind, mz, mR, prm, model, q, gates, max_rej, pos_var_limit, reinit_nis, innov,
                       accepted, resets, row, X, SD, PB, none, none_tri, none, none_sq, none_sq, bad)
    return fst[FS_LOGLIK]


@njit
def _chol_solve(L, inv, A, B, X):
    """Solve A X = B for symmetric positive definite A (n x n) via Cholesky; L scratch
    (reciprocals of the diagonal: no divisions in the loops). The substitutions run over
    all columns of B at once (row operations: contiguous, vectorised); each entry sees the
    same operations in the same order as column by column."""
    n = A.shape[0]
    m = B.shape[1]
    for i in range(n):
        for j in range(i + 1):
            s = A[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            if i == j:
                L[i, i] = math.sqrt(s)
                inv[i] = 1.0 / L[i, i]
            else:
                L[i, j] = s * inv[j]
    for i in range(n):
        for c in range(m):
            X[i, c] = B[i, c]
        for k in range(i):
            w = L[i, k]
            for c in range(m):
                X[i, c] -= w * X[k, c]
        w = inv[i]
        for c in range(m):
            X[i, c] *= w
    for i in range(n - 1, -1, -1):
        for k in range(i + 1, n):
            w = L[k, i]
            for c in range(m):
                X[i, c] -= w * X[k, c]
        w = inv[i]
        for c in range(m):
            X[i, c] *= w


@njit
def _unpack(tri, P):
    """The symmetric matrix P from its upper triangle stored row by row (as :func:`_forward_steps` stores it)."""
    n = P.shape[0]
    i = 0
    for a in range(n):
        for b in range(a, n):
            P[a, b] = tri[i]
            P[b, a] = tri[i]
            i += 1


class SmoothBuffers:
    """One block's forward posteriors made again (:func:`smooth_rerun`) for the smoother:
    BX, BP the posterior state and the upper triangle of its P (row by row), BXp, BPp the
    prior of each step and BC the transposed RTS gain of the step before it (SMOOTH_BLOCK rows)."""

    def __init__(self, nx: int):
        self.BX = np.zeros((SMOOTH_BLOCK, nx))
        self.BP = np.zeros((SMOOTH_BLOCK, nx * (nx + 1) // 2))
        self.BXp = np.zeros((SMOOTH_BLOCK, nx))
        self.BPp = np.zeros((SMOOTH_BLOCK, nx, nx))
        self.BC = np.zeros((SMOOTH_BLOCK, nx, nx))


@njit(nogil=True)
def smooth_rerun(c, x0, P0, dts, taus, qjump, mstep, mkind, mz, mR, prm, model, q, gates, max_rej, pos_var_limit,
                 reinit_nis, innov, accepted, resets, CX, CP, CI, CF, BX, BP, BXp, BPp, BC):
    """The forward pass over block ``c`` (steps c SMOOTH_BLOCK ..) made again from its
    checkpoint (CX, CP, CI, CF of :func:`forward`, the same arguments: the very same
    numbers), keeping every step's posterior, prior and RTS gain in the buffers
    (:class:`SmoothBuffers`) for :func:`smooth_back`. Writes only block ``c``'s entries of
    innov, accepted and resets (the values the forward pass wrote there)."""
    N = dts.shape[0]
    nx = x0.shape[0]
    k0, k1 = c * SMOOTH_BLOCK, min(N, (c + 1) * SMOOTH_BLOCK)
    x = CX[c].copy()
    P = CP[c].copy()
    ist = CI[c].copy()
    fst = CF[c].copy()
    none = np.zeros((0, nx))
    _forward_steps(k0, k1, x, P, ist, fst, x0, P0, dts, taus, qjump, mstep, mkind, mz, mR, prm, model, q,
                   gates, max_rej, pos_var_limit, reinit_nis, innov, accepted, resets, np.zeros(0, np.int64), none,
                   none, np.zeros((0, PB_SIZE, PB_SIZE)), BX, BP, BXp, BPp, BC, np.zeros(1, np.int64))


@njit(nogil=True)
def smooth_back(c, N, resets, BX, BP, BXp, BPp, BC, xs, Ps, xpn, Ppn, Cn, pos_var_limit, row, r0, XS, SD, PB, bad):
    """Extended RTS smoother over block ``c`` of an N-step run, backwards, from the buffers
    :func:`smooth_rerun` filled for it.

    ``xs``, ``Ps`` enter as the smoothed state of the step after the block (ignored for
    the last block) and leave as that of the block's first step; ``xpn``, ``Ppn``, ``Cn``
    enter as the prior and gain (BXp, BPp, BC) of the step after the block and leave as
    those of the block's first step (the carry to block c - 1). Writes the smoothed state of step k in
    row ``row[k] - r0`` of XS (its first XS.shape[1] states; skipped when ``row[k] < 0``; ``r0`` 0 for
    XS of every row, the block's first row for XS of the block's rows alone), their
    one-sigma in SD and the covariance block of states PB_FIRST.. (PB_SIZE) in PB (PB may
    have no rows: not stored); ``bad[0]`` becomes any step of the block whose smoothed
    state is unusable (as in :func:`forward`; going backwards, the last one set is the
    first). A step the forward pass re-initialised (``resets[k] != 0``) starts a new
    segment: the steps before it are smoothed from their own forward posterior, not across
    the restart."""
    nx = xs.shape[0]
    k0, k1 = c * SMOOTH_BLOCK, min(N, (c + 1) * SMOOTH_BLOCK)
    tmp = np.zeros((nx, nx))
    Pk = np.zeros((nx, nx))
    Pn = np.zeros((nx, nx))
    d = np.zeros(nx)
    acc = np.zeros(nx)
    sd_limit = math.sqrt(pos_var_limit)
    for k in range(k1 - 1, k0 - 1, -1):
        _unpack(BP[k - k0], Pk)
        xk = BX[k - k0]
        if k == N - 1 or resets[k + 1] != 0:   # the end, or a restart: a segment ends at k
            for a in range(nx):
                xs[a] = xk[a]
                for b in range(nx):
                    Ps[a, b] = Pk[a, b]
        elif k == k1 - 1:
            _smooth_step(xk, Pk, xs, Ps, xpn, Ppn, Cn, tmp, Pn, d, acc)
        else:
            _smooth_step(xk, Pk, xs, Ps, BXp[k + 1 - k0], BPp[k + 1 - k0], BC[k + 1 - k0], tmp, Pn, d, acc)
        if row[k] >= 0:
            _store_row(row[k] - r0, xs, Ps, XS, SD, PB)
        if _bad_step(xs, Ps, sd_limit):
            bad[0] = k
    for a in range(nx):
        xpn[a] = BXp[0, a]
        for b in range(nx):
            Ppn[a, b] = BPp[0, a, b]
            Cn[a, b] = BC[0, a, b]


@njit(inline="always")
def _col_dots4(U, a, V, b):
    """sum_c U[c, a] V[c, b + i] for i = 0..3, each summed over c from 0 up (from 0.0)."""
    s0 = s1 = s2 = s3 = 0.0
    for c in range(U.shape[0]):
        w = U[c, a]
        s0 += w * V[c, b]
        s1 += w * V[c, b + 1]
        s2 += w * V[c, b + 2]
        s3 += w * V[c, b + 3]
    return s0, s1, s2, s3


@njit(inline="always")
def _col_dot(U, a, V, b):
    """sum_c U[c, a] V[c, b], summed over c from 0 up (from 0.0)."""
    s = 0.0
    for c in range(U.shape[0]):
        s += U[c, a] * V[c, b]
    return s


@njit
def _smooth_step(xk, Pk, xs, Ps, xp, Pp, Ct, tmp, Pn, d, acc):
    """One RTS step: from the forward posterior xk, Pk of step k, the prior xp, Pp of step
    k + 1, the transposed gain Ct (C = Pk Phi^T Pp^-1, Phi of step k + 1) and the smoothed
    xs, Ps of step k + 1, the smoothed state of step k into xs, Ps.

    Every entry's sum is taken in the same order as the textbook loops (over c from 0 up,
    from 0.0, Pk added last), in scalar accumulators four entries at a time (no stores in
    the inner loops); ``tmp`` holds (C (Ps - Pp))^T."""
    nx = xk.shape[0]
    for a in range(nx):
        d[a] = xs[a] - xp[a]
    d[X_PSI] = wrap_angle(d[X_PSI])
    for a in range(nx):
        acc[a] = 0.0
    for c in range(nx):
        w = d[c]
        for a in range(nx):
            acc[a] += Ct[c, a] * w
    for a in range(nx):
        xs[a] = xk[a] + acc[a]
    xs[X_PSI] = wrap_angle(xs[X_PSI])
    # Ps_k = Pk + C (Ps - Pp) C^T, C = Ct^T: tmp^T = Ct^T Pn, then Ps = Pk + tmp^T Ct (upper triangle, mirrored)
    for a in range(nx):
        for b in range(nx):
            Pn[a, b] = Ps[a, b] - Pp[a, b]
    for a in range(nx):
        b = 0
        while b + 4 <= nx:
            tmp[b, a], tmp[b + 1, a], tmp[b + 2, a], tmp[b + 3, a] = _col_dots4(Ct, a, Pn, b)
            b += 4
        for e in range(b, nx):
            tmp[e, a] = _col_dot(Ct, a, Pn, e)
    for a in range(nx):
        b = a
        while b + 4 <= nx:
            s0, s1, s2, s3 = _col_dots4(tmp, a, Ct, b)
            Ps[a, b], Ps[a, b + 1], Ps[a, b + 2], Ps[a, b + 3] = (
                Pk[a, b] + s0, Pk[a, b + 1] + s1, Pk[a, b + 2] + s2, Pk[a, b + 3] + s3)
            for i in range(b, b + 4):
                Ps[i, a] = Ps[a, i]
            b += 4
        for e in range(b, nx):
            v = Pk[a, e] + _col_dot(tmp, a, Ct, e)
            Ps[a, e] = v
            Ps[e, a] = v
