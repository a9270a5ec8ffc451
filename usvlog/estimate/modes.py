"""The estimator's modes: GNSS only, course as heading, the heading mounting offset.

A heading is fused unless it is missing, judged dead at import, still while the GNSS track
turns (:func:`still_heading`) or contradicted by the track (:func:`_compass_disagrees`, which
makes :func:`usvlog.estimate.core.estimate` run again on GNSS alone). Without a heading the
run starts from the track's first course (:func:`initial_course`) and the kinematic model's
heading is its course over ground (:func:`course_as_heading`). A heading source mounted off
the hull's axis is found on the track (:func:`heading_offset_of`) and applied
(:func:`apply_heading_offset`) before :mod:`usvlog.estimate.problem` builds the problem.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pandas as pd

from ..log.fieldlog import FieldLog
from ..log.summary import health_from_provenance
from ..model.frames import Datum, geodetic_to_ned
from ..model.heading_offset import HeadingOffset, detect_heading_offset
from ..model.vessel import Vessel
from . import kernels
from .kernels import (
    COMPASS,
)
from .layout import _P0_SIGMA, COMPASS_TOPIC, GNSS_TOPIC, Problem, _channel, _col
from .run import RawRun
from .settings import EstimateSettings

HEADING_STILL_DEG = 2.0
"""A heading whose unwrapped span stays under this (deg) while the track turns has not moved
(as in the import's health audit)."""
TRACK_TURN_DEG = 90.0
"""The GNSS track's course must span at least this much (deg) to call a still heading dead."""
TRACK_LEG_M = 10.0
"""Legs of the (2 s averaged) track at least this long (m) give its course."""
TRACK_SMOOTH_S = 2.0
"""GNSS fixes are averaged over this long (s) before their course is taken (noise)."""


def _alive(log: FieldLog, topic: str) -> bool:
    """The log has ``topic`` with data and the import's health audit did not judge it dead."""
    health = health_from_provenance(log.provenance) or {}
    return topic not in (health.get("dead") or []) and _channel(log, topic, required=False) is not None


def _heading_unusable(log: FieldLog, comp: pd.DataFrame | None, s: EstimateSettings) -> str:
    """Why the heading channel is not fused ("" when it is): missing, not wanted, or
    judged dead by the import's health audit (stored in the log's provenance)."""
    if s.gps_only:
        return "GNSS only was asked for (gps_only)"
    health = health_from_provenance(log.provenance) or {}
    if COMPASS_TOPIC in (health.get("dead") or []):
        why = ((health.get("channels") or {}).get(COMPASS_TOPIC) or {}).get("why") or "dead"
        return f"the import's health audit judged {COMPASS_TOPIC} dead ({why}), not fused"
    if comp is None:
        return f"the log has no heading channel ({COMPASS_TOPIC})"
    if not np.isfinite(_col(comp, "heading_rad")).any():
        return f"{COMPASS_TOPIC} has no valid heading"
    return ""


def track_courses(t_ns: np.ndarray, n: np.ndarray, e: np.ndarray, leg_m: float = TRACK_LEG_M,
                  smooth_s: float = TRACK_SMOOTH_S) -> np.ndarray:
    """Courses (rad, clockwise from north) of the legs of a GNSS track, in time order.

    The fixes are first averaged over ``smooth_s`` (a moving mean), so that the noise of
    single fixes does not pass for motion; each leg then ends at the first averaged
    position at least ``leg_m`` from its start.

    Parameters
    ----------
    t_ns : numpy.ndarray
        Fix times, ns (for the rate).
    n, e : numpy.ndarray
        Positions in time order, m.
    leg_m : float
        Shortest leg, m.
    smooth_s : float
        Averaging window, s.

    Returns
    -------
    numpy.ndarray
        One course per leg (empty when the track never moves ``leg_m``).
    """
    if len(n) < 2:
        return np.zeros(0)
    dt = float(np.median(np.diff(t_ns))) * 1e-9
    w = int(min(max(1, round(smooth_s / dt)) if dt > 0 else 1, len(n)))
    kern = np.full(w, 1.0 / w)
    n, e = np.convolve(n, kern, "valid"), np.convolve(e, kern, "valid")
    out = []
    i, N, look = 0, len(n), 64
    while i < N - 1:
        far = np.flatnonzero(np.hypot(n[i:i + look] - n[i], e[i:i + look] - e[i]) >= leg_m)
        if not len(far):
            if i + look >= N:
                break
            look *= 2     # a slow stretch: look further ahead
            continue
        j = i + int(far[0])
        out.append(math.atan2(e[j] - e[i], n[j] - n[i]))
        i, look = j, 64
    return np.asarray(out)


def still_heading(psi: np.ndarray, t_ns: np.ndarray, n: np.ndarray, e: np.ndarray) -> str:
    """Why a heading that does not move while the GNSS track turns is not fused ("" when it moves).

    The heading is still when its unwrapped span stays under :data:`HEADING_STILL_DEG`;
    the track turns when the unwrapped courses of its legs (:func:`track_courses`) span
    at least :data:`TRACK_TURN_DEG`.

    Parameters
    ----------
    psi : numpy.ndarray
        Headings, rad.
    t_ns, n, e : numpy.ndarray
        GNSS fix times (ns) and positions (m).

    Returns
    -------
    str
        The reason in words, or "".
    """
    span = math.degrees(float(np.ptp(np.unwrap(psi)))) if len(psi) else 0.0
    if span >= HEADING_STILL_DEG:
        return ""
    c = track_courses(t_ns, n, e)
    turn = math.degrees(float(np.ptp(np.unwrap(c)))) if len(c) > 1 else 0.0
    if turn < TRACK_TURN_DEG:
        return ""
    return (f"{COMPASS_TOPIC} moved {span:.2f} deg in all while the GNSS track's course spanned {turn:.0f} deg: "
            "a dead compass, not fused")


def initial_course(t_ns: np.ndarray, n: np.ndarray, e: np.ndarray) -> float:
    """Heading to start from without a compass: the course of the track's first leg
    (:func:`track_courses`, rad), 0 if it never moves that far."""
    c = track_courses(t_ns[:20000], n[:20000], e[:20000])
    return float(c[0]) if len(c) else 0.0


COURSE_MIN_SPEED_MPS = 0.3
"""GNSS-only kinematic estimate: above this speed over ground (m/s) the heading is the course
over ground; below it the last such course is held (stated as unknown)."""


def course_as_heading(X: np.ndarray, SD: np.ndarray, PB: np.ndarray, gyro: bool,
                      min_speed: float = COURSE_MIN_SPEED_MPS) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Heading = course over ground for the kinematic (NED) model run without a compass.

    Without a heading measurement the psi, r states of the kinematic model are not
    observed; the boat's heading is taken as its course over ground while it moves
    (sideslip unobservable: the over-ground body velocity then has v = 0) and the yaw rate
    as the course rate (v_n a_e - v_e a_n) / |v|^2, unless a gyro measured r.

    Parameters
    ----------
    X, SD : numpy.ndarray
        States of the kinematic model (N, 8 or more: its first eight states) and their one-sigma.
    PB : numpy.ndarray
        Covariance of (psi, v_n, v_e), (N, 3, 3).
    gyro : bool
        A yaw-rate channel was fused (keep the r state).
    min_speed : float
        Speed over ground (m/s) above which the course is the heading; below it the last
        course is held with a one-sigma of pi / sqrt(3) (unknown) and r is 0 +- 0.3 rad/s.

    Returns
    -------
    tuple of numpy.ndarray
        Copies of X, SD, PB with psi, r, their one-sigma and the psi rows of PB replaced
        (first-order propagation of the velocity covariance).
    """
    X, SD, PB = X.copy(), SD.copy(), PB.copy()
    vn, ve = X[:, kernels.X_VN], X[:, kernels.X_VE]
    sp2 = vn * vn + ve * ve
    moving = sp2 > min_speed ** 2
    if not moving.any():
        moving[:] = False
    idx = np.maximum.accumulate(np.where(moving, np.arange(len(vn)), -1))
    idx[idx < 0] = int(np.argmax(moving)) if moving.any() else 0
    cog = np.arctan2(ve, vn)
    psi = cog[idx] if moving.any() else np.zeros(len(vn))
    safe = np.where(moving, sp2, 1.0)
    J = np.stack([-ve / safe, vn / safe], -1)                    # d cog / d(v_n, v_e)
    Pvv = PB[:, 1:, 1:]
    cross = np.einsum("ki,kij->kj", J, Pvv)
    var = np.einsum("kj,kj->k", cross, J)
    unknown = math.pi / math.sqrt(3.0)
    sd = np.where(moving, np.minimum(np.sqrt(np.maximum(var, 0.0)), unknown), unknown)
    cross[~moving] = 0.0
    X[:, kernels.X_PSI] = psi
    SD[:, kernels.X_PSI] = sd
    PB[:, 0, 0] = sd ** 2
    PB[:, 0, 1:] = cross
    PB[:, 1:, 0] = cross
    if not gyro:
        an, ae = X[:, kernels.X_AN], X[:, kernels.X_AE]
        X[:, kernels.X_R] = np.where(moving, (vn * ae - ve * an) / safe, 0.0)
        s_an, s_ae = SD[:, kernels.X_AN], SD[:, kernels.X_AE]
        SD[:, kernels.X_R] = np.where(moving, np.sqrt(vn ** 2 * s_ae ** 2 + ve ** 2 * s_an ** 2) / safe,
                                      _P0_SIGMA[kernels.X_R])
    return X, SD, PB


COMPASS_REJECT_LIMIT = 0.5
"""A compass whose measurements the gate rejects more often than this is not fused: the
estimate is made again from GNSS alone (a rough or wrong heading source)."""


def _compass_disagrees(pb: Problem, raw: RawRun) -> str:
    """Why a fused compass is dropped ("" to keep it): rejected by the gate more than
    :data:`COMPASS_REJECT_LIMIT` of the time."""
    sel = pb.mkind == COMPASS
    if not sel.any():
        return ""
    rejected = float((raw.accepted[sel] == 0).mean())
    if rejected <= COMPASS_REJECT_LIMIT:
        return ""
    return (f"{COMPASS_TOPIC} disagrees with the track ({100 * rejected:.0f} % of its headings rejected by the "
            "gate): not fused")


def heading_offset_of(log: FieldLog, settings: EstimateSettings) -> HeadingOffset | None:
    """The heading mounting offset detected in a log
    (:func:`usvlog.model.heading_offset.detect_heading_offset` on its fixes and its headings
    as measured, magnetic ones with the declination added); None without fixes or headings."""
    gps = _channel(log, GNSS_TOPIC, required=False)
    comp = _channel(log, COMPASS_TOPIC, required=False)
    if gps is None or comp is None:
        return None
    lat, lon = _col(gps, "lat_deg"), _col(gps, "lon_deg")
    good = np.isfinite(lat) & np.isfinite(lon) & (np.abs(lat) <= 90) & (np.abs(lon) <= 180)
    if not good.any():
        return None
    datum = log.datum or Datum(lat_deg=float(lat[good][0]), lon_deg=float(lon[good][0]))
    n, e, _ = geodetic_to_ned(lat[good], lon[good], 0.0, datum=datum)
    tg, tc = np.asarray(gps.index, np.int64)[good], np.asarray(comp.index, np.int64)
    hd = _col(comp, "heading_rad")
    if "reference" in comp.columns:
        hd = hd + np.where(comp["reference"].astype(str).to_numpy() == "magnetic", settings.declination_rad, 0.0)
    t0 = int(min(tg[0], tc[0]))
    return detect_heading_offset((tg - t0) * 1e-9, n, e, (tc - t0) * 1e-9, hd)


def apply_heading_offset(settings: EstimateSettings, found: HeadingOffset | None,
                         vessel: Vessel) -> tuple[EstimateSettings, str]:
    """The settings with the heading mounting offset in effect, and where it came from.

    ``heading_offset_auto``: the detected offset when one was decided (``auto``), else the
    given one; otherwise ``compass_offset_rad`` when not 0 (``given``), else the vessel
    file's ``[sensors] heading_offset_deg`` (``vessel file``), else none.
    """
    if settings.heading_offset_auto:
        if found is not None and found.decided:
            return replace(settings, compass_offset_rad=found.offset_rad), "auto"
        return settings, "auto (none detected)" if not settings.compass_offset_rad else "given"
    if settings.compass_offset_rad:
        return settings, "given"
    deg = getattr(vessel, "heading_offset_deg", None)
    if deg:
        return replace(settings, compass_offset_rad=math.radians(deg)), "vessel file"
    return settings, "none"
