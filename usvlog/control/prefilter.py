"""Reference prefilters: psi_ref -> (psi_d, r_d, r_d_dot) and u_ref -> (u_d, u_d_dot).

Heading: Fossen's third-order reference model (Handbook of Marine Craft Hydrodynamics,
sec. 12.1.1), a critically damped (zeta = 1) or general mass-spring-damper in cascade
with a first-order low-pass:

    psi_d''' + (2 zeta + 1) w psi_d'' + (2 zeta + 1) w^2 psi_d' + w^3 psi_d = w^3 psi_ref

The +-pi wrap is handled by driving it with the wrapped error ssa(psi_ref - psi_d):
psi_d itself stays continuous (it may leave [-pi, pi) after full turns) and is
reported wrapped. A psi_ref that jumps from +179 deg to -179 deg is a 2 deg step.

Surge: order 0 (u_d = u_ref, u_d_dot = 0: a step in u_ref reaches the controller as a
step), order 1 (u_d_dot = w (u_ref - u_d)) or order 2 (u_d'' = w^2 (u_ref - u_d) -
2 zeta w u_d'). With order >= 1, u_d_dot is the exact derivative of u_d, so the model
term m u_d_dot of (9) feeds the change forward and the full controller tracks it
without a transient (Section IV).

Both filters are integrated with forward Euler at the controller step, which keeps
r_d = d(psi_d)/dt and r_d_dot = d(r_d)/dt exactly consistent with a first-order plant
integration (the closed-loop error dynamics are then exactly the Euler form of A_e).
"""

from __future__ import annotations

import numpy as np

from .._jit import njit
from ..model.frames import wrap_angle


@njit
def heading_filter_step(psi_d, r_d, a_d, psi_ref, dt, omega, zeta):
    """One Euler step of the third-order model: returns the next (psi_d, r_d, r_d_dot)."""
    k = 2.0 * zeta + 1.0
    jerk = omega ** 3 * wrap_angle(psi_ref - psi_d) - k * omega * a_d - k * omega * omega * r_d
    return psi_d + dt * r_d, r_d + dt * a_d, a_d + dt * jerk


@njit
def surge_filter_output(u_f, ud_f, u_ref, order, omega):
    """(u_d, u_d_dot) from the filter state (u_f, ud_f) and the reference."""
    if order == 0:
        return u_ref, 0.0
    if order == 1:
        return u_f, omega * (u_ref - u_f)
    return u_f, ud_f


@njit
def surge_filter_step(u_f, ud_f, u_ref, dt, order, omega, zeta):
    """Next (u_f, ud_f)."""
    if order == 0:
        return u_ref, 0.0
    if order == 1:
        return u_f + dt * omega * (u_ref - u_f), 0.0
    return u_f + dt * ud_f, ud_f + dt * (omega * omega * (u_ref - u_f) - 2.0 * zeta * omega * ud_f)


@njit
def _run_heading(psi_ref, dt, omega, zeta, psi0, r0, a0):
    n = psi_ref.shape[0]
    out = np.empty((n, 3))
    p, r, a = psi0, r0, a0
    for k in range(n):
        out[k, 0] = wrap_angle(p)
        out[k, 1] = r
        out[k, 2] = a
        p, r, a = heading_filter_step(p, r, a, psi_ref[k], dt, omega, zeta)
    return out


@njit
def _run_surge(u_ref, dt, order, omega, zeta, u0, ud0):
    n = u_ref.shape[0]
    out = np.empty((n, 2))
    uf, udf = u0, ud0
    for k in range(n):
        a, b = surge_filter_output(uf, udf, u_ref[k], order, omega)
        out[k, 0] = a
        out[k, 1] = b
        uf, udf = surge_filter_step(uf, udf, u_ref[k], dt, order, omega, zeta)
    return out


def filter_heading(psi_ref, dt: float, *, omega: float, zeta: float = 1.0, psi0: float | None = None,
                   r0: float = 0.0, a0: float = 0.0) -> np.ndarray:
    """Run the heading model over a sampled psi_ref: columns psi_d (wrapped), r_d, r_d_dot.

    Parameters
    ----------
    psi_ref : array_like, shape (N,)
        Reference heading in rad, one sample per step.
    dt : float
        Step in s.
    omega : float
        Natural frequency in rad/s.
    zeta : float, default 1.0
        Relative damping.
    psi0 : float, optional
        Initial psi_d in rad (default ``psi_ref[0]``).
    r0 : float, default 0.0
        Initial r_d in rad/s.
    a0 : float, default 0.0
        Initial r_d_dot in rad/s^2.

    Returns
    -------
    numpy.ndarray, shape (N, 3)
        psi_d (rad, wrapped to [-pi, pi)), r_d (rad/s), r_d_dot (rad/s^2); row k is the
        output at step k, before the input ``psi_ref[k]`` acts.
    """
    x = np.ascontiguousarray(np.asarray(psi_ref, dtype=float))
    p0 = float(x[0]) if psi0 is None else float(psi0)
    return _run_heading(x, float(dt), float(omega), float(zeta), p0, float(r0), float(a0))


def filter_surge(u_ref, dt: float, *, order: int = 2, omega: float = 0.5, zeta: float = 1.0,
                 u0: float | None = None, ud0: float = 0.0) -> np.ndarray:
    """Run the surge model over a sampled u_ref: columns u_d, u_d_dot.

    Parameters
    ----------
    u_ref : array_like, shape (N,)
        Reference surge speed in m/s, one sample per step.
    dt : float
        Step in s.
    order : {0, 1, 2}, default 2
        Order of the reference model (0: u_d = u_ref).
    omega : float, default 0.5
        Natural frequency in rad/s.
    zeta : float, default 1.0
        Relative damping (order 2).
    u0 : float, optional
        Initial u_d in m/s (default ``u_ref[0]``).
    ud0 : float, default 0.0
        Initial u_d_dot in m/s^2 (order 2).

    Returns
    -------
    numpy.ndarray, shape (N, 2)
        u_d (m/s) and u_d_dot (m/s^2) at each step.
    """
    x = np.ascontiguousarray(np.asarray(u_ref, dtype=float))
    v0 = float(x[0]) if u0 is None else float(u0)
    return _run_surge(x, float(dt), int(order), float(omega), float(zeta), v0, float(ud0))


__all__ = ["heading_filter_step", "surge_filter_output", "surge_filter_step", "filter_heading",
           "filter_surge"]
