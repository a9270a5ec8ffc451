"""Desired paths p_d(theta) = [n_d(theta), e_d(theta)] in local NED, with analytic dp_d/dtheta.

The paper (Section II-A) parameterises the path by a scalar theta. Here theta is in
metres: arc length for circles, lines and waypoint splines (chord-length knots), and
distance along the axis for a sinusoid, so the carrot ``delta_theta`` is a distance.

Kinds (TOML ``[path]``, see docs/replay.md):

* ``circle``: ``center_ne``, ``radius_m``, ``direction`` ("cw" or "ccw" as seen on a
  north-up map, i.e. cw = heading increases along the path), ``start_deg`` (bearing from
  the centre of the point theta = 0, default 0 = north of the centre).
* ``sinusoid``: ``start_ne``, ``direction_deg`` (course of the axis, clockwise from north),
  ``amplitude_m``, ``period_m``, ``length_m`` (extent drawn and searched; the path
  continues beyond it). p_d = start + theta a + A sin(2 pi theta / period) s, with a the
  axis and s its starboard normal.
* ``line``: ``start_ne``, ``direction_deg``, ``length_m``.
* ``waypoints``: ``frame`` "ned" (``points`` [[n, e], ...]) or "latlon" ([[lat, lon], ...],
  converted about the log's datum), joined by a C1 cubic Hermite spline (Catmull-Rom
  tangents on chord-length knots); beyond the ends it continues straight.

Every kind compiles to ``(kind, prm)``: an integer and a float array evaluated by
:func:`path_eval` (numba), which the guidance kernel calls.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass

import numpy as np

from .._jit import njit
from ..errors import ConfigError
from ..model.frames import geodetic_to_ned

CIRCLE, SINUSOID, LINE, SPLINE = 0, 1, 2, 3
KINDS = {"circle": CIRCLE, "sinusoid": SINUSOID, "line": LINE, "waypoints": SPLINE}


# spline prm layout: [nseg, knots (nseg + 1), coefficients nseg x SPLINE_NCOEF]; per segment the
# cubic in s = theta - knot: n = an0 + an1 s + an2 s^2 + an3 s^3 (SPLINE_N + 0..3), e likewise (SPLINE_E)
SPLINE_KNOTS = 1
SPLINE_N, SPLINE_E, SPLINE_NCOEF = 0, 4, 8


@njit
def path_eval(kind, prm, theta):
    """(n_d, e_d, dn_d/dtheta, de_d/dtheta) at ``theta`` (m) of the path ``(kind, prm)``.

    Parameters
    ----------
    kind : int
        CIRCLE, SINUSOID, LINE or SPLINE.
    prm : ndarray
        The kind's parameters (see :func:`path_from_spec`), metres and radians.
    theta : float
        Path parameter, m.

    Returns
    -------
    tuple of 4 floats
        North and east of p_d(theta) (m) and their derivatives with respect to theta.
    """
    if kind == CIRCLE:
        cn, ce, R, s, phi0 = prm  # centre (m), radius (m), +1 cw / -1 ccw, bearing of theta = 0 (rad)
        a = phi0 + s * theta / R
        c = math.cos(a)
        sn = math.sin(a)
        return cn + R * c, ce + R * sn, -s * sn, s * c
    if kind == SINUSOID:
        n0, e0, an, ae, amp, period = prm  # start (m), unit axis, amplitude (m), period (m)
        k = 2.0 * math.pi / period
        w = amp * math.sin(k * theta)
        dw = amp * k * math.cos(k * theta)
        # starboard normal of the axis (an, ae) is (-ae, an)
        return (n0 + theta * an - w * ae, e0 + theta * ae + w * an,
                an - dw * ae, ae + dw * an)
    if kind == LINE:
        n0, e0, an, ae = prm  # start (m), unit axis
        return n0 + theta * an, e0 + theta * ae, an, ae
    # SPLINE
    nseg = int(prm[0])
    k0 = SPLINE_KNOTS
    c0 = k0 + nseg + 1
    t0 = prm[k0]
    tN = prm[k0 + nseg]
    cn0 = c0 + SPLINE_N
    ce0 = c0 + SPLINE_E
    if theta <= t0:  # straight on before the first waypoint
        g = theta - t0
        return prm[cn0] + g * prm[cn0 + 1], prm[ce0] + g * prm[ce0 + 1], prm[cn0 + 1], prm[ce0 + 1]
    h = 0.0
    if theta >= tN:  # straight on beyond the last waypoint
        j = nseg - 1
        h = theta - tN
        s = tN - prm[k0 + j]
    else:
        lo = 0
        hi = nseg
        while hi - lo > 1:  # knots[lo] <= theta < knots[hi]
            mid = (lo + hi) // 2
            if prm[k0 + mid] <= theta:
                lo = mid
            else:
                hi = mid
        j = lo
        s = theta - prm[k0 + j]
    bn = c0 + SPLINE_NCOEF * j + SPLINE_N
    be = c0 + SPLINE_NCOEF * j + SPLINE_E
    n = prm[bn] + s * (prm[bn + 1] + s * (prm[bn + 2] + s * prm[bn + 3]))
    e = prm[be] + s * (prm[be + 1] + s * (prm[be + 2] + s * prm[be + 3]))
    dn = prm[bn + 1] + s * (2.0 * prm[bn + 2] + 3.0 * s * prm[bn + 3])
    de = prm[be + 1] + s * (2.0 * prm[be + 2] + 3.0 * s * prm[be + 3])
    return n + h * dn, e + h * de, dn, de


@njit
def path_eval_many(kind, prm, theta):
    """:func:`path_eval` at many values of theta (compiled loop).

    Parameters
    ----------
    kind : int
        CIRCLE, SINUSOID, LINE or SPLINE.
    prm : ndarray
        The kind's parameters (see :func:`path_from_spec`), metres and radians.
    theta : ndarray, shape (N,)
        Path parameter values, m (a contiguous float array).

    Returns
    -------
    ndarray, shape (N, 4)
        Per theta: n_d, e_d (m) and dn_d/dtheta, de_d/dtheta (dimensionless).
    """
    out = np.empty((theta.shape[0], 4))
    for i in range(theta.shape[0]):
        a, b, c, d = path_eval(kind, prm, theta[i])
        out[i, 0] = a
        out[i, 1] = b
        out[i, 2] = c
        out[i, 3] = d
    return out


@dataclass(frozen=True)
class Path:
    """A compiled path: ``spec`` (as written), ``kind``/``prm`` for the kernels, theta range.

    Build one with :func:`path_from_spec`. theta is in m along the path (see the module
    docstring); positions are local NED in m.

    Attributes
    ----------
    spec : dict
        The definition as written (the ``[path]`` table).
    kind : int
        ``CIRCLE``, ``SINUSOID``, ``LINE`` or ``SPLINE``.
    prm : numpy.ndarray
        Packed parameters for :func:`path_eval`.
    theta_min, theta_max : float
        The drawn (and searched) range of theta, m.
    periodic : bool
        True for a circle (theta wraps every 2 pi R).
    """

    spec: dict
    kind: int
    prm: np.ndarray
    theta_min: float
    theta_max: float
    periodic: bool = False

    def _eval(self, theta) -> np.ndarray:
        th = np.atleast_1d(np.asarray(theta, dtype=float))
        return path_eval_many(self.kind, self.prm, np.ascontiguousarray(th))

    def point(self, theta) -> np.ndarray:
        """p_d(theta): shape (..., 2) as [n, e]."""
        th = np.asarray(theta, dtype=float)
        return self._eval(th)[:, :2].reshape(th.shape + (2,))

    def derivative(self, theta) -> np.ndarray:
        """dp_d/dtheta: shape (..., 2)."""
        th = np.asarray(theta, dtype=float)
        return self._eval(th)[:, 2:].reshape(th.shape + (2,))

    def polyline(self, n: int = 1000) -> np.ndarray:
        """``n`` points [n, e] sampling the path over its drawn range."""
        if n < 2:
            raise ConfigError("polyline needs at least 2 points")
        return self.point(np.linspace(self.theta_min, self.theta_max, n))

    def spec_json(self) -> str:
        """The spec as JSON with sorted keys (read back by :func:`path_from_json`)."""
        return json.dumps(self.spec, sort_keys=True)

    def metadata(self, n: int = 1000) -> dict[str, str]:
        """The ``usvlog.path`` metadata record."""
        poly = np.round(self.polyline(n), 4).tolist()
        return {"spec": self.spec_json(), "polyline_ne": json.dumps(poly)}


def _num(spec, key, source, default=None, positive=False):
    if key not in spec:
        if default is None:
            raise ConfigError(f"{source}: [path] {spec.get('type')} needs {key}")
        return float(default)
    v = spec[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise ConfigError(f"{source}: [path] {key} = {v!r} is not a finite number")
    if positive and not v > 0:
        raise ConfigError(f"{source}: [path] {key} = {v!r} must be > 0")
    return float(v)


def _pair(spec, key, source, default=None):
    v = spec.get(key, default)
    if v is None:
        raise ConfigError(f"{source}: [path] {spec.get('type')} needs {key}")
    try:
        a = np.asarray(v, dtype=float)
    except (TypeError, ValueError) as err:
        raise ConfigError(f"{source}: [path] {key} = {v!r} is not [n, e]") from err
    if a.shape != (2,) or not np.all(np.isfinite(a)):
        raise ConfigError(f"{source}: [path] {key} = {v!r} is not [n, e]")
    return a


_ALLOWED = {
    "circle": {"type", "center_ne", "radius_m", "direction", "start_deg"},
    "sinusoid": {"type", "start_ne", "direction_deg", "amplitude_m", "period_m", "length_m"},
    "line": {"type", "start_ne", "direction_deg", "length_m"},
    "waypoints": {"type", "frame", "points"},
}


def hermite_coefficients(knots: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Per-segment cubic coefficients (nseg, 8) of the C1 Catmull-Rom Hermite spline."""
    n = len(knots)
    m = np.empty_like(pts)
    m[0] = (pts[1] - pts[0]) / (knots[1] - knots[0])
    m[-1] = (pts[-1] - pts[-2]) / (knots[-1] - knots[-2])
    if n > 2:
        m[1:-1] = (pts[2:] - pts[:-2]) / (knots[2:] - knots[:-2])[:, None]
    h = np.diff(knots)[:, None]
    dp = np.diff(pts, axis=0)
    a0, a1 = pts[:-1], m[:-1]
    a2 = (3.0 * dp / h - 2.0 * m[:-1] - m[1:]) / h
    a3 = (m[:-1] + m[1:] - 2.0 * dp / h) / h**2
    coef = np.empty((n - 1, 8))
    for j, a in enumerate((a0, a1, a2, a3)):
        coef[:, j] = a[:, 0]
        coef[:, 4 + j] = a[:, 1]
    return coef


def path_from_spec(spec: dict, *, datum=None, source: str = "path") -> Path:
    """Build a :class:`Path` from its TOML/JSON definition (see module docstring).

    Parameters
    ----------
    spec : dict
        The ``[path]`` table: ``type`` and that kind's keys (lengths in m, angles in
        degrees).
    datum : Datum, optional
        Needed for ``waypoints`` in the ``latlon`` frame (converted to NED about it).
    source : str, default "path"
        Name of the document, for error messages.

    Returns
    -------
    Path

    Raises
    ------
    usvlog.errors.ConfigError
        On an unknown type or key, a missing or invalid value, fewer than two or
        coinciding waypoints, or lat/lon waypoints without a datum.
    """
    if not isinstance(spec, dict):
        raise ConfigError(f"{source}: [path] must be a table")
    typ = spec.get("type")
    if typ not in KINDS:
        raise ConfigError(f"{source}: [path] type {typ!r} is not one of {', '.join(KINDS)}")
    unknown = set(spec) - _ALLOWED[typ]
    if unknown:
        raise ConfigError(f"{source}: [path] {typ} has unknown key(s) {', '.join(sorted(unknown))}")
    spec = dict(spec)
    if typ == "circle":
        c = _pair(spec, "center_ne", source, (0.0, 0.0))
        R = _num(spec, "radius_m", source, positive=True)
        d = spec.get("direction", "cw")
        if d not in ("cw", "ccw"):
            raise ConfigError(f"{source}: [path] direction {d!r} is not cw or ccw")
        s = 1.0 if d == "cw" else -1.0
        phi0 = math.radians(_num(spec, "start_deg", source, 0.0))
        prm = np.array([c[0], c[1], R, s, phi0])
        return Path(spec, CIRCLE, prm, 0.0, 2 * math.pi * R, periodic=True)
    if typ in ("sinusoid", "line"):
        p0 = _pair(spec, "start_ne", source, (0.0, 0.0))
        a = math.radians(_num(spec, "direction_deg", source, 0.0))
        L = _num(spec, "length_m", source, positive=True)
        axis = [math.cos(a), math.sin(a)]
        if typ == "line":
            return Path(spec, LINE, np.array([p0[0], p0[1], *axis]), 0.0, L)
        A = _num(spec, "amplitude_m", source)
        P = _num(spec, "period_m", source, positive=True)
        return Path(spec, SINUSOID, np.array([p0[0], p0[1], *axis, A, P]), 0.0, L)
    frame = spec.get("frame", "ned")
    if frame not in ("ned", "latlon"):
        raise ConfigError(f"{source}: [path] frame {frame!r} is not ned or latlon")
    try:
        pts = np.asarray(spec.get("points", []), dtype=float)
    except (TypeError, ValueError) as err:
        raise ConfigError(f"{source}: [path] points are not a list of pairs") from err
    if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 2:
        raise ConfigError(f"{source}: [path] waypoints need at least 2 points [a, b]")
    if not np.all(np.isfinite(pts)):
        raise ConfigError(f"{source}: [path] waypoint {int(np.flatnonzero(~np.isfinite(pts).all(1))[0])} is not finite")
    if frame == "latlon":
        if datum is None:
            raise ConfigError(f"{source}: [path] lat/lon waypoints need a datum (the log's usvlog.datum)")
        n, e, _ = geodetic_to_ned(pts[:, 0], pts[:, 1], 0.0, datum=datum)
        pts = np.column_stack([n, e])
    seg = np.hypot(*np.diff(pts, axis=0).T)
    if np.any(seg <= 1e-9):
        i = int(np.flatnonzero(seg <= 1e-9)[0])
        raise ConfigError(f"{source}: [path] waypoints {i} and {i + 1} coincide")
    knots = np.concatenate([[0.0], np.cumsum(seg)])
    coef = hermite_coefficients(knots, pts)
    prm = np.concatenate([[len(seg)], knots, coef.ravel()])
    return Path(spec, SPLINE, prm, 0.0, float(knots[-1]))


def path_from_json(text: str, *, datum=None) -> Path:
    """Path from the JSON of :meth:`Path.spec_json` (e.g. a log's ``usvlog.path`` metadata).

    Raises ``json.JSONDecodeError`` on invalid JSON and
    :class:`~usvlog.errors.ConfigError` on an invalid spec.
    """
    return path_from_spec(json.loads(text), datum=datum, source="usvlog.path")


__all__ = ["Path", "path_from_spec", "path_from_json", "path_eval", "path_eval_many", "KINDS",
           "hermite_coefficients"]
