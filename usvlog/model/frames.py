"""Frames and angles: geodetic <-> local NED, smallest signed angle, R(psi).

World frame is local NED about a datum (WGS-84, exact ECEF-based tangent plane);
body frame is FRD. ``psi`` is heading clockwise from north in radians.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .._jit import jitable
from ..errors import ConfigError

# WGS-84
_A = 6378137.0
_F = 1.0 / 298.257223563
_E2 = _F * (2.0 - _F)


def ssa(angle):
    """Smallest signed angle: wrap radians to [-pi, pi).

    Parameters
    ----------
    angle : float or array_like
        Angle(s) in rad, any range.

    Returns
    -------
    numpy.float64 or numpy.ndarray
        The same angle(s) in rad, in [-pi, pi); a scalar for a Python float, otherwise
        a float array of the input's shape.
    """
    if type(angle) is float:  # one value (sentence parsers): the same arithmetic without an array
        return np.float64((angle + np.pi) % (2.0 * np.pi) - np.pi)
    return (np.asarray(angle, dtype=float) + np.pi) % (2.0 * np.pi) - np.pi


@jitable
def wrap_angle(a):
    """:func:`ssa` of one float, callable from Python and from compiled kernels.

    Parameters
    ----------
    a : float
        Angle in rad, any range.

    Returns
    -------
    float
        The same angle in rad, in [-pi, pi) (the same arithmetic as :func:`ssa`).
    """
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def rot(psi):
    """R(psi) of the paper's eq. (2): body -> world (NED), shape (..., 3, 3).

    Parameters
    ----------
    psi : float or array_like
        Heading in rad, clockwise from north.

    Returns
    -------
    numpy.ndarray
        Rotation matrices of shape ``psi.shape + (3, 3)``; ``rot(psi) @ nu`` turns body
        velocities [u_mps, v_mps, r_radps] into world rates [n_dot, e_dot, psi_dot].
    """
    psi = np.asarray(psi, dtype=float)
    c, s = np.cos(psi), np.sin(psi)
    z, o = np.zeros_like(psi), np.ones_like(psi)
    return np.stack(
        [np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2
    )


def unwrap(psi):
    """Continuous heading for display and differentiation (no jumps of 2 pi).

    Parameters
    ----------
    psi : array_like
        Heading samples in rad, in time order.

    Returns
    -------
    numpy.ndarray
        Float array of the same shape in rad, with 2 pi added or removed so that
        consecutive samples differ by at most pi.
    """
    return np.unwrap(np.asarray(psi, dtype=float))


@dataclass(frozen=True, kw_only=True)
class Datum:
    """Origin of the local NED frame.

    Parameters
    ----------
    lat_deg : float
        WGS-84 latitude in degrees, in [-90, 90].
    lon_deg : float
        WGS-84 longitude in degrees, in [-180, 180].
    alt_m : float, default 0.0
        Height above the WGS-84 ellipsoid in m.

    Raises
    ------
    usvlog.errors.ConfigError
        If a value is not finite or out of range.
    """

    lat_deg: float
    lon_deg: float
    alt_m: float = 0.0

    def __post_init__(self):
        if not (np.isfinite(self.lat_deg) and -90.0 <= self.lat_deg <= 90.0):
            raise ConfigError(f"datum latitude {self.lat_deg} out of range [-90, 90]")
        if not (np.isfinite(self.lon_deg) and -180.0 <= self.lon_deg <= 180.0):
            raise ConfigError(f"datum longitude {self.lon_deg} out of range [-180, 180]")
        if not np.isfinite(self.alt_m):
            raise ConfigError(f"datum altitude {self.alt_m} is not finite")

    def to_dict(self) -> dict[str, str]:
        """Fields as exact strings (``repr`` of the floats), for MCAP metadata.

        Returns
        -------
        dict of str to str
            Keys ``lat_deg``, ``lon_deg`` (degrees) and ``alt_m`` (m); read back by
            :meth:`from_dict` without loss.
        """
        return {"lat_deg": repr(float(self.lat_deg)), "lon_deg": repr(float(self.lon_deg)),
                "alt_m": repr(float(self.alt_m))}

    @classmethod
    def from_dict(cls, d: dict[str, str]) -> Datum:
        """Datum from the strings written by :meth:`to_dict`.

        Parameters
        ----------
        d : mapping
            ``lat_deg`` and ``lon_deg`` (degrees), optional ``alt_m`` (m, default 0);
            values are strings or numbers.

        Returns
        -------
        Datum

        Raises
        ------
        KeyError
            If ``lat_deg`` or ``lon_deg`` is missing.
        usvlog.errors.ConfigError
            If a value is out of range.
        """
        return cls(lat_deg=float(d["lat_deg"]), lon_deg=float(d["lon_deg"]),
                   alt_m=float(d.get("alt_m", 0.0)))


def _ecef(lat_deg, lon_deg, alt_m):
    lat, lon = np.radians(lat_deg), np.radians(lon_deg)
    sl, cl = np.sin(lat), np.cos(lat)
    n = _A / np.sqrt(1.0 - _E2 * sl * sl)
    x = (n + alt_m) * cl * np.cos(lon)
    y = (n + alt_m) * cl * np.sin(lon)
    z = (n * (1.0 - _E2) + alt_m) * sl
    return x, y, z


def _ned_basis(datum: Datum):
    lat, lon = np.radians(datum.lat_deg), np.radians(datum.lon_deg)
    sl, cl, so, co = np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon)
    # rows: north, east, down expressed in ECEF
    return np.array([[-sl * co, -sl * so, cl], [-so, co, 0.0], [-cl * co, -cl * so, -sl]])


def geodetic_to_ned(lat_deg, lon_deg, alt_m=0.0, *, datum: Datum):
    """Latitude/longitude/altitude -> (north, east, down) metres about ``datum``.

    Exact (ECEF-based) tangent-plane conversion on the WGS-84 ellipsoid.

    Parameters
    ----------
    lat_deg, lon_deg : float or array_like
        WGS-84 latitude and longitude in degrees, of one shape.
    alt_m : float or array_like, default 0.0
        Height above the ellipsoid in m, broadcast to the shape of ``lat_deg``.
    datum : Datum
        Origin of the local NED frame (keyword only).

    Returns
    -------
    n_m, e_m, d_m : numpy.ndarray
        North, east and down offsets from the datum in m, each of the input's shape.
    """
    lat_deg, lon_deg = np.asarray(lat_deg, float), np.asarray(lon_deg, float)
    alt_m = np.broadcast_to(np.asarray(alt_m, float), lat_deg.shape)
    x, y, z = _ecef(lat_deg, lon_deg, alt_m)
    x0, y0, z0 = _ecef(datum.lat_deg, datum.lon_deg, datum.alt_m)
    d = np.stack([x - x0, y - y0, z - z0], -1)
    ned = d @ _ned_basis(datum).T
    return ned[..., 0], ned[..., 1], ned[..., 2]


def ned_to_geodetic(n_m, e_m, d_m=0.0, *, datum: Datum):
    """(north, east, down) metres about ``datum`` -> latitude, longitude, altitude.

    Inverse of :func:`geodetic_to_ned` (iterative, converged to < 1e-12 rad).

    Parameters
    ----------
    n_m, e_m : float or array_like
        North and east offsets from the datum in m, of one shape.
    d_m : float or array_like, default 0.0
        Down offset in m, broadcast to the shape of ``n_m``.
    datum : Datum
        Origin of the local NED frame (keyword only).

    Returns
    -------
    lat_deg, lon_deg, alt_m : numpy.ndarray
        WGS-84 latitude and longitude in degrees and height above the ellipsoid in m.
    """
    n_m, e_m = np.asarray(n_m, float), np.asarray(e_m, float)
    d_m = np.broadcast_to(np.asarray(d_m, float), n_m.shape)
    ned = np.stack([n_m, e_m, d_m], -1)
    x0, y0, z0 = _ecef(datum.lat_deg, datum.lon_deg, datum.alt_m)
    xyz = ned @ _ned_basis(datum) + np.array([x0, y0, z0])
    x, y, z = xyz[..., 0], xyz[..., 1], xyz[..., 2]
    # Bowring/iterative inverse, converges to < 1e-12 rad in a few steps
    lon = np.arctan2(y, x)
    p = np.hypot(x, y)
    lat = np.arctan2(z, p * (1.0 - _E2))
    for _ in range(6):
        sl = np.sin(lat)
        n = _A / np.sqrt(1.0 - _E2 * sl * sl)
        alt = p / np.cos(lat) - n
        lat = np.arctan2(z, p * (1.0 - _E2 * n / (n + alt)))
    sl = np.sin(lat)
    n = _A / np.sqrt(1.0 - _E2 * sl * sl)
    alt = p / np.cos(lat) - n
    return np.degrees(lat), np.degrees(lon), alt
