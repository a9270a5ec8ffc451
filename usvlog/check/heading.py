"""Heading checks: mounting offset against the course over ground, deviation that varies with
the heading, a disturbance that follows the thrust (motor current near the compass), and a
yaw-rate signal's sign and scale against the compass.

The offset, deviation and thrust checks use the straight runs of the GNSS track
(:func:`usvlog.model.heading_offset.straight_runs`): on each leg of :data:`LEG_M` inside a run
the boat's heading is its course over ground up to its crab angle, so the leg's mean
``heading - course`` measures the compass error there. One least-squares fit explains those
leg differences by

    d = A + B sin c + C cos c + D sin 2c + E cos 2c + k_s (|left| + |right|) + k_d (left - right)

(c the leg's course, the classic deviation curve plus the leg's mean thrust), and two
F-tests against the nested fits without the harmonic terms and without the thrust terms
tell whether each part is significant (p < :data:`P_SIGNIFICANT`) and large enough to
matter (:data:`MIN_EFFECT_DEG`). A cross current crabs the boat by an angle that changes
with the course once per turn: it looks like a one-cycle deviation (B, C), which the
evidence shows apart from the two-cycle part (D, E).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.special import fdtrc

from ..estimate.core import COMPASS_TOPIC, YAW_RATE_TOPIC
from ..identify.signs import heading_rate_agreement
from ..log.findings import Finding
from ..model.frames import ssa
from ..model.heading_offset import LEG_M, detect_heading_offset, straight_runs, track_legs
from .common import CheckContext

P_SIGNIFICANT = 1e-3
"""A part of the leg fit is significant when its F-test p-value is below this."""
MIN_EFFECT_DEG = 2.0
"""...and its effect (the curve's amplitude; the thrust term over the run's thrust range) at least this (deg)."""
MAX_LEG_HEADING_STD_DEG = 15.0
"""Legs whose heading scatters more than this (circular std, deg) are left out."""
MAX_LEG_TURN_DEG = 3.0
"""Legs over which the heading's linear trend turns more than this (deg) are left out."""
MIN_THRUST_SPREAD = 0.05
"""A thrust term enters the leg fit when its spread over the legs is at least this share of the
mean total thrust (a differential thrust that is zero on every straight leg says nothing)."""
MIN_LEGS = 12
"""The leg fit needs this many legs..."""
MIN_OCTANTS = 5
"""...and, for the deviation curve, courses in this many of the eight 45 deg sectors (four
courses 90 deg apart cannot tell the two-cycle terms apart)."""


def mounting_offset(ctx: CheckContext) -> list[Finding]:
    """A constant offset between the heading and the course over ground: decided by
    :func:`usvlog.model.heading_offset.detect_heading_offset` (the import's test: the same on
    every course), measured on the steady legs (:func:`_legs`) when there are
    :data:`MIN_LEGS`: a whole straight run also holds the seconds after a turn, when the
    sway still decays and the hull crabs (about 2 deg too much on a simulated run turning
    one way every minute)."""
    tr, h = ctx.track, ctx.heading
    if tr is None or h is None:
        return []
    off = detect_heading_offset(tr[0], tr[1], tr[2], h[0], h[1])
    given = ctx.vessel.heading_offset_deg if ctx.vessel_given else None
    nums = {"offset_deg": off.offset_deg, "std_deg": off.std_deg, "runs": off.runs, "courses": off.courses}
    if given is not None:
        return [Finding(severity="info", code="heading.mounting_offset", channel=COMPASS_TOPIC,
                        evidence=f"the vessel file applies {given:+.1f} deg; {off.describe()}", numbers=nums)]
    if not off.decided:
        return [Finding(severity="info", code="heading.mounting_offset", channel=COMPASS_TOPIC,
                        evidence=off.describe(), numbers=nums)]
    o, sd, what = off.offset_deg, off.std_deg, f"{off.runs} straight runs"
    legs = _legs(ctx)
    if len(legs) >= MIN_LEGS:   # the steady legs only: no crab of the sway still decaying after a turn
        c, s = float(np.mean(np.cos(legs[:, 3]))), float(np.mean(np.sin(legs[:, 3])))
        spread = math.sqrt(-2.0 * math.log(min(max(math.hypot(c, s), 1e-12), 1.0)))
        o, sd = math.degrees(math.atan2(s, c)), math.degrees(spread) / math.sqrt(len(legs))
        what = f"{len(legs)} steady legs ({off.offset_deg:+.1f} deg on {off.runs} whole straight runs)"
    nums.update(offset_deg=o, std_deg=sd)
    big = abs(o) >= 20.0
    return [Finding(severity="error" if big else "warning", code="heading.mounting_offset", channel=COMPASS_TOPIC,
                    evidence=f"heading - course over ground {o:+.1f} +- {sd:.1f} deg on {what} over {off.courses} "
                             f"courses (spread {off.spread_deg:.1f} deg): the same on every course, a mounting offset",
                    action="apply it: usvlog estimate --heading-offset auto (or heading_offset_deg in the vessel "
                           "file's [sensors]); or turn the sensor/antenna baseline to the keel",
                    numbers=nums)]


def _legs(ctx: CheckContext) -> np.ndarray:
    """Legs on straight runs: rows (t0 s, t1 s, course rad, heading - course rad, |L|+|R|, L-R)."""
    tr, h = ctx.track, ctx.heading
    if tr is None or h is None:
        return np.zeros((0, 6))
    pts = track_legs(tr[0], tr[1], tr[2])
    th, hd = h
    thr = ctx.thrust
    rows = []
    for a, b, _ in straight_runs(pts):
        idx = np.flatnonzero((pts[:, 0] >= a - 1e-9) & (pts[:, 0] <= b + 1e-9))
        for i, j in zip(idx[:-1], idx[1:]):
            t0, t1 = float(pts[i, 0]), float(pts[j, 0])
            k0, k1 = np.searchsorted(th, [t0, t1])
            if k1 - k0 < 3:
                continue
            c, s = float(np.mean(np.cos(hd[k0:k1]))), float(np.mean(np.sin(hd[k0:k1])))
            r = min(math.hypot(c, s), 1.0)
            if r <= 0 or math.degrees(math.sqrt(-2.0 * math.log(r))) > MAX_LEG_HEADING_STD_DEG:
                continue
            turned = np.polyfit(th[k0:k1] - t0, np.unwrap(hd[k0:k1]), 1)[0] * (t1 - t0)
            if abs(math.degrees(turned)) > MAX_LEG_TURN_DEG:   # still turning: the chord is not the heading
                continue
            course = math.atan2(pts[j, 2] - pts[i, 2], pts[j, 1] - pts[i, 1])
            tot = dif = float("nan")
            if thr is not None:
                m = (thr[0] >= t0) & (thr[0] <= t1)
                if m.any():
                    tot = float(np.mean(np.abs(thr[1][m]) + np.abs(thr[2][m])))
                    dif = float(np.mean(thr[1][m] - thr[2][m]))
            rows.append((t0, t1, course, float(ssa(math.atan2(s, c) - course)), tot, dif))
    return np.asarray(rows, float).reshape(-1, 6)


def _rss(y: np.ndarray, X: np.ndarray) -> tuple[float, np.ndarray]:
    beta = np.linalg.lstsq(X, y, rcond=None)[0]
    r = y - X @ beta
    return float(r @ r), beta


def _f_test(y, full, reduced) -> tuple[float, float]:
    """F statistic and p-value of the columns ``full`` has beyond ``reduced``."""
    rss_f, _ = _rss(y, full)
    rss_r, _ = _rss(y, reduced)
    rank_f = int(np.linalg.matrix_rank(full))
    q, dof = rank_f - int(np.linalg.matrix_rank(reduced)), len(y) - rank_f   # collinear columns count once
    if q <= 0 or dof <= 0 or rss_f <= 0:
        return float("nan"), float("nan")
    f = ((rss_r - rss_f) / q) / (rss_f / dof)
    return float(f), float(fdtrc(q, dof, max(f, 0.0)))


def deviation_and_thrust(ctx: CheckContext) -> list[Finding]:
    """The leg fit (module docstring): deviation that varies with the heading, and a heading
    disturbance that follows the thrust."""
    if ctx.track is None or ctx.heading is None:
        return []
    legs = _legs(ctx)
    legs = legs[np.all(np.isfinite(legs[:, :4]), 1)]
    if len(legs) < MIN_LEGS:
        return [Finding(severity="info", code="heading.deviation", channel=COMPASS_TOPIC,
                        evidence=f"not decidable: {len(legs)} legs of {LEG_M:g} m on straight runs with a steady "
                                 f"heading ({MIN_LEGS} needed)",
                        action="drive straight legs of 30 m or more on several courses",
                        numbers={"legs": len(legs)})]
    c, d = legs[:, 2], np.degrees(legs[:, 3])
    one = np.ones(len(c))
    harm = np.stack([np.sin(c), np.cos(c), np.sin(2 * c), np.cos(2 * c)], 1)
    level = float(np.mean(np.abs(legs[:, 4]))) if np.all(np.isfinite(legs[:, 4])) else 0.0
    thr_cols = [(name, x) for name, x in (("|left|+|right|", legs[:, 4]), ("left-right", legs[:, 5]))
                if np.all(np.isfinite(x)) and np.std(x) > MIN_THRUST_SPREAD * level]
    T = np.stack([x for _, x in thr_cols], 1) if thr_cols else np.zeros((len(c), 0))
    octants = len(set(np.floor(np.mod(c, 2 * math.pi) / (math.pi / 4)).astype(int).tolist()))
    out = []
    t0, t1 = float(legs[0, 0]), float(legs[-1, 1])
    if octants >= MIN_OCTANTS:
        full = np.column_stack([one, harm, T])
        f, p = _f_test(d, full, np.column_stack([one, T]))
        _, beta = _rss(d, full)
        grid = np.radians(np.arange(0, 360, 1.0))
        curve = np.stack([np.sin(grid), np.cos(grid), np.sin(2 * grid), np.cos(2 * grid)], 1) @ beta[1:5]
        amp = float(np.max(np.abs(curve)))
        one_cycle, two_cycle = math.hypot(beta[1], beta[2]), math.hypot(beta[3], beta[4])
        nums = {"amplitude_deg": amp, "F": f, "p": p, "legs": len(c), "A_deg": float(beta[0]),
                "one_cycle_deg": one_cycle, "two_cycle_deg": two_cycle}
        text = (f"heading - course on {len(c)} legs over {octants} of 8 course sectors: A {beta[0]:+.1f} deg, "
                f"one-cycle {one_cycle:.1f} deg, two-cycle {two_cycle:.1f} deg; amplitude {amp:.1f} deg "
                f"(F = {f:.1f}, p = {p:.2g} against a constant)")
        if p < P_SIGNIFICANT and amp >= MIN_EFFECT_DEG:
            out.append(Finding(severity="warning", code="heading.deviation", channel=COMPASS_TOPIC, t0_s=t0, t1_s=t1,
                               evidence=f"the compass error changes with the heading: {text}",
                               action="calibrate the compass (hard and soft iron) on the boat, away from motors "
                                      "and batteries; a one-cycle part alone can be a cross current's crab",
                               numbers=nums))
        else:
            out.append(Finding(severity="info", code="heading.deviation", channel=COMPASS_TOPIC, t0_s=t0, t1_s=t1,
                               evidence=f"no significant deviation curve: {text}", numbers=nums))
    else:
        out.append(Finding(severity="info", code="heading.deviation", channel=COMPASS_TOPIC,
                           evidence=f"not decidable: straight legs on {octants} of 8 course sectors "
                                    f"({MIN_OCTANTS} needed)", action="drive straight legs on more courses",
                           numbers={"legs": len(c), "octants": octants}))
    if T.shape[1]:
        # the deviation curve is part of the base only when it is significant: else its four terms
        # would soak up part of a thrust effect that changes from leg to leg with the course
        curve = any(f.code == "heading.deviation" and f.severity == "warning" for f in out)
        base = np.column_stack([one, harm]) if curve else one[:, None]
        full = np.column_stack([base, T])
        f, p = _f_test(d, full, base)
        _, beta = _rss(d, full)
        k = beta[base.shape[1]:]
        effect = float(sum(abs(b) * np.ptp(x) for b, x in zip(k, T.T)))
        parts = ", ".join(f"{b:+.2f} deg per unit of {name}" for b, (name, _) in zip(k, thr_cols))
        nums = {"F": f, "p": p, "effect_deg": effect, "legs": len(c),
                **{f"per_unit_{'total' if name.startswith('|') else 'differential'}_deg": float(b)
                   for b, (name, _) in zip(k, thr_cols)}}
        if p < P_SIGNIFICANT and effect >= MIN_EFFECT_DEG:
            out.append(Finding(severity="warning", code="heading.thrust_disturbance", channel=COMPASS_TOPIC,
                               t0_s=t0, t1_s=t1,
                               evidence=f"heading - course follows the thrust: {parts}; {effect:.1f} deg over the "
                                        f"run's thrust range (F = {f:.1f}, p = {p:.2g}, {len(c)} legs)",
                               action="motor current near the compass? move the compass away from the motor cables "
                                      "and batteries, or calibrate with the motors running",
                               numbers=nums))
    return out


def yaw_rate(ctx: CheckContext) -> list[Finding]:
    """A yaw-rate signal against the compass heading's rate: sign and scale
    (:func:`usvlog.identify.signs.heading_rate_agreement`)."""
    f, h = ctx.log.get(YAW_RATE_TOPIC), ctx.heading
    if f is None or len(f) < 10 or h is None or "r_radps" not in f:
        return []
    t = ctx.seconds(f.index)
    r = f["r_radps"].to_numpy(float)
    o = np.argsort(t, kind="stable")
    t, r = t[o], r[o]
    inside = (t >= h[0][0]) & (t <= h[0][-1])
    t, r = t[inside], r[inside]
    psi = np.interp(t, h[0], np.unwrap(h[1]))
    rc = heading_rate_agreement(t, psi, r)
    nums = {"scale": rc.scale, "scale_se": rc.scale_se, "sign": rc.sign, "t_stat": rc.t_stat}
    span = (float(t[0]), float(t[-1])) if len(t) else (None, None)
    if rc.sign == 0 or rc.agree:
        return [Finding(severity="info", code="heading.yaw_rate", channel=YAW_RATE_TOPIC, t0_s=span[0], t1_s=span[1],
                        evidence=rc.message, numbers=nums)]
    unit = abs(abs(rc.scale) * math.pi / 180 - 1) < 0.2 or abs(abs(rc.scale) / (math.pi / 180) - 1) < 0.2
    bad = rc.sign < 0 or unit
    action = []
    if rc.sign < 0:
        action.append("reverse the yaw-rate signal's sign (gyro upside down or counter-clockwise positive)")
    if unit:
        action.append("import the yaw rate with the right unit (deg/s or rad/s)")
    return [Finding(severity="error" if bad else "warning", code="heading.yaw_rate", channel=YAW_RATE_TOPIC,
                    t0_s=span[0], t1_s=span[1], evidence=rc.message,
                    action="; ".join(action) or "check the gyro's scale factor", numbers=nums)]


CHECKS = ((mounting_offset, ("heading.mounting_offset",)),
          (deviation_and_thrust, ("heading.deviation", "heading.thrust_disturbance")),
          (yaw_rate, ("heading.yaw_rate",)))
"""(function(ctx) -> findings, the checks it reports under)."""
