"""Multiple-shooting simulation of eqs. (1)+(3) with forward sensitivities (numba).

The dynamics are :func:`usvlog.vessel.nu_dot_terms` itself, compiled by numba (no
second copy of the model); its derivatives with respect to (u, v, r) and to the six
parameters are taken by complex step, exact to rounding. Kinematics are eq. (1) plus a
constant current, as in :func:`usvlog.simulate.plant_step`.

Sensitivity columns: 0-5 the segment's initial state (n, e, psi, u, v, r), 6-11 the
parameters (m, Iz, d11, d22, d33, xg), 12-13 the current (north, east).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from ..vessel import nu_dot_terms

NS = 14
_CS = 1e-30  # complex step

_nd = numba.njit(cache=True)(nu_dot_terms)


@numba.njit(cache=True)
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
    h = 1j * _CS
    bu = _nd(u + h, v + 0j, r + 0j, tu, tr, m, Iz, d11, d22, d33, xg)
    bv = _nd(u + 0j, v + h, r + 0j, tu, tr, m, Iz, d11, d22, d33, xg)
    br = _nd(u + 0j, v + 0j, r + h, tu, tr, m, Iz, d11, d22, d33, xg)
    A00, A01, A02 = bu[0].imag / _CS, bv[0].imag / _CS, br[0].imag / _CS
    A10, A11, A12 = bu[1].imag / _CS, bv[1].imag / _CS, br[1].imag / _CS
    A20, A21, A22 = bu[2].imag / _CS, bv[2].imag / _CS, br[2].imag / _CS
    for k in range(NS):
        s2, s3, s4, s5 = S[2, k], S[3, k], S[4, k], S[5, k]
        Sd[0, k] = a02 * s2 + c * s3 - s * s4
        Sd[1, k] = a12 * s2 + s * s3 + c * s4
        Sd[2, k] = s5
        Sd[3, k] = A00 * s3 + A01 * s4 + A02 * s5
        Sd[4, k] = A10 * s3 + A11 * s4 + A12 * s5
        Sd[5, k] = A20 * s3 + A21 * s4 + A22 * s5
    for j in range(6):
        p0 = m + (h if j == 0 else 0j)
        p1 = Iz + (h if j == 1 else 0j)
        p2 = d11 + (h if j == 2 else 0j)
        p3 = d22 + (h if j == 3 else 0j)
        p4 = d33 + (h if j == 4 else 0j)
        p5 = xg + (h if j == 5 else 0j)
        b = _nd(u + 0j, v + 0j, r + 0j, tu, tr, p0, p1, p2, p3, p4, p5)
        Sd[3, 6 + j] += b[0].imag / _CS
        Sd[4, 6 + j] += b[1].imag / _CS
        Sd[5, 6 + j] += b[2].imag / _CS
    Sd[0, 12] += 1.0
    Sd[1, 13] += 1.0


@numba.njit(cache=True)
def _rk4(x, S, tu, tr, prm, cn, ce, dt, sens, w6, W6):
    """One RK4 step of state and sensitivities; ``w6`` (9, 6) and ``W6`` (9, 6, NS) are scratch."""
    k1, k2, k3, k4, xt = w6[0], w6[1], w6[2], w6[3], w6[4]
    K1, K2, K3, K4, St = W6[0], W6[1], W6[2], W6[3], W6[4]
    _deriv(x, S, tu, tr, prm, cn, ce, k1, K1, sens)
    for i in range(6):
        xt[i] = x[i] + 0.5 * dt * k1[i]
    if sens:
        for i in range(6):
            for k in range(NS):
                St[i, k] = S[i, k] + 0.5 * dt * K1[i, k]
    _deriv(xt, St, tu, tr, prm, cn, ce, k2, K2, sens)
    for i in range(6):
        xt[i] = x[i] + 0.5 * dt * k2[i]
    if sens:
        for i in range(6):
            for k in range(NS):
                St[i, k] = S[i, k] + 0.5 * dt * K2[i, k]
    _deriv(xt, St, tu, tr, prm, cn, ce, k3, K3, sens)
    for i in range(6):
        xt[i] = x[i] + dt * k3[i]
    if sens:
        for i in range(6):
            for k in range(NS):
                St[i, k] = S[i, k] + dt * K3[i, k]
    _deriv(xt, St, tu, tr, prm, cn, ce, k4, K4, sens)
    w = dt / 6.0
    for i in range(6):
        x[i] += w * (k1[i] + 2 * k2[i] + 2 * k3[i] + k4[i])
    if sens:
        for i in range(6):
            for k in range(NS):
                S[i, k] += w * (K1[i, k] + 2 * K2[i, k] + 2 * K3[i, k] + K4[i, k])


@numba.njit(cache=True)
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
