"""The extended 3-DOF model: added mass and quadratic damping (Fossen's 3-DOF form).

:class:`ExtendedParams` has M = [[m11, 0, 0], [0, m22, m26], [0, m26, m66]],
C(nu) nu = [-(m22 v + m26 r) r, m11 u r, (m22 - m11) u v + m26 u r] and
D(nu) nu = [(d11 + d11q |u|) u, (d22 + d22q |v|) v, (d33 + d33q |r|) r]:

    m11 u_dot                    = tau_u + (m22 v + m26 r) r - d11 u - d11q |u| u
    m22 v_dot + m26 r_dot        = -m11 u r - d22 v - d22q |v| v
    m26 v_dot + m66 r_dot        = tau_r - (m22 - m11) u v - m26 u r - d33 r - d33q |r| r

With m11 = m22 = m, m26 = m xg, m66 = Iz and no quadratic damping it is the paper's model
(:mod:`usvlog.model.dynamics`). Pure functions of arrays, SI units.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from .._jit import jitable
from ..choices import EXTENDED_PARAM_NAMES
from ..errors import ConfigError
from .dynamics import VesselParams, require_finite


@dataclass(frozen=True, kw_only=True)
class ExtendedParams:
    """Parameters of the extended 3-DOF model (see the module docstring), SI units.

    Inertia terms are rigid body plus added mass, about the body origin. The paper's
    model is the special case m11 = m22 = m, m26 = m xg, m66 = Iz, d11q = d22q = d33q = 0
    (:meth:`from_paper`).

    Parameters
    ----------
    m11 : float
        Surge inertia m - X_udot in kg, > 0.
    m22 : float
        Sway inertia m - Y_vdot in kg, > 0.
    m26 : float
        Sway-yaw coupling m xg - Y_rdot (= m xg - N_vdot) in kg m.
    m66 : float
        Yaw inertia Iz - N_rdot in kg m^2, > 0; m22 m66 - m26^2 must be > 0.
    d11, d22 : float
        Linear surge and sway damping in kg/s, >= 0.
    d33 : float
        Linear yaw damping in kg m^2/s, >= 0.
    d11q, d22q : float, default 0.0
        Quadratic surge and sway damping in kg/m, >= 0 (force d11q |u| u).
    d33q : float, default 0.0
        Quadratic yaw damping in kg m^2, >= 0 (moment d33q |r| r).
    map_u_mps, map_v_mps, map_r_radps : float, default 1.0, 0.1, 0.2
        Typical |u| (m/s), |v| (m/s) and |r| (rad/s) at which :meth:`paper_terms` folds the
        quadratic damping into the paper's linear terms, >= 0.

    Raises
    ------
    usvlog.errors.ConfigError
        If a value is not a finite number, an inertia is not positive, the sway-yaw
        block is not positive definite or a damping coefficient is negative.
    """

    m11: float
    m22: float
    m26: float
    m66: float
    d11: float
    d22: float
    d33: float
    d11q: float = 0.0
    d22q: float = 0.0
    d33q: float = 0.0
    map_u_mps: float = 1.0
    map_v_mps: float = 0.1
    map_r_radps: float = 0.2

    def __post_init__(self):
        require_finite(self, EXTENDED_PARAM_NAMES + ("map_u_mps", "map_v_mps", "map_r_radps"),
                       "vessel parameter")
        for f in ("m11", "m22", "m66"):
            if getattr(self, f) <= 0:
                raise ConfigError(f"vessel parameter {f} = {getattr(self, f)} must be > 0")
        for f in ("d11", "d22", "d33", "d11q", "d22q", "d33q", "map_u_mps", "map_v_mps", "map_r_radps"):
            if getattr(self, f) < 0:
                raise ConfigError(f"vessel parameter {f} = {getattr(self, f)} must be >= 0")
        if self.m22 * self.m66 - self.m26 ** 2 <= 0:
            raise ConfigError(f"vessel parameters m22 m66 - m26^2 = {self.m22 * self.m66 - self.m26 ** 2:.6g} "
                              "must be > 0 (a positive definite inertia)")

    @classmethod
    def from_paper(cls, p: VesselParams) -> ExtendedParams:
        """The paper's model written in the extended form (exactly the same dynamics).

        Parameters
        ----------
        p : VesselParams

        Returns
        -------
        ExtendedParams
            m11 = m22 = m, m26 = m xg, m66 = Iz, the paper's linear damping, no quadratic.
        """
        return cls(m11=p.m, m22=p.m, m26=p.m * p.xg, m66=p.Iz, d11=p.d11, d22=p.d22, d33=p.d33)

    def paper_terms(self) -> VesselParams:
        """The paper's model nearest to this one, for the paper's controller and estimator.

        m = m11 (surge inertia), Iz = m66, xg = m26 / m11, and each damping linearised
        at its typical speed: d11 + d11q map_u_mps, d22 + d22q map_v_mps,
        d33 + d33q map_r_radps. The sway inertia m22 and the Munk moment (m22 - m11) u v
        have no place in the paper's model and are dropped.

        Returns
        -------
        VesselParams
        """
        return VesselParams(m=self.m11, Iz=self.m66, xg=self.m26 / self.m11,
                            d11=self.d11 + self.d11q * self.map_u_mps,
                            d22=self.d22 + self.d22q * self.map_v_mps,
                            d33=self.d33 + self.d33q * self.map_r_radps)

    def as_array(self) -> np.ndarray:
        """Parameters as a float array of shape (10,), in the order of ``EXTENDED_PARAM_NAMES``.

        Returns
        -------
        numpy.ndarray
            ``[m11, m22, m26, m66, d11, d11q, d22, d22q, d33, d33q]`` (SI units).
        """
        return np.array([getattr(self, f) for f in EXTENDED_PARAM_NAMES], dtype=float)

    def to_dict(self) -> dict[str, float]:
        """Every field (the parameters and the typical speeds) as Python floats, SI units."""
        return {f.name: float(getattr(self, f.name)) for f in fields(self)}



@jitable
def nu_dot_ext_terms(u, v, r, tau_u, tau_r, m11, m22, m26, m66, d11, d11q, d22, d22q, d33, d33q):
    """(u_dot, v_dot, r_dot) of the extended model (module docstring) in closed form.

    Plain arithmetic like :func:`nu_dot_terms` (scalars and arrays, Python and numba);
    parameters in ``EXTENDED_PARAM_NAMES`` order, SI units.
    """
    f1 = tau_u + (m22 * v + m26 * r) * r - d11 * u - d11q * abs(u) * u
    f2 = -m11 * u * r - d22 * v - d22q * abs(v) * v
    f3 = tau_r - (m22 - m11) * u * v - m26 * u * r - d33 * r - d33q * abs(r) * r
    det = m22 * m66 - m26 * m26
    return f1 / m11, (m66 * f2 - m26 * f3) / det, (m22 * f3 - m26 * f2) / det


def nu_dot_ext(nu, tau_u, tau_r, p: ExtendedParams):
    """nu_dot of the extended model, vectorised over leading axes.

    Parameters
    ----------
    nu : array_like, shape (..., 3)
        Body velocity relative to the water [u (m/s), v (m/s), r (rad/s)].
    tau_u : float or array_like
        Surge force in N.
    tau_r : float or array_like
        Yaw moment in N m.
    p : ExtendedParams

    Returns
    -------
    numpy.ndarray, shape (..., 3)
        [u_dot (m/s^2), v_dot (m/s^2), r_dot (rad/s^2)].
    """
    nu = np.asarray(nu, float)
    ud, vd, rd = nu_dot_ext_terms(nu[..., 0], nu[..., 1], nu[..., 2], tau_u, tau_r, *p.as_array())
    return np.stack(np.broadcast_arrays(ud, vd, rd), -1)
