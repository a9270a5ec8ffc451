"""Control law (9)-(10), thrust allocation, saturation and anti-windup; one controller tick.

Full controller (the paper's):

    tau_u = -KPu ue - KIu int(ue) + m u_d_dot + d11 u_d - m r (v + r xg)                  (9)
    tau_r = -KPpsi psie - KIpsi int(psie) - KDpsi re + (Iz - m xg^2) r_d_dot
            + d33 r_d - d22 v xg                                                           (10)

with ue = u - u_d, psie = ssa(psi - psi_d), re = r - r_d. The baseline the paper compares
against (Fig. 2, solid lines) is the same PI (surge) / PID (heading) without the model terms.

Allocation: F_left = (tau_u + tau_r / arm) / 2, F_right = (tau_u - tau_r / arm) / 2 (the
inverse of ``Thrusters.tau_from_forces``), each clipped to [-reverse_n, forward_n] as
``Thrusters.saturate`` does; the applied tau is recomputed from the clipped forces. (The
kernel repeats these two one-line formulas so it can run compiled; a test checks it
against ``Thrusters.forces_from_tau``/``saturate``/``tau_from_forces``.)

Anti-windup (the paper ignores saturation; a field tool cannot): conditional integration.
While a thruster saturates, an integrator is frozen when integrating would move its
demand further in the direction the thrusters cannot follow. Integrators use forward
Euler: int(ue)[k+1] = int(ue)[k] + dt ue[k].

One tick at time t_k with state x_k = [n, e, psi, u, v, r] (velocities relative to water):
guidance (theta warm-started), prefilter outputs at k, errors, law, allocation, then the
integrators and the prefilters advance to k+1.
"""

from __future__ import annotations

import numpy as np

from .._jit import njit
from ..model.vessel import Vessel
from .gains import Gains, GuidanceSettings
from .guidance import guidance_step, initial_theta
from .paths import Path
from .prefilter import heading_filter_step, surge_filter_output, surge_filter_step, wrap

# controller state vector layout
CS_THETA, CS_PSI_D, CS_R_D, CS_A_D, CS_UF, CS_UDF, CS_UEI, CS_PSIEI, CS_INIT = range(9)
CS_LEN = 9

# one output row per tick
OUT_COLUMNS = ("theta", "closest_n_m", "closest_e_m", "carrot_n_m", "carrot_e_m", "psi_ref_rad",
               "psi_d_rad", "r_d_radps", "r_d_dot_radps2", "u_d_mps", "u_d_dot_mps2", "u_e_mps",
               "psi_e_rad", "cross_track_m", "tau_u_n", "tau_r_nm", "thrust_left_n", "thrust_right_n",
               "saturated", "tau_u_demand_n", "tau_r_demand_nm", "u_e_int", "psi_e_int")
NOUT = len(OUT_COLUMNS)
COL = {c: i for i, c in enumerate(OUT_COLUMNS)}


@njit
def control_law(full, G, P, ue, ueI, psie, psieI, re, u_d, u_d_dot, r_d, r_d_dot, v, r):
    """(tau_u, tau_r) of (9)-(10) (``full``) or of the baseline PI/PID."""
    tau_u = -G[0] * ue - G[1] * ueI
    tau_r = -G[2] * psie - G[3] * psieI - G[4] * re
    if full:
        m, Iz, d11, d22, d33, xg = P[0], P[1], P[2], P[3], P[4], P[5]
        tau_u += m * u_d_dot + d11 * u_d - m * r * (v + r * xg)
        tau_r += (Iz - m * xg * xg) * r_d_dot + d33 * r_d - d22 * v * xg
    return tau_u, tau_r


@njit
def control_tick(x, u_ref, dtheta, dt, cs, kind, prm, G, P, S, T, out):
    """One controller tick; updates ``cs`` in place and writes the decisions into ``out``.

    ``dtheta`` is the carrot distance delta_theta at this tick.
    S = [delta_theta (default), gamma, iterations, psi_omega, psi_zeta, surge_order, u_omega, u_zeta,
         full (1) / baseline (0), anti_windup, prefilter_init (0 reference, 1 state)]
    T = [arm_m, forward_n, reverse_n]
    """
    pn, pe, psi, u, v, r = x[0], x[1], x[2], x[3], x[4], x[5]
    th, cpn, cpe, can, cae, psi_ref, xt = guidance_step(kind, prm, pn, pe, cs[0], S[1], int(S[2]), dtheta)
    cs[0] = th
    order = int(S[5])
    if cs[8] == 0.0:
        if S[10] == 0.0:
            cs[1], cs[2], cs[3], cs[4], cs[5] = psi_ref, 0.0, 0.0, u_ref, 0.0
        else:
            cs[1], cs[2], cs[3], cs[4], cs[5] = psi, r, 0.0, u, 0.0
        cs[8] = 1.0
    u_d, u_d_dot = surge_filter_output(cs[4], cs[5], u_ref, order, S[6])
    psi_d, r_d, r_d_dot = cs[1], cs[2], cs[3]
    ue = u - u_d
    psie = wrap(psi - psi_d)
    re = r - r_d
    full = S[8] != 0.0
    tau_u, tau_r = control_law(full, G, P, ue, cs[6], psie, cs[7], re, u_d, u_d_dot, r_d, r_d_dot, v, r)
    # allocation + saturation
    arm, fwd, rev = T[0], T[1], T[2]
    d = tau_r / arm
    fl = 0.5 * (tau_u + d)
    fr = 0.5 * (tau_u - d)
    fls = min(max(fl, -rev), fwd)
    frs = min(max(fr, -rev), fwd)
    sat = (fls != fl) or (frs != fr)
    tua = fls + frs
    tra = arm * (fls - frs)
    # integrators (conditional integration while saturated)
    inc_u = dt * ue
    inc_p = dt * psie
    if sat and S[9] != 0.0:
        if (-G[1] * inc_u) * (tau_u - tua) > 0.0:
            inc_u = 0.0
        if (-G[3] * inc_p) * (tau_r - tra) > 0.0:
            inc_p = 0.0
    out[0] = th
    out[1] = cpn
    out[2] = cpe
    out[3] = can
    out[4] = cae
    out[5] = psi_ref
    out[6] = wrap(psi_d)
    out[7] = r_d
    out[8] = r_d_dot
    out[9] = u_d
    out[10] = u_d_dot
    out[11] = ue
    out[12] = psie
    out[13] = xt
    out[14] = tua
    out[15] = tra
    out[16] = fls
    out[17] = frs
    out[18] = 1.0 if sat else 0.0
    out[19] = tau_u
    out[20] = tau_r
    out[21] = cs[6]
    out[22] = cs[7]
    cs[6] += inc_u
    cs[7] += inc_p
    cs[1], cs[2], cs[3] = heading_filter_step(cs[1], cs[2], cs[3], psi_ref, dt, S[3], S[4])
    cs[4], cs[5] = surge_filter_step(cs[4], cs[5], u_ref, dt, order, S[6], S[7])


@njit
def run_open_loop(X, u_ref, dtheta, dt, cs, kind, prm, G, P, S, T):
    """Controller decisions for a sequence of states X (N x 6) at ticks with steps dt (N)."""
    n = X.shape[0]
    out = np.empty((n, 23))
    for k in range(n):
        control_tick(X[k], u_ref[k], dtheta[k], dt[k], cs, kind, prm, G, P, S, T, out[k])
    return out


def speed_at(schedule: np.ndarray, t_rel, column: int = 1) -> np.ndarray:
    """Column ``column`` (1: u_ref, 2: delta_theta) of a piecewise-constant schedule
    [[t_s, u_d, (delta_theta)], ...] sorted by t_s, at times ``t_rel``."""
    t_rel = np.asarray(t_rel, dtype=float)
    idx = np.searchsorted(schedule[:, 0], t_rel, side="right") - 1
    return schedule[np.clip(idx, 0, len(schedule) - 1), column]


class Controller:
    """The paper's controller (or the baseline) bound to a path, a vessel model and settings."""

    def __init__(self, path: Path, vessel: Vessel, gains: Gains, guidance: GuidanceSettings, *,
                 full: bool = True):
        self.path, self.vessel, self.gains, self.guidance, self.full = path, vessel, gains, guidance, full
        g = guidance
        self.G = gains.as_array()
        self.P = vessel.params.as_array()
        self.S = np.array([g.delta_theta, g.gamma, g.iterations, g.psi_omega, g.psi_zeta, g.surge_order,
                           g.u_omega, g.u_zeta, 1.0 if full else 0.0, 1.0 if g.anti_windup else 0.0,
                           0.0 if g.prefilter_init == "reference" else 1.0])
        t = vessel.thrusters
        self.T = np.array([t.arm_m, t.forward_n, t.reverse_n])
        self.cs = np.zeros(CS_LEN)

    def reset(self, x0) -> None:
        """Forget the filters and integrators; start theta at the nearest path point to x0."""
        self.cs = np.zeros(CS_LEN)
        self.cs[CS_THETA] = initial_theta(self.path, float(x0[0]), float(x0[1]))

    def step(self, x, u_ref: float, dt: float, out: np.ndarray | None = None,
             delta_theta: float | None = None) -> np.ndarray:
        """One tick; returns the output row (see OUT_COLUMNS)."""
        row = np.empty(NOUT) if out is None else out
        dth = self.guidance.delta_theta if delta_theta is None else float(delta_theta)
        control_tick(np.asarray(x, dtype=float), float(u_ref), dth, float(dt), self.cs, self.path.kind,
                     self.path.prm, self.G, self.P, self.S, self.T, row)
        return row

    def run(self, X, u_ref, dt, delta_theta=None) -> np.ndarray:
        """Open loop over recorded states: (N, NOUT) decisions, starting from the current state."""
        X = np.ascontiguousarray(np.asarray(X, dtype=float))
        dth = np.full(len(X), self.guidance.delta_theta) if delta_theta is None else delta_theta
        return run_open_loop(X, np.ascontiguousarray(np.asarray(u_ref, float)),
                             np.ascontiguousarray(np.asarray(dth, float)),
                             np.ascontiguousarray(np.asarray(dt, float)), self.cs, self.path.kind,
                             self.path.prm, self.G, self.P, self.S, self.T)


__all__ = ["Controller", "control_law", "control_tick", "run_open_loop", "OUT_COLUMNS", "NOUT", "COL",
           "speed_at"]
