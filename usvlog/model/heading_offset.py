"""Heading mounting offset: a heading sensor that sits a constant angle off the hull (pure numpy).

A dual-antenna GNSS heading whose antenna baseline is not along the keel, or a compass
mounted askew, reads ``heading_measured = heading_true + offset`` on every course. On a
straight run a boat's heading is its course over ground up to its crab angle, so
``heading - course`` on each straight run of the GNSS track estimates the offset. What
separates a mounting offset from a cross current is how that difference depends on the
course: an offset is the same on every course, a current's crab angle
``asin(c sin(course - current direction) / speed)`` changes with the course and flips sign
between opposite courses. So an offset is called only when the run differences agree on
at least two distinct courses (:data:`MIN_COURSE_SEPARATION_DEG` apart).

Sign convention (as ``EstimateSettings.compass_offset_rad``): ``offset = heading_measured -
heading_true``; the true heading is ``heading_measured - offset``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from .frames import ssa

MIN_SPEED_MPS = 0.5
"""A straight run is made of legs faster than this over ground (m/s)."""
LEG_M = 10.0
"""Legs of the (smoothed) track at least this long (m) give its course."""
SMOOTH_S = 2.0
"""Fixes are averaged over this long (s) before legs are cut (GNSS noise)."""
STRAIGHT_DEG = 15.0
"""A leg whose course is within this (deg) of the run's course so far continues the run."""
MIN_RUN_M = 30.0
"""A straight run covers at least this distance (m)..."""
MIN_RUN_S = 15.0
"""...and lasts at least this long (s)."""
MAX_HEADING_STD_DEG = 15.0
"""A run whose heading scatters more than this (circular std, deg) is not used."""
MIN_COURSE_SEPARATION_DEG = 60.0
"""Run courses at least this far apart (deg) are distinct courses; an offset needs two."""
MAX_COURSE_DISAGREEMENT_DEG = 8.0
"""The mean difference on each distinct course stays within this (deg) of the overall
mean for a constant offset (a 0.3 m/s cross current at 1.2 m/s crabs up to 14.5 deg)."""
MIN_OFFSET_DEG = 5.0
"""An offset smaller than this (deg), or than :data:`MIN_OFFSET_SIGMAS` uncertainties, is not reported."""
MIN_OFFSET_SIGMAS = 3.0


@dataclass(frozen=True)
class HeadingOffset:
    """Result of :func:`detect_heading_offset`.

    Attributes
    ----------
    decided : bool
        A constant mounting offset was found (``offset_deg`` is to be applied).
    offset_deg : float
        Mean of heading - course over the straight runs (deg, in [-180, 180); NaN when
        there are no runs), whether or not it is called an offset.
    std_deg : float
        Its uncertainty: the runs' spread / sqrt(runs) (deg; NaN with fewer than 2 runs).
    spread_deg : float
        Circular standard deviation of the run differences (deg).
    runs : int
        Straight runs used.
    courses : int
        Distinct courses among them (clusters :data:`MIN_COURSE_SEPARATION_DEG` apart).
    reason : str
        Why no offset is reported (not decidable, changes with the course, too small);
        empty when ``decided``.
    run_courses_deg, run_offsets_deg : tuple of float
        Course over ground and heading - course of each run (deg).
    """

    decided: bool
    offset_deg: float
    std_deg: float
    spread_deg: float
    runs: int
    courses: int
    reason: str = ""
    run_courses_deg: tuple[float, ...] = ()
    run_offsets_deg: tuple[float, ...] = ()

    @property
    def offset_rad(self) -> float:
        """``offset_deg`` in rad."""
        return math.radians(self.offset_deg)

    def describe(self) -> str:
        """One line in words: the offset with its uncertainty and support, or why none."""
        if self.decided:
            return (f"mounting offset {self.offset_deg:+.1f}\N{DEGREE SIGN} \N{PLUS-MINUS SIGN} "
                    f"{self.std_deg:.1f}\N{DEGREE SIGN} against the course over ground on {self.runs} straight runs "
                    f"over {self.courses} courses")
        return f"no mounting offset: {self.reason}"

    def to_dict(self) -> dict:
        """The fields as a JSON-ready dict (NaN as None)."""
        def num(x: float) -> float | None:
            return None if not math.isfinite(x) else round(float(x), 3)
        return {"decided": self.decided, "offset_deg": num(self.offset_deg), "std_deg": num(self.std_deg),
                "spread_deg": num(self.spread_deg), "runs": self.runs, "courses": self.courses,
                "reason": self.reason, "run_courses_deg": [num(c) for c in self.run_courses_deg],
                "run_offsets_deg": [num(o) for o in self.run_offsets_deg]}


def _smoothed(t_s: np.ndarray, n: np.ndarray, e: np.ndarray, smooth_s: float):
    """Moving means of t, n, e over ``smooth_s`` (in fixes, by the median interval)."""
    dt = float(np.median(np.diff(t_s))) if len(t_s) > 1 else 0.0
    w = int(min(max(1, round(smooth_s / dt)) if dt > 0 else 1, len(n)))
    k = np.full(w, 1.0 / w)
    return (np.convolve(t_s, k, "valid"), np.convolve(n, k, "valid"), np.convolve(e, k, "valid"))


def track_legs(t_s: np.ndarray, n: np.ndarray, e: np.ndarray, leg_m: float = LEG_M,
               smooth_s: float = SMOOTH_S) -> np.ndarray:
    """End points of the legs of a GNSS track: each leg ends at the first smoothed position
    at least ``leg_m`` from its start.

    Parameters
    ----------
    t_s, n, e : numpy.ndarray
        Fix times (s) and positions (m, local NED), in time order.
    leg_m, smooth_s : float
        Shortest leg (m) and averaging window (s).

    Returns
    -------
    numpy.ndarray
        (L + 1, 3): time (s), n, e (m) of the leg boundaries (empty when the track never
        moves ``leg_m``).
    """
    if len(n) < 2:
        return np.zeros((0, 3))
    ts, ns, es = _smoothed(t_s, n, e, smooth_s)
    idx, i, look = [0], 0, 64
    while i < len(ns) - 1:
        far = np.flatnonzero(np.hypot(ns[i:i + look] - ns[i], es[i:i + look] - es[i]) >= leg_m)
        if not len(far):
            if i + look >= len(ns):
                break
            look *= 2
            continue
        i, look = i + int(far[0]), 64
        idx.append(i)
    if len(idx) < 2:
        return np.zeros((0, 3))
    j = np.asarray(idx)
    return np.column_stack([ts[j], ns[j], es[j]])


def straight_runs(pts: np.ndarray, min_speed: float = MIN_SPEED_MPS, straight_deg: float = STRAIGHT_DEG,
                  min_run_m: float = MIN_RUN_M, min_run_s: float = MIN_RUN_S) -> list[tuple[float, float, float]]:
    """Straight runs of a track: consecutive legs (:func:`track_legs`) faster than
    ``min_speed`` whose courses stay within ``straight_deg`` of the run's course so far.

    Parameters
    ----------
    pts : numpy.ndarray
        (L + 1, 3) leg boundaries: time (s), n, e (m).
    min_speed, straight_deg, min_run_m, min_run_s : float
        See the module constants.

    Returns
    -------
    list of (float, float, float)
        (start s, end s, course over ground in rad) of each run covering at least
        ``min_run_m`` in at least ``min_run_s``.
    """
    if len(pts) < 2:
        return []
    d = np.diff(pts, axis=0)
    course = np.arctan2(d[:, 2], d[:, 1])
    with np.errstate(divide="ignore", invalid="ignore"):
        fast = np.hypot(d[:, 1], d[:, 2]) / d[:, 0] > min_speed
    tol = math.radians(straight_deg)
    runs, a = [], None
    for k in range(len(d) + 1):
        if a is not None and k < len(d) and fast[k]:
            ref = math.atan2(pts[k, 2] - pts[a, 2], pts[k, 1] - pts[a, 1])
            if abs(float(ssa(course[k] - ref))) <= tol:
                continue
        if a is not None:   # the run a..k (legs a..k-1) ends
            dn, de = pts[k, 1] - pts[a, 1], pts[k, 2] - pts[a, 2]
            if math.hypot(dn, de) >= min_run_m and pts[k, 0] - pts[a, 0] >= min_run_s:
                runs.append((float(pts[a, 0]), float(pts[k, 0]), math.atan2(de, dn)))
        a = k if k < len(d) and fast[k] else None
    return runs


def _circ_mean_std(a: np.ndarray) -> tuple[float, float]:
    """Circular mean (rad) and circular standard deviation (rad) of angles ``a``."""
    c, s = float(np.mean(np.cos(a))), float(np.mean(np.sin(a)))
    r = min(math.hypot(c, s), 1.0)
    return math.atan2(s, c), math.sqrt(-2.0 * math.log(r)) if r > 0 else math.inf


def _course_clusters(courses: np.ndarray, sep_deg: float) -> np.ndarray:
    """Cluster label (0, 1, ...) of each course (rad): a course joins the first cluster whose
    first course is closer than ``sep_deg``, else starts a new one."""
    reps: list[float] = []
    lab = np.zeros(len(courses), int)
    for i, c in enumerate(courses):
        near = [j for j, r in enumerate(reps) if abs(float(ssa(c - r))) < math.radians(sep_deg)]
        if near:
            lab[i] = near[0]
        else:
            reps.append(float(c))
            lab[i] = len(reps) - 1
    return lab


def run_offsets(t_heading_s: np.ndarray, heading_rad: np.ndarray, runs: list[tuple[float, float, float]],
                max_std_deg: float = MAX_HEADING_STD_DEG) -> tuple[np.ndarray, np.ndarray]:
    """Courses (rad) and heading - course (rad) of the runs with a steady heading.

    Parameters
    ----------
    t_heading_s, heading_rad : numpy.ndarray
        Heading times (s, increasing) and headings (rad).
    runs : list of (float, float, float)
        From :func:`straight_runs`.
    max_std_deg : float
        Runs whose heading scatters more than this (deg) are left out.

    Returns
    -------
    tuple of numpy.ndarray
        Courses and differences of the runs kept.
    """
    courses, offs = [], []
    for t0, t1, cog in runs:
        i0, i1 = np.searchsorted(t_heading_s, [t0, t1])
        if i1 - i0 < 3:
            continue
        m, sd = _circ_mean_std(heading_rad[i0:i1])
        if math.degrees(sd) > max_std_deg:
            continue
        courses.append(cog)
        offs.append(float(ssa(m - cog)))
    return np.asarray(courses, float), np.asarray(offs, float)


def detect_heading_offset(t_gnss_s, n_m, e_m, t_heading_s, heading_rad) -> HeadingOffset:
    """Find a constant mounting offset between a heading sensor and the course over ground.

    Straight runs of the GNSS track (:func:`straight_runs`: legs of :data:`LEG_M` over
    :data:`MIN_RUN_M` / :data:`MIN_RUN_S` at more than :data:`MIN_SPEED_MPS`) give
    heading - course each; an offset is reported when there are at least 2 runs on at
    least 2 distinct courses (:data:`MIN_COURSE_SEPARATION_DEG` apart), the mean
    difference on every course agrees with the overall mean within
    :data:`MAX_COURSE_DISAGREEMENT_DEG` (a cross current's crab changes with the course),
    and the mean is at least :data:`MIN_OFFSET_DEG` and :data:`MIN_OFFSET_SIGMAS` times
    its uncertainty (spread / sqrt(runs)).

    Parameters
    ----------
    t_gnss_s, n_m, e_m : array_like
        Fix times (s, any origin shared with the headings, increasing) and local NED
        positions (m).
    t_heading_s, heading_rad : array_like
        Heading times (s, increasing) and the headings as measured (rad, clockwise from
        north).

    Returns
    -------
    HeadingOffset
        ``decided`` and the offset (measured - true, deg) with its uncertainty, or the reason
        there is none.
    """
    t, n, e = (np.asarray(a, float) for a in (t_gnss_s, n_m, e_m))
    th, hd = np.asarray(t_heading_s, float), np.asarray(heading_rad, float)
    ok, okh = np.isfinite(t) & np.isfinite(n) & np.isfinite(e), np.isfinite(th) & np.isfinite(hd)
    runs = straight_runs(track_legs(t[ok], n[ok], e[ok]))
    courses, offs = run_offsets(th[okh], hd[okh], runs)
    nan = float("nan")
    if len(offs) == 0:
        return HeadingOffset(False, nan, nan, nan, 0, 0, "not decidable: no straight run of the GNSS track "
                             f"(>= {MIN_RUN_M:g} m over >= {MIN_RUN_S:g} s above {MIN_SPEED_MPS:g} m/s) with a "
                             "steady heading")
    lab = _course_clusters(courses, MIN_COURSE_SEPARATION_DEG)
    m, sd = _circ_mean_std(offs)
    k, n_courses = len(offs), int(lab.max()) + 1
    std = sd / math.sqrt(k) if k > 1 else nan
    res = HeadingOffset(False, math.degrees(m), math.degrees(std), math.degrees(sd), k, n_courses,
                        run_courses_deg=tuple(np.degrees(courses).tolist()),
                        run_offsets_deg=tuple(np.degrees(offs).tolist()))
    if k < 2 or n_courses < 2:
        return replace(res, reason=f"not decidable: {k} straight run(s) on {n_courses} course(s) (an offset "
                                   f"needs 2 courses >= {MIN_COURSE_SEPARATION_DEG:g} deg apart)")
    per = [math.degrees(abs(float(ssa(_circ_mean_std(offs[lab == c])[0] - m)))) for c in range(n_courses)]
    if max(per) > MAX_COURSE_DISAGREEMENT_DEG:
        return replace(res, reason=f"heading - course changes with the course (by up to {max(per):.1f} deg from "
                                   "its mean): a crab angle (current or wind), not a mounting offset")
    if abs(res.offset_deg) < max(MIN_OFFSET_DEG, MIN_OFFSET_SIGMAS * res.std_deg):
        return replace(res, reason=f"heading agrees with the course: mean difference {res.offset_deg:+.1f} "
                                   f"\N{PLUS-MINUS SIGN} {res.std_deg:.1f} deg")
    return replace(res, decided=True)
