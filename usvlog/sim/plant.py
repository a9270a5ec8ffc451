"""The paper's plant: eqs. (1)-(3) integrated one step at a time.

:func:`plant_step` integrates the paper's model (RK4, or first-order like the paper's Section IV)
acting on the velocity relative to the water when there is a current; :func:`plant_step_ext` the
extended structure, or any vessel with a first-order thruster lag. :func:`plant_form` says which a
vessel needs, :func:`plant_advance` takes one step of either, and :class:`PlantStepper` steps it
from Python (the closed loop, the tests). The open-loop scenarios (:mod:`usvlog.sim.simulate`) and
the closed loop (:mod:`usvlog.sim.closed_loop`) compile these into their kernels.
"""

from __future__ import annotations

import math

from .._jit import jitable
from ..model.vessel import Vessel, nu_dot_ext_terms, nu_dot_terms


@jitable
def _plant_rhs(n, e, psi, u, v, r, tau_u, tau_r, prm, cn, ce):
    """Time derivative of [n, e, psi, u, v, r] (eqs. (1)+(3), current (cn, ce) in NED)."""
    c, s = math.cos(psi), math.sin(psi)
    m, Iz, d11, d22, d33, xg = prm  # PARAM_NAMES order
    ud, vd, rd = nu_dot_terms(u, v, r, tau_u, tau_r, m, Iz, d11, d22, d33, xg)
    return (c * u - s * v + cn, s * u + c * v + ce, r, ud, vd, rd)


@jitable
def plant_step(state, tau_u, tau_r, prm, dt, cn, ce, rk4=True):
    """One integration step of eqs. (1)+(3) on a 6-tuple of floats (fast scalar path).

    Plain Python, and also callable from numba-compiled loops (:func:`usvlog._jit.jitable`).
    The stages combine the six components one by one (k[i] is the derivative of state[i]).

    Parameters
    ----------
    state : tuple of 6 floats
        [n (m), e (m), psi (rad), u (m/s), v (m/s), r (rad/s)], u, v relative to the water.
    tau_u, tau_r : float
        Surge force (N) and yaw moment (N m), held over the step.
    prm : tuple or ndarray
        Vessel parameters in PARAM_NAMES order (m, Iz, d11, d22, d33, xg; SI units).
    dt : float
        Step, s.
    cn, ce : float
        Water current, north and east, m/s.
    rk4 : bool
        RK4 (True) or forward Euler (the paper's Section IV).

    Returns
    -------
    tuple of 6 floats
        The state after ``dt``.
    """
    x0, x1, x2, x3, x4, x5 = state
    k1 = _plant_rhs(x0, x1, x2, x3, x4, x5, tau_u, tau_r, prm, cn, ce)
    if not rk4:
        return (x0 + dt * k1[0], x1 + dt * k1[1], x2 + dt * k1[2], x3 + dt * k1[3], x4 + dt * k1[4],
                x5 + dt * k1[5])
    h = 0.5 * dt
    k2 = _plant_rhs(x0 + h * k1[0], x1 + h * k1[1], x2 + h * k1[2], x3 + h * k1[3], x4 + h * k1[4],
                    x5 + h * k1[5], tau_u, tau_r, prm, cn, ce)
    k3 = _plant_rhs(x0 + h * k2[0], x1 + h * k2[1], x2 + h * k2[2], x3 + h * k2[3], x4 + h * k2[4],
                    x5 + h * k2[5], tau_u, tau_r, prm, cn, ce)
    k4 = _plant_rhs(x0 + dt * k3[0], x1 + dt * k3[1], x2 + dt * k3[2], x3 + dt * k3[3], x4 + dt * k3[4],
                    x5 + dt * k3[5], tau_u, tau_r, prm, cn, ce)
    w = dt / 6.0
    return (x0 + w * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0]), x1 + w * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1]),
            x2 + w * (k1[2] + 2 * k2[2] + 2 * k3[2] + k4[2]), x3 + w * (k1[3] + 2 * k2[3] + 2 * k3[3] + k4[3]),
            x4 + w * (k1[4] + 2 * k2[4] + 2 * k3[4] + k4[4]), x5 + w * (k1[5] + 2 * k2[5] + 2 * k3[5] + k4[5]))


@jitable
def _plant_rhs_ext(n, e, psi, u, v, r, tau_u, tau_r, prm, cn, ce):
    """Time derivative of [n, e, psi, u, v, r] under the extended model (prm: EXTENDED_PARAM_NAMES order)."""
    c, s = math.cos(psi), math.sin(psi)
    ud, vd, rd = nu_dot_ext_terms(u, v, r, tau_u, tau_r, prm[0], prm[1], prm[2], prm[3], prm[4], prm[5], prm[6],
                                  prm[7], prm[8], prm[9])
    return (c * u - s * v + cn, s * u + c * v + ce, r, ud, vd, rd)


@jitable
def _lagged(cmd, f0, t, lag_s):
    """Force t s into a step of a first-order lag (time constant lag_s) from f0 towards cmd."""
    if lag_s <= 0.0:
        return cmd
    return cmd + (f0 - cmd) * math.exp(-t / lag_s)


@jitable
def plant_step_ext(state, force, tau_u, tau_r, prm, dt, cn, ce, rk4=True):
    """One integration step of the extended model with a first-order thruster lag.

    The applied force follows T dF/dt = F_cmd - F exactly (F_cmd held over the step); the
    stages of RK4 see the force at their own times. Plain Python, also callable from
    numba-compiled loops.

    Parameters
    ----------
    state : tuple of 6 floats
        [n (m), e (m), psi (rad), u (m/s), v (m/s), r (rad/s)], u, v relative to the water.
    force : tuple of 2 floats
        Applied (lagged) surge force (N) and yaw moment (N m) at the start of the step.
    tau_u, tau_r : float
        Commanded surge force (N) and yaw moment (N m), held over the step.
    prm : tuple or ndarray of 11 floats
        The extended model in EXTENDED_PARAM_NAMES order (SI units), then the lag time
        constant in s (0: none, the force is the command).
    dt : float
        Step, s.
    cn, ce : float
        Water current, north and east, m/s.
    rk4 : bool
        RK4 (True) or forward Euler.

    Returns
    -------
    state : tuple of 6 floats
        The state after ``dt``.
    force : tuple of 2 floats
        The applied force and moment after ``dt``.
    """
    lag = prm[10]
    x0, x1, x2, x3, x4, x5 = state
    fu0 = _lagged(tau_u, force[0], 0.0, lag) if lag > 0.0 else tau_u
    fr0 = _lagged(tau_r, force[1], 0.0, lag) if lag > 0.0 else tau_r
    fu1, fr1 = _lagged(tau_u, force[0], dt, lag), _lagged(tau_r, force[1], dt, lag)
    k1 = _plant_rhs_ext(x0, x1, x2, x3, x4, x5, fu0, fr0, prm, cn, ce)
    if not rk4:
        return ((x0 + dt * k1[0], x1 + dt * k1[1], x2 + dt * k1[2], x3 + dt * k1[3], x4 + dt * k1[4],
                 x5 + dt * k1[5]), (fu1, fr1))
    h = 0.5 * dt
    fuh, frh = _lagged(tau_u, force[0], h, lag), _lagged(tau_r, force[1], h, lag)
    k2 = _plant_rhs_ext(x0 + h * k1[0], x1 + h * k1[1], x2 + h * k1[2], x3 + h * k1[3], x4 + h * k1[4],
                        x5 + h * k1[5], fuh, frh, prm, cn, ce)
    k3 = _plant_rhs_ext(x0 + h * k2[0], x1 + h * k2[1], x2 + h * k2[2], x3 + h * k2[3], x4 + h * k2[4],
                        x5 + h * k2[5], fuh, frh, prm, cn, ce)
    k4 = _plant_rhs_ext(x0 + dt * k3[0], x1 + dt * k3[1], x2 + dt * k3[2], x3 + dt * k3[3], x4 + dt * k3[4],
                        x5 + dt * k3[5], fu1, fr1, prm, cn, ce)
    w = dt / 6.0
    return ((x0 + w * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0]), x1 + w * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1]),
             x2 + w * (k1[2] + 2 * k2[2] + 2 * k3[2] + k4[2]), x3 + w * (k1[3] + 2 * k2[3] + 2 * k3[3] + k4[3]),
             x4 + w * (k1[4] + 2 * k2[4] + 2 * k3[4] + k4[4]), x5 + w * (k1[5] + 2 * k2[5] + 2 * k3[5] + k4[5])),
            (fu1, fr1))


def plant_form(vessel: Vessel) -> tuple[bool, tuple]:
    """Which step a vessel's plant takes, and its parameter tuple.

    Parameters
    ----------
    vessel : Vessel

    Returns
    -------
    extended : bool
        True for :func:`plant_step_ext` (a vessel of the extended structure, or with a
        thruster lag), False for the paper's :func:`plant_step`.
    prm : tuple of float
        The parameters that step takes: PARAM_NAMES order (6), or the extended model in
        EXTENDED_PARAM_NAMES order and the lag time constant in s (11).
    """
    if vessel.extended is None and vessel.thrusters.lag_s == 0.0:
        return False, tuple(vessel.params.as_array().tolist())
    return True, (*vessel.plant_params().as_array().tolist(), float(vessel.thrusters.lag_s))


@jitable
def plant_advance(x, force, tau_u, tau_r, ext, prm, ext_prm, dt, cn, ce, rk4=True):
    """One plant step of either form, as every simulation loop takes it.

    ``ext``: the extended form with thruster lag (:func:`plant_step_ext`, parameters
    ``ext_prm``), else the paper's (:func:`plant_step`, parameters ``prm``). ``x`` the
    6-tuple state, ``force`` the lagged (tau_u N, tau_r N m) of the extended form (passed
    through unchanged by the paper's), the command ``tau_u`` N, ``tau_r`` N m over the step
    of ``dt`` s, current ``cn``, ``ce`` m/s, RK4 or forward Euler.

    Returns
    -------
    x : tuple of 6 floats
        The state after the step.
    force : tuple of 2 floats
        The lagged force and moment after the step.
    applied_u, applied_r : float
        The force (N) and moment (N m) the plant felt at the start of the step: the lagged
        one with a lag, else the command.
    """
    if ext:
        if ext_prm[10] > 0.0:
            au, ar = force[0], force[1]
        else:
            au, ar = tau_u, tau_r
        x, force = plant_step_ext(x, force, tau_u, tau_r, ext_prm, dt, cn, ce, rk4)
        return x, force, au, ar
    return plant_step(x, tau_u, tau_r, prm, dt, cn, ce, rk4), force, tau_u, tau_r


class PlantStepper:
    """A vessel's plant stepped from Python: :func:`plant_step` or :func:`plant_step_ext`.

    Parameters
    ----------
    vessel : Vessel
        The plant (its extended model and thruster lag when it has them).
    dt : float
        Step, s.
    current_ne : (float, float)
        Water current, north and east, m/s.
    rk4 : bool
        RK4 (True) or forward Euler.

    Notes
    -----
    The lagged force starts at zero (thrusters at rest). ``applied`` is the force and
    moment (N, N m) at the start of the last step taken: the command itself without a lag.
    """

    def __init__(self, vessel: Vessel, dt: float, current_ne, rk4: bool):
        self.extended, self.prm = plant_form(vessel)
        self.dt, self.rk4 = float(dt), bool(rk4)
        self.cn, self.ce = float(current_ne[0]), float(current_ne[1])
        self.force = (0.0, 0.0)
        self.applied = (0.0, 0.0)

    def __call__(self, x, tau_u: float, tau_r: float):
        """The state after one step from ``x`` (6-tuple) under the command (tau_u N, tau_r N m)."""
        x, self.force, au, ar = plant_advance(x, self.force, tau_u, tau_r, self.extended, self.prm, self.prm,
                                              self.dt, self.cn, self.ce, self.rk4)
        self.applied = (au, ar)
        return x
