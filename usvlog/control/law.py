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
from ..model.frames import wrap_angle
from ..model.vessel import Vessel
from .gains import GAIN_NAMES, Gains, GuidanceSettings
from .guidance import guidance_step, initial_theta
from .paths import Path
from .prefilter import heading_filter_step, surge_filter_output, surge_filter_step

# controller state vector ``ctrl_state`` layout (Controller.cs)
CS_THETA, CS_PSI_D, CS_R_D, CS_A_D, CS_UF, CS_UDF, CS_UEI, CS_PSIEI, CS_INIT = range(9)
CS_LEN = 9

# gains array (Gains.as_array, GAIN_NAMES order)
G_KPU, G_KIU, G_KPPSI, G_KIPSI, G_KDPSI = (GAIN_NAMES.index(g) for g in ("KPu", "KIu", "KPpsi", "KIpsi", "KDpsi"))

# guidance/prefilter settings array (Controller.S)
(S_DELTA_THETA, S_GAMMA, S_ITERATIONS, S_PSI_OMEGA, S_PSI_ZETA, S_SURGE_ORDER, S_U_OMEGA, S_U_ZETA,
 S_FULL, S_ANTI_WINDUP, S_PREFILTER_INIT) = range(11)
S_LEN = 11

# thruster array (Controller.T)
T_ARM, T_FORWARD, T_REVERSE = range(3)
T_LEN = 3

# one output row per tick
OUT_COLUMNS = ("theta", "closest_n_m", "closest_e_m", "carrot_n_m", "carrot_e_m", "psi_ref_rad",
               "psi_d_rad", "r_d_radps", "r_d_dot_radps2", "u_d_mps", "u_d_dot_mps2", "u_e_mps",
               "psi_e_rad", "cross_track_m", "tau_u_n", "tau_r_nm", "thrust_left_n", "thrust_right_n",
               "saturated", "tau_u_demand_n", "tau_r_demand_nm", "u_e_int", "psi_e_int")
NOUT = len(OUT_COLUMNS)
COL = {c: i for i, c in enumerate(OUT_COLUMNS)}
# the same positions as names the kernels can use (in OUT_COLUMNS order)
(OUT_THETA, OUT_CLOSEST_N, OUT_CLOSEST_E, OUT_CARROT_N, OUT_CARROT_E, OUT_PSI_REF, OUT_PSI_D, OUT_R_D,
 OUT_R_D_DOT, OUT_U_D, OUT_U_D_DOT, OUT_U_E, OUT_PSI_E, OUT_CROSS_TRACK, OUT_TAU_U, OUT_TAU_R,
 OUT_THRUST_LEFT, OUT_THRUST_RIGHT, OUT_SATURATED, OUT_TAU_U_DEMAND, OUT_TAU_R_DEMAND, OUT_U_E_INT,
 OUT_PSI_E_INT) = range(NOUT)


@njit
def control_law(full, gains, params, u_err, u_err_int, psi_err, psi_err_int, r_err, u_d, u_d_dot, r_d,
                r_d_dot, v_mps, r_radps):
    """(tau_u, tau_r) of (9)-(10) (``full``) or of the baseline PI/PID.

    Parameters
    ----------
    full : bool
        True: control law (9)-(10) with the model terms; False: the baseline PI/PID.
    gains : ndarray
        Gains.as_array() (G_* positions).
    params : ndarray
        VesselParams.as_array(): m (kg), Iz (kg m^2), d11 (kg/s), d22 (kg/s), d33 (kg m^2/s), xg (m).
    u_err, u_err_int : float
        Surge error u - u_d (m/s) and its integral (m).
    psi_err, psi_err_int : float
        Heading error ssa(psi - psi_d) (rad) and its integral (rad s).
    r_err : float
        Yaw-rate error r - r_d (rad/s).
    u_d, u_d_dot : float
        Desired surge speed (m/s) and its derivative (m/s^2).
    r_d, r_d_dot : float
        Desired yaw rate (rad/s) and its derivative (rad/s^2).
    v_mps, r_radps : float
        Sway velocity v (m/s) and yaw rate r (rad/s).

    Returns
    -------
    tau_u : float
        Surge force demand, N.
    tau_r : float
        Yaw moment demand, N m.
    """
    tau_u = -gains[G_KPU] * u_err - gains[G_KIU] * u_err_int
    tau_r = -gains[G_KPPSI] * psi_err - gains[G_KIPSI] * psi_err_int - gains[G_KDPSI] * r_err
    if full:
        m, Iz, d11, d22, d33, xg = params  # PARAM_NAMES order
        tau_u += m * u_d_dot + d11 * u_d - m * r_radps * (v_mps + r_radps * xg)
        tau_r += (Iz - m * xg * xg) * r_d_dot + d33 * r_d - d22 * v_mps * xg
    return tau_u, tau_r


@njit
def control_tick(state, u_ref, dtheta, dt, ctrl_state, path_kind, path_prm, gains, params, settings, thrusters,
                 row):
    """One controller tick; updates ``ctrl_state`` in place and writes the decisions into ``row``.

    Parameters
    ----------
    state : ndarray
        Vessel state [n (m), e (m), psi (rad), u (m/s), v (m/s), r (rad/s)] the controller sees.
    u_ref : float
        Speed reference, m/s.
    dtheta : float
        Carrot distance delta_theta at this tick, m.
    dt : float
        Controller step, s.
    ctrl_state : ndarray
        Controller state (CS_* positions), advanced to the next tick in place.
    path_kind, path_prm :
        The path (``Path.kind``, ``Path.prm``).
    gains, params, settings, thrusters : ndarray
        ``Controller.G`` (G_*), ``.P`` (PARAM_NAMES), ``.S`` (S_*), ``.T`` (T_*).
    row : ndarray
        Output row (NOUT, OUT_* positions), written in place.
    """
    cs = ctrl_state
    pn, pe, psi, u, v, r = state
    th, cpn, cpe, can, cae, psi_ref, xt = guidance_step(path_kind, path_prm, pn, pe, cs[CS_THETA],
                                                        settings[S_GAMMA], int(settings[S_ITERATIONS]), dtheta)
    cs[CS_THETA] = th
    order = int(settings[S_SURGE_ORDER])
    u_omega = settings[S_U_OMEGA]
    if cs[CS_INIT] == 0.0:
        if settings[S_PREFILTER_INIT] == 0.0:  # start the prefilters at the reference
            cs[CS_PSI_D], cs[CS_R_D], cs[CS_A_D], cs[CS_UF], cs[CS_UDF] = psi_ref, 0.0, 0.0, u_ref, 0.0
        else:                                  # at the vessel's heading and speed
            cs[CS_PSI_D], cs[CS_R_D], cs[CS_A_D], cs[CS_UF], cs[CS_UDF] = psi, r, 0.0, u, 0.0
        cs[CS_INIT] = 1.0
    u_d, u_d_dot = surge_filter_output(cs[CS_UF], cs[CS_UDF], u_ref, order, u_omega)
    psi_d, r_d, r_d_dot = cs[CS_PSI_D], cs[CS_R_D], cs[CS_A_D]
    ue = u - u_d
    psie = wrap_angle(psi - psi_d)
    re = r - r_d
    full = settings[S_FULL] != 0.0
    tau_u, tau_r = control_law(full, gains, params, ue, cs[CS_UEI], psie, cs[CS_PSIEI], re, u_d, u_d_dot, r_d,
                               r_d_dot, v, r)
    # allocation + saturation
    arm, fwd, rev = thrusters[T_ARM], thrusters[T_FORWARD], thrusters[T_REVERSE]
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
    if sat and settings[S_ANTI_WINDUP] != 0.0:
        if (-gains[G_KIU] * inc_u) * (tau_u - tua) > 0.0:
            inc_u = 0.0
        if (-gains[G_KIPSI] * inc_p) * (tau_r - tra) > 0.0:
            inc_p = 0.0
    row[OUT_THETA] = th
    row[OUT_CLOSEST_N] = cpn
    row[OUT_CLOSEST_E] = cpe
    row[OUT_CARROT_N] = can
    row[OUT_CARROT_E] = cae
    row[OUT_PSI_REF] = psi_ref
    row[OUT_PSI_D] = wrap_angle(psi_d)
    row[OUT_R_D] = r_d
    row[OUT_R_D_DOT] = r_d_dot
    row[OUT_U_D] = u_d
    row[OUT_U_D_DOT] = u_d_dot
    row[OUT_U_E] = ue
    row[OUT_PSI_E] = psie
    row[OUT_CROSS_TRACK] = xt
    row[OUT_TAU_U] = tua
    row[OUT_TAU_R] = tra
    row[OUT_THRUST_LEFT] = fls
    row[OUT_THRUST_RIGHT] = frs
    row[OUT_SATURATED] = 1.0 if sat else 0.0
    row[OUT_TAU_U_DEMAND] = tau_u
    row[OUT_TAU_R_DEMAND] = tau_r
    row[OUT_U_E_INT] = cs[CS_UEI]
    row[OUT_PSI_E_INT] = cs[CS_PSIEI]
    cs[CS_UEI] += inc_u
    cs[CS_PSIEI] += inc_p
    cs[CS_PSI_D], cs[CS_R_D], cs[CS_A_D] = heading_filter_step(cs[CS_PSI_D], cs[CS_R_D], cs[CS_A_D], psi_ref, dt,
                                                               settings[S_PSI_OMEGA], settings[S_PSI_ZETA])
    cs[CS_UF], cs[CS_UDF] = surge_filter_step(cs[CS_UF], cs[CS_UDF], u_ref, dt, order, u_omega,
                                              settings[S_U_ZETA])


@njit(nogil=True)   # replay runs it beside the what-if closed loop (two cores)
def run_open_loop(states, u_ref, dtheta, dt, ctrl_state, path_kind, path_prm, gains, params, settings, thrusters):
    """Controller decisions for a sequence of states (N x 6) at ticks with steps ``dt`` (N, s).

    Arguments as :func:`control_tick`, with ``u_ref``, ``dtheta`` and ``dt`` per tick
    (arrays of N); returns the (N, NOUT) output rows, stored by column (a transposed
    (NOUT, N) array: each output's N values are contiguous, for the channel frames).
    """
    n = states.shape[0]
    out = np.empty((NOUT, n))
    row = np.empty(NOUT)
    for k in range(n):
        control_tick(states[k], u_ref[k], dtheta[k], dt[k], ctrl_state, path_kind, path_prm, gains, params,
                     settings, thrusters, row)
        for i in range(NOUT):
            out[i, k] = row[i]
    return out.T


def speed_at(schedule: np.ndarray, t_rel, column: int = 1) -> np.ndarray:
    """Column ``column`` (1: u_ref, 2: delta_theta) of a piecewise-constant schedule
    [[t_s, u_d, (delta_theta)], ...] sorted by t_s, at times ``t_rel``."""
    t_rel = np.asarray(t_rel, dtype=float)
    idx = np.searchsorted(schedule[:, 0], t_rel, side="right") - 1
    return schedule[np.clip(idx, 0, len(schedule) - 1), column]


class Controller:
    """The paper's controller (or the baseline) bound to a path, a vessel model and settings.

    The kernels take the settings as flat arrays: ``G`` gains (G_* positions), ``P`` vessel
    parameters (PARAM_NAMES order, SI units), ``S`` guidance and prefilter settings (S_*),
    ``T`` thrusters (T_*: arm m, forward and reverse force limits N); ``cs`` is the
    controller state (CS_*).
    """

    def __init__(self, path: Path, vessel: Vessel, gains: Gains, guidance: GuidanceSettings, *,
                 full: bool = True):
        self.path, self.vessel, self.gains, self.guidance, self.full = path, vessel, gains, guidance, full
        g = guidance
        self.G = gains.as_array()
        self.P = vessel.params.as_array()
        self.S = np.zeros(S_LEN)
        self.S[S_DELTA_THETA], self.S[S_GAMMA], self.S[S_ITERATIONS] = g.delta_theta, g.gamma, g.iterations
        self.S[S_PSI_OMEGA], self.S[S_PSI_ZETA] = g.psi_omega, g.psi_zeta
        self.S[S_SURGE_ORDER], self.S[S_U_OMEGA], self.S[S_U_ZETA] = g.surge_order, g.u_omega, g.u_zeta
        self.S[S_FULL] = 1.0 if full else 0.0
        self.S[S_ANTI_WINDUP] = 1.0 if g.anti_windup else 0.0
        self.S[S_PREFILTER_INIT] = 0.0 if g.prefilter_init == "reference" else 1.0
        t = vessel.thrusters
        self.T = np.zeros(T_LEN)
        self.T[T_ARM], self.T[T_FORWARD], self.T[T_REVERSE] = t.arm_m, t.forward_n, t.reverse_n
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
