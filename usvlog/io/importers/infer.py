"""Units decided from the data: time columns, angles (degrees or radians), yaw rates.

A column's name says what it is more often than in what unit; these functions look at
the values. Each returns its decision with one line saying why, for the import report.

* :func:`judge_time`: a time column must be monotonic (non-decreasing almost
  everywhere, not constant); its magnitude tells seconds, milliseconds, microseconds or
  nanoseconds since 1970 (the years 2000-2100 in exactly one unit), else it counts from
  boot or from the start, and the unit is the one a name says (``_ms``, ``TimeUS``) or
  the one whose row interval is closest to :data:`TYPICAL_ROW_S`.
* :func:`angle_unit`: radians when the values stay within one turn of radians and
  spread over a turning run, degrees when they go beyond, else the name's default.
* :func:`rate_scale`: the scale of a yaw-rate column against d(heading)/dt (1 for
  rad/s, ~57.3 for deg/s).

Pure numpy: arrays in, results out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

TIME_UNITS: dict[str, float] = {"s": 1.0, "ms": 1e3, "us": 1e6, "ns": 1e9}
"""Time units -> ticks per second."""
EPOCH_RANGE_S = (946_684_800.0, 4_102_444_800.0)
"""Seconds since 1970 of 2000-01-01 and 2100-01-01: an epoch time in one unit lies within."""
TYPICAL_ROW_S = 0.1
"""A since-boot time's unit is the one whose row interval is closest (log) to this (s)."""
MONOTONIC_MIN = 0.99
"""A time column must step forward (or stay) in at least this share of its rows."""
RAD_SPAN_MIN = 1.5
"""Angles within one turn of radians are radians only when they spread over this much."""
RATE_MIN_RADPS = 0.02
"""d(heading)/dt must vary by at least this (rad/s, RMS) to judge a yaw rate's unit."""
RATE_MIN_CORR = 0.7
"""...and correlate at least this well with the yaw-rate column."""
_HINTS = {"s": ("s", "sec", "secs", "seconds"), "ms": ("ms", "msec", "millis", "milliseconds", "timems"),
          "us": ("us", "usec", "micros", "microseconds", "timeus"),
          "ns": ("ns", "nsec", "nanos", "nanoseconds", "timens")}


@dataclass(frozen=True)
class TimeVerdict:
    """What a candidate time column is.

    Attributes
    ----------
    ok : bool
        Usable as the record time (monotonic, not constant).
    unit : str or None
        ``s``, ``ms``, ``us`` or ``ns`` (None when not ok).
    epoch : bool
        Counted from 1970 (else from boot or from the start of the log).
    step_s : float or None
        Median row interval (s).
    why : str
        One line: the decision and its evidence, or why the column was rejected.
    """

    ok: bool
    unit: str | None
    epoch: bool
    step_s: float | None
    why: str


def unit_hint(name: str) -> str | None:
    """The time unit a normalized column name states (``time_ms``, ``timeus``), or None."""
    tokens = name.split("_")
    for unit, words in _HINTS.items():
        if any(w in tokens for w in words):
            return unit
    return None


def monotonic_share(v: np.ndarray) -> float:
    """Share of the steps between finite values that do not go backwards (1.0 for < 2 values)."""
    v = v[np.isfinite(v)]
    if len(v) < 2:
        return 1.0
    return float(np.mean(np.diff(v) >= 0))


def judge_time(v, name: str = "", *, text: bool = False) -> TimeVerdict:
    """Whether values are a usable time column, and in which unit.

    Parameters
    ----------
    v : array_like of float
        The column's values (NaN where empty); ns since 1970 for parsed ISO 8601 text.
    name : str
        The normalized header (its unit hint, if any, decides a since-boot unit).
    text : bool
        The values were parsed from ISO 8601 text (unit ns since 1970, not judged).

    Returns
    -------
    TimeVerdict
    """
    v = np.asarray(v, float)
    fin = v[np.isfinite(v)]
    if len(fin) < 2:
        return TimeVerdict(False, None, False, None, "fewer than two values")
    share = monotonic_share(fin)
    if share < MONOTONIC_MIN:
        return TimeVerdict(False, None, False, None,
                           f"not monotonic ({1 - share:.0%} of its steps go backwards)")
    d = np.diff(fin)
    if not (d > 0).any():
        return TimeVerdict(False, None, False, None, "constant")
    step = float(np.median(d[d > 0]))
    if text:
        return TimeVerdict(True, "ns", True, step / 1e9, f"ISO 8601 times, {1e9 / step:.3g} Hz rows")
    med = float(np.median(np.abs(fin)))
    for unit, per in TIME_UNITS.items():
        if EPOCH_RANGE_S[0] * per <= med <= EPOCH_RANGE_S[1] * per:
            return TimeVerdict(True, unit, True, step / per,
                               f"{unit} since 1970 (values ~{med:.4g}, rows every {step / per:.3g} s)")
    hint = unit_hint(name)
    if hint is not None:
        unit, how = hint, "as its name says"
    else:
        unit = min(TIME_UNITS, key=lambda u: abs(math.log10(step / TIME_UNITS[u] / TYPICAL_ROW_S)))
        how = f"steps of {step:.4g} are {step / TIME_UNITS[unit]:.3g} s rows"
    per = TIME_UNITS[unit]
    return TimeVerdict(True, unit, False, step / per,
                       f"{unit} since boot or start (values ~{med:.4g}, not 2000-2100 in any unit; {how})")


def angle_unit(v, default: str) -> tuple[str, str]:
    """Degrees or radians of a heading column, from its values.

    Parameters
    ----------
    v : array_like of float
        The values (NaN where empty).
    default : str
        ``deg`` or ``rad``: the name's unit, kept when the values cannot tell.

    Returns
    -------
    unit : str
        ``deg`` or ``rad``.
    why : str
        One line.
    """
    v = np.asarray(v, float)
    v = v[np.isfinite(v)]
    if len(v) == 0:
        return default, "no values: the name's unit"
    lo, hi = float(v.min()), float(v.max())
    span = hi - lo
    if max(abs(lo), abs(hi)) > 2 * math.pi + 0.05:
        return "deg", f"values {lo:.4g}..{hi:.4g} go beyond one turn of radians"
    if (max(abs(lo), abs(hi)) <= math.pi + 0.06 or lo >= -0.01) and span >= RAD_SPAN_MIN:
        return "rad", f"values {lo:.4g}..{hi:.4g} stay within one turn of radians while turning"
    return default, f"values {lo:.4g}..{hi:.4g} cannot tell (a run that hardly turns): the name's unit"


def rate_scale(t_h, psi_rad, t_r, r, window_s: float = 0.5) -> tuple[float, float] | None:
    """Scale and correlation of a yaw-rate column against d(heading)/dt.

    The heading is unwrapped and differentiated over +-``window_s`` (robust to held or
    noisy headings); the yaw rate, interpolated at the heading times, is regressed on it
    through the origin: r ~ k * d(psi)/dt. ``k`` ~ 1 for rad/s, ~57.3 for deg/s
    (negative when the column's sign convention is the other way round).

    Parameters
    ----------
    t_h, psi_rad : array_like
        Heading times (s) and headings (rad).
    t_r, r : array_like
        Yaw-rate times (s) and values (unit unknown).
    window_s : float
        Half-width of the differentiation window (s).

    Returns
    -------
    tuple of float or None
        ``(k, correlation)``; None when the heading does not turn enough
        (:data:`RATE_MIN_RADPS`) or the two do not correlate (:data:`RATE_MIN_CORR`).
    """
    t_h, psi, t_r, r = (np.asarray(a, float) for a in (t_h, psi_rad, t_r, r))
    ok = np.isfinite(t_h) & np.isfinite(psi)
    t_h, psi = t_h[ok], np.unwrap(psi[ok])
    ok = np.isfinite(t_r) & np.isfinite(r)
    t_r, r = t_r[ok], r[ok]
    if len(t_h) < 10 or len(t_r) < 10 or np.any(np.diff(t_h) < 0) or np.any(np.diff(t_r) < 0):
        return None
    j0 = np.searchsorted(t_h, t_h - window_s)
    j1 = np.searchsorted(t_h, t_h + window_s, side="right") - 1
    span = t_h[j1] - t_h[j0]
    use = span >= window_s
    if use.sum() < 10:
        return None
    d = (psi[j1] - psi[j0])[use] / span[use]
    rr = np.interp(t_h[use], t_r, r)
    if float(np.sqrt(np.mean(d * d))) < RATE_MIN_RADPS:
        return None
    corr = float(np.corrcoef(d, rr)[0, 1]) if np.std(rr) > 0 else 0.0
    if not np.isfinite(corr) or abs(corr) < RATE_MIN_CORR:
        return None
    return float(np.sum(rr * d) / np.sum(d * d)), corr
