"""Guidance (Section II-A): closest point by gradient descent (7), carrot point, psi_ref (8).

With e(theta) = p - p_d(theta) and J = 1/2 e^T e, grad J = -e . dp_d/dtheta, so (7) reads

    theta(k+1) = theta(k) + gamma e(theta(k)) . dp_d/dtheta(theta(k)),

run for a fixed number of iterations at every controller tick, warm-started from the
previous tick's theta (the very first theta comes from a dense search along the path).
The carrot is p_d(theta + delta_theta); (8) in NED is psi_ref = atan2(e_c - e, n_c - n).
Convergence needs 0 < gamma J'' < 2 near the minimum (J'' = |p_d'|^2 - e . p_d''), e.g.
gamma < 2 R / rho for a circle of radius R seen from distance rho of its centre.
"""

from __future__ import annotations

import math

import numpy as np

from .._jit import njit
from .paths import Path, path_eval


@njit
def closest_theta(kind, prm, pn, pe, theta, gamma, iterations):
    """Gradient descent (7) from ``theta``: returns the new theta."""
    for _ in range(iterations):
        n, e, dn, de = path_eval(kind, prm, theta)
        theta = theta + gamma * ((pn - n) * dn + (pe - e) * de)
    return theta


@njit
def guidance_step(kind, prm, pn, pe, theta, gamma, iterations, delta_theta):
    """(theta, closest n, e, carrot n, e, psi_ref, signed cross-track) for position (pn, pe).

    Cross-track is positive when the vessel is to starboard of the path direction.
    """
    th = closest_theta(kind, prm, pn, pe, theta, gamma, iterations)
    n, e, dn, de = path_eval(kind, prm, th)
    cn, ce, _, _ = path_eval(kind, prm, th + delta_theta)
    psi_ref = math.atan2(ce - pe, cn - pn)
    norm = math.sqrt(dn * dn + de * de)
    xt = ((pe - e) * dn - (pn - n) * de) / norm if norm > 0 else math.sqrt((pn - n) ** 2 + (pe - e) ** 2)
    return th, n, e, cn, ce, psi_ref, xt


def initial_theta(path: Path, n: float, e: float, samples: int = 4000) -> float:
    """Global start for the descent: the nearest of ``samples`` points along the drawn range.

    Parameters
    ----------
    path : Path
    n, e : float
        Vessel position north, east in m.
    samples : int, default 4000
        Number of evenly spaced path parameters tried.

    Returns
    -------
    float
        Path parameter theta (m along the path) of the nearest sample.
    """
    th = np.linspace(path.theta_min, path.theta_max, samples)
    pts = path.point(th)
    return float(th[int(np.argmin((pts[:, 0] - n) ** 2 + (pts[:, 1] - e) ** 2))])


def closest_point(path: Path, n: float, e: float, theta0: float | None = None, *, gamma: float = 0.5,
                  iterations: int = 50) -> float:
    """Theta of the (locally) closest point to (n, e), by (7) from ``theta0`` (dense search if None).

    Parameters
    ----------
    path : Path
    n, e : float
        Position north, east in m.
    theta0 : float, optional
        Start of the descent, m along the path (default :func:`initial_theta`).
    gamma : float, default 0.5
        Descent step (dimensionless).
    iterations : int, default 50
        Descent iterations.

    Returns
    -------
    float
        Path parameter theta in m.
    """
    th0 = initial_theta(path, n, e) if theta0 is None else float(theta0)
    return float(closest_theta(path.kind, path.prm, float(n), float(e), th0, float(gamma), int(iterations)))


def reference_heading(path: Path, n: float, e: float, theta: float, delta_theta: float) -> float:
    """psi_ref of (8) in NED for the vessel at (n, e) and closest-point parameter theta.

    Parameters
    ----------
    path : Path
    n, e : float
        Vessel position north, east in m.
    theta : float
        Closest-point parameter, m along the path.
    delta_theta : float
        Carrot distance ahead, m.

    Returns
    -------
    float
        Heading towards the carrot point, rad clockwise from north, in [-pi, pi].
    """
    cn, ce = path.point(theta + delta_theta)
    return math.atan2(ce - e, cn - n)


__all__ = ["closest_theta", "guidance_step", "initial_theta", "closest_point", "reference_heading"]
