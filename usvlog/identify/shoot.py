"""Multiple-shooting simulation of eqs. (1)+(3) with forward sensitivities (numba).

The dynamics are :func:`usvlog.model.vessel.nu_dot_terms` itself, compiled by numba (no
second copy of the model); its derivatives with respect to (u, v, r) and to the six
parameters are M^-1 (dF - dM nu_dot) with F = tau - C(nu) nu - D nu (eqs. (4)-(6)),
checked against finite differences of the whole simulation in the tests. Kinematics are eq. (1) plus a
constant current, as in :func:`usvlog.sim.simulate.plant_step`.

Sensitivity columns: 0-5 the segment's initial state (n, e, psi, u, v, r), 6-11 the
parameters (m, Iz, d11, d22, d33, xg), 12-13 the current (north, east).
"""

from __future__ import annotations

import math

import numpy as np

from .._jit import njit
from ..model.vessel import PARAM_NAMES, nu_dot_terms

# plant state [n, e, psi, u, v, r]
X_N, X_E, X_PSI, X_U, X_V, X_R = range(6)
NX = 6
# sensitivity columns: initial state (X_* + SENS_X0), parameters (PARAM_NAMES order + SENS_PARAM), current
SENS_X0 = 0
SENS_PARAM = 6
SENS_CUR_N, SENS_CUR_E = 12, 13
NS = 14
# parameter positions, PARAM_NAMES order
P_M, P_IZ, P_D11, P_D22, P_D33, P_XG = (PARAM_NAMES.index(p) for p in ("m", "Iz", "d11", "d22", "d33", "xg"))
NP = len(PARAM_NAMES)
# the sensitivity columns that move: of n and e, all but those of their own initial values
# (n0 and e0 shift n and e by one, nothing else does: those stay 1 and 0); of psi, u, v, r, those
# of the initial u, v, r and of the parameters (the initial position and heading and the current
# do not enter the velocity dynamics: those columns stay as they start, 1 for psi0, else 0).
# Skipped, they are the same numbers; the derivatives of the rest are computed as before.
NE_LO = SENS_X0 + X_PSI
DYN_LO, DYN_HI = SENS_X0 + X_U, SENS_PARAM + NP

# the step's helpers are inlined into shoot (numba IR inlining: the same arithmetic in the same
# order, without a call and its array arguments per stage; ~20 % of the kernel's time)
_nd = njit(inline="always")(nu_dot_terms)


@njit(inline="always")
def _deriv(x, S, tu, tr, prm, cn, ce, xd, Sd, sens):
    """State derivative into ``xd`` and, with ``sens``, sensitivity derivative into ``Sd`` (NX, NS)."""
    psi, u, v, r = x[X_PSI], x[X_U], x[X_V], x[X_R]
    c, s = math.cos(psi), math.sin(psi)
    m, Iz, d11, d22, d33, xg = prm  # PARAM_NAMES order
    ud, vd, rd = _nd(u, v, r, tu, tr, m, Iz, d11, d22, d33, xg)
    xd[X_N] = c * u - s * v + cn
    xd[X_E] = s * u + c * v + ce
    xd[X_PSI] = r
    xd[X_U] = ud
    xd[X_V] = vd
    xd[X_R] = rd
    if not sens:
        return
    a02 = -s * u - c * v
    a12 = c * u - s * v
    # d(nu_dot)/d(nu) and d(nu_dot)/d(theta) = M^-1 (dF - dM nu_dot), F = tau - C(nu) nu - D nu
    mx = m * xg
    det = m * Iz - mx * mx
    i00, i11, i12, i22 = 1.0 / m, Iz / det, -mx / det, m / det
    g00, g01, g02 = -d11, m * r, 2.0 * mx * r + m * v
    g10, g11, g12 = -m * r, -d22, -m * u
    g20, g21, g22 = -mx * r, 0.0, -mx * u - d33
    A00, A01, A02 = i00 * g00, i00 * g01, i00 * g02
    A10, A11, A12 = i11 * g10 + i12 * g20, i11 * g11 + i12 * g21, i11 * g12 + i12 * g22
    A20, A21, A22 = i12 * g10 + i22 * g20, i12 * g11 + i22 * g21, i12 * g12 + i22 * g22
    for k in range(NE_LO, NS):      # only the columns that move (see DYN_LO)
        s_psi, s_u, s_v = S[X_PSI, k], S[X_U, k], S[X_V, k]
        Sd[X_N, k] = a02 * s_psi + c * s_u - s * s_v
        Sd[X_E, k] = a12 * s_psi + s * s_u + c * s_v
    for k in range(DYN_LO, DYN_HI):
        s_u, s_v, s_r = S[X_U, k], S[X_V, k], S[X_R, k]
        Sd[X_PSI, k] = s_r
        Sd[X_U, k] = A00 * s_u + A01 * s_v + A02 * s_r
        Sd[X_V, k] = A10 * s_u + A11 * s_v + A12 * s_r
        Sd[X_R, k] = A20 * s_u + A21 * s_v + A22 * s_r
    for j in range(NP):  # (dF - dM nu_dot)/d(parameter j)
        if j == P_M:      # m (with xg held: m xg moves too)
            q0, q1, q2 = xg * r * r + v * r - ud, -u * r - vd - xg * rd, -xg * u * r - xg * vd
        elif j == P_IZ:
            q0, q1, q2 = 0.0, 0.0, -rd
        elif j == P_D11:
            q0, q1, q2 = -u, 0.0, 0.0
        elif j == P_D22:
            q0, q1, q2 = 0.0, -v, 0.0
        elif j == P_D33:
            q0, q1, q2 = 0.0, 0.0, -r
        else:             # P_XG
            q0, q1, q2 = m * r * r, -m * rd, -m * u * r - m * vd
        Sd[X_U, SENS_PARAM + j] += i00 * q0
        Sd[X_V, SENS_PARAM + j] += i11 * q1 + i12 * q2
        Sd[X_R, SENS_PARAM + j] += i12 * q1 + i22 * q2
    Sd[X_N, SENS_CUR_N] += 1.0
    Sd[X_E, SENS_CUR_E] += 1.0


@njit(inline="always")
def _trial(x, S, h, k, K, sens, xt, St):
    """xt = x + h k (and St = S + h K): the state an RK4 stage is evaluated at."""
    for i in range(NX):
        xt[i] = x[i] + h * k[i]
    if sens:   # the columns that move (the others of St hold S's constant values)
        for i in range(X_PSI):
            for c in range(NE_LO, NS):
                St[i, c] = S[i, c] + h * K[i, c]
        for i in range(X_PSI, NX):
            for c in range(DYN_LO, DYN_HI):
                St[i, c] = S[i, c] + h * K[i, c]


@njit(inline="always")
def _rk4(x, S, tu, tr, prm, cn, ce, dt, sens, w6, W6):
    """One RK4 step of state and sensitivities; ``w6`` (5, NX) and ``W6`` (5, NX, NS) are scratch."""
    k1, k2, k3, k4, xt = w6[0], w6[1], w6[2], w6[3], w6[4]
    K1, K2, K3, K4, St = W6[0], W6[1], W6[2], W6[3], W6[4]
    _deriv(x, S, tu, tr, prm, cn, ce, k1, K1, sens)
    _trial(x, S, 0.5 * dt, k1, K1, sens, xt, St)
    _deriv(xt, St, tu, tr, prm, cn, ce, k2, K2, sens)
    _trial(x, S, 0.5 * dt, k2, K2, sens, xt, St)
    _deriv(xt, St, tu, tr, prm, cn, ce, k3, K3, sens)
    _trial(x, S, dt, k3, K3, sens, xt, St)
    _deriv(xt, St, tu, tr, prm, cn, ce, k4, K4, sens)
    w = dt / 6.0
    for i in range(NX):
        x[i] += w * (k1[i] + 2 * k2[i] + 2 * k3[i] + k4[i])
    if sens:   # the columns that move
        for i in range(X_PSI):
            for k in range(NE_LO, NS):
                S[i, k] += w * (K1[i, k] + 2 * K2[i, k] + 2 * K3[i, k] + K4[i, k])
        for i in range(X_PSI, NX):
            for k in range(DYN_LO, DYN_HI):
                S[i, k] += w * (K1[i, k] + 2 * K2[i, k] + 2 * K3[i, k] + K4[i, k])


@njit
def shoot(tg, tau_u, tau_r, seg_i0, seg_i1, x0s, prm, seg_cur, meas_t, meas_ptr, max_dt, sens,
          out_x, out_S):
    """Integrate every segment k from ``x0s[k]`` at ``tg[seg_i0[k]]`` to ``tg[seg_i1[k]]``,
    thrust held over each grid step (RK4, sub-stepped to <= ``max_dt``); write the state (and
    sensitivities) at the segment's measurement times ``meas_t[meas_ptr[k]:meas_ptr[k+1]]``
    (sorted, linear interpolation inside a step)."""
    nseg = len(seg_i0)
    for k in range(nseg):
        w6 = np.empty((5, NX))
        W6 = np.zeros((5, NX, NS))
        x = x0s[k].copy()
        S = np.zeros((NX, NS))
        for i in range(NX):
            S[i, SENS_X0 + i] = 1.0
        W6[4, :, :] = S   # St: the columns that do not move keep these values
        xa = x.copy()
        Sa = S.copy()
        cn, ce = seg_cur[k, 0], seg_cur[k, 1]   # current north, east (m/s)
        j = meas_ptr[k]
        jend = meas_ptr[k + 1]
        for i in range(seg_i0[k], seg_i1[k]):
            if j >= jend:
                break
            ta, tb = tg[i], tg[i + 1]
            dt = tb - ta
            need = meas_t[j] <= tb + 1e-9
            if need:
                for q in range(NX):   # element loops: slice assignment costs more per step
                    xa[q] = x[q]
                if sens:
                    for q in range(NX):
                        for c in range(NS):
                            Sa[q, c] = S[q, c]
            nsub = max(1, int(math.ceil(dt / max_dt - 1e-9)))
            h = dt / nsub
            for _ in range(nsub):
                _rk4(x, S, tau_u[i], tau_r[i], prm, cn, ce, h, sens, w6, W6)
            if need:
                while j < jend and meas_t[j] <= tb + 1e-9:
                    w = (meas_t[j] - ta) / dt
                    w = min(max(w, 0.0), 1.0)
                    for q in range(NX):
                        out_x[j, q] = (1 - w) * xa[q] + w * x[q]
                    if sens:
                        for q in range(NX):
                            for c in range(NS):
                                out_S[j, q, c] = (1 - w) * Sa[q, c] + w * S[q, c]
                    j += 1
