"""The paper's 3-DOF model, eqs. (1)-(6): its parameters and dynamics with analytic Jacobians.

Pure functions of arrays. ``nu`` is the velocity the model acts on (relative to the
water when there is a current); ``tau = [tau_u, tau_v = 0, tau_r]``.

Expanding M nu_dot + C(nu) nu + D nu = tau with (4)-(6):

    m u_dot                      = tau_u + m (xg r + v) r - d11 u
    m v_dot + m xg r_dot         = -m u r - d22 v
    m xg v_dot + Iz r_dot        = tau_r - m xg u r - d33 r

The extended model is in :mod:`usvlog.model.extended`; the thrusters in
:mod:`usvlog.model.thrusters`; a whole vessel and its TOML in :mod:`usvlog.model.vessel`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .._jit import jitable
from ..choices import PARAM_NAMES
from ..errors import ConfigError, InputError


def require_finite(obj, names, kind: str) -> None:
    """Every field in ``names`` of ``obj`` is a finite number (not a bool), else ConfigError.

    Parameters
    ----------
    obj : object
        Object (usually a parameter dataclass) whose attributes are checked.
    names : iterable of str
        Attribute names to check.
    kind : str
        What the fields are, for the message (e.g. ``"vessel parameter"``).

    Raises
    ------
    usvlog.errors.ConfigError
        On the first field that is a bool, not an int/float, NaN or infinite.
    """
    for f in names:
        v = getattr(obj, f)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ConfigError(f"{kind} {f} = {v!r} is not a finite number")


@dataclass(frozen=True, kw_only=True)
class VesselParams:
    """Model parameters of eq. (3), SI units, paper symbols.

    Defaults are the paper's Section IV vessel.

    Parameters
    ----------
    m : float, default 33.0
        Mass in kg, > 0.
    Iz : float, default 10.0
        Yaw moment of inertia about the body origin in kg m^2, > 0.
    d11 : float, default 5.0
        Linear surge damping in N s/m (kg/s), >= 0.
    d22 : float, default 5.0
        Linear sway damping in N s/m (kg/s), >= 0.
    d33 : float, default 5.0
        Linear yaw damping in N m s/rad (kg m^2/s), >= 0.
    xg : float, default 0.1
        Longitudinal position of the centre of gravity ahead of the body origin in m.

    Raises
    ------
    usvlog.errors.ConfigError
        If a value is not a finite number, ``m`` or ``Iz`` is not positive or a damping
        coefficient is negative.
    """

    m: float = 33.0
    Iz: float = 10.0
    d11: float = 5.0
    d22: float = 5.0
    d33: float = 5.0
    xg: float = 0.1

    def __post_init__(self):
        require_finite(self, PARAM_NAMES, "vessel parameter")
        if self.m <= 0:
            raise ConfigError(f"vessel parameter m = {self.m} must be > 0")
        if self.Iz <= 0:
            raise ConfigError(f"vessel parameter Iz = {self.Iz} must be > 0")
        for f in ("d11", "d22", "d33"):
            if getattr(self, f) < 0:
                raise ConfigError(f"vessel parameter {f} = {getattr(self, f)} must be >= 0")

    @property
    def Iz_eff(self) -> float:
        """Iz - m xg^2: Theorem 3.1 condition 1 requires it > 0."""
        return self.Iz - self.m * self.xg**2

    def as_array(self) -> np.ndarray:
        """Parameters as a float array of shape (6,), in the order of ``PARAM_NAMES``.

        Returns
        -------
        numpy.ndarray
            ``[m (kg), Iz (kg m^2), d11 (kg/s), d22 (kg/s), d33 (kg m^2/s), xg (m)]``.
        """
        return np.array([getattr(self, f) for f in PARAM_NAMES], dtype=float)

    def to_dict(self) -> dict[str, float]:
        """Parameters by paper symbol (``m, Iz, d11, d22, d33, xg``) as Python floats, SI units."""
        return {f: float(getattr(self, f)) for f in PARAM_NAMES}



# ---------------------------------------------------------------------------
# Dynamics, eq. (3); vectorised over leading axes
# ---------------------------------------------------------------------------

def mass_matrix(p: VesselParams) -> np.ndarray:
    """M of eq. (4).

    Parameters
    ----------
    p : VesselParams

    Returns
    -------
    numpy.ndarray
        Rigid-body mass matrix, shape (3, 3), in kg, kg m and kg m^2.
    """
    return np.array([[p.m, 0.0, 0.0], [0.0, p.m, p.m * p.xg], [0.0, p.m * p.xg, p.Iz]])


def coriolis_matrix(nu, p: VesselParams) -> np.ndarray:
    """C(nu) of eq. (5), shape (..., 3, 3).

    Parameters
    ----------
    nu : array_like, shape (..., 3)
        Body velocity [u (m/s), v (m/s), r (rad/s)].
    p : VesselParams

    Returns
    -------
    numpy.ndarray
        Coriolis-centripetal matrix of shape ``nu.shape[:-1] + (3, 3)``.
    """
    nu = np.asarray(nu, float)
    u, v, r = nu[..., 0], nu[..., 1], nu[..., 2]
    z = np.zeros_like(u)
    a = p.m * (p.xg * r + v)
    b = p.m * u
    return np.stack([np.stack([z, z, -a], -1), np.stack([z, z, b], -1), np.stack([a, -b, z], -1)], -2)


def damping_matrix(p: VesselParams) -> np.ndarray:
    """D of eq. (6).

    Parameters
    ----------
    p : VesselParams

    Returns
    -------
    numpy.ndarray
        Linear damping matrix diag(d11, d22, d33), shape (3, 3).
    """
    return np.diag([p.d11, p.d22, p.d33])


@jitable
def nu_dot_terms(u, v, r, tau_u, tau_r, m, Iz, d11, d22, d33, xg):
    """(u_dot, v_dot, r_dot) of eq. (3) in closed form.

    Plain arithmetic, so it serves scalars (the simulators' inner loops) and arrays alike,
    in Python and inside numba-compiled loops (:func:`usvlog._jit.jitable`).
    """
    f1 = tau_u + m * (xg * r + v) * r - d11 * u
    f2 = -m * u * r - d22 * v
    f3 = tau_r - m * xg * u * r - d33 * r
    det = m * Iz - (m * xg) * (m * xg)
    return f1 / m, (Iz * f2 - m * xg * f3) / det, (m * f3 - m * xg * f2) / det



def nu_dot(nu, tau_u, tau_r, p: VesselParams):
    """nu_dot = M^-1 (tau - C(nu) nu - D nu), vectorised over leading axes.

    Parameters
    ----------
    nu : array_like, shape (..., 3)
        Body velocity relative to the water [u (m/s), v (m/s), r (rad/s)].
    tau_u : float or array_like
        Surge force in N, broadcast against ``nu[..., 0]``.
    tau_r : float or array_like
        Yaw moment in N m.
    p : VesselParams

    Returns
    -------
    numpy.ndarray, shape (..., 3)
        [u_dot (m/s^2), v_dot (m/s^2), r_dot (rad/s^2)].
    """
    nu = np.asarray(nu, float)
    ud, vd, rd = nu_dot_terms(nu[..., 0], nu[..., 1], nu[..., 2], tau_u, tau_r,
                              p.m, p.Iz, p.d11, p.d22, p.d33, p.xg)
    return np.stack(np.broadcast_arrays(ud, vd, rd), -1)


def nu_dot_jacobian_terms(u, v, r, m, Iz, d11, d22, d33, xg):
    """The nine entries of d(nu_dot)/d(nu), row-major, in closed form.

    Plain arithmetic like :func:`nu_dot_terms`, so compiled inner loops (numba) and
    arrays share it; :func:`nu_dot_jacobian` stacks it.
    """
    det = m * Iz - (m * xg) * (m * xg)
    # partials of f1, f2, f3 of nu_dot_terms w.r.t. (u, v, r)
    a1, a2, a3 = -d11 + 0.0 * u, m * r, m * v + 2.0 * m * xg * r
    b1, b2, b3 = -m * r, -d22 + 0.0 * u, -m * u
    c1, c2, c3 = -m * xg * r, 0.0 * u, -m * xg * u - d33
    return (a1 / m, a2 / m, a3 / m,
            (Iz * b1 - m * xg * c1) / det, (Iz * b2 - m * xg * c2) / det, (Iz * b3 - m * xg * c3) / det,
            (m * c1 - m * xg * b1) / det, (m * c2 - m * xg * b2) / det, (m * c3 - m * xg * b3) / det)


def nu_dot_jacobian(nu, p: VesselParams):
    """d(nu_dot)/d(nu), shape (..., 3, 3); tau enters linearly (see :func:`nu_dot_tau_matrix`).

    Parameters
    ----------
    nu : array_like, shape (..., 3)
        Body velocity [u (m/s), v (m/s), r (rad/s)].
    p : VesselParams

    Returns
    -------
    numpy.ndarray
        Jacobian of shape ``nu.shape[:-1] + (3, 3)``, rows u_dot, v_dot, r_dot.
    """
    nu = np.asarray(nu, float)
    t = nu_dot_jacobian_terms(nu[..., 0], nu[..., 1], nu[..., 2],
                              p.m, p.Iz, p.d11, p.d22, p.d33, p.xg)
    t = np.broadcast_arrays(*t)
    return np.stack([np.stack(t[0:3], -1), np.stack(t[3:6], -1), np.stack(t[6:9], -1)], -2)


def nu_dot_tau_matrix(p: VesselParams) -> np.ndarray:
    """B such that nu_dot = ... + B @ [tau_u, tau_r] (the input matrix).

    Parameters
    ----------
    p : VesselParams

    Returns
    -------
    numpy.ndarray
        Shape (3, 2): columns for tau_u (N) and tau_r (N m).
    """
    det = p.m * p.Iz - (p.m * p.xg) ** 2
    return np.array([[1.0 / p.m, 0.0], [0.0, -p.m * p.xg / det], [0.0, p.m / det]])


def eta_dot(eta, nu, current_ne=(0.0, 0.0)):
    """Eq. (1) plus a current in NED: eta_dot = R(psi) nu + [c_n, c_e, 0].

    Parameters
    ----------
    eta : array_like, shape (..., 3)
        Pose [n (m), e (m), psi (rad)].
    nu : array_like, shape (..., 3)
        Body velocity relative to the water [u (m/s), v (m/s), r (rad/s)].
    current_ne : (float, float), default (0.0, 0.0)
        Water current, north and east, in m/s.

    Returns
    -------
    numpy.ndarray, shape (..., 3)
        [n_dot (m/s), e_dot (m/s), psi_dot (rad/s)].
    """
    eta, nu = np.asarray(eta, float), np.asarray(nu, float)
    psi = eta[..., 2]
    c, s = np.cos(psi), np.sin(psi)
    u, v, r = nu[..., 0], nu[..., 1], nu[..., 2]
    return np.stack([c * u - s * v + current_ne[0], s * u + c * v + current_ne[1], r], -1)


def plant_rhs(x, tau_u, tau_r, p: VesselParams, current_ne=(0.0, 0.0)):
    """State x = [n, e, psi, u, v, r] -> x_dot (eqs. (1) and (3)).

    Parameters
    ----------
    x : array_like, shape (..., 6)
        [n (m), e (m), psi (rad), u (m/s), v (m/s), r (rad/s)]; u, v relative to the water.
    tau_u : float or array_like
        Surge force in N.
    tau_r : float or array_like
        Yaw moment in N m.
    p : VesselParams
    current_ne : (float, float), default (0.0, 0.0)
        Water current, north and east, in m/s.

    Returns
    -------
    numpy.ndarray, shape (..., 6)
        Time derivative of ``x`` (SI units per second).
    """
    x = np.asarray(x, float)
    return np.concatenate([eta_dot(x[..., :3], x[..., 3:], current_ne),
                           nu_dot(x[..., 3:], tau_u, tau_r, p)], -1)


def plant_jacobian(x, p: VesselParams):
    """d(plant_rhs)/dx, shape (..., 6, 6) (independent of tau and of a constant current).

    Parameters
    ----------
    x : array_like, shape (..., 6)
        State [n (m), e (m), psi (rad), u (m/s), v (m/s), r (rad/s)].
    p : VesselParams

    Returns
    -------
    numpy.ndarray
        Jacobian of shape ``x.shape[:-1] + (6, 6)``.
    """
    x = np.asarray(x, float)
    psi, u, v = x[..., 2], x[..., 3], x[..., 4]
    c, s = np.cos(psi), np.sin(psi)
    J = np.zeros(x.shape[:-1] + (6, 6))
    J[..., 0, 2] = -s * u - c * v
    J[..., 1, 2] = c * u - s * v
    J[..., 0, 3], J[..., 0, 4] = c, -s
    J[..., 1, 3], J[..., 1, 4] = s, c
    J[..., 2, 5] = 1.0
    J[..., 3:, 3:] = nu_dot_jacobian(x[..., 3:], p)
    return J


def model_residual(nu, nu_dot_meas, tau_u, tau_r, p: VesselParams):
    """M nu_dot + C(nu) nu + D nu - tau for given accelerations (shape (..., 3)).

    Parameters
    ----------
    nu : array_like, shape (..., 3)
        Body velocity [u (m/s), v (m/s), r (rad/s)].
    nu_dot_meas : array_like, shape (..., 3)
        Measured or smoothed accelerations [m/s^2, m/s^2, rad/s^2].
    tau_u : float or array_like
        Surge force in N.
    tau_r : float or array_like
        Yaw moment in N m.
    p : VesselParams

    Returns
    -------
    numpy.ndarray, shape (..., 3)
        Equation error [N, N, N m]; zero where the data follow the model exactly.
    """
    nu = np.asarray(nu, float)
    M, D = mass_matrix(p), damping_matrix(p)
    Cnu = np.einsum("...ij,...j->...i", coriolis_matrix(nu, p), nu)
    tau = np.stack([np.asarray(tau_u, float) + 0 * nu[..., 0], 0 * nu[..., 0],
                    np.asarray(tau_r, float) + 0 * nu[..., 0]], -1)
    return np.asarray(nu_dot_meas) @ M.T + Cnu + nu @ D.T - tau


def rk4_step(x, tau_u, tau_r, p: VesselParams, dt: float, current_ne=(0.0, 0.0)):
    """One RK4 step of the plant with thrust held over the step.

    Parameters
    ----------
    x : array_like, shape (..., 6)
        State [n (m), e (m), psi (rad), u (m/s), v (m/s), r (rad/s)].
    tau_u : float or array_like
        Surge force in N.
    tau_r : float or array_like
        Yaw moment in N m.
    p : VesselParams
    dt : float
        Step in s.
    current_ne : (float, float), default (0.0, 0.0)
        Water current, north and east, in m/s.

    Returns
    -------
    numpy.ndarray, shape (..., 6)
        State after ``dt``.
    """
    k1 = plant_rhs(x, tau_u, tau_r, p, current_ne)
    k2 = plant_rhs(x + 0.5 * dt * k1, tau_u, tau_r, p, current_ne)
    k3 = plant_rhs(x + 0.5 * dt * k2, tau_u, tau_r, p, current_ne)
    k4 = plant_rhs(x + dt * k3, tau_u, tau_r, p, current_ne)
    return x + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)


def euler_step(x, tau_u, tau_r, p: VesselParams, dt: float, current_ne=(0.0, 0.0)):
    """First-order step, as the paper's Section IV simulation.

    Parameters are those of :func:`rk4_step`; returns the state after ``dt`` s,
    x + dt plant_rhs(x).
    """
    return x + dt * plant_rhs(x, tau_u, tau_r, p, current_ne)


def check_finite(name: str, arr, source: str = "") -> None:
    """Raise InputError if ``arr`` holds a NaN or an infinity.

    Parameters
    ----------
    name : str
        Name of the array (a column or channel), for the message.
    arr : array_like
        Values to check; rows are along the first axis.
    source : str, default ""
        File or channel the values come from, prefixed to the message.

    Raises
    ------
    usvlog.errors.InputError
        Naming the first row (first-axis index) with a non-finite value.
    """
    a = np.asarray(arr, float)
    if not np.all(np.isfinite(a)):
        i = int(np.flatnonzero(~np.isfinite(a.reshape(len(a), -1)).any(-1))[0]) if a.ndim else 0
        raise InputError(f"{source} {name}: non-finite value at row {i}".strip())
