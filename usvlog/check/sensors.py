"""Sensor checks: channels missing, dead or frozen, sample-and-hold, rate and gaps, time going
backwards, GNSS jumps the boat cannot make, fix quality (HDOP, satellites, RTK or not).

Thresholds are the module constants; each check returns a list of findings (empty: passed).
"""

from __future__ import annotations

import math

import numpy as np

from ..estimate.core import COMPASS_TOPIC, GNSS_TOPIC, THRUST_TOPIC, YAW_RATE_TOPIC
from ..log.findings import Finding
from ..log.positions import LOCAL_TOPIC
from .common import QUALITY_TOPIC, SENSOR_TOPICS, CheckContext

GAP_FACTOR = 3.0
"""An interval longer than this many median intervals (and than :data:`GAP_MIN_S`) is a gap."""
GAP_MIN_S = 0.5
HEADING_STILL_DEG = 2.0
"""A heading whose whole span stays under this (deg) has not moved..."""
TRACK_TURN_DEG = 90.0
"""...and is dead when the track turned at least this much (deg, summed over 5 m legs)."""
FROZEN_S = 5.0
"""A sensor repeating exactly one value this long (s, and :data:`FROZEN_MIN_SAMPLES` samples) is frozen."""
FROZEN_MIN_SAMPLES = 20
HELD_MIN_REPEAT = 0.2
"""Sample-and-hold: at least this share of the fixes repeat the one before..."""
HELD_MIN_REGULAR = 0.6
"""...and this share of the intervals between changes are one regular update period."""
JUMP_FACTOR = 3.0
"""A GNSS jump: a speed between consecutive fixes over this many times the track's 99th
percentile speed and over :data:`JUMP_MIN_MPS`."""
JUMP_MIN_MPS = 5.0
JUMP_MIN_M = 2.0
"""...and a step at least this long (m): smaller ones are the receiver's noise."""
HDOP_HIGH = 2.0
"""HDOP above this on more than :data:`QUALITY_SHARE` of the fixes is a warning."""
SATS_LOW = 6
"""Fewer satellites than this on more than :data:`QUALITY_SHARE` of the fixes is a warning."""
QUALITY_SHARE = 0.1
FIX_TYPES = {0: "invalid", 1: "autonomous", 2: "DGPS", 4: "RTK fixed", 5: "RTK float", 6: "dead reckoning"}


def missing(ctx: CheckContext) -> list[Finding]:
    """Positions (GNSS or local), heading and thrust: an error without positions, a warning without the others."""
    out = []
    if ctx.track is None:
        out.append(Finding(severity="error", code="sensors.missing", channel=GNSS_TOPIC,
                           evidence="no usable position (no GNSS fix or local position with 2 valid records)",
                           action="map the position source at import (--topic gnss=... or local_n/local_e)"))
    if ctx.heading is None:
        dead = COMPASS_TOPIC in (ctx.health.get("dead") or [])
        out.append(Finding(severity="warning", code="sensors.missing", channel=COMPASS_TOPIC,
                           evidence="no compass heading" + (" (judged dead at import)" if dead else ""),
                           action="the estimate runs on GNSS alone; identify needs a heading"))
    if ctx.thrust is None:
        out.append(Finding(severity="warning", code="sensors.missing", channel=THRUST_TOPIC,
                           evidence="no thruster commands",
                           action="identify and replay need them: map thrust_left/thrust_right at import"))
    return out


def rates_and_gaps(ctx: CheckContext) -> list[Finding]:
    """Each sensor's rate (one info for all) and its gaps (a warning per channel with any)."""
    out, rates = [], []
    for topic in SENSOR_TOPICS:
        t = ctx.times(topic)
        if t is None or len(t) < 3:
            continue
        t.sort()   # a fresh array: sorted in place
        dt = np.diff(t)
        pos = dt[dt > 0]
        if not len(pos):
            continue
        med = float(np.median(pos, overwrite_input=True))   # pos is not used again
        rates.append(f"{topic} {1 / med:.3g} Hz")
        big = np.flatnonzero(dt > max(GAP_FACTOR * med, GAP_MIN_S))
        if len(big):
            k = int(big[np.argmax(dt[big])])
            out.append(Finding(severity="warning", code="sensors.gaps", channel=topic, t0_s=float(t[k]),
                               t1_s=float(t[k + 1]),
                               evidence=f"{len(big)} gap(s) longer than {GAP_FACTOR:g} intervals of {med:.3g} s; "
                                        f"longest {dt[k]:.2f} s (shown), {dt[big].sum():.1f} s in all",
                               action="check the sensor's connection and the logger's load",
                               numbers={"gaps": len(big), "longest_gap_s": float(dt[k]), "rate_hz": 1 / med}))
    if rates:
        out.append(Finding(severity="info", code="sensors.rate", evidence="rates: " + ", ".join(rates)))
    return out


def time_order(ctx: CheckContext) -> list[Finding]:
    """Records whose log time or own sensor stamp is not after the one before."""
    out = []
    for topic in SENSOR_TOPICS:
        f = ctx.log.get(topic)
        if f is None or len(f) < 2:
            continue
        for what, t_ns in (("log time", np.asarray(f.index, np.int64)),
                           ("sensor stamp", f["stamp_ns"].to_numpy(np.int64) if "stamp_ns" in f else None)):
            if t_ns is None:
                continue
            back = np.flatnonzero(np.diff(t_ns) < 0) + 1
            if not len(back):
                continue
            ts = ctx.seconds(np.asarray(f.index, np.int64))
            worst = float(-np.diff(t_ns)[back - 1].min() / 1e9)
            out.append(Finding(severity="warning", code="sensors.time_backwards", channel=topic,
                               t0_s=float(ts[back[0]]), t1_s=float(ts[back[-1]]),
                               evidence=f"{len(back)} of {len(f)} records with a {what} before the one before "
                                        f"(largest step back {worst:.3f} s)",
                               action="check the logger's clock or the sensor's stamps; the stages sort by time",
                               numbers={"backwards": len(back), "largest_back_s": worst}))
    return out


def dead_or_frozen(ctx: CheckContext) -> list[Finding]:
    """A heading that never moves while the track turns (dead); any sensor repeating one
    exact value for :data:`FROZEN_S` (frozen: for a position, only while thrust is applied)."""
    out = []
    h = ctx.heading
    turn = ctx.track_turn_deg
    dead_heading = False
    if h is not None and len(h[0]) >= FROZEN_MIN_SAMPLES:
        span = math.degrees(float(np.ptp(np.unwrap(h[1]))))
        if span < HEADING_STILL_DEG:
            dead_heading = turn is not None and turn >= TRACK_TURN_DEG
            out.append(Finding(
                severity="error" if dead_heading else "warning",
                code="sensors.dead" if dead_heading else "sensors.dead.suspect", channel=COMPASS_TOPIC,
                t0_s=float(h[0][0]), t1_s=float(h[0][-1]),
                evidence=f"heading moved {span:.2f} deg in all ({len(h[0])} records) while the track turned "
                         + ("an unknown angle" if turn is None else f"{turn:.0f} deg"),
                action="the compass is dead (or stuck): check it; estimate without it (GNSS only)"
                if dead_heading else "a still heading on a track that hardly turns: look at the channel",
                numbers={"span_deg": span, "track_turn_deg": float("nan") if turn is None else turn}))
    thrust = ctx.thrust
    for topic in (COMPASS_TOPIC, YAW_RATE_TOPIC, GNSS_TOPIC, LOCAL_TOPIC):
        if topic == COMPASS_TOPIC and dead_heading:
            continue
        f = ctx.log.get(topic)
        if f is None or len(f) < FROZEN_MIN_SAMPLES:
            continue
        cols = {COMPASS_TOPIC: ["heading_rad"], YAW_RATE_TOPIC: ["r_radps"], GNSS_TOPIC: ["lat_deg", "lon_deg"],
                LOCAL_TOPIC: ["n_m", "e_m"]}[topic]
        if not all(c in f for c in cols):
            continue
        t = ctx.seconds(f.index)
        key = np.stack([f[c].to_numpy(float) for c in cols], 1)
        same = np.concatenate([[False], np.all(key[1:] == key[:-1], 1)])
        starts = np.flatnonzero(~same)
        ends = np.concatenate([starts[1:] - 1, [len(t) - 1]])
        dur = t[ends] - t[starts]
        long = np.flatnonzero((dur >= FROZEN_S) & (ends - starts + 1 >= FROZEN_MIN_SAMPLES))
        if topic in (GNSS_TOPIC, LOCAL_TOPIC) and thrust is not None:   # a boat at rest repeats its fix
            tt, lft, rgt, _ = thrust
            on = (lft != 0) | (rgt != 0)
            share = [float(on[m].mean()) if m.any() else 0.0
                     for m in ((tt >= t[starts[k]]) & (tt <= t[ends[k]]) for k in long)]
            long = long[np.asarray(share) > 0.5] if len(long) else long
        elif topic in (GNSS_TOPIC, LOCAL_TOPIC):
            long = long[:0]
        if not len(long):
            continue
        k = int(long[np.argmax(dur[long])])
        val = ", ".join(f"{x:.6g}" for x in key[starts[k]])
        out.append(Finding(severity="warning", code="sensors.frozen", channel=topic, t0_s=float(t[starts[k]]),
                           t1_s=float(t[ends[k]]),
                           evidence=f"{len(long)} stretch(es) repeating one exact value; longest {dur[k]:.1f} s "
                                    f"({ends[k] - starts[k] + 1} records of {val})",
                           action="the sensor froze (or its driver republished its last value): check it; the "
                                  "stages treat the copies as measurements",
                           numbers={"frozen_s": float(dur[k]), "stretches": len(long)}))
    return out


def held(ctx: CheckContext) -> list[Finding]:
    """GNSS positions held between updates on a faster row grid (sample-and-hold)."""
    f = ctx.log.get(GNSS_TOPIC)
    if f is None or len(f) < FROZEN_MIN_SAMPLES:
        return []
    t = ctx.seconds(f.index)
    lat, lon = f["lat_deg"].to_numpy(float), f["lon_deg"].to_numpy(float)
    same = np.concatenate([[False], (lat[1:] == lat[:-1]) & (lon[1:] == lon[:-1])])
    share = float(same.mean())
    dt = np.diff(t)
    pos = dt[dt > 0]
    if share < HELD_MIN_REPEAT or not len(pos):
        return []
    row = float(np.median(pos))
    upd = np.diff(t[~same])
    if len(upd) < 5:
        return []
    med = float(np.median(upd))
    regular = float(np.mean(np.abs(upd - med) <= 0.5 * row + 0.05 * med))
    if med < 1.5 * row or regular < HELD_MIN_REGULAR:
        return []
    return [Finding(severity="warning", code="sensors.held", channel=GNSS_TOPIC, t0_s=float(t[0]), t1_s=float(t[-1]),
                    evidence=f"positions held between updates: {share:.0%} of {len(t)} fixes repeat the one before; "
                             f"they change every {med:.3g} s ({1 / med:.3g} Hz) in {1 / row:.3g} Hz rows "
                             f"({regular:.0%} of the changes regular)",
                    action="import from the source again (import keeps one row per real update) or drop the "
                           "repeats: the filter counts each fix as many times as it is held",
                    numbers={"repeat_share": share, "update_hz": 1 / med, "row_hz": 1 / row})]


def gnss_jumps(ctx: CheckContext) -> list[Finding]:
    """Positions that jump: a step of more than :data:`JUMP_MIN_M` whose speed (over at least the
    median interval) is beyond :data:`JUMP_FACTOR` x the track's 99th percentile speed and beyond
    :data:`JUMP_MIN_MPS`."""
    tr = ctx.track
    if tr is None or len(tr[0]) < 20:
        return []
    t, n, e = tr
    step = np.hypot(np.diff(n), np.diff(e))
    dt = np.diff(t)
    # over at least the typical interval: two records stamped a few microseconds apart (a pose
    # published by two nodes) are no speed; and a step smaller than JUMP_MIN_M is noise, not a jump
    v = step / np.maximum(dt, float(np.median(dt)))
    limit = max(JUMP_FACTOR * float(np.percentile(v, 99)), JUMP_MIN_MPS)
    bad = np.flatnonzero((v > limit) & (step > JUMP_MIN_M))
    if not len(bad):
        return []
    k = int(bad[np.argmax(step[bad])])
    topic = GNSS_TOPIC if GNSS_TOPIC in ctx.log else LOCAL_TOPIC
    return [Finding(severity="warning", code="sensors.gnss_jump", channel=topic, t0_s=float(t[bad[0]]),
                    t1_s=float(t[bad[-1] + 1]),
                    evidence=f"{len(bad)} step(s) between consecutive fixes faster than {limit:.1f} m/s "
                             f"({JUMP_FACTOR:g} x the 99th percentile {np.percentile(v, 99):.1f} m/s); largest "
                             f"{step[k]:.1f} m in {t[k + 1] - t[k]:.2f} s at {t[k + 1]:.1f} s",
                    action="multipath or a receiver reset: the estimate's innovation gate drops such fixes; "
                           "check the antenna's view of the sky",
                    numbers={"jumps": len(bad), "largest_m": float(step[k]), "at_s": float(t[k + 1]),
                             "limit_mps": limit})]


def gnss_quality(ctx: CheckContext) -> list[Finding]:
    """Fix quality, HDOP and satellites of ``/gnss/quality``: invalid fixes, high HDOP, few
    satellites (warnings), and which fix types the run had (an info; RTK lost on part of a
    run with RTK a warning)."""
    f = ctx.log.get(QUALITY_TOPIC)
    if f is None or not len(f):
        return []
    t = ctx.seconds(f.index)
    q = f["fix_quality"].to_numpy(np.int64) if "fix_quality" in f else np.full(len(f), -1)
    out = []
    kinds = {k: float(np.mean(q == k)) for k in sorted(set(q.tolist())) if k >= 0}
    if kinds:
        out.append(Finding(severity="info", code="sensors.gnss_quality", channel=QUALITY_TOPIC,
                           evidence="fix types: " + ", ".join(f"{FIX_TYPES.get(k, f'quality {k}')} {s:.0%}"
                                                              for k, s in kinds.items()),
                           numbers={f"share_{FIX_TYPES.get(k, str(k)).replace(' ', '_')}": s
                                    for k, s in kinds.items()}))
    invalid = np.flatnonzero(q == 0)
    if len(invalid):
        out.append(Finding(severity="warning", code="sensors.gnss_quality.invalid", channel=QUALITY_TOPIC,
                           t0_s=float(t[invalid[0]]), t1_s=float(t[invalid[-1]]),
                           evidence=f"{len(invalid)} of {len(q)} fixes flagged invalid (quality 0)",
                           action="the stages should not use them: import with the quality so they are dropped",
                           numbers={"invalid": len(invalid)}))
    rtk = np.isin(q, (4, 5))
    auto = np.isin(q, (1, 2))
    if rtk.mean() >= QUALITY_SHARE and auto.mean() >= QUALITY_SHARE:
        ia = np.flatnonzero(auto)
        out.append(Finding(severity="warning", code="sensors.gnss_quality.rtk_lost", channel=QUALITY_TOPIC,
                           t0_s=float(t[ia[0]]), t1_s=float(t[ia[-1]]),
                           evidence=f"RTK on {rtk.mean():.0%} of the fixes, autonomous/DGPS on {auto.mean():.0%}: "
                                    "the position noise changes from centimetres to metres",
                           action="check the correction link; the estimate sets each fix's noise from its quality",
                           numbers={"rtk_share": float(rtk.mean()), "autonomous_share": float(auto.mean())}))
    if "hdop" in f:
        hd = f["hdop"].to_numpy(float)
        ok = np.isfinite(hd)
        if ok.any():
            high = float(np.mean(hd[ok] > HDOP_HIGH))
            if high > QUALITY_SHARE:
                ih = np.flatnonzero(ok & (hd > HDOP_HIGH))
                out.append(Finding(severity="warning", code="sensors.gnss_quality.hdop", channel=QUALITY_TOPIC,
                                   t0_s=float(t[ih[0]]), t1_s=float(t[ih[-1]]),
                                   evidence=f"HDOP above {HDOP_HIGH:g} on {high:.0%} of the fixes (median "
                                            f"{np.median(hd[ok]):.2f}, max {np.max(hd[ok]):.1f})",
                                   action="poor satellite geometry: expect metres of position noise",
                                   numbers={"hdop_high_share": high, "hdop_median": float(np.median(hd[ok]))}))
    if "satellites" in f:
        s = f["satellites"].to_numpy(np.int64)
        ok = s >= 0
        if ok.any():
            low = float(np.mean(s[ok] < SATS_LOW))
            if low > QUALITY_SHARE:
                out.append(Finding(severity="warning", code="sensors.gnss_quality.satellites",
                                   channel=QUALITY_TOPIC,
                                   evidence=f"fewer than {SATS_LOW} satellites on {low:.0%} of the fixes "
                                            f"(min {int(s[ok].min())})",
                                   action="obstructed sky or a weak antenna",
                                   numbers={"low_share": low, "min_satellites": int(s[ok].min())}))
    return out


CHECKS = ((missing, ("sensors.missing",)), (rates_and_gaps, ("sensors.rate", "sensors.gaps")),
          (time_order, ("sensors.time_backwards",)), (dead_or_frozen, ("sensors.dead", "sensors.frozen")),
          (held, ("sensors.held",)), (gnss_jumps, ("sensors.gnss_jump",)), (gnss_quality, ("sensors.gnss_quality",)))
"""(function(ctx) -> findings, the checks it reports under: each a JUnit testcase)."""
