"""The checks made before any fit: logs the model cannot describe are refused, in plain words.

:meth:`usvlog.identify.identifier.Identifier.fit` runs them first: a propulsion outside the
twin-thruster model (:func:`_refuse_outside_model`), a heading or position channel judged dead
at import (:func:`_refuse_dead_channels`), and a thruster channel or yaw response of the wrong
sign (:func:`_refuse_wrong_signs`, on :mod:`usvlog.identify.signs`), each refused with the
fix. :func:`_excitation_warnings` says when the yaw was too little excited to determine the
yaw terms (a hint when every candidate failed, and a caveat of the verdict).
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import UnusableResultError
from ..log.fieldlog import FieldLog
from ..log.summary import propulsion_from_provenance
from .data import RunData
from .signs import channel_signs, surge_sign, thrust_yaw_sign
from .smooth import KinStates, thrust_on_grid


def _why_dead(health: dict, topic: str) -> str:
    why = ((health.get("channels") or {}).get(topic) or {}).get("why") or ""
    return why or "no reason recorded"


def _refuse_dead_channels(logs: list[FieldLog], health: list[dict]) -> None:
    """A channel the import judged dead and left out cannot be identified from: unusable, in plain words."""
    for log, h in zip(logs, health):
        dead = [t for t in (h.get("dead") or []) if t in ("/compass/heading", "/gnss/fix")
                and log.get(t) is None]
        if not dead:
            continue
        reasons = [f"{t} was judged dead at import ({_why_dead(h, t)}) and left out" for t in dead]
        if (h.get("thrust") or {}).get("force_scale") == "unknown":
            unit = (h.get("thrust") or {}).get("unit") or "unknown units"
            reasons.append(f"the thrust has no known force scale ({unit})")
        err = UnusableResultError(f"{log.source or 'log'}: identification unusable: " + "; ".join(reasons))
        err.reasons = reasons      # type: ignore[attr-defined]
        raise err


def _refuse_outside_model(logs: list[FieldLog]) -> None:
    """A log whose import found a propeller and rudder (or one thruster) is not the paper's
    twin-thruster boat: the model (3) with differential thrust cannot be fitted to it."""
    for log in logs:
        prop = propulsion_from_provenance(log.provenance)
        if prop is None:
            continue
        reasons = [str(prop["reason"])]
        err = UnusableResultError(f"{log.source or 'log'}: identification refused: " + reasons[0])
        err.reasons = reasons      # type: ignore[attr-defined]
        raise err


def _refuse_wrong_signs(runs: list[RunData], kin: list[KinStates], arm_m: float) -> list:
    """Sign checks of each run (:mod:`usvlog.identify.signs`) before any fit: the yaw rate against
    the differential thrust and the surge speed against the total thrust. A yaw response of the
    wrong sign is refused with the fix (a fit would find negative inertias, or a boat that does not
    exist, and say nothing of why). The surge check is recorded only: the sway-yaw coupling in the
    surge equation makes it far less certain (t ~ 6 against ~ 21 for yaw on a simulated run), and it
    was wrong on a short run of the paper's vessel."""
    checks = []
    for run, ks in zip(runs, kin):
        tu, tr = thrust_on_grid(run, ks.t)
        nu = ks.nu()
        yaw, surge = thrust_yaw_sign(ks.t, tr, nu[:, 2]), surge_sign(ks.t, tu, nu[:, 0])
        fl, fr = 0.5 * (tu + tr / arm_m), 0.5 * (tu - tr / arm_m)   # each channel's force again
        ch = channel_signs(ks.t, fl, fr, nu[:, 0], nu[:, 2])
        checks.append({"source": run.source, "yaw": yaw.to_dict(), "surge": surge.to_dict(),
                       "channels": ch.to_dict()})
        reasons = []
        if ch.verdict.endswith("reversed"):
            side = {"left reversed": "reversed_left = true", "right reversed": "reversed_right = true",
                    "both reversed": "reversed_left = true and reversed_right = true"}[ch.verdict]
            reasons.append(f"{ch.message}: set {side} in the vessel's [thrusters] (commands in PWM, counts or "
                           f"normalized) or negate that channel's recorded forces")
        elif yaw.sign < 0:
            reasons.append(f"{yaw.message}: map the channel named right to thrust_left and the one named left to "
                           f"thrust_right when importing (--column/--topic thrust_left=... thrust_right=...), or "
                           f"set the vessel's arm sign right")
        if reasons:
            err = UnusableResultError(f"{run.source or 'log'}: identification refused: " + "; ".join(reasons))
            err.reasons = reasons      # type: ignore[attr-defined]
            raise err
    return checks


def _excitation_warnings(kin: list[KinStates], force: bool = False) -> list[str]:
    r_rms = math.sqrt(np.mean(np.concatenate([k.r for k in kin]) ** 2))
    psi_span = max(float(np.ptp(k.psi)) for k in kin)
    if r_rms > math.radians(90.0):   # not a boat turning: the heading itself is bad
        return [f"yaw rate rms {math.degrees(r_rms):.0f} deg/s is no boat's: the heading record is bad "
                f"(a dead or noisy compass); Iz, d33, d22 and xg cannot be trusted"]
    if r_rms < math.radians(2.0) or psi_span < math.radians(30.0) or (
            force and (r_rms < math.radians(5.0) or psi_span < math.radians(90.0))):
        return [f"yaw barely excited (yaw rate rms {math.degrees(r_rms):.2f} deg/s, heading span "
                f"{math.degrees(psi_span):.0f} deg): Iz, d33, d22 and xg are not determined; "
                f"add a zig-zag run"]
    return []
