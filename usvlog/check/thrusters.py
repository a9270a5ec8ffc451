"""Thruster checks: left/right (or the moment's sign) swapped, surge thrust reversed, time
saturated, commands outside their stated range, and a deadband.

The command limits come from the unit: ``normalized`` -1..1, ``counts`` the range the import
used; ``pwm_us`` the vessel's neutral +- span and ``newton`` its reverse/forward force, when a
vessel is given or stored (else unknown: not judged).

The deadband check is deliberately simple: a stretch of at least :data:`DEADBAND_S` in
which both commands are small but not both zero (at most :data:`SMALL_COMMAND` of full
scale) and the boat's speed over ground (the smoothed states') stays under
:data:`STILL_MPS` says those commands did nothing (a boat that answers a command of a few
percent moves faster than that within seconds: 0.6 m/s x (1 - exp(-t / 6.6 s)) for 1.5 N
per thruster on the paper's vessel).
"""

from __future__ import annotations

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from ..estimate.core import THRUST_TOPIC
from ..identify.signs import surge_sign, thrust_yaw_sign
from ..log.findings import Finding
from .common import CheckContext

SATURATED_SHARE = 0.05
"""A thruster at its limit for more than this share of the run is a warning."""
AT_LIMIT = 0.005
"""A command within this share of the full range of its limit is at the limit."""
DEADBAND_S = 10.0
SMALL_COMMAND = 0.15
STILL_MPS = 0.1
MEDIAN_ROWS = 4096
"""The deadband's running median is taken over this many windows at a time."""


def limits(ctx: CheckContext, unit: str) -> tuple[float, float] | None:
    """(lowest, highest) command of the unit (module docstring), None when unknown."""
    th = ctx.vessel.thrusters
    if unit == "normalized":
        return -1.0, 1.0
    if unit == "pwm_us" and ctx.vessel_given:   # ESCs differ (1100-1900, 1000-2000 us): the boat's own only
        return th.pwm_neutral_us - th.pwm_span_us, th.pwm_neutral_us + th.pwm_span_us
    if unit == "counts":
        rng = (ctx.health.get("thrust") or {}).get("range")
        if isinstance(rng, (list, tuple)) and len(rng) == 2 and all(isinstance(x, (int, float)) for x in rng):
            return float(rng[0]), float(rng[1])
        return None
    if unit == "newton" and ctx.vessel_given:
        return -float(th.reverse_n), float(th.forward_n)
    return None


def signs(ctx: CheckContext) -> list[Finding]:
    """The yaw response to the differential thrust (left/right swapped?) and the surge response
    to the total thrust (commands reversed?), from the smoothed states
    (:mod:`usvlog.identify.signs`)."""
    ks, tau = ctx.states, ctx.tau_on_states
    if ks is None or tau is None:
        return []
    span = (float(ctx.run_seconds(ks.t[0])), float(ctx.run_seconds(ks.t[-1])))
    yaw = thrust_yaw_sign(ks.t, tau[1], ks.r)
    out = []
    nums = {"sign": yaw.sign, "correlation": yaw.correlation, "t_stat": yaw.t_stat}
    if yaw.sign < 0:
        out.append(Finding(severity="error", code="thrusters.swapped", channel=THRUST_TOPIC, t0_s=span[0],
                           t1_s=span[1], evidence=yaw.message,
                           action="map the channel named right to thrust_left and the one named left to "
                                  "thrust_right when importing (--column/--topic thrust_left=... thrust_right=...)",
                           numbers=nums))
    else:
        out.append(Finding(severity="info", code="thrusters.swapped", channel=THRUST_TOPIC, t0_s=span[0],
                           t1_s=span[1], evidence=yaw.message, numbers=nums))
    nu = ks.nu()
    surge = surge_sign(ks.t, tau[0], nu[:, 0])
    if surge.sign < 0:
        out.append(Finding(severity="warning", code="thrusters.reversed", channel=THRUST_TOPIC, t0_s=span[0],
                           t1_s=span[1], evidence=surge.message,
                           action="check the commands' direction (reversed ESC or propeller: reversed_left/right "
                                  "in the vessel file)",
                           numbers={"sign": surge.sign, "correlation": surge.correlation}))
    return out


def saturation_and_range(ctx: CheckContext) -> list[Finding]:
    """Share of the time each thruster sits at its limit; commands beyond the limits."""
    thr = ctx.thrust
    if thr is None:
        return []
    t, left, right, unit = thr
    lim = limits(ctx, unit)
    if lim is None:
        return []
    lo, hi = lim
    tol = AT_LIMIT * (hi - lo)
    dt = np.diff(t, append=t[-1])
    total = float(dt.sum()) or 1.0
    out = []
    for side, c in (("left", left), ("right", right)):
        ok = np.isfinite(c)
        at = ok & ((np.abs(c - hi) <= tol) | (np.abs(c - lo) <= tol))
        share = float(dt[at].sum() / total)
        if share > SATURATED_SHARE:
            i = np.flatnonzero(at)
            out.append(Finding(severity="warning", code="thrusters.saturated", channel=THRUST_TOPIC,
                               t0_s=float(t[i[0]]), t1_s=float(t[i[-1]]),
                               evidence=f"{side} thruster at its limit ({lo:g} or {hi:g} {unit}) {share:.0%} of "
                                        f"the time ({len(i)} commands)",
                               action="the controller had no margin: lower the speed set-point or the gains; an "
                                      "identification only learns the limits' force there",
                               numbers={"share": share, "lo": lo, "hi": hi}))
        beyond = ok & ((c > hi + tol) | (c < lo - tol))
        if beyond.any():
            i = np.flatnonzero(beyond)
            out.append(Finding(severity="warning", code="thrusters.out_of_range", channel=THRUST_TOPIC,
                               t0_s=float(t[i[0]]), t1_s=float(t[i[-1]]),
                               evidence=f"{len(i)} {side} commands outside {lo:g}..{hi:g} {unit} (from "
                                        f"{np.nanmin(c):.4g} to {np.nanmax(c):.4g})",
                               action="check the unit and the vessel's thruster limits (--thrust-unit, "
                                      "--thrust-range, forward_n/reverse_n)",
                               numbers={"count": len(i), "min": float(np.nanmin(c)), "max": float(np.nanmax(c))}))
    return out


def deadband(ctx: CheckContext) -> list[Finding]:
    """Small commands that moved nothing (module docstring)."""
    thr, ks = ctx.thrust, ctx.states
    if thr is None or ks is None:
        return []
    t, left, right, unit = thr
    lim = limits(ctx, unit)
    neutral = ctx.vessel.thrusters.pwm_neutral_us if unit == "pwm_us" else 0.0
    a, b = left - neutral, right - neutral
    np.abs(a, out=a)
    np.abs(b, out=b)
    # the largest command of either (NaN when neither has a finite one): np.nanmax of both together
    full = (max(abs(lim[0] - neutral), abs(lim[1] - neutral)) if lim is not None
            else float(np.fmax(np.fmax.reduce(a), np.fmax.reduce(b))))
    if not full > 0:
        return []
    tg, sog = ctx.run_seconds(ks.t), np.hypot(ks.vn, ks.ve)
    w = min(51, len(sog) // 2 * 2 - 1)   # running median over ~5 s: the smoothed speed's noise crosses 0.1 m/s
    if w >= 3:
        win = sliding_window_view(sog, w)   # a window's median at a time of MEDIAN_ROWS (not w copies of the run)
        sog = np.concatenate([np.full(w // 2, np.nan),
                              *(np.median(win[i:i + MEDIAN_ROWS], 1) for i in range(0, len(win), MEDIAN_ROWS)),
                              np.full(w // 2, np.nan)])
        sog[: w // 2], sog[-(w // 2):] = sog[w // 2], sog[-(w // 2) - 1]
    still = np.interp(t, tg, sog, left=np.nan, right=np.nan) < STILL_MPS
    small = (np.maximum(a, b) <= SMALL_COMMAND * full) & ((a > 0) | (b > 0)) & still
    out = []
    edges = np.flatnonzero(np.diff(small.astype(np.int8), prepend=0, append=0))
    for s, f in zip(edges[::2], edges[1::2]):
        t0, t1 = float(t[s]), float(t[f - 1])
        if t1 - t0 < DEADBAND_S:
            continue
        m = (tg >= t0) & (tg <= t1)
        speed = float(np.median(sog[m])) if m.any() else float("nan")
        if speed < STILL_MPS:
            cmax = float(np.max(np.maximum(a[s:f], b[s:f])))
            out.append(Finding(severity="warning", code="thrusters.deadband", channel=THRUST_TOPIC, t0_s=t0, t1_s=t1,
                               evidence=f"commands up to {cmax:.3g} {unit} from neutral ({cmax / full:.0%} of full "
                                        f"scale) for {t1 - t0:.1f} s left the boat at {speed:.2f} m/s",
                               action="a deadband (T200-class ESCs: about 1500 +- 25 us): give the vessel's thruster "
                                      "map one (thruster curve) or leave the stretch out of an identification",
                               numbers={"command_max": cmax, "speed_mps": float(speed), "duration_s": t1 - t0}))
    return out


CHECKS = ((signs, ("thrusters.swapped", "thrusters.reversed")),
          (saturation_and_range, ("thrusters.saturated", "thrusters.out_of_range")),
          (deadband, ("thrusters.deadband",)))
"""(function(ctx) -> findings, the checks it reports under)."""
