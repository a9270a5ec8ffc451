"""Run content: which model parameters the run can determine, and which manoeuvre to drive next.

From the smoothed over-ground states (the identification's own, :mod:`usvlog.identify.smooth`):

* surge (m, d11): the surge speed changes (its 5-95 % spread at least :data:`SURGE_SPREAD_MPS`,
  four times the smoothed speed's noise: speed steps, an acceleration or a coast-down) -> else
  "drive speed steps";
* yaw (Iz, d33): the yaw rate is excited as the identifier asks (rms at least
  :data:`YAW_RMS_DEG_S` and the heading spanning :data:`HEADING_SPAN_DEG`,
  :func:`usvlog.identify.ahead.excited` beyond its noise) -> else "drive a zig-zag";
* sway and coupling (d22, xg): sway is excited and the boat turns at speed (yaw rate over
  :data:`TURN_DEG_S` at more than :data:`SPEED_MPS`) for :data:`TURN_SHARE` of the run ->
  else "drive turning circles both ways at speed".

One info lists what is determined; one warning per part that is not, with the manoeuvre.
"""

from __future__ import annotations

import math

import numpy as np

from ..identify.ahead import NOISE, excited
from ..log.findings import Finding
from .common import CheckContext

SURGE_SPREAD_MPS = 0.2
YAW_RMS_DEG_S = 2.0
HEADING_SPAN_DEG = 30.0
TURN_DEG_S = 3.0
SPEED_MPS = 0.3
TURN_SHARE = 0.1


def excitation(ctx: CheckContext) -> list[Finding]:
    """What the run determines (module docstring)."""
    ks = ctx.states
    if ks is None:
        return [Finding(severity="info", code="content.excitation",
                        evidence="not judged: the run has no thrust, positions and heading together "
                                 "(identification needs all three)")]
    nu = ks.nu()
    u, v, r = nu[:, 0], nu[:, 1], nu[:, 2]
    spread = float(np.percentile(u, 95) - np.percentile(u, 5))
    r_rms = math.degrees(math.sqrt(float(np.mean(r ** 2))))
    span = math.degrees(float(np.ptp(ks.psi)))
    turning = float(np.mean((np.abs(r) > math.radians(TURN_DEG_S)) & (u > SPEED_MPS)))
    t0, t1 = float(ctx.run_seconds(ks.t[0])), float(ctx.run_seconds(ks.t[-1]))
    nums = {"surge_spread_mps": spread, "yaw_rate_rms_deg_s": r_rms, "heading_span_deg": span,
            "turning_at_speed_share": turning, "sway_std_mps": float(np.std(v))}
    parts = [
        ("m, d11", spread >= SURGE_SPREAD_MPS,
         f"surge speed spread {spread:.2f} m/s (5-95 %)",
         "drive speed steps: accelerate from rest, change the thrust in steps, and coast down"),
        ("Iz, d33", r_rms >= YAW_RMS_DEG_S and span >= HEADING_SPAN_DEG and excited(r, NOISE["r"]),
         f"yaw rate rms {r_rms:.1f} deg/s, heading span {span:.0f} deg",
         "drive a 20/20 zig-zag (full differential thrust one way until 20 deg off course, then the other)"),
        ("d22, xg", turning >= TURN_SHARE and excited(v, NOISE["v"]),
         f"turning at speed {turning:.0%} of the time, sway std {np.std(v):.2f} m/s",
         "drive turning circles both ways at speed"),
    ]
    got = [p for p in parts if p[1]]
    out = [Finding(severity="info", code="content.excitation", t0_s=t0, t1_s=t1,
                   evidence=("determines " + "; ".join(f"{name} ({why})" for name, _, why, _ in got)) if got
                   else "determines no model parameter", numbers=nums)]
    for name, ok, why, todo in parts:
        if not ok:
            out.append(Finding(severity="warning", code="content.next_manoeuvre", t0_s=t0, t1_s=t1,
                               evidence=f"{name} not determined: {why}", action=todo, numbers=nums))
    return out


CHECKS = ((excitation, ("content.excitation", "content.next_manoeuvre")),)
"""(function(ctx) -> findings, the checks it reports under)."""
