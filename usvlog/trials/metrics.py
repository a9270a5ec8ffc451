"""Metrics of each standard manoeuvre, measured on a :class:`~usvlog.trials.detect.Track`.

Pure functions: a track and the manoeuvre's times in, a :class:`~usvlog.trials.result.Manoeuvre`
out (or None when the track does not cover it). The definitions are in ``docs/manoeuvres.md``.

One-sigmas: a value read at one time (a position, a heading) takes the estimate's own
standard deviation there; a crossing time (the heading reaching 90 deg, the speed reaching a
threshold) takes the sigma of the crossing quantity over its rate of change; a mean over a
window takes the spread of the values over the square root of the number of independent
samples in it (one per :data:`CORRELATION_S`), combined with the estimate's mean sigma there
(reduced likewise). Errors at two times are treated as independent.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from .result import Manoeuvre, Metric

if TYPE_CHECKING:  # annotations only (detect imports this module)
    from .detect import Track

CORRELATION_S = 2.0
"""Samples of a state this far apart count as independent in a window's mean, s."""

EXECUTE_HEADING_S = 2.0
"""The execute heading is the mean heading over this long before the execute, s."""

APPROACH_S = 5.0
"""The approach speed is the mean speed over this long before the execute, s."""

STOP_FRACTION = 0.15
"""A coast-down has stopped when the surge speed is at most this fraction of the approach speed."""

STEADY_FRACTION = 0.3
"""A speed step's steady speed is the mean surge speed over this last fraction of the step."""


# -----------------------------------------------------------------------------
# helpers
# -----------------------------------------------------------------------------

def _window(track: Track, t0: float, t1: float) -> slice:
    i0 = int(np.searchsorted(track.t, t0))
    i1 = int(np.searchsorted(track.t, t1))
    return slice(i0, max(i1, i0 + 1))


def _mean(values: np.ndarray, est_std: np.ndarray, duration: float) -> tuple[float, float]:
    """Mean of ``values`` over a window of ``duration`` s and its one-sigma (see the module doc)."""
    values = np.asarray(values, float)
    if len(values) == 0:
        return math.nan, math.nan
    n_ind = max(1.0, duration / CORRELATION_S)
    spread = float(np.std(values)) if len(values) > 1 else 0.0
    est = float(np.mean(est_std)) if len(est_std) else 0.0
    return float(np.mean(values)), math.hypot(spread, est) / math.sqrt(n_ind)


def execute_heading(track: Track, t: float) -> float:
    """Heading at the execute (unwrapped, rad): the mean over the :data:`EXECUTE_HEADING_S` before ``t``."""
    w = _window(track, t - EXECUTE_HEADING_S, t)
    return float(np.mean(track.psi[w]))


def _execute_heading_std(track: Track, t: float) -> float:
    w = _window(track, t - EXECUTE_HEADING_S, t)
    return float(np.mean(track.psi_std[w]))


def _crossing(x: np.ndarray, level: float, i0: int, i1: int) -> float | None:
    """Fractional index of the first upward crossing of ``level`` by ``x`` in [i0, i1), or None."""
    seg = x[i0:i1]
    above = np.flatnonzero(seg >= level)
    if not len(above):
        return None
    k = int(above[0])
    if k == 0:
        return float(i0)
    a, b = seg[k - 1], seg[k]
    return i0 + k - 1 + (float((level - a) / (b - a)) if b != a else 1.0)


def _interp(a: np.ndarray, fi: float) -> float:
    i = int(math.floor(fi))
    if i >= len(a) - 1:
        return float(a[-1])
    f = fi - i
    return float(a[i] * (1 - f) + a[i + 1] * f)


def _pos_var(track: Track, i: int, axis: tuple[float, float]) -> float:
    """Variance of the position at sample ``i`` projected on the unit vector ``axis`` (n, e)."""
    return (axis[0] * track.n_std[i]) ** 2 + (axis[1] * track.e_std[i]) ** 2


def _rate(x: np.ndarray, t: np.ndarray, i: int, half_s: float = 0.5) -> float:
    """d x / d t at sample i, by a central difference over +-half_s."""
    j0 = int(np.searchsorted(t, t[i] - half_s))
    j1 = min(int(np.searchsorted(t, t[i] + half_s)), len(t) - 1)
    if j1 <= j0:
        return 0.0
    return float((x[j1] - x[j0]) / (t[j1] - t[j0]))


def _direction(sign: float) -> str:
    return "starboard" if sign > 0 else "port"


def _metrics(items: list[tuple[str, float, float]]) -> tuple[Metric, ...]:
    """Metrics from (name, value, std), leaving out the values that are not finite."""
    return tuple(Metric(n, float(v), float(s) if math.isfinite(s) else 0.0)
                 for n, v, s in items if v is not None and math.isfinite(v))


# -----------------------------------------------------------------------------
# turning circle
# -----------------------------------------------------------------------------

def turning_circle(track: Track, t0: float, t1: float) -> Manoeuvre | None:
    """Turning circle executed at ``t0`` (the differential applied), held until ``t1``.

    Axes at the execute: x along the execute heading, y towards the turn. Advance and
    transfer: x and y of the position (from the one at the execute) when the heading has
    turned 90 deg; tactical diameter: y at 180 deg; steady turning rate: the mean |r| from
    180 deg to ``t1``; steady turning diameter: 2 mean(speed) / steady rate there; speed
    loss: 100 (1 - steady speed / approach speed) %.

    Returns
    -------
    Manoeuvre or None
        None when the heading does not turn 180 deg within the track.
    """
    i0, i1 = track.at(t0), track.at(t1)
    psi0 = execute_heading(track, t0)
    s0 = _execute_heading_std(track, t0)
    sign = 1.0 if track.psi[i1] >= psi0 else -1.0
    turned = sign * (track.psi - psi0)
    x_ax = (math.cos(psi0), math.sin(psi0))
    y_ax = (-sign * math.sin(psi0), sign * math.cos(psi0))   # towards the turn
    n0, e0 = track.n[i0], track.e[i0]
    out: list[tuple[str, float, float]] = []
    at = {}
    for deg in (90, 180):
        fi = _crossing(turned, math.radians(deg), i0, i1 + 1)
        if fi is None:
            return None
        at[deg] = fi
    for deg, names in ((90, ("advance_m", "transfer_m")), (180, (None, "tactical_diameter_m"))):
        fi = at[deg]
        i = int(round(fi))
        dn, de = _interp(track.n, fi) - n0, _interp(track.e, fi) - e0
        x = dn * x_ax[0] + de * x_ax[1]
        y = dn * y_ax[0] + de * y_ax[1]
        r_abs = max(abs(track.r[i]), 1e-6)
        sig_t = math.hypot(track.psi_std[i], s0) / r_abs
        vn, ve = _rate(track.n, track.t, i), _rate(track.e, track.t, i)
        for name, val, ax, other in ((names[0], x, x_ax, y), (names[1], y, y_ax, x)):
            if name is None:
                continue
            v_ax = vn * ax[0] + ve * ax[1]
            var = _pos_var(track, i, ax) + _pos_var(track, i0, ax) + (v_ax * sig_t) ** 2 + (other * s0) ** 2
            out.append((name, val, math.sqrt(var)))
        out.append((f"time_to_{deg}_s", float(_interp(track.t, fi) - t0), sig_t))
    t180 = _interp(track.t, at[180])
    w = _window(track, t180, t1)
    dur = track.t[w][-1] - track.t[w][0] if len(track.t[w]) > 1 else 0.0
    rate, rate_s = _mean(sign * track.r[w], track.r_std[w], dur)
    spd, spd_s = _mean(track.speed[w], track.u_std[w], dur)
    out.append(("steady_turn_rate_degps", math.degrees(rate), math.degrees(rate_s)))
    if rate > 0:
        d = 2 * spd / rate
        out.append(("steady_turning_diameter_m", d, d * math.hypot(spd_s / max(spd, 1e-9), rate_s / rate)))
    wa = _window(track, t0 - APPROACH_S, t0)
    v_app, v_app_s = _mean(track.speed[wa], track.u_std[wa], APPROACH_S)
    if v_app > 0.05:
        loss = 100.0 * (1.0 - spd / v_app)
        out.append(("approach_speed_mps", v_app, v_app_s))
        out.append(("speed_loss_pct", loss, 100.0 * (spd / v_app) * math.hypot(spd_s / max(spd, 1e-9),
                                                                             v_app_s / v_app)))
    return Manoeuvre("turning_circle", float(t0), float(t1), _direction(sign), _metrics(out))


# -----------------------------------------------------------------------------
# zig-zag
# -----------------------------------------------------------------------------

def nominal_angle(measured_deg: float) -> float:
    """The zig-zag's nominal angle: the measured one rounded to a multiple of 5 deg when within
    2 deg of it (the angles trials use: 10, 15, 20, ...), else to the whole degree."""
    five = 5.0 * round(measured_deg / 5.0)
    return five if abs(measured_deg - five) <= 2.0 and five > 0 else float(round(measured_deg))


def zigzag(track: Track, switches: list[float], t_end: float) -> Manoeuvre | None:
    """Zig-zag executed at ``switches[0]``, the differential reversed at ``switches[1:]``, ended
    (the differential taken off or changed) at ``t_end``.

    Deviation: heading minus the execute heading. Checking angle: the mean |deviation| at the
    reversals; the zig-zag angle is its nominal value (:func:`nominal_angle`). Overshoot k:
    the largest |deviation| after reversal k (to the side it was on), before the heading turns
    back, minus the zig-zag angle. Initial turning time: execute to the first reversal;
    time to check: first reversal to the first heading extremum; period: twice the mean time
    between reversals.

    Returns
    -------
    Manoeuvre or None
        None when the first reversal's overshoot is not in the track.
    """
    te = switches[0]
    psi0 = execute_heading(track, te)
    s0 = _execute_heading_std(track, te)
    idx = [track.at(t) for t in switches[1:]]
    devs = np.array([track.psi[i] - psi0 for i in idx])
    checking = float(np.degrees(np.mean(np.abs(devs))))
    chk_s = math.degrees(math.hypot(float(np.std(np.abs(devs))) / math.sqrt(len(devs)),
                                    math.hypot(float(np.mean(track.psi_std[idx])), s0)))
    alpha = nominal_angle(checking)
    out: list[tuple[str, float, float]] = [("zigzag_angle_deg", alpha, 0.0), ("checking_angle_deg", checking, chk_s)]
    t_ext = []
    for k, i in enumerate(idx[:2]):
        side = float(np.sign(devs[k]))
        nxt = idx[k + 1] if k + 1 < len(idx) else track.at(t_end + 30.0)
        back = np.flatnonzero(side * track.r[i:nxt + 1] < 0)
        if not len(back):
            break
        j_end = i + int(back[0])
        seg = side * (track.psi[i:j_end + 1] - psi0)
        j = i + int(np.argmax(seg))
        over = math.degrees(float(seg.max())) - alpha
        name = ("first", "second")[k]
        out.append((f"{name}_overshoot_deg", over, math.degrees(math.hypot(track.psi_std[j], s0))))
        t_ext.append((j, j_end))
    r_at = abs(track.r[idx[0]])
    out.append(("initial_turning_time_s", track.t[idx[0]] - te,
                math.hypot(track.psi_std[idx[0]], s0) / max(r_at, 1e-6)))
    if not t_ext:
        return None
    j, j_end = t_ext[0]
    rdot = abs(_rate(track.r, track.t, j_end))
    out.append(("time_to_check_s", track.t[j_end] - track.t[idx[0]], track.r_std[j_end] / max(rdot, 1e-6)))
    sw = np.asarray(switches[1:], float)
    if len(sw) >= 2:
        gaps = np.diff(sw)
        spread = float(np.std(gaps)) / math.sqrt(len(gaps)) if len(gaps) > 1 else 0.0
        out.append(("period_s", 2 * float(np.mean(gaps)), 2 * spread))
    return Manoeuvre("zigzag", float(te), float(t_end), _direction(float(np.sign(devs[0]))), _metrics(out))


# -----------------------------------------------------------------------------
# speed steps, stop, pivot
# -----------------------------------------------------------------------------

def _step_response(track: Track, t0: float, t1: float) -> tuple[float, float, float, float, float]:
    """(speed before, steady speed, its sigma, time constant, its sigma) of a surge step at t0."""
    wb = _window(track, t0 - 1.0, t0)
    u0 = float(np.mean(track.u[wb]))
    dur = (t1 - t0) * STEADY_FRACTION
    ws = _window(track, t1 - dur, t1)
    uss, uss_s = _mean(track.u[ws], track.u_std[ws], dur)
    tau, tau_s = math.nan, math.nan
    if abs(uss - u0) > 0.05:
        sgn = 1.0 if uss > u0 else -1.0
        level = sgn * (u0 + (1 - math.exp(-1)) * (uss - u0))
        i0, i1 = track.at(t0), track.at(t1)
        fi = _crossing(sgn * track.u, level, i0, i1 + 1)
        if fi is not None:
            i = int(round(fi))
            tau = _interp(track.t, fi) - t0
            tau_s = math.hypot(track.u_std[i], (1 - math.exp(-1)) * uss_s) / max(abs(_rate(track.u, track.t, i)), 1e-6)
    return u0, uss, uss_s, tau, tau_s


def speed_steps(track: Track, steps: list[tuple[float, float, float]], unit: str = "N") -> Manoeuvre | None:
    """Consecutive steps of the common thrust, each (start s, end s, left + right thrust).

    Per step: the steady surge speed (mean over the last :data:`STEADY_FRACTION` of the step)
    and the time constant (from the step to 63.2 % of the change of surge speed). Metrics:
    the mean time constant and the top steady speed; the steps are the speed-thrust curve.
    """
    rows = []
    for (a, b, thrust) in steps:
        _u0, uss, uss_s, tau, tau_s = _step_response(track, a, b)
        rows.append({"start_s": float(a), "end_s": float(b), "thrust": float(thrust), "speed_mps": uss,
                     "speed_mps_std": uss_s, "time_constant_s": tau, "time_constant_s_std": tau_s})
    if not rows:
        return None
    taus = np.array([r["time_constant_s"] for r in rows])
    tau_sd = np.array([r["time_constant_s_std"] for r in rows])
    ok = np.isfinite(taus)
    out: list[tuple[str, float, float]] = []
    if ok.any():
        spread = float(np.std(taus[ok])) / math.sqrt(ok.sum()) if ok.sum() > 1 else 0.0
        out.append(("time_constant_s", float(np.mean(taus[ok])),
                    math.hypot(spread, float(np.sqrt(np.sum(tau_sd[ok] ** 2))) / ok.sum())))
    top = max(rows, key=lambda r: r["speed_mps"])
    out.append(("top_speed_mps", top["speed_mps"], top["speed_mps_std"]))
    out.append(("steps", float(len(rows)), 0.0))
    return Manoeuvre("speed_steps", float(steps[0][0]), float(steps[-1][1]), "", _metrics(out), tuple(rows), unit)


def stop(track: Track, t0: float, t1: float) -> Manoeuvre | None:
    """Stop / coast-down: both thrusters to zero at ``t0``, held until ``t1``.

    Stopped: the surge speed at most :data:`STOP_FRACTION` of the approach surge speed.
    Stopping time: execute to stopped; stopping distance (track reach): the distance
    travelled over ground until then; head reach: the displacement along the execute
    heading; coast-down time constant: execute to 1/e of the approach surge speed. Without
    a stop before ``t1`` only the time constant and the speed at ``t1`` are given.
    """
    wa = _window(track, t0 - EXECUTE_HEADING_S, t0)
    u0, u0_s = _mean(track.u[wa], track.u_std[wa], EXECUTE_HEADING_S)
    if not u0 > 0.05:
        return None
    i0, i1 = track.at(t0), track.at(t1)
    psi0 = execute_heading(track, t0)
    s0 = _execute_heading_std(track, t0)
    out: list[tuple[str, float, float]] = [("approach_speed_mps", u0, u0_s)]
    for name, frac in (("coast_time_constant_s", math.exp(-1)), ("stopping_time_s", STOP_FRACTION)):
        fi = _crossing(-track.u, -frac * u0, i0, i1 + 1)
        if fi is None:
            continue
        i = int(round(fi))
        sig_t = math.hypot(track.u_std[i], frac * u0_s) / max(abs(_rate(track.u, track.t, i)), 1e-6)
        out.append((name, _interp(track.t, fi) - t0, sig_t))
        if name == "stopping_time_s":
            sp = track.speed[i0:i + 1]
            reach = float(np.sum(0.5 * (sp[1:] + sp[:-1]) * np.diff(track.t[i0:i + 1])))
            ax = (math.cos(psi0), math.sin(psi0))
            dn, de = track.n[i] - track.n[i0], track.e[i] - track.e[i0]
            head = dn * ax[0] + de * ax[1]
            cross = -dn * ax[1] + de * ax[0]
            pos_s = math.sqrt(_pos_var(track, i, ax) + _pos_var(track, i0, ax))
            out.append(("stopping_distance_m", reach, math.hypot(pos_s, track.speed[i] * sig_t)))
            out.append(("head_reach_m", head, math.hypot(pos_s, cross * s0)))
    out.append(("end_speed_mps", float(track.u[i1]), float(track.u_std[i1])))
    return Manoeuvre("stop", float(t0), float(t1), "", _metrics(out))


def pivot(track: Track, t0: float, t1: float) -> Manoeuvre:
    """Pivot turn: thrusters of opposite signs from ``t0`` to ``t1``. Yaw rate and speed: the
    means over the second half of the hold; heading change: over the whole hold."""
    mid = 0.5 * (t0 + t1)
    w = _window(track, mid, t1)
    dur = t1 - mid
    rate, rate_s = _mean(track.r[w], track.r_std[w], dur)
    spd, spd_s = _mean(track.speed[w], track.u_std[w], dur)
    i0, i1 = track.at(t0), track.at(t1)
    turn = math.degrees(track.psi[i1] - track.psi[i0])
    out = [("yaw_rate_degps", abs(math.degrees(rate)), math.degrees(rate_s)), ("speed_mps", spd, spd_s),
           ("heading_change_deg", abs(turn), math.degrees(math.hypot(track.psi_std[i0], track.psi_std[i1])))]
    return Manoeuvre("pivot", float(t0), float(t1), _direction(rate), _metrics(out))


__all__ = ["APPROACH_S", "CORRELATION_S", "EXECUTE_HEADING_S", "STEADY_FRACTION", "STOP_FRACTION",
           "execute_heading", "nominal_angle", "pivot", "speed_steps", "stop", "turning_circle", "zigzag"]
