"""Multiple-shooting simulation of eqs. (1)+(3) with forward sensitivities (numba).

The dynamics are :func:`usvlog.model.vessel.nu_dot_terms` itself, compiled by numba (no
second copy of the model); its derivatives with respect to (u, v, r) and to the six
parameters are M^-1 (dF - dM nu_dot) with F = tau - C(nu) nu - D nu (eqs. (4)-(6)),
checked against finite differences of the whole simulation in the tests. Kinematics are eq. (1) plus a
constant current, as in :func:`usvlog.sim.plant.plant_step`.

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

# the state's stage is inlined into shoot (numba IR inlining: scalars in registers, no call per
# stage); the column helpers are left to LLVM (inlined at the IR level too they run ~7 % faster
# but take 2.5 times as long to compile)
_nd = njit(inline="always")(nu_dot_terms)
# coefficients of the sensitivity equations at one RK4 stage (:func:`_stage`): cos psi, sin psi,
# d(n_dot, e_dot)/d(psi), d(nu_dot)/d(nu) (3 x 3, row-major), then per parameter j its forcing
# of (u_dot, v_dot, r_dot) from CO_PARAM + 3 j
CO_C, CO_S, CO_A02, CO_A12, CO_A = 0, 1, 2, 3, 4
CO_PARAM = CO_A + 9
N_CO = CO_PARAM + 3 * NP
_NO_CO = (0.0,) * N_CO   # the coefficients' place without sensitivities


@njit(inline="always")
def _stage(n, e, psi, u, v, r, tu, tr, m, Iz, d11, d22, d33, xg, cn, ce, sens):
    """State derivative at one RK4 stage (a tuple of NX) and, with ``sens``, the coefficients of
    the sensitivity equations there (a tuple of N_CO, layout CO_*; zeros without)."""
    c, s = math.cos(psi), math.sin(psi)
    ud, vd, rd = _nd(u, v, r, tu, tr, m, Iz, d11, d22, d33, xg)
    xd = (c * u - s * v + cn, s * u + c * v + ce, r, ud, vd, rd)
    if not sens:
        return xd, _NO_CO
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
    # (dF - dM nu_dot)/d(parameter), PARAM_NAMES order: m (with xg held: m xg moves too), Iz,
    # d11, d22, d33, xg
    qm0, qm1, qm2 = xg * r * r + v * r - ud, -u * r - vd - xg * rd, -xg * u * r - xg * vd
    qi0, qi1, qi2 = 0.0, 0.0, -rd
    qa0, qa1, qa2 = -u, 0.0, 0.0
    qb0, qb1, qb2 = 0.0, -v, 0.0
    qc0, qc1, qc2 = 0.0, 0.0, -r
    qx0, qx1, qx2 = m * r * r, -m * rd, -m * u * r - m * vd
    return xd, (c, s, a02, a12, A00, A01, A02, A10, A11, A12, A20, A21, A22,
                i00 * qm0, i11 * qm1 + i12 * qm2, i12 * qm1 + i22 * qm2,
                i00 * qi0, i11 * qi1 + i12 * qi2, i12 * qi1 + i22 * qi2,
                i00 * qa0, i11 * qa1 + i12 * qa2, i12 * qa1 + i22 * qa2,
                i00 * qb0, i11 * qb1 + i12 * qb2, i12 * qb1 + i22 * qb2,
                i00 * qc0, i11 * qc1 + i12 * qc2, i12 * qc1 + i22 * qc2,
                i00 * qx0, i11 * qx1 + i12 * qx2, i12 * qx1 + i22 * qx2)


@njit
def _col_deriv(co, k, sn, se, spsi, su, sv, sr):
    """Derivative of sensitivity column ``k`` (rows n, e, psi, u, v, r) at a stage with
    coefficients ``co`` (:func:`_stage`); zero in the rows that do not move (see DYN_LO)."""
    c, s = co[CO_C], co[CO_S]
    dn = co[CO_A02] * spsi + c * su - s * sv
    de = co[CO_A12] * spsi + s * su + c * sv
    if k == SENS_CUR_N:
        dn += 1.0
    if k == SENS_CUR_E:
        de += 1.0
    dpsi, du, dv, dr = 0.0, 0.0, 0.0, 0.0
    if DYN_LO <= k < DYN_HI:
        dpsi = sr
        du = co[CO_A] * su + co[CO_A + 1] * sv + co[CO_A + 2] * sr
        dv = co[CO_A + 3] * su + co[CO_A + 4] * sv + co[CO_A + 5] * sr
        dr = co[CO_A + 6] * su + co[CO_A + 7] * sv + co[CO_A + 8] * sr
        if k >= SENS_PARAM:
            b = CO_PARAM + 3 * (k - SENS_PARAM)
            du += co[b]
            dv += co[b + 1]
            dr += co[b + 2]
    return dn, de, dpsi, du, dv, dr


@njit
def _col_rk4(S, k, h, c1, c2, c3, c4):
    """One RK4 step of length ``h`` of sensitivity column ``k`` of ``S`` (NX, NS) in place, from
    the four stages' coefficients ``c1``..``c4``; only the rows that move are written (shoot
    calls it once per moving column, each with a constant ``k`` the compiler can fold)."""
    h2 = 0.5 * h
    w = h / 6.0
    s0, s1, s2, s3, s4, s5 = S[X_N, k], S[X_E, k], S[X_PSI, k], S[X_U, k], S[X_V, k], S[X_R, k]
    dyn = DYN_LO <= k < DYN_HI   # psi, u, v, r move
    K1 = _col_deriv(c1, k, s0, s1, s2, s3, s4, s5)
    t2, t3, t4, t5 = s2, s3, s4, s5
    if dyn:
        t2, t3, t4, t5 = s2 + h2 * K1[2], s3 + h2 * K1[3], s4 + h2 * K1[4], s5 + h2 * K1[5]
    K2 = _col_deriv(c2, k, s0 + h2 * K1[0], s1 + h2 * K1[1], t2, t3, t4, t5)
    if dyn:
        t2, t3, t4, t5 = s2 + h2 * K2[2], s3 + h2 * K2[3], s4 + h2 * K2[4], s5 + h2 * K2[5]
    K3 = _col_deriv(c3, k, s0 + h2 * K2[0], s1 + h2 * K2[1], t2, t3, t4, t5)
    if dyn:
        t2, t3, t4, t5 = s2 + h * K3[2], s3 + h * K3[3], s4 + h * K3[4], s5 + h * K3[5]
    K4 = _col_deriv(c4, k, s0 + h * K3[0], s1 + h * K3[1], t2, t3, t4, t5)
    S[X_N, k] = s0 + w * (K1[0] + 2 * K2[0] + 2 * K3[0] + K4[0])
    S[X_E, k] = s1 + w * (K1[1] + 2 * K2[1] + 2 * K3[1] + K4[1])
    if dyn:
        S[X_PSI, k] = s2 + w * (K1[2] + 2 * K2[2] + 2 * K3[2] + K4[2])
        S[X_U, k] = s3 + w * (K1[3] + 2 * K2[3] + 2 * K3[3] + K4[3])
        S[X_V, k] = s4 + w * (K1[4] + 2 * K2[4] + 2 * K3[4] + K4[4])
        S[X_R, k] = s5 + w * (K1[5] + 2 * K2[5] + 2 * K3[5] + K4[5])


@njit(nogil=True)
def shoot(tg, tau_u, tau_r, seg_i0, seg_i1, x0s, prm, seg_cur, meas_t, meas_ptr, max_dt, sens,
          out_x, row_ptr, row_dst, row_q, row_w, out_rows):
    """Integrate every segment k from ``x0s[k]`` at ``tg[seg_i0[k]]`` to ``tg[seg_i1[k]]``,
    thrust held over each grid step (RK4, sub-stepped to <= ``max_dt``); write the state at
    the segment's measurement times ``meas_t[meas_ptr[k]:meas_ptr[k+1]]`` (sorted, linear
    interpolation inside a step) into ``out_x`` (rows j of those times).

    With ``sens``, the sensitivities there too, only the rows asked for: for measurement j and
    each e in ``row_ptr[j]:row_ptr[j+1]``, row ``row_q[e]`` (a state) of its (NX, NS)
    sensitivity matrix times ``row_w[e]`` into ``out_rows[row_dst[e]]`` (e.g. a residual
    row's Jacobian row, weight and sign applied). Without, those four are not read.

    The state is held in scalars; each RK4 stage's state derivative also gives the
    coefficients of the (linear) sensitivity equations there, and the sensitivity columns
    that move are stepped one by one from those (the same arithmetic per entry as stepping
    the whole matrix, a column's entries in registers). Segments write disjoint rows and
    share nothing: a caller may run groups of them in parallel threads (no GIL held)."""
    nseg = len(seg_i0)
    m, Iz, d11, d22, d33, xg = prm[P_M], prm[P_IZ], prm[P_D11], prm[P_D22], prm[P_D33], prm[P_XG]
    S = np.zeros((NX, NS))
    Sa = np.zeros((NX, NS))
    for k in range(nseg):
        x0, x1, x2, x3, x4, x5 = x0s[k, 0], x0s[k, 1], x0s[k, 2], x0s[k, 3], x0s[k, 4], x0s[k, 5]
        a0, a1, a2, a3, a4, a5 = x0, x1, x2, x3, x4, x5   # the state at the step's start
        S[:, :] = 0.0
        for i in range(NX):
            S[i, SENS_X0 + i] = 1.0
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
                a0, a1, a2, a3, a4, a5 = x0, x1, x2, x3, x4, x5
                if sens:
                    for q in range(NX):   # element loops: slice assignment costs more per step
                        for c in range(NS):
                            Sa[q, c] = S[q, c]
            nsub = max(1, int(math.ceil(dt / max_dt - 1e-9)))
            h = dt / nsub
            tu, tr = tau_u[i], tau_r[i]
            for _ in range(nsub):
                h2 = 0.5 * h
                k1, c1 = _stage(x0, x1, x2, x3, x4, x5, tu, tr, m, Iz, d11, d22, d33, xg, cn, ce, sens)
                k2, c2 = _stage(x0 + h2 * k1[0], x1 + h2 * k1[1], x2 + h2 * k1[2], x3 + h2 * k1[3],
                                x4 + h2 * k1[4], x5 + h2 * k1[5], tu, tr, m, Iz, d11, d22, d33, xg, cn, ce, sens)
                k3, c3 = _stage(x0 + h2 * k2[0], x1 + h2 * k2[1], x2 + h2 * k2[2], x3 + h2 * k2[3],
                                x4 + h2 * k2[4], x5 + h2 * k2[5], tu, tr, m, Iz, d11, d22, d33, xg, cn, ce, sens)
                k4, c4 = _stage(x0 + h * k3[0], x1 + h * k3[1], x2 + h * k3[2], x3 + h * k3[3],
                                x4 + h * k3[4], x5 + h * k3[5], tu, tr, m, Iz, d11, d22, d33, xg, cn, ce, sens)
                w = h / 6.0
                x0 += w * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
                x1 += w * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
                x2 += w * (k1[2] + 2 * k2[2] + 2 * k3[2] + k4[2])
                x3 += w * (k1[3] + 2 * k2[3] + 2 * k3[3] + k4[3])
                x4 += w * (k1[4] + 2 * k2[4] + 2 * k3[4] + k4[4])
                x5 += w * (k1[5] + 2 * k2[5] + 2 * k3[5] + k4[5])
                if sens:   # the columns that move (NE_LO..NS-1), each with a constant index
                    _col_rk4(S, 2, h, c1, c2, c3, c4)
                    _col_rk4(S, 3, h, c1, c2, c3, c4)
                    _col_rk4(S, 4, h, c1, c2, c3, c4)
                    _col_rk4(S, 5, h, c1, c2, c3, c4)
                    _col_rk4(S, 6, h, c1, c2, c3, c4)
                    _col_rk4(S, 7, h, c1, c2, c3, c4)
                    _col_rk4(S, 8, h, c1, c2, c3, c4)
                    _col_rk4(S, 9, h, c1, c2, c3, c4)
                    _col_rk4(S, 10, h, c1, c2, c3, c4)
                    _col_rk4(S, 11, h, c1, c2, c3, c4)
                    _col_rk4(S, 12, h, c1, c2, c3, c4)
                    _col_rk4(S, 13, h, c1, c2, c3, c4)
            if need:
                while j < jend and meas_t[j] <= tb + 1e-9:
                    wt = (meas_t[j] - ta) / dt
                    wt = min(max(wt, 0.0), 1.0)
                    out_x[j, X_N] = (1 - wt) * a0 + wt * x0
                    out_x[j, X_E] = (1 - wt) * a1 + wt * x1
                    out_x[j, X_PSI] = (1 - wt) * a2 + wt * x2
                    out_x[j, X_U] = (1 - wt) * a3 + wt * x3
                    out_x[j, X_V] = (1 - wt) * a4 + wt * x4
                    out_x[j, X_R] = (1 - wt) * a5 + wt * x5
                    if sens:
                        for e in range(row_ptr[j], row_ptr[j + 1]):
                            q, d, we = row_q[e], row_dst[e], row_w[e]
                            for c in range(NS):
                                out_rows[d, c] = ((1 - wt) * Sa[q, c] + wt * S[q, c]) * we
                    j += 1


def no_rows() -> tuple:
    """:func:`shoot`'s last five arguments (row_ptr .. out_rows) when ``sens`` is False
    (not read)."""
    return np.zeros(1, np.int64), np.zeros(0, np.int32), np.zeros(0, np.int8), np.zeros(0), np.zeros((0, NS))
