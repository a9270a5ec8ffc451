"""Does a candidate's data behave like what its role needs? Checks on sample series.

The mapping (:mod:`usvlog.io.importers.mapping`) chooses sources by structure: names,
types, one sample value. Names fool it (a controller's ``heading_gain`` is named like a
heading), so where a reader can give a candidate's values (:class:`Series`), these checks
decide from the data:

* :func:`angle_like`: a heading must behave like an angle: values within one turn (degrees
  or radians, decided from the magnitude), not constant, and continuous apart from wraps
  (no jump a boat cannot turn between two samples);
* :func:`course_agreement`: where the boat moves, a heading is close to the course over
  ground most of the time (a gain or an error signal is not).

Pure numpy: arrays in, small result objects out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ...model.frames import ssa

MAX_TURN_RATE_RADPS = 3.0
"""A boat's heading does not change faster than this (rad/s, ~170 deg/s) between samples."""
JUMP_FLOOR_RAD = 0.35
"""...nor by more than this between two samples, whatever their spacing (20 deg)."""
MAX_JUMP_FRACTION = 0.02
"""An angle may jump (noise, a re-initialisation) at most this fraction of its samples."""
MIN_MOVE_MPS = 0.2
"""Legs slower than this do not give a course over ground."""
LEG_M = 1.0
"""Legs of the track at least this long (m) give its course."""
MAX_LEGS = 20_000
"""At most this many legs are looked at."""
AGREE_RAD = math.radians(45.0)
"""A heading within this of the course over ground agrees with it."""


@dataclass(frozen=True)
class Series:
    """Values of one candidate field: times (int64 ns) and values (float)."""

    t_ns: np.ndarray
    v: np.ndarray


@dataclass(frozen=True)
class AngleCheck:
    """Whether a series behaves like an angle; its unit; why not."""

    ok: bool
    unit: str          # "rad" or "deg" ("" when not an angle)
    why: str           # the reason it is not an angle ("" when it is)
    constant: bool = False   # within one turn but never moves (a dead sensor, or not an angle)


def angle_like(s: Series) -> AngleCheck:
    """Do these values behave like a heading: within one turn, moving, continuous apart from wraps?

    Parameters
    ----------
    s : Series
        The candidate's samples in time order.

    Returns
    -------
    AngleCheck
        ``unit`` "deg" when the values exceed 2 pi (and stay within 360 deg), else "rad".
    """
    v = np.asarray(s.v, float)
    t = np.asarray(s.t_ns, np.int64)
    fin = np.isfinite(v)
    if len(v) < 5 or fin.mean() < 0.9:
        return AngleCheck(False, "", f"{int(fin.sum())} finite values of {len(v)}")
    v, t = v[fin], t[fin]
    top = float(np.abs(v).max())
    if top <= 2.0 * math.pi + 0.05:
        unit, rad = "rad", v
    elif top <= 360.5:
        unit, rad = "deg", np.radians(v)
    else:
        return AngleCheck(False, "", f"values beyond one turn (|value| up to {top:.3g})")
    if float(np.ptp(v)) < 1e-6:
        return AngleCheck(False, unit, f"constant ({v[0]:.4g})", constant=True)
    step = np.abs(ssa(np.diff(rad)))
    dt = np.maximum(np.diff(t) * 1e-9, 1e-3)
    jumps = step > np.maximum(JUMP_FLOOR_RAD, MAX_TURN_RATE_RADPS * dt)
    frac = float(jumps.mean()) if len(jumps) else 0.0
    if frac > MAX_JUMP_FRACTION:
        return AngleCheck(False, "", f"jumps between samples {100 * frac:.0f} % of the time (a heading is continuous "
                                     "apart from wraps)")
    return AngleCheck(True, unit, "")


def course_legs(t_ns: np.ndarray, n: np.ndarray, e: np.ndarray, leg_m: float = LEG_M
                ) -> tuple[np.ndarray, np.ndarray]:
    """(mid times ns, courses rad) of the track's legs of at least ``leg_m`` moved above MIN_MOVE_MPS."""
    t_ns, n, e = np.asarray(t_ns, np.int64), np.asarray(n, float), np.asarray(e, float)
    ok = np.isfinite(n) & np.isfinite(e)
    t_ns, n, e = t_ns[ok], n[ok], e[ok]
    if len(t_ns) < 2:
        return np.zeros(0, np.int64), np.zeros(0)
    with np.errstate(over="ignore", invalid="ignore"):
        d = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(n), np.diff(e)))])
    if not np.isfinite(d[-1]):
        return np.zeros(0, np.int64), np.zeros(0)
    leg_m = max(leg_m, d[-1] / MAX_LEGS)   # a track with absurd jumps is not cut into billions of legs
    starts = np.searchsorted(d, np.arange(0.0, d[-1] - leg_m, leg_m))
    ends = np.searchsorted(d, d[starts] + leg_m)
    keep = ends < len(d)
    i, j = starts[keep], ends[keep]
    dt = (t_ns[j] - t_ns[i]) * 1e-9
    dn, de = n[j] - n[i], e[j] - e[i]
    with np.errstate(invalid="ignore", divide="ignore"):
        fast = np.hypot(dn, de) / np.maximum(dt, 1e-9) > MIN_MOVE_MPS
    mid = (t_ns[i] + (t_ns[j] - t_ns[i]) // 2)[fast]
    return mid, np.arctan2(de, dn)[fast]


def course_agreement(heading: Series, unit: str, t_ns: np.ndarray, n: np.ndarray, e: np.ndarray) -> float | None:
    """Fraction of the moving track's legs whose course the heading is within 45 deg of (None: no leg).

    Parameters
    ----------
    heading : Series
        The candidate (clockwise from north).
    unit : str
        "deg" or "rad" (as :func:`angle_like` decided).
    t_ns, n, e : ndarray
        Positions in a north-east frame (m) and their times.
    """
    mid, cog = course_legs(t_ns, n, e)
    ht, hv = np.asarray(heading.t_ns, np.int64), np.asarray(heading.v, float)
    ok = np.isfinite(hv)
    ht, hv = ht[ok], hv[ok]
    if len(mid) == 0 or len(ht) < 2:
        return None
    rad = np.radians(hv) if unit == "deg" else hv
    i = np.clip(np.searchsorted(ht, mid), 0, len(ht) - 1)
    return float(np.mean(np.abs(ssa(rad[i] - cog)) < AGREE_RAD))
