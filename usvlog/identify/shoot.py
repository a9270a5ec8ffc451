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
from ..model.vessel import nu_dot_terms

NS = 14

_nd = njit(nu_dot_terms)


@njit
def _deriv(x, S, tu, tr, prm, cn, ce, xd, Sd, sens):
    psi, u, v, r = x[2], x[3], x[4], x[5]
    c, s = math.cos(psi), math.sin(psi)
    m, Iz, d11, d22, d33, xg = prm[0], prm[1], prm[2], prm[3], prm[4], prm[5]
    a = _nd(u, v, r, tu, tr, m, Iz, d11, d22, d33, xg)
    xd[0] = c * u - s * v + cn
    xd[1] = s * u + c * v + ce
    xd[2] = r
    xd[3] = a[0]
    xd[4] = a[1]
    xd[5] = a[2]
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
    for k in range(NS):
        s2, s3, s4, s5 = S[2, k], S[3, k], S[4, k], S[5, k]
        Sd[0, k] = a02 * s2 + c * s3 - s * s4
        Sd[1, k] = a12 * s2 + s * s3 + c * s4
        Sd[2, k] = s5
        Sd[3, k] = A00 * s3 + A01 * s4 + A02 * s5
        Sd[4, k] = A10 * s3 + A11 * s4 + A12 * s5
        Sd[5, k] = A20 * s3 + A21 * s4 + A22 * s5
    ud, vd, rd = a[0], a[1], a[2]
    for j in range(6):
        if j == 0:      # m (with xg held: m xg moves too)
            q0, q1, q2 = xg * r * r + v * r - ud, -u * r - vd - xg * rd, -xg * u * r - xg * vd
        elif j == 1:    # Iz
            q0, q1, q2 = 0.0, 0.0, -rd
        elif j == 2:    # d11
            q0, q1, q2 = -u, 0.0, 0.0
        elif j == 3:    # d22
            q0, q1, q2 = 0.0, -v, 0.0
        elif j == 4:    # d33
            q0, q1, q2 = 0.0, 0.0, -r
        else:           # xg
            q0, q1, q2 = m * r * r, -m * rd, -m * u * r - m * vd
        Sd[3, 6 + j] += i00 * q0
        Sd[4, 6 + j] += i11 * q1 + i12 * q2
        Sd[5, 6 + j] += i12 * q1 + i22 * q2
    Sd[0, 12] += 1.0
    Sd[1, 13] += 1.0


@njit
def _trial(x, S, h, k, K, sens, xt, St):
    """xt = x + h k (and St = S + h K): the state an RK4 stage is evaluated at."""
    for i in range(6):
        xt[i] = x[i] + h * k[i]
    if sens:
        for i in range(6):
            for c in range(NS):
                St[i, c] = S[i, c] + h * K[i, c]


@njit
def _rk4(x, S, tu, tr, prm, cn, ce, dt, sens, w6, W6):
    """One RK4 step of state and sensitivities; ``w6`` (5, 6) and ``W6`` (5, 6, NS) are scratch."""
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
    for i in range(6):
        x[i] += w * (k1[i] + 2 * k2[i] + 2 * k3[i] + k4[i])
    if sens:
        for i in range(6):
            for k in range(NS):
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
        w6 = np.empty((5, 6))
        W6 = np.zeros((5, 6, NS))
        x = x0s[k].copy()
        S = np.zeros((6, NS))
        for i in range(6):
            S[i, i] = 1.0
        xa = x.copy()
        Sa = S.copy()
        cn, ce = seg_cur[k, 0], seg_cur[k, 1]
        j = meas_ptr[k]
        jend = meas_ptr[k + 1]
        for i in range(seg_i0[k], seg_i1[k]):
            if j >= jend:
                break
            ta, tb = tg[i], tg[i + 1]
            dt = tb - ta
            need = meas_t[j] <= tb + 1e-9
            if need:
                xa[:] = x
                if sens:
                    Sa[:, :] = S
            nsub = max(1, int(math.ceil(dt / max_dt - 1e-9)))
            h = dt / nsub
            for q in range(nsub):
                _rk4(x, S, tau_u[i], tau_r[i], prm, cn, ce, h, sens, w6, W6)
            if need:
                while j < jend and meas_t[j] <= tb + 1e-9:
                    w = (meas_t[j] - ta) / dt
                    w = min(max(w, 0.0), 1.0)
                    for q in range(6):
                        out_x[j, q] = (1 - w) * xa[q] + w * x[q]
                    if sens:
                        for q in range(6):
                            for c in range(NS):
                                out_S[j, q, c] = (1 - w) * Sa[q, c] + w * S[q, c]
                    j += 1
