"""Offline state estimation of one run: inputs from a FieldLog, the forward EKF, the
extended RTS smoother, innovation gating, process-noise tuning, results."""

from __future__ import annotations

import math
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from functools import cached_property
from statistics import NormalDist
from typing import Literal, overload

import numpy as np
import pandas as pd

from .._cpu import spare_cpu
from ..errors import ConfigError, InputError, UnusableResultError
from ..log.channels import StrCodes, channel_spec, frame_from_columns
from ..log.fieldlog import FieldLog, format_time
from ..log.positions import LOCAL_TOPIC, local_positions, uses_local
from ..log.status import EstimateStatus, set_estimate_status
from ..log.summary import health_from_provenance
from ..model.frames import Datum, geodetic_to_ned, ssa
from ..model.gnss_noise import gnss_sigma_from_quality, quality_name
from ..model.heading_offset import MIN_OFFSET_DEG, MIN_OFFSET_SIGMAS, HeadingOffset, detect_heading_offset
from ..model.vessel import Vessel, VesselParams, default_vessel
from . import kernels
from .kernels import (
    COMPASS,
    DYNAMIC,
    GNSS,
    KINEMATIC,
    KINEMATIC_SWAY,
    SENSOR_DIM,
    SENSORS,
    VELOCITY,
    YAW_RATE,
)
from .latency import META_LATENCY, DelayEstimate, find_delays, latency_record
from .settings import Q_R_KINEMATIC_NO_JUMPS, EstimateSettings

STATE_COLUMNS = ("n_m", "e_m", "psi_rad", "u_mps", "v_mps", "r_radps", "current_n_mps", "current_e_mps")
STATE_TOPIC = "/estimate/state"
INNOVATION_TOPIC = "/estimate/innovations"
GNSS_TOPIC, COMPASS_TOPIC, THRUST_TOPIC = "/gnss/fix", "/compass/heading", "/thrust/command"
YAW_RATE_TOPIC = "/imu/yaw_rate"   # fused without being asked for when no heading is
VELOCITY_TOPIC = "/gnss/velocity"  # speed and course over ground: fused by the kinematic model in NED
QUALITY_TOPIC = "/gnss/quality"    # GGA fix quality and HDOP: each fix's noise when it has no covariance
INPUT_TOPICS = (GNSS_TOPIC, COMPASS_TOPIC, THRUST_TOPIC, VELOCITY_TOPIC, YAW_RATE_TOPIC, QUALITY_TOPIC, LOCAL_TOPIC)
"""Every channel the estimator reads (the ``usvlog estimate`` verb decodes only these)."""

# initial one-sigma before the first measurements: n, e, psi, u, v, r, then the extra states
_P0_SIGMA = (10.0, 10.0, 0.5, 1.0, 1.0, 0.3)
_P0_EXTRA = {"kinematic": (0.3, 0.3, 0.3, 0.3), "dynamic": (0.3, 0.3)}  # accelerations (, k) / current
POSITION_STD_LIMIT_M = 1e4
"""A position one-sigma beyond this (m) is a filter that has lost the track, not an estimate
(the forward pass restarts from the measurements there, see ``kernels.forward``)."""

# random walk of the sway damping k of the kinematic model with sway damping, 1/s^3:
# a constant in effect
Q_SWAY_DAMPING = 1e-8


def state_size(settings: EstimateSettings) -> int:
    """9 for the kinematic model (n, e, psi, v_n, v_e, r, a_n, a_e, r_dot), 10 with sway
    damping (n, e, psi, u, v, r, a_x, a_y, r_dot, k), 6 or 8
    (with the current) for the dynamic one."""
    if settings.model == "kinematic":
        return 10 if settings.sway_damping else 9
    return 8 if settings.use_current else 6


def initial_covariance(settings: EstimateSettings) -> np.ndarray:
    """Initial state covariance before the first measurement, diagonal.

    One-sigma 10 m on n, e, 0.5 rad on psi, 1 m/s on the velocities, 0.3 rad/s on r and
    0.3 (SI units) on the extra states (accelerations, sway damping or current).

    Parameters
    ----------
    settings : EstimateSettings

    Returns
    -------
    numpy.ndarray
        Shape (nx, nx) with nx = :func:`state_size` (settings).
    """
    nx = state_size(settings)
    sig = (_P0_SIGMA + _P0_EXTRA[settings.model])[:nx]
    return np.diag(np.square(sig))


# -----------------------------------------------------------------------------
# inputs
# -----------------------------------------------------------------------------

@dataclass(frozen=True)
class Problem:
    """Everything the filter loops need, as arrays (shared by both paths)."""

    t_ns: np.ndarray        # (N,) step times
    is_grid: np.ndarray     # (N,) bool: an output time
    dts: np.ndarray         # (N,) s since the previous step (0 for the first)
    taus: np.ndarray        # (N, 2) tau_u, tau_r held over the step that ends at k
    qjump: np.ndarray       # (N,) yaw-acceleration variance added at step k (kinematic)
    m_t_ns: np.ndarray      # (M,) measurement times
    mstep: np.ndarray       # (M,) step index of each measurement
    mkind: np.ndarray       # (M,) GNSS / COMPASS / YAW_RATE
    mz: np.ndarray          # (M, 2)
    mR: np.ndarray          # (M, 3) R00, R01, R11
    x0: np.ndarray
    P0: np.ndarray
    prm: np.ndarray         # vessel parameters m, Iz, d11, d22, d33, xg
    model: int
    gates: np.ndarray       # (3,) NIS thresholds per sensor
    dropouts: tuple         # ((start_ns, duration_s), ...) GNSS gaps bridged by prediction
    skipped: dict = field(default_factory=dict)   # sensor -> records skipped (non-finite, out of range)
    mode: str = "gnss+compass"   # or "gps-only": no heading measurement fused
    mode_reason: str = ""        # why GNSS only (empty with a compass)
    gnss_noise: str = ""         # where the GNSS noise came from, in words (gnss_noise_source)

    @property
    def nx(self) -> int:
        """Number of states."""
        return len(self.x0)


def _where(log: FieldLog) -> str:
    return f"{log.source}: " if log.source else ""


@overload
def _channel(log: FieldLog, topic: str, required: Literal[True] = True) -> pd.DataFrame: ...
@overload
def _channel(log: FieldLog, topic: str, required: bool) -> pd.DataFrame | None: ...
def _channel(log: FieldLog, topic: str, required: bool = True) -> pd.DataFrame | None:
    frame = log.get(topic)
    if frame is None or len(frame) == 0:
        if required:
            have = ", ".join(log.topics) or "none"
            raise InputError(f"{_where(log)}channel {topic} is missing or empty "
                             f"(the estimator needs it; channels: {have})")
        return None
    t = np.asarray(frame.index, dtype=np.int64)
    back = np.flatnonzero(np.diff(t) < 0)
    if len(back):
        i = int(back[0]) + 1
        raise InputError(f"{_where(log)}channel {topic}: time goes backwards at message {i} "
                         f"({format_time(int(t[i]))} after {format_time(int(t[i - 1]))})")
    return frame


def _col(frame: pd.DataFrame, name: str, default=np.nan) -> np.ndarray:
    if name in frame.columns:
        return np.array(frame[name].to_numpy(), dtype=float)  # a writable copy
    return np.full(len(frame), default, dtype=float)


PWM_NEUTRAL_US = 1500.0
"""RC pulse width (us) of a stopped thruster: the centre of a pwm_us command."""


def _thrust_tau(log: FieldLog, frame: pd.DataFrame, vessel: Vessel, vessel_free: bool = False):
    """(tau_u, tau_r, ok): forces from thrust_*_n, else from the command through the
    thruster map; ``ok`` marks the usable records (tau has one entry per usable one).

    ``vessel_free`` (the kinematic model, which uses the yaw moment only to find its steps,
    scale-free): commands that the vessel's map cannot turn into newtons give a moment in
    command units instead, port minus starboard about the neutral command (pwm_us: 1500),
    so no thruster map is needed."""
    if vessel_free:
        try:
            return _thrust_tau(log, frame, vessel)
        except InputError:
            left, right = _col(frame, "left"), _col(frame, "right")
            units = frame["unit"].astype(str).to_numpy() if "unit" in frame.columns else np.full(len(frame), "")
            mid = np.where(units == "pwm_us", PWM_NEUTRAL_US, 0.0)
            ok = np.isfinite(left) & np.isfinite(right)
            return np.zeros(int(ok.sum())), (left - mid)[ok] - (right - mid)[ok], ok
    thr = vessel.thrusters
    fl, fr = _col(frame, "thrust_left_n"), _col(frame, "thrust_right_n")
    need = ~(np.isfinite(fl) & np.isfinite(fr))
    if need.any():
        units = frame["unit"].astype(str).to_numpy() if "unit" in frame.columns else np.full(len(frame), "newton")
        left, right = _col(frame, "left"), _col(frame, "right")
        try:
            fl[need], fr[need] = thr.forces_from_commands(left[need], right[need], units[need])
        except ConfigError as err:
            raise InputError(f"{_where(log)}channel {THRUST_TOPIC}: {err}") from err
    ok = np.isfinite(fl) & np.isfinite(fr)
    # a bad record is skipped: the command before it stays in force
    tu, tr = thr.tau_from_forces(fl[ok], fr[ok])
    return tu, tr, ok


DELAYED_TOPICS = {GNSS_TOPIC: "gnss_delay_s", "/gnss/velocity": "gnss_delay_s", COMPASS_TOPIC: "compass_delay_s"}
"""Channel -> the :class:`EstimateSettings` field holding its latency in s."""


def delayed_log(log: FieldLog, settings: EstimateSettings) -> FieldLog:
    """``log`` with each sensor's stamps moved back by its latency (a shallow copy; ``log``
    itself when there is none): a record stamped t describes the boat at t - delay.

    The channels of :data:`DELAYED_TOPICS` are shifted by the setting named there (s);
    the order of the records within a channel is kept.
    """
    shift = {t: int(round(getattr(settings, f) * 1e9)) for t, f in DELAYED_TOPICS.items()}
    shift = {t: ns for t, ns in shift.items() if ns and t in log.channels}
    if not shift:
        return log
    out = log.copy()
    for topic, ns in shift.items():
        frame = log.channels[topic]
        out.channels[topic] = frame.set_axis(pd.Index(np.asarray(frame.index, np.int64) - ns, name="t_ns"), axis=0)
    return out


def build_problem(log: FieldLog, settings: EstimateSettings, vessel: Vessel) -> Problem:
    """Collect the filter's inputs from a log: measurements, step grid, thrust, gates.

    GNSS fixes become NED positions about the log's datum (else its first valid fix),
    compass headings true hull headings; non-finite or out-of-range records are skipped
    and counted. The steps are the output grid (``settings.output_step_s``) plus every
    measurement time; thrust is held (zero-order) between its records. Measurement times
    are the stamps minus the sensor's latency (``gnss_delay_s``, ``compass_delay_s``).

    The heading is not fused (``mode`` "gps-only", ``mode_reason`` says why) when the log
    has none, the import's health audit judged it dead, it stays still while the track
    turns (:func:`still_heading`) or ``settings.gps_only``; the kinematic model then runs
    over ground in NED (:func:`gps_only_settings`), the start heading is the track's first
    course, and ``/imu/yaw_rate`` is fused when the log has it, and ``/gnss/velocity`` (speed
    and course over ground) by the kinematic model.

    Parameters
    ----------
    log : FieldLog
        Needs ``/gnss/fix``; ``/compass/heading`` unless GNSS only; ``/thrust/command`` for
        the dynamic model (optional for the kinematic one); ``settings.yaw_rate_topic`` if set.
    settings : EstimateSettings
    vessel : Vessel
        Thruster map for commands not in newtons and the model parameters.

    Returns
    -------
    Problem

    Raises
    ------
    usvlog.errors.InputError
        If a needed channel is missing or empty, its time goes backwards, it has no valid
        record, or thrust commands cannot be turned into forces.
    """
    s = settings
    log = delayed_log(log, s)   # latency: stamps -> the times the measurements describe
    comp = _channel(log, COMPASS_TOPIC, required=False)
    thrust = _channel(log, THRUST_TOPIC, required=s.model == "dynamic")
    if uses_local(log):   # positions in metres (an INS pose, motion capture): measured like fixes
        tg, n, e, Rg, gnss_noise, nbad = _local_measurements(log, s)
        skipped = {"gnss": nbad}
    else:
        # GNSS -> NED about the datum
        gps = _channel(log, GNSS_TOPIC)
        tg = np.asarray(gps.index, dtype=np.int64)
        lat, lon = _col(gps, "lat_deg"), _col(gps, "lon_deg")
        good = np.isfinite(lat) & np.isfinite(lon) & (np.abs(lat) <= 90) & (np.abs(lon) <= 180)
        if not good.any():
            raise InputError(f"{_where(log)}channel {GNSS_TOPIC}: no valid fix")
        datum = log.datum or Datum(lat_deg=float(lat[good][0]), lon_deg=float(lon[good][0]))
        n, e, _ = geodetic_to_ned(lat[good], lon[good], 0.0, datum=datum)
        tg = tg[good]
        skipped = {"gnss": int((~good).sum())}
        Rg, gnss_noise = _gnss_noise(log, gps, good, tg, s)

    parts = [(tg, GNSS, np.column_stack([n, e]), Rg)]
    mode_reason = _heading_unusable(log, comp, s)
    if not mode_reason:
        tc, psi, vc, skipped["compass"] = _compass_measurements(comp, s)
        mode_reason = still_heading(psi, tg, n, e)
    if not mode_reason:
        parts.append((tc, COMPASS, np.column_stack([psi, np.zeros(len(tc))]),
                      np.column_stack([vc, np.zeros(len(tc)), np.zeros(len(tc))])))
        psi0 = float(psi[0])
    else:
        psi0 = initial_course(tg, n, e)
    yaw_topic = s.yaw_rate_topic or (YAW_RATE_TOPIC if mode_reason and _alive(log, YAW_RATE_TOPIC) else None)
    yaw = _channel(log, yaw_topic) if yaw_topic else None
    if yaw is not None:
        ty = np.asarray(yaw.index, dtype=np.int64)
        ry = _col(yaw, "r_radps")
        gy = np.isfinite(ry)
        skipped["yaw_rate"] = int((~gy).sum())
        vy = np.full(gy.sum(), s.yaw_rate_noise_radps ** 2)
        parts.append((ty[gy], YAW_RATE, np.column_stack([ry[gy], np.zeros(gy.sum())]),
                      np.column_stack([vy, np.zeros(len(vy)), np.zeros(len(vy))])))
    vel = _channel(log, VELOCITY_TOPIC, required=False)
    if vel is not None and s.model == "kinematic" and mode_reason:   # (the NED model of gps_only_settings)
        parts.append(_velocity_measurements(vel, s, skipped))
    m_t = np.concatenate([p[0] for p in parts])
    mkind = np.concatenate([np.full(len(p[0]), p[1], np.int64) for p in parts])
    mz = np.concatenate([p[2] for p in parts])
    mR = np.concatenate([p[3] for p in parts])
    order = np.lexsort((mkind, m_t))
    m_t, mkind, mz, mR = m_t[order], mkind[order], mz[order], mR[order]

    # step grid: the output grid plus every measurement time
    t_start, t_end = int(m_t[0]), int(m_t[-1])
    step_ns = int(round(s.output_step_s * 1e9))
    # the grid's phase is that of the first stamp, whatever the latencies: moving it with a
    # delay would move the thrust's steps within the grid's (the likelihood would ripple)
    stamp = m_t + np.where((mkind == GNSS) | (mkind == VELOCITY), int(round(s.gnss_delay_s * 1e9)),
                           np.where(mkind == COMPASS, int(round(s.compass_delay_s * 1e9)), 0))
    t_start = t_start - (t_start - int(stamp.min())) % step_ns
    grid = t_start + step_ns * np.arange((t_end - t_start) // step_ns + 1, dtype=np.int64)
    grid = grid[grid >= m_t[0]]
    t_ns = np.sort(np.concatenate([grid, m_t]))    # union1d / isin, by sorting (several times faster)
    t_ns = t_ns[np.concatenate([[True], t_ns[1:] != t_ns[:-1]])]
    is_grid = np.zeros(len(t_ns), bool)
    is_grid[np.searchsorted(t_ns, grid)] = True
    mstep = np.searchsorted(t_ns, m_t)
    dts = np.diff(t_ns, prepend=t_ns[0]).astype(float) * 1e-9

    taus = np.zeros((len(t_ns), 2))
    skipped["thrust"] = 0
    if thrust is not None:
        tu, tr, ok = _thrust_tau(log, thrust, vessel, vessel_free=s.model == "kinematic")
        tt = np.asarray(thrust.index, dtype=np.int64)[ok]
        skipped["thrust"] = int((~ok).sum())
        # zero-order hold: the step ending at k uses the command in force at t[k-1]
        i = np.searchsorted(tt, t_ns[:-1], side="right") - 1
        has = (i >= 0) & (len(tt) > 0)
        i = np.clip(i, 0, max(len(tt) - 1, 0))
        if not len(tt):
            tu = tr = np.zeros(1)
        taus[1:, 0] = np.where(has, tu[i], 0.0)
        taus[1:, 1] = np.where(has, tr[i], 0.0)

    qjump = yaw_jump_variance(taus[:, 1], s)

    if mode_reason:
        s = gps_only_settings(s)
    nx = state_size(s)
    x0 = np.zeros(nx)
    x0[0], x0[1], x0[2] = n[0], e[0], psi0
    P0 = initial_covariance(s)
    gate = [chi2_quantile(s.gate_probability, m) for m in SENSOR_DIM]

    # GNSS gaps bridged by prediction: longer than 5 typical intervals and 1 s
    dtg = np.diff(tg)
    drop: tuple[tuple[int, float], ...] = ()
    if len(dtg):
        thr = max(5 * float(np.median(dtg)), 1e9)
        gi = np.flatnonzero(dtg > thr)
        drop = tuple((int(tg[i]), float(dtg[i]) * 1e-9) for i in gi)
    return Problem(t_ns=t_ns, is_grid=is_grid, dts=dts, taus=taus, qjump=qjump, m_t_ns=m_t, mstep=mstep, mkind=mkind,
                   mz=mz, mR=mR, x0=x0, P0=P0, prm=vessel.params.as_array(),
                   model=DYNAMIC if s.model == "dynamic" else KINEMATIC_SWAY if s.sway_damping else KINEMATIC,
                   gates=np.asarray(gate, float), dropouts=drop, skipped=skipped,
                   mode="gps-only" if mode_reason else "gnss+compass", mode_reason=mode_reason,
                   gnss_noise=gnss_noise)


QUALITY_MATCH_S = 0.5
"""A ``/gnss/quality`` record sets the noise of the fix nearest it within this (s)."""


def fix_quality_sigma(log: FieldLog, tg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One-sigma noise (m, NaN: the log says nothing) and GGA fix quality (-1: none) of each
    fix at times ``tg`` (ns), from the ``/gnss/quality`` record nearest in time (within
    :data:`QUALITY_MATCH_S`) through :func:`usvlog.model.gnss_noise.gnss_sigma_from_quality`."""
    sig, code = np.full(len(tg), np.nan), np.full(len(tg), -1, np.int64)
    qf = log.get(QUALITY_TOPIC)
    if qf is None or not len(qf) or not len(tg):
        return sig, code
    tq = np.asarray(qf.index, np.int64)
    order = np.argsort(tq, kind="stable")
    tq, q, h = tq[order], _col(qf, "fix_quality")[order], _col(qf, "hdop")[order]
    j = np.searchsorted(tq, tg)
    lo, hi = np.clip(j - 1, 0, len(tq) - 1), np.clip(j, 0, len(tq) - 1)
    j = np.where(np.abs(tq[lo] - tg) <= np.abs(tq[hi] - tg), lo, hi)
    near = np.abs(tq[j] - tg) <= QUALITY_MATCH_S * 1e9
    sig = np.where(near, gnss_sigma_from_quality(q[j], h[j]), np.nan)
    code = np.where(near & np.isfinite(q[j]), q[j], -1).astype(np.int64)
    return sig, code


def _local_measurements(log: FieldLog, s: EstimateSettings):
    """(t_ns, n, e, R (M, 3), noise in words, records skipped) of the local position channel:
    ``gps_noise_m`` when set, else each record's variance, else ``local_noise_m``."""
    lp = local_positions(log)
    if lp is None or not len(lp.t_ns):
        raise InputError(f"{_where(log)}channel {LOCAL_TOPIC}: no valid position")
    if s.gps_noise_m is not None:
        var, why = np.full(len(lp.t_ns), s.gps_noise_m ** 2), f"position noise as set: {s.gps_noise_m:g} m"
    else:
        own = np.isfinite(lp.var_m2)
        var = np.where(own, lp.var_m2, s.local_noise_m ** 2)
        why = (f"local position noise: its own variance on {100 * own.mean():.0f} % of records, "
               f"else {s.local_noise_m:g} m" if own.any() else
               f"local position noise {s.local_noise_m:g} m (the source gives none; --gps-noise sets it)")
    R = np.column_stack([var, np.zeros(len(var)), var])
    return lp.t_ns, lp.n_m, lp.e_m, R, f"positions from {LOCAL_TOPIC} ({lp.frame}); {why}", lp.skipped


def _gnss_noise(log: FieldLog, gps: pd.DataFrame, good: np.ndarray, tg: np.ndarray, s: EstimateSettings):
    """(R (M, 3) of the valid fixes, where it came from in words): ``gps_noise_m`` when set;
    else per fix its covariance columns, else its fix quality and HDOP (``/gnss/quality``),
    else ``gps_fallback_m``."""
    if s.gps_noise_m is not None:
        var = s.gps_noise_m ** 2
        Rg = np.column_stack([np.full(len(tg), var), np.zeros(len(tg)), np.full(len(tg), var)])
        return Rg, f"GNSS noise as set: {s.gps_noise_m:g} m on every fix"
    nn, ne, ee = (_col(gps, c)[good] for c in ("cov_nn_m2", "cov_ne_m2", "cov_ee_m2"))
    ok = np.isfinite(nn) & np.isfinite(ee) & (nn > 0) & (ee > 0)
    ne = np.where(np.isfinite(ne) & ok, ne, 0.0)
    fb = np.full(len(tg), s.gps_fallback_m ** 2)
    sig, code = fix_quality_sigma(log, tg) if not ok.all() else (np.full(len(tg), np.nan), None)
    byq = ~ok & np.isfinite(sig)
    if byq.any():
        fb = np.where(byq, sig * sig, fb)
    Rg = np.column_stack([np.where(ok, nn, fb), ne, np.where(ok, ee, fb)])
    return Rg, gnss_noise_source(ok, byq, sig, code, s.gps_fallback_m)


def gnss_noise_source(cov: np.ndarray, byq: np.ndarray, sig: np.ndarray, code: np.ndarray | None,
                      fallback_m: float) -> str:
    """Where the fixes' noise came from, in words: e.g. ``GNSS noise from fix quality: RTK
    fixed 3 cm on 95 % of fixes; the default 2 m on 5 %``.

    Parameters
    ----------
    cov, byq : numpy.ndarray
        (M,) bool: fixes with their own covariance; fixes whose noise is their fix quality's.
    sig : numpy.ndarray
        (M,) the fix-quality sigmas (m).
    code : numpy.ndarray or None
        (M,) GGA fix qualities.
    fallback_m : float
        The default one-sigma (m).
    """
    M = max(len(cov), 1)
    parts = []
    if cov.any():
        parts.append(f"the fixes' own covariance on {100 * cov.sum() / M:.0f} %")
    if byq.any() and code is not None:
        kinds, counts = np.unique(code[byq], return_counts=True)
        for k, c in sorted(zip(kinds.tolist(), counts.tolist()), key=lambda x: -x[1]):
            sd = float(np.median(sig[byq][code[byq] == k]))
            size = f"{100 * sd:.0f} cm" if sd < 1 else f"{sd:.2g} m"
            parts.append(f"fix quality {quality_name(k)} {size} on {100 * c / M:.0f} %")
    rest = ~(cov | byq)
    if rest.any():
        parts.append(f"the default {fallback_m:g} m on {100 * rest.sum() / M:.0f} %"
                     + (" (the log states no fix quality or covariance)" if not (cov.any() or byq.any()) else ""))
    return "GNSS noise from " + "; ".join(parts) + " of fixes"


def chi2_quantile(p: float, dof: int) -> float:
    """Quantile of the chi-square distribution with 1 or 2 degrees of freedom (the NIS
    gate of a scalar or 2-D measurement), in closed form: for 2, the exponential's
    -2 ln(1 - p); for 1, the square of the normal quantile of (1 - p) / 2 (as scipy's
    ``chi2.ppf`` to a few units in the last place, without importing scipy.stats).

    Parameters
    ----------
    p : float
        Probability in [0, 1]; 1 gives inf (no gate).
    dof : int
        1 or 2.

    Returns
    -------
    float
    """
    if p >= 1.0:
        return math.inf
    if p <= 0.0:
        return 0.0
    if dof == 2:
        return -2.0 * math.log1p(-p)
    if dof == 1:
        return NormalDist().inv_cdf(0.5 * (1.0 - p)) ** 2
    raise ValueError(f"chi2_quantile: {dof} degrees of freedom (1 or 2)")


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


def _velocity_measurements(vel: pd.DataFrame, s: EstimateSettings, skipped: dict):
    """(t_ns, GNSS, [v_n, v_e] in m/s, R) of the usable ``/gnss/velocity`` records (speed
    and course over ground; a record without a course is skipped and counted)."""
    sog, cog = _col(vel, "sog_mps"), _col(vel, "cog_rad")
    ok = np.isfinite(sog) & np.isfinite(cog) & (sog >= 0)
    skipped["gnss_velocity"] = int((~ok).sum())
    t = np.asarray(vel.index, dtype=np.int64)[ok]
    var = np.full(len(t), s.gnss_velocity_noise_mps ** 2)
    z = np.column_stack([sog[ok] * np.cos(cog[ok]), sog[ok] * np.sin(cog[ok])])
    return t, VELOCITY, z, np.column_stack([var, np.zeros(len(t)), var])


def _compass_measurements(comp: pd.DataFrame, s: EstimateSettings):
    """(t_ns, true heading of the hull in rad, variance in rad^2, records skipped) of the
    valid compass records."""
    tc = np.asarray(comp.index, dtype=np.int64)
    hd = _col(comp, "heading_rad")
    gc = np.isfinite(hd)
    if "reference" in comp.columns:
        magnetic = comp["reference"].astype(str).to_numpy() == "magnetic"
    else:
        magnetic = np.zeros(len(comp), bool)
    psi = ssa(hd + np.where(magnetic, s.declination_rad, 0.0) - s.compass_offset_rad)[gc]
    tc = tc[gc]
    if s.compass_noise_rad is not None:
        vc = np.full(len(tc), s.compass_noise_rad ** 2)
    else:
        sd = _col(comp, "std_rad")[gc]
        vc = np.where(np.isfinite(sd) & (sd > 0), sd, s.compass_fallback_rad) ** 2
    return tc, psi, vc, int((~gc).sum())


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


def gps_only_settings(settings: EstimateSettings) -> EstimateSettings:
    """The settings a GNSS-only run uses: the kinematic model over ground in NED (no sway
    damping: without a heading the sway is not observable), the dynamic model unchanged."""
    if settings.model == "kinematic" and settings.sway_damping:
        return replace(settings, sway_damping=False)
    return settings


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


def gps_only_start(log: FieldLog, settings: EstimateSettings, vessel: Vessel, pb: Problem) -> Problem:
    """``pb`` with a better start heading for the dynamic model run on GNSS alone.

    Without a compass the dynamic model's heading is observed only through the track, and
    a start heading far off (the course of the track's first 10 m leg, see
    :func:`initial_course`, is tens of degrees from the start heading of a boat that turns
    as it sets off) costs the forward pass a long transient the smoother does not fully
    undo. The start heading is instead the course over ground where the boat first moves,
    from the GNSS-only kinematic smoother (:func:`course_as_heading`) on the same
    measurements. Other problems are returned as they are.

    Parameters
    ----------
    log : FieldLog
        The run ``pb`` was built from.
    settings : EstimateSettings
        The settings ``pb`` was built with (latencies applied as they say).
    vessel : Vessel
    pb : Problem

    Returns
    -------
    Problem
        ``pb``, or a copy whose ``x0`` heading (rad) is that course.
    """
    if pb.mode != "gps-only" or pb.model != DYNAMIC:
        return pb
    ks = gps_only_settings(replace(settings, model="kinematic", current=None, sway_damping=False, tune=False,
                                   estimate_delays=(), gps_only=True, q_uv=None, q_r=None))
    kp = build_problem(log, ks, vessel)
    runner = run_fast if ks.fast else run_reference_path
    q = process_noise(ks)
    # smoothed over a head of the run reaching START_MARGIN_S beyond the first moving step
    # (doubled until it does): the whole run would cost as much as the estimate itself
    span = int(round(START_HEAD_S / ks.output_step_s))
    while True:
        k = min(span, len(kp.dts))
        raw = runner(head_problem(kp, k), q, ks.max_consecutive_rejects, True)
        vn, ve = raw.XS[:, kernels.X_VN], raw.XS[:, kernels.X_VE]
        moving = np.flatnonzero(vn * vn + ve * ve > COURSE_MIN_SPEED_MPS ** 2)
        t_left = (kp.t_ns[k - 1] - kp.t_ns[moving[0]]) * 1e-9 if len(moving) else 0.0
        if k == len(kp.dts) or t_left >= START_MARGIN_S:
            break
        span *= 2
    X, _, _ = course_as_heading(raw.XS, raw.SDs, raw.PBs, gyro=True)
    x0 = pb.x0.copy()
    x0[kernels.X_PSI] = X[0, kernels.X_PSI]
    return replace(pb, x0=x0)


START_HEAD_S = 120.0
"""First length (s) of the run smoothed for a GNSS-only dynamic start heading (:func:`gps_only_start`)."""
START_MARGIN_S = 30.0
"""That head reaches at least this far (s) beyond the boat's first moving step."""


def head_problem(pb: Problem, k: int) -> Problem:
    """The first ``k`` steps of a problem and their measurements (a shorter run)."""
    if k >= len(pb.dts):
        return pb
    sel = pb.mstep < k
    return replace(pb, t_ns=pb.t_ns[:k], is_grid=pb.is_grid[:k], dts=pb.dts[:k], taus=pb.taus[:k],
                   qjump=pb.qjump[:k], m_t_ns=pb.m_t_ns[sel], mstep=pb.mstep[sel], mkind=pb.mkind[sel],
                   mz=pb.mz[sel], mR=pb.mR[sel])


def yaw_jump_variance(tau_r: np.ndarray, settings: EstimateSettings) -> np.ndarray:
    """Variance added to the kinematic model's yaw acceleration at each step (N,).

    A boat's yaw acceleration jumps when its yaw moment does (a bang-bang zig-zag, a
    thruster reversal), which a random-walk r_dot follows only slowly. Where the log
    records the thrust, a step of the yaw moment by d between two steps adds the variance
    (yaw_jump_radps2 * d / max|tau_r|)^2: scale-free in the moment, so no vessel
    parameter enters; zero without thrust, for the dynamic model (which is driven by the
    thrust itself) and with yaw_jump_radps2 = 0."""
    q = np.zeros(len(tau_r))
    if settings.model != "kinematic" or settings.yaw_jump_radps2 == 0 or len(tau_r) < 3:
        return q
    scale = float(np.max(np.abs(tau_r[1:])))
    if scale > 0:
        q[2:] = np.square(settings.yaw_jump_radps2 * np.diff(tau_r[1:]) / scale)
    return q


def process_noise(settings: EstimateSettings, q_uv=None, q_r=None, q_c=None) -> np.ndarray:
    """Diagonal of the continuous process-noise intensity for the state layout: on the
    accelerations (kinematic) or on u, v, r and the current (dynamic).

    ``q_uv``, ``q_r``, ``q_c`` override the settings' values (units as in
    :class:`EstimateSettings`); returns an array of :func:`state_size` entries (0 on
    states without process noise)."""
    nx = state_size(settings)
    q = np.zeros(nx)
    i = 6 if settings.model == "kinematic" else 3
    q[i] = q[i + 1] = settings.q_uv_value if q_uv is None else q_uv
    q[i + 2] = settings.q_r_value if q_r is None else q_r
    if settings.model == "kinematic" and settings.sway_damping:
        q[9] = Q_SWAY_DAMPING
    if settings.model == "dynamic" and nx == 8:
        q[6] = q[7] = settings.q_current if q_c is None else q_c
    return q


# -----------------------------------------------------------------------------
# running the filter
# -----------------------------------------------------------------------------

@dataclass(frozen=True)
class RawRun:
    """Raw arrays of one filter (and smoother) run, on the steps of a :class:`Problem` asked for
    (every step, or the rows given to :func:`run_fast`: R of them).

    ``X``/``XS`` forward and smoothed states (R, nx), ``SDf``/``SDs`` their one-sigma,
    ``PBf``/``PBs`` their covariance block of states 2..4 (R, 3, 3; (0, 3, 3) when not
    asked for); ``innov`` (M, 4) [res_0, res_1, nis, log-likelihood term] per measurement,
    ``accepted`` (M,) 0 rejected / 1 accepted / 2 accepted after too many rejections;
    ``loglik`` their sum; ``resets`` (N,) the divergence guard's re-initialisations
    (``kernels.REINIT_*``, 0 none); ``first_bad`` the first step (of all N) whose forward or
    smoothed state or one-sigma is not finite or whose position one-sigma exceeds
    :data:`POSITION_STD_LIMIT_M`, -1 for none. Without the smoother the smoothed arrays are
    the forward ones.
    """

    X: np.ndarray          # forward posteriors (N, nx)
    SDf: np.ndarray        # their one-sigma
    PBf: np.ndarray        # their covariance block of states 2..4 (N, 3, 3)
    XS: np.ndarray         # smoothed (N, nx)
    SDs: np.ndarray
    PBs: np.ndarray
    innov: np.ndarray      # (M, 4)
    accepted: np.ndarray   # (M,) 0/1/2
    loglik: float
    resets: np.ndarray     # (N,) why the state was re-initialised at a step (kernels.REINIT_*), 0 for none
    first_bad: int = -1    # first step with an unusable state (see _check_finite), -1 for none


def run_fast(pb: Problem, q: np.ndarray, max_rej: int, smoother: bool, rows: np.ndarray | None = None,
             covariance_block: bool = True, columns: int | None = None, threads: bool | None = None,
             forward: bool = True) -> RawRun:
    """Forward EKF (and RTS smoother) with the numba-compiled kernels.

    Memory is that of the rows asked for, not of the steps: the smoother makes the forward
    posteriors again a block at a time from checkpoints of the forward pass (the same
    numbers; see :func:`smooth`).

    Parameters
    ----------
    pb : Problem
    q : numpy.ndarray
        Diagonal of the continuous process-noise intensity (:func:`process_noise`).
    max_rej : int
        Rejections in a row after which a sensor's next measurement is forced in.
    smoother : bool
        Run the smoother after the forward pass.
    rows : numpy.ndarray, optional
        (N,) bool: the steps whose states are returned (e.g. ``pb.is_grid``); default all.
    covariance_block : bool
        Return the covariance block of states 2..4 (``PBf``, ``PBs``).
    columns : int, optional
        Return the first ``columns`` states (and their one-sigma) only; default all.
    threads : bool, optional
        The smoother's two halves in two threads (:func:`smooth`; default: with more than one CPU).
    forward : bool
        Return the forward posteriors (``X``, ``SDf``, ``PBf``); False (with the smoother
        only): not stored, they have no rows (memory and time, when only the smoothed
        states are wanted; every other output is the same).

    Returns
    -------
    RawRun
    """
    if not (forward or smoother):
        raise ValueError("run_fast: without the smoother the forward posteriors are the result (forward=True)")
    N, nx, M = len(pb.dts), pb.nx, len(pb.mstep)
    nc = nx if columns is None else columns
    if rows is None:
        row = np.arange(N, dtype=np.int64)
    else:
        row = np.cumsum(rows, dtype=np.int64) - 1
        row[~np.asarray(rows, bool)] = -1
    R = int(row.max()) + 1 if N else 0
    npb = R if covariance_block else 0
    Rf = R if forward else 0
    X, SDf, PBf = np.empty((Rf, nc)), np.empty((Rf, nc)), np.empty((npb if forward else 0, 3, 3))
    C = -(-N // kernels.SMOOTH_BLOCK) if smoother else 0   # checkpoints, for the smoother
    CX, CP = np.empty((C, nx)), np.empty((C, nx, nx))
    CI, CF = np.empty((C, kernels.N_IST), np.int64), np.empty((C, kernels.NFS))
    innov = np.zeros((M, 4))
    acc = np.zeros(M, np.int8)
    resets = np.zeros(N, np.int8)
    bad_f, bad_s = np.full(1, -1, np.int64), np.full(1, -1, np.int64)
    args = (pb.x0, pb.P0, pb.dts, pb.taus, pb.qjump, pb.mstep, pb.mkind, pb.mz, pb.mR, pb.prm, pb.model, q, pb.gates,
            max_rej, POSITION_STD_LIMIT_M ** 2, reinit_nis(pb))
    ll = kernels.forward(*args, row if forward else np.empty(0, np.int64), X, SDf, PBf, innov, acc, resets,
                         CX, CP, CI, CF, bad_f)
    if smoother:
        XS, SDs, PBs = np.empty((R, nc)), np.empty((R, nc)), np.empty((npb, 3, 3))
        smooth(args, (innov, acc, resets, CX, CP, CI, CF), row, XS, SDs, PBs, bad_s, threads)
    else:
        XS, SDs, PBs = X, SDf, PBf
    bad = [int(b[0]) for b in (bad_f, bad_s) if b[0] >= 0]
    return RawRun(X, SDf, PBf, XS, SDs, PBs, innov, acc, float(ll), resets, min(bad) if bad else -1)


SMOOTH_BUFFERS = 4
"""Blocks' buffers the two-thread smoother holds (about 4.5 MB each for the 10-state model):
the re-runs may run this many blocks minus one ahead of the smoothing."""


def smooth(args: tuple, run: tuple, row: np.ndarray, XS: np.ndarray, SD: np.ndarray, PB: np.ndarray,
           bad: np.ndarray, threads: bool | None = None) -> None:
    """The extended RTS smoother after ``kernels.forward``, block by block from the end.

    Each block's forward posteriors are made again from its checkpoint
    (``kernels.smooth_rerun``) and smoothed backwards (``kernels.smooth_back``). With
    ``threads`` (default: when the machine has more than one CPU) two threads share the
    work: the smoothing goes block by block down the run in the calling thread, and the
    re-runs of the blocks before it (they depend only on their checkpoints) are taken by
    whichever thread is free, up to :data:`SMOOTH_BUFFERS` - 1 blocks ahead. The same
    numbers in the same order; the wall time of about half the work.

    Parameters
    ----------
    args : tuple
        The arguments ``kernels.forward`` took before its outputs (x0 .. reinit_nis).
    run : tuple
        Its innov, accepted, resets and checkpoints CX, CP, CI, CF.
    row : numpy.ndarray
        (N,) int64: the output row of each step, -1 for none.
    XS, SD, PB : numpy.ndarray
        Outputs: smoothed states (R, columns), their one-sigma and covariance block (R, 3, 3)
        or (0, 3, 3).
    bad : numpy.ndarray
        (1,) int64: the first step whose smoothed state is unusable, -1 for none.
    threads : bool, optional
        Share the blocks' re-runs and the smoothing between two threads (see above).
    """
    x0, dts, pos_var_limit = args[0], args[2], args[14]
    N, nx = len(dts), len(x0)
    blocks = -(-N // kernels.SMOOTH_BLOCK)
    bad[0] = -1
    if not blocks:
        return
    if threads is None:
        threads = spare_cpu() and blocks > 1
    buf = [kernels.SmoothBuffers(nx) for _ in range(min(SMOOTH_BUFFERS, blocks) if threads else 1)]
    xs, Ps, xpn, Ppn, Cn = np.zeros(nx), np.zeros((nx, nx)), np.zeros(nx), np.zeros((nx, nx)), np.zeros((nx, nx))
    resets = run[2]

    def rerun(c: int) -> None:
        b = buf[c % len(buf)]
        kernels.smooth_rerun(c, *args, *run, b.BX, b.BP, b.BXp, b.BPp, b.BC)

    def back(c: int) -> None:
        b = buf[c % len(buf)]
        kernels.smooth_back(c, N, resets, b.BX, b.BP, b.BXp, b.BPp, b.BC, xs, Ps, xpn, Ppn, Cn, pos_var_limit,
                            row, XS, SD, PB, bad)

    if not threads:
        for c in range(blocks - 1, -1, -1):
            rerun(c)
            back(c)
        return
    _shared_blocks(blocks, len(buf), rerun, back)


def _shared_blocks(blocks: int, nbuf: int, rerun: Callable[[int], None], back: Callable[[int], None]) -> None:
    """back(c) for c = blocks - 1 .. 0 in this thread, each after rerun(c); the reruns,
    from the last block down, taken by a second thread or by this one while the block it
    is to smooth is still being re-run. Block c uses buffer c % nbuf: its re-run waits for
    back(c + nbuf)."""
    cond = threading.Condition()
    todo = [blocks - 1]       # the next block to re-run
    low = [blocks]            # the lowest block smoothed so far
    done: set[int] = set()    # blocks re-run and not smoothed yet
    failed: list[BaseException] = []

    def take() -> int:        # (under cond) the next re-run whose buffer is free, or -1
        c = todo[0]
        if c < 0 or c + nbuf < low[0]:
            return -1
        todo[0] = c - 1
        return c

    def run_one(c: int) -> None:
        try:
            rerun(c)
        except BaseException as e:   # handed to the smoothing thread
            failed.append(e)
        with cond:
            done.add(c)
            cond.notify_all()

    def worker() -> None:
        while True:
            with cond:
                while (c := take()) < 0 and todo[0] >= 0 and not failed:
                    cond.wait()
            if c < 0:
                return
            run_one(c)

    with ThreadPoolExecutor(max_workers=1) as pool:
        helper = pool.submit(worker)
        try:
            for c in range(blocks - 1, -1, -1):
                while True:
                    with cond:
                        while c not in done and (own := take()) < 0 and not failed:
                            cond.wait()
                        if failed:
                            raise failed[0]
                        ready = c in done
                    if ready:
                        break
                    run_one(own)   # this block is still being re-run in the other thread: do one ahead
                back(c)
                with cond:
                    done.discard(c)
                    low[0] = c
                    cond.notify_all()
        finally:
            with cond:
                todo[0] = -1   # the helper stops (after the re-run it may be in)
                cond.notify_all()
        helper.result()


REINIT_GATE_FACTOR = 100.0
"""A GNSS fix forced in after ``max_consecutive_rejects`` rejections whose NIS exceeds this
many times its gate re-initialises the filter from the measurements (it lost the track)."""


def reinit_nis(pb: Problem) -> float:
    """NIS of a forced-in GNSS fix above which the filter restarts (0: never, the gate off)."""
    g = float(pb.gates[GNSS])
    return REINIT_GATE_FACTOR * g if math.isfinite(g) else 0.0


def forward_loglik(pb: Problem, q: np.ndarray, max_rej: int) -> float:
    """Innovation log-likelihood of the forward pass (no states stored)."""
    nx, M = pb.nx, len(pb.mstep)
    none = np.empty((0, nx))
    return float(kernels.forward(pb.x0, pb.P0, pb.dts, pb.taus, pb.qjump, pb.mstep, pb.mkind, pb.mz, pb.mR,
                                 pb.prm, pb.model, q, pb.gates, max_rej, POSITION_STD_LIMIT_M ** 2, reinit_nis(pb),
                                 np.empty(0, np.int64), none, none, np.empty((0, 3, 3)), np.zeros((M, 4)),
                                 np.zeros(M, np.int8), np.zeros(len(pb.dts), np.int8), none, np.empty((0, nx, nx)),
                                 np.empty((0, kernels.N_IST), np.int64), np.empty((0, kernels.NFS)),
                                 np.empty(1, np.int64)))


def run_reference_path(pb: Problem, q: np.ndarray, max_rej: int, smoother: bool, rows: np.ndarray | None = None,
                       covariance_block: bool = True, columns: int | None = None, forward: bool = True) -> RawRun:
    """As :func:`run_fast`, on the filterpy reference path (:mod:`.reference`): slow, for checks."""
    from .reference import run_reference  # heavy: filterpy and scipy.stats, only for the reference path

    params = VesselParams(**dict(zip(("m", "Iz", "d11", "d22", "d33", "xg"), map(float, pb.prm))))
    out = run_reference(pb.x0, pb.P0, pb.dts, pb.taus, pb.qjump, pb.mstep, pb.mkind, pb.mz, pb.mR, params,
                        pb.model == DYNAMIC, q, pb.gates, max_rej, smoother,   # (kinematic: by nx)
                        POSITION_STD_LIMIT_M ** 2, reinit_nis(pb))
    X, SDf, PBf, XS, SDs, PBs, innov, acc, ll, resets = out
    bad = np.flatnonzero(_unusable(X, SDf) | _unusable(XS, SDs))
    keep = slice(None) if rows is None else np.asarray(rows, bool)
    X, SDf, XS, SDs = (a[keep, :columns] for a in (X, SDf, XS, SDs))
    PBf, PBs = (PBf[keep], PBs[keep]) if covariance_block else (PBf[:0], PBs[:0])
    if not forward and smoother:
        X, SDf, PBf = X[:0], SDf[:0], PBf[:0]
    return RawRun(X, SDf, PBf, XS, SDs, PBs, innov, acc, float(ll), resets, int(bad[0]) if len(bad) else -1)


def _unusable(X: np.ndarray, SD: np.ndarray) -> np.ndarray:
    """(N,) bool: a state or one-sigma not finite, or a position one-sigma beyond
    :data:`POSITION_STD_LIMIT_M` (as ``kernels._bad_step``)."""
    with np.errstate(invalid="ignore"):
        finite = np.isfinite(X).all(axis=1) & np.isfinite(SD).all(axis=1)
        return ~finite | (SD[:, :2] > POSITION_STD_LIMIT_M).any(axis=1)


def tune_process_noise(pb: Problem, settings: EstimateSettings, max_steps: int = 60_000) -> dict:
    """q_uv, q_r (and q_current) maximising the forward innovation likelihood.

    Searched in log10 space with Nelder-Mead on the first ``max_steps`` steps.

    Parameters
    ----------
    pb : Problem
    settings : EstimateSettings
        Model and starting intensities.
    max_steps : int, default 60000
        Only this many filter steps enter the likelihood (speed).

    Returns
    -------
    dict
        ``q_uv``, ``q_r`` (and ``q_current`` with current states) in the units of
        :class:`EstimateSettings`, ``loglik`` at the optimum, ``evaluations``.
    """
    sub = head_problem(pb, max_steps)
    nx = pb.nx
    start = [math.log10(settings.q_uv_value), math.log10(settings.q_r_value)]
    if settings.model == "dynamic" and nx == 8:
        start.append(math.log10(settings.q_current))

    def cost(z):
        z = np.clip(z, -12, 2)
        q = process_noise(settings, *(10.0 ** z))
        return -forward_loglik(sub, q, settings.max_consecutive_rejects)

    from scipy.optimize import minimize  # heavy: scipy.optimize, only when tuning

    res = minimize(cost, np.array(start), method="Nelder-Mead",
                   options={"xatol": 0.05, "fatol": 0.5, "maxfev": 120})
    z = np.clip(res.x, -12, 2)
    out = {"q_uv": float(10 ** z[0]), "q_r": float(10 ** z[1])}
    if len(z) == 3:
        out["q_current"] = float(10 ** z[2])
    out["loglik"] = float(-res.fun)
    out["evaluations"] = int(res.nfev)
    return out


# -----------------------------------------------------------------------------
# results
# -----------------------------------------------------------------------------

@dataclass(frozen=True)
class SensorReport:
    """Measurement counts and consistency of one sensor in an estimate.

    ``sensor`` is ``gnss``, ``compass``, ``yaw_rate`` or ``gnss_velocity`` and ``dim`` its measurement
    dimension; ``forced`` counts measurements accepted after ``max_consecutive_rejects``
    rejections in a row (they are also in ``accepted``); ``mean_nis`` is the mean
    normalised innovation squared over the accepted ones (near ``dim`` for a consistent
    filter); ``skipped`` counts unusable records (non-finite or out of range), which are
    in neither count.
    """

    sensor: str
    dim: int
    accepted: int
    rejected: int
    forced: int        # accepted after max_consecutive_rejects rejections in a row
    mean_nis: float    # over accepted measurements (near ``dim`` for a consistent filter)
    skipped: int = 0   # records not usable (non-finite or out of range), not counted above

    def to_dict(self) -> dict:
        """The fields as a JSON-ready dict."""
        return {"sensor": self.sensor, "dim": self.dim, "accepted": self.accepted,
                "rejected": self.rejected, "forced": self.forced, "mean_nis": self.mean_nis,
                "skipped": self.skipped}


@dataclass(frozen=True)
class EstimateReport:
    """Summary of an estimate: model, size, sensors, GNSS dropouts, likelihood.

    Attributes
    ----------
    model : str
        ``kinematic`` or ``dynamic``.
    states : int
        Number of filter states.
    steps : int
        Filter steps (output grid plus measurement times).
    duration_s : float
        First to last measurement, s.
    sensors : tuple of SensorReport
        One per sensor present in the log.
    dropouts : tuple of (int, float)
        GNSS gaps bridged by prediction: (start in ns since the Unix epoch, duration in s).
    loglik : float
        Innovation log-likelihood of the forward pass.
    thrust_skipped : int
        Thrust records that could not be used.
    settings : dict
        The settings in effect (:meth:`EstimateSettings.to_dict` plus the vessel).
    tuned : dict or None
        Result of process-noise tuning (``q_uv``, ``q_r``, maybe ``q_current``,
        ``loglik``, ``evaluations``), None without tuning.
    mode : str
        ``gnss+compass``, or ``gps-only`` when no heading was fused.
    mode_reason : str
        Why GNSS only (empty with a compass).
    reinits : tuple of (int, str)
        Re-initialisations of the divergence guard: (time in ns since the Unix epoch, why).
    latency : tuple of DelayEstimate
        The sensor delays searched (``settings.estimate_delays``), empty without a search.
    heading_offset : dict or None
        The heading mounting offset: ``detected`` (:meth:`HeadingOffset.to_dict`, None
        without a heading to test), ``text`` (it in words), ``applied_deg`` (subtracted from
        the heading before fusion) and ``source`` (``auto``, ``given``, ``vessel file``, ``none``).
    sideslip : dict or None
        Over the moving parts of the estimate (speed > :data:`SIDESLIP_MIN_SPEED_MPS`):
        ``median_abs_deg`` (|atan2(v, u)|), ``median_u_mps``, ``median_abs_v_mps``,
        ``moving_s``; None when the boat never moves or no heading was fused.
    blocking : tuple of str
        Why the estimate must not be used (status ``failed``): an implausible sideslip, a
        mounting offset detected and not applied.
    gnss_noise : str
        Where the GNSS noise came from, in words (covariance, fix quality or the default).
    """

    model: str
    states: int
    steps: int
    duration_s: float
    sensors: tuple[SensorReport, ...]
    dropouts: tuple[tuple[int, float], ...]    # GNSS gaps bridged: (start t_ns, duration s)
    loglik: float
    thrust_skipped: int
    settings: dict
    tuned: dict | None = None
    mode: str = "gnss+compass"
    mode_reason: str = ""
    reinits: tuple[tuple[int, str], ...] = ()
    latency: tuple[DelayEstimate, ...] = ()
    heading_offset: dict | None = None
    sideslip: dict | None = None
    blocking: tuple[str, ...] = ()
    gnss_noise: str = ""

    @property
    def dropouts_bridged(self) -> int:
        """Number of GNSS gaps bridged by prediction."""
        return len(self.dropouts)

    def sensor(self, name: str) -> SensorReport:
        """The report of sensor ``name`` (``gnss``, ``compass``, ``yaw_rate``, ``gnss_velocity``).

        Raises
        ------
        KeyError
            If that sensor had no measurements.
        """
        for r in self.sensors:
            if r.sensor == name:
                return r
        raise KeyError(name)

    def consistency(self) -> list[str]:
        """Plain-word warnings from each sensor's NIS and gate (empty for a consistent run).

        The mean NIS of a sensor whose noise is stated right is its dimension; below a tenth
        of it the stated noise is far too large or the sensor does not move (a dead compass
        fused with a large sigma), above five times it the noise is understated, the sensor
        lags (latency) or the model does not fit; more than 20 % rejected by the gate says
        the sensor and the track disagree.

        Returns
        -------
        list of str
            One line per finding.
        """
        out = []
        for r in self.sensors:
            n = r.accepted + r.rejected
            if r.accepted and np.isfinite(r.mean_nis):
                if r.mean_nis < 0.1 * r.dim:
                    out.append(f"{r.sensor} NIS {r.mean_nis:.3f} (expected about {r.dim}): its noise is overstated "
                               "or it does not move - check the sensor")
                elif r.mean_nis > 5.0 * r.dim:
                    out.append(f"{r.sensor} NIS {r.mean_nis:.3g} (expected about {r.dim}): its noise is understated, "
                               "it lags (a latency), or the model does not fit")
            if n and r.rejected > 0.2 * n:
                out.append(f"{r.sensor}: {100.0 * r.rejected / n:.0f} % of its measurements rejected by the gate - "
                           "the sensor and the track disagree")
        return out

    def mode_notes(self) -> list[str]:
        """What the mode means for the estimate, in plain words (empty with a compass)."""
        if self.mode != "gps-only":
            return []
        if self.model == "kinematic":
            what = ("heading = course over ground while the boat moves (held below "
                    f"{COURSE_MIN_SPEED_MPS:g} m/s); sideslip is not observable without a heading (v = 0)")
        else:
            what = ("heading estimated through the vessel model from the thrust and the track (sideslip included), "
                    "starting from the course over ground where the boat first moves")
        return [f"GNSS only: {self.mode_reason}; {what}"]

    @property
    def status(self) -> str:
        """``failed`` with a :attr:`blocking` reason (not to be used: ``usvlog estimate`` exits 1),
        else ``degraded`` when GNSS only, re-initialised or a sensor is inconsistent, else ``ok``."""
        if self.blocking:
            return "failed"
        return "degraded" if self.status_reasons() else "ok"

    def status_reasons(self) -> list[str]:
        """Why the estimate failed or is degraded, in plain words (empty when ``ok``)."""
        out = list(self.blocking)
        if self.mode == "gps-only":
            out.append(f"gps-only: {self.mode_reason}")
        if self.reinits:
            first = self.reinits[0]
            out.append(f"{len(self.reinits)} re-initialisation{'s' if len(self.reinits) > 1 else ''} "
                       f"after divergence (first at {format_time(first[0])}: {first[1]})")
        return out + self.consistency()

    def to_dict(self) -> dict:
        """JSON-ready dict; dropouts carry ``start_ns``, a readable ``start`` and ``duration_s``;
        ``warnings`` are :meth:`consistency`'s plain-word findings, ``status`` and
        ``status_reasons`` as :attr:`status`, ``reinitialisations`` the guard's restarts
        (``t_ns``, ``time``, ``reason``)."""
        return {"status": self.status, "status_reasons": self.status_reasons(), "mode": self.mode,
                "mode_reason": self.mode_reason, "notes": self.mode_notes(),
                "reinitialisations": [{"t_ns": t, "time": format_time(t), "reason": r} for t, r in self.reinits],
                "warnings": self.consistency(), "model": self.model, "states": self.states, "steps": self.steps,
                "duration_s": self.duration_s, "sensors": {r.sensor: r.to_dict() for r in self.sensors},
                "dropouts_bridged": self.dropouts_bridged, "thrust_skipped": self.thrust_skipped,
                "dropouts": [{"start_ns": a, "start": format_time(a), "duration_s": d} for a, d in self.dropouts],
                "loglik": self.loglik, "settings": self.settings, "tuned": self.tuned,
                "latency": [d.to_dict() for d in self.latency], "heading_offset": self.heading_offset,
                "sideslip": self.sideslip, "gnss_noise": self.gnss_noise}

    def format(self) -> str:
        """Human-readable multi-line summary (what ``usvlog estimate`` prints)."""
        lines = [f"estimate ({self.model}, {self.states} states, {self.mode}): {self.steps} steps over "
                 f"{self.duration_s:.1f} s; status {self.status}"]
        lines += [f"  note: {x}" for x in self.mode_notes()]
        lines += [f"  FAILED: {x}" for x in self.blocking]
        if self.gnss_noise:
            lines.append(f"  {self.gnss_noise}")
        ho = self.heading_offset or {}
        if ho.get("text"):
            lines.append(f"  heading: {ho['text']}; applied {ho.get('applied_deg', 0.0):+.1f} deg "
                         f"({ho.get('source', 'none')})")
        if self.sideslip:
            sl = self.sideslip
            lines.append(f"  sideslip while moving: median |beta| {sl['median_abs_deg']:.1f} deg, median u "
                         f"{sl['median_u_mps']:.2f} m/s, |v| {sl['median_abs_v_mps']:.2f} m/s")
        for r in self.sensors:
            lines.append(f"  {r.sensor:8s} accepted {r.accepted:7d}  rejected {r.rejected:5d}"
                         f"  mean NIS {r.mean_nis:6.3f} (dim {r.dim})"
                         + (f"  forced {r.forced}" if r.forced else "")
                         + (f"  skipped {r.skipped}" if r.skipped else ""))
        if self.thrust_skipped:
            lines.append(f"  thrust records skipped: {self.thrust_skipped}")
        lines.append(f"  GNSS dropouts bridged: {self.dropouts_bridged}"
                     + "".join(f"\n    {format_time(a)}  {d:.1f} s" for a, d in self.dropouts))
        if self.tuned:
            lines.append("  tuned process noise: " + ", ".join(
                f"{k} {v:.3g}" for k, v in self.tuned.items() if k.startswith("q_")))
        if self.reinits:
            lines.append(f"  re-initialisations after divergence: {len(self.reinits)}"
                         + "".join(f"\n    {format_time(t)}  {r}" for t, r in self.reinits[:20])
                         + (f"\n    ... {len(self.reinits) - 20} more" if len(self.reinits) > 20 else ""))
        lines += [f"  {d.format()}" for d in self.latency]
        lines += [f"  warning: {w}" for w in self.consistency()]
        return "\n".join(lines)


def _state_frame(X: np.ndarray, SD: np.ndarray, PB: np.ndarray, t_ns: np.ndarray,
                 model: int) -> pd.DataFrame:
    """The /estimate/state frame (STATE_COLUMNS and their ``_std``) of states X, one-sigma SD
    (and, kinematic, the covariance block PB), built as one block of columns (one copy)."""
    n_out = 8 if (model == DYNAMIC and X.shape[1] == 8) else 6
    spec = channel_spec(STATE_TOPIC)
    names = spec.columns if spec is not None else [*STATE_COLUMNS, *(c + "_std" for c in STATE_COLUMNS)]
    row = {c: k for k, c in enumerate(names)}
    block = np.empty((len(names), len(X)))   # rows: the frame's columns
    for c in STATE_COLUMNS[n_out:]:
        block[row[c]] = block[row[c + "_std"]] = np.nan
    if model == KINEMATIC:  # NED velocity -> over-ground body velocity
        X, SD = X[:, :6].copy(), SD[:, :6].copy()
        X[:, 3], X[:, 4], SD[:, 3], SD[:, 4] = kernels.body_velocity(X[:, 2], X[:, 3], X[:, 4], PB)
    for i, c in enumerate(STATE_COLUMNS[:n_out]):
        block[row[c]] = X[:, i]
        block[row[c + "_std"]] = SD[:, i]
    return pd.DataFrame(block.T, index=pd.Index(np.asarray(t_ns, np.int64), name="t_ns"), columns=names, copy=False)


@dataclass(frozen=True)
class EstimateResult:
    """State estimate of a run.

    ``state``: smoothed (or forward, with the smoother off) state on the output grid,
    indexed by ``t_ns``; ``forward``: the forward filter alone, same columns (made when
    first asked for, see :attr:`forward`); ``innovations``: one row per measurement;
    ``report``: counts and consistency. For the kinematic model u, v are body velocities
    over ground; for the dynamic model they are the model's nu, relative to the water when
    current states are estimated.
    """

    state: pd.DataFrame
    innovations: pd.DataFrame
    report: EstimateReport
    settings: EstimateSettings
    vessel: Vessel | None = None
    _make_forward: Callable[[], pd.DataFrame] | None = field(default=None, repr=False, compare=False)

    @cached_property
    def forward(self) -> pd.DataFrame:
        """The forward filter's state alone, the columns of ``state`` on the same grid.

        Made on first access (then kept): with the smoother on, by running the forward pass
        again over the same problem (the very same numbers as the pass the smoother
        started from; about a third of the estimate's filter time), so that an estimate
        whose forward frame is never looked at (``usvlog estimate``) neither builds nor holds
        it; with the smoother off, a copy of ``state``.

        Returns
        -------
        pandas.DataFrame
            Columns as ``state`` (positions m, heading rad, velocities m/s and rad/s and
            their ``_std``), indexed by ``t_ns`` (ns since the Unix epoch).
        """
        make = self._make_forward
        if make is None:
            raise AttributeError("this EstimateResult was made without its forward filter")
        frame = make()
        object.__setattr__(self, "_make_forward", None)   # its problem arrays are let go
        return frame

    def to_dataframe(self) -> pd.DataFrame:
        """The state estimate ``state`` (not a copy): columns n_m, e_m, psi_rad, u_mps,
        v_mps, r_radps, current_n_mps, current_e_mps (NaN without current states) and a
        ``*_std`` one-sigma for each, indexed by t_ns (ns since the Unix epoch)."""
        return self.state

    def to_log(self, log: FieldLog) -> FieldLog:
        """A copy of ``log`` plus /estimate/state, /estimate/innovations, provenance and the
        estimate's status record (:mod:`usvlog.log.status`: ok or degraded, with reasons) and the
        sensor delays applied (metadata record ``usvlog.latency``, see
        :func:`usvlog.estimate.latency.stored_delays`)."""
        out = log.copy()
        out.set(STATE_TOPIC, self.state)
        out.set(INNOVATION_TOPIC, self.innovations)
        out.add_provenance(producer="usvlog estimate", source=log.source or "",
                           settings=self.report.settings,
                           vessel=self.vessel.name if self.vessel else "",
                           report={k: v for k, v in self.report.to_dict().items() if k != "settings"})
        set_estimate_status(out, EstimateStatus(status=self.report.status, mode=self.report.mode,
                                                reasons=tuple(self.report.status_reasons())))
        out.meta[META_LATENCY] = latency_record(self.settings, self.report.latency)
        return out


def _grid_frame(pb: Problem, X: np.ndarray, SD: np.ndarray, PB: np.ndarray) -> pd.DataFrame:
    """The state frame of a run's output rows (the grid's: X, SD, PB hold those rows only);
    a GNSS-only kinematic run's heading is its course (:func:`course_as_heading`)."""
    if pb.mode == "gps-only" and pb.model == KINEMATIC:
        X, SD, PB = course_as_heading(X, SD, PB, bool((pb.mkind == YAW_RATE).any()))
    return _state_frame(X, SD, PB, pb.t_ns[pb.is_grid], pb.model)


@dataclass(frozen=True)
class _ForwardFrame:
    """Makes the forward filter's frame of a run when called (for :attr:`EstimateResult.forward`):
    the forward pass over ``pb`` with process noise ``q`` again (picklable, unlike a closure)."""

    pb: Problem
    q: np.ndarray
    settings: EstimateSettings

    def __call__(self) -> pd.DataFrame:
        fwd = _output_run(self.pb, self.q, self.settings, smoother=False)
        return _grid_frame(self.pb, fwd.X, fwd.SDf, fwd.PBf)


def _divergence_hint(settings: EstimateSettings) -> str:
    """What to check after a divergence, by model."""
    if settings.model == "dynamic":
        return "check the thrust units and the sensors' noise, or use the kinematic model"
    return "check the process noise (q_uv, q_r) and the sensors' noise"


REINIT_LIMIT = 20
"""More re-initialisations than this in one run: the filter cannot recover (exit 1)."""


def _reinits(raw: RawRun, pb: Problem, settings: EstimateSettings, src: str) -> tuple[tuple[int, str], ...]:
    """The divergence guard's restarts as (t_ns, why); refuses a run that kept diverging.

    Raises
    ------
    usvlog.errors.UnusableResultError
        With more than :data:`REINIT_LIMIT` restarts, naming the first one and its reason.
    """
    k = np.flatnonzero(raw.resets)
    out = tuple((int(pb.t_ns[i]), kernels.REINIT_REASONS[int(raw.resets[i])]) for i in k[:1000])
    if len(k) > REINIT_LIMIT:
        t_s = (int(pb.t_ns[k[0]]) - int(pb.t_ns[0])) * 1e-9
        raise UnusableResultError(
            f"{src}: the {settings.model} estimate diverged and could not recover: re-initialised from the "
            f"measurements {len(k)} times (more than {REINIT_LIMIT}), first at t = {t_s:.1f} s from the start "
            f"({out[0][1]}); nothing written: " + _divergence_hint(settings))
    return out


def _check_finite(raw: RawRun, pb: Problem, settings: EstimateSettings, src: str) -> None:
    """Refuse a run whose states or one-sigmas are not finite, or whose position one-sigma
    exceeds :data:`POSITION_STD_LIMIT_M`: an estimate is finite or it is not returned.

    Raises
    ------
    usvlog.errors.UnusableResultError
        Naming the model, the first bad time (s from the start) and the largest
        innovation NIS before it.
    """
    if raw.first_bad < 0:
        return
    i = raw.first_bad
    t_s = (int(pb.t_ns[i]) - int(pb.t_ns[0])) * 1e-9
    before = pb.m_t_ns <= pb.t_ns[i]
    nis = raw.innov[before, 2] if before.any() else np.zeros(0)
    worst = f"; largest NIS before it {float(np.nanmax(np.abs(nis))):.3g}" if np.isfinite(nis).any() else ""
    raise UnusableResultError(
        f"{src}: the {settings.model} estimate diverged at t = {t_s:.1f} s from the start (state not finite or "
        f"position uncertainty beyond {POSITION_STD_LIMIT_M:g} m{worst}); nothing written: check the thrust "
        "units and the sensors' noise, or use the kinematic model")


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


def _solve(pb: Problem, settings: EstimateSettings, log: FieldLog, vessel: Vessel
           ) -> tuple[EstimateSettings, RawRun, dict | None, tuple[DelayEstimate, ...], Problem, np.ndarray]:
    """Settings in effect, the filter (and smoother) run, the tuning result, the sensor delays
    searched, the problem they give and the process noise, for one run (``pb`` built from
    ``log`` with ``settings``). With the smoother the run holds no forward posteriors
    (:func:`_output_run` makes them again when asked for)."""
    if pb.mode == "gps-only":
        settings = gps_only_settings(settings)
    if settings.model == "kinematic" and settings.q_r is None and not pb.qjump.any():
        settings = replace(settings, q_r=Q_R_KINEMATIC_NO_JUMPS)   # no thrust record
    latency: tuple[DelayEstimate, ...] = ()
    given = {"gnss": settings.gnss_delay_s, "compass": settings.compass_delay_s}

    def search_delays(st: EstimateSettings, q: np.ndarray):
        lat, st = find_delays(log, st, lambda lg, s_: forward_loglik(build_problem(lg, s_, vessel), q,
                                                                       s_.max_consecutive_rejects), given=given)
        return lat, st, gps_only_start(log, st, vessel, build_problem(log, st, vessel))

    pb = gps_only_start(log, settings, vessel, pb)
    tuned = None
    if settings.tune:
        if settings.estimate_delays:   # first the delays, so that the tuned noise does not absorb them
            latency, settings, pb = search_delays(settings, process_noise(settings))
        tuned = tune_process_noise(pb, settings)
        settings = replace(settings, q_uv=tuned["q_uv"], q_r=tuned["q_r"],
                           q_current=tuned.get("q_current", settings.q_current), tune=False)
    q = process_noise(settings)
    if settings.estimate_delays:   # (again) with the noise in effect
        latency, settings, pb = search_delays(settings, q)
    raw = _output_run(pb, q, settings, smoother=settings.smoother)
    return settings, raw, tuned, latency, pb, q


def _output_run(pb: Problem, q: np.ndarray, settings: EstimateSettings, smoother: bool) -> RawRun:
    """The run of the output frames: with the smoother, the smoothed states only (the forward
    posteriors not stored); without it, the forward ones."""
    runner = run_fast if settings.fast else run_reference_path
    # only what the output needs (memory): the grid's rows, the frame's states (the kinematic
    # model's accelerations too, for course_as_heading) and the covariance block of the NED model
    kinematic = pb.model == KINEMATIC
    return runner(pb, q, settings.max_consecutive_rejects, smoother, rows=pb.is_grid, covariance_block=kinematic,
                  columns=8 if kinematic or pb.nx == kernels.NX_DYNAMIC_CURRENT else 6, forward=not smoother)


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


SIDESLIP_MIN_SPEED_MPS = 0.5
"""Sideslip is judged where the estimated speed exceeds this (m/s)."""
SIDESLIP_MAX_DEG = 30.0
"""A median |sideslip| beyond this (deg) while moving is no boat's: a wrong heading."""
SIDESLIP_MIN_MOVING_S = 10.0
"""...judged only when the boat moved at least this long (s)."""


def sideslip_figures(state: pd.DataFrame) -> dict | None:
    """Median |atan2(v, u)| (deg), u and |v| (m/s) where the speed exceeds
    :data:`SIDESLIP_MIN_SPEED_MPS`, and how long that was (s); None when never."""
    u, v = state["u_mps"].to_numpy(), state["v_mps"].to_numpy()
    moving = np.hypot(u, v) > SIDESLIP_MIN_SPEED_MPS
    if not moving.any():
        return None
    t = np.asarray(state.index, np.int64)
    dt = float(np.median(np.diff(t))) * 1e-9 if len(t) > 1 else 0.0
    beta = np.degrees(np.abs(np.arctan2(v[moving], u[moving])))
    return {"median_abs_deg": float(np.median(beta)), "median_u_mps": float(np.median(u[moving])),
            "median_abs_v_mps": float(np.median(np.abs(v[moving]))), "moving_s": float(moving.sum() * dt)}


def heading_blocking(found: HeadingOffset | None, applied_rad: float, mode: str,
                     sideslip: dict | None) -> tuple[str, ...]:
    """Why an estimate whose heading was fused must not be used: a mounting offset detected
    and not applied (its heading-based velocities are wrong), a median sideslip beyond
    :data:`SIDESLIP_MAX_DEG` while moving; each with the likely fix."""
    if mode != "gnss+compass":
        return ()
    out = []
    missed = found is not None and found.decided and abs(
        math.degrees(float(ssa(found.offset_rad - applied_rad)))) > max(MIN_OFFSET_DEG,
                                                                       MIN_OFFSET_SIGMAS * found.std_deg)
    fix = (f"heading {found.describe()} (applied {math.degrees(applied_rad):+.1f} deg): rerun with "
           f"`usvlog estimate --heading-offset auto` (or --heading-offset {found.offset_deg:.1f}, or "
           "heading_offset_deg in the vessel file's [sensors])" if missed and found is not None else "")
    if missed:
        out.append(fix)
    if sideslip and sideslip["moving_s"] >= SIDESLIP_MIN_MOVING_S and sideslip["median_abs_deg"] > SIDESLIP_MAX_DEG:
        cause = ("the heading mounting offset above" if missed else
                 "a heading mounting offset or a wrong heading source (check --heading-offset, or --gps-only)")
        out.append(f"implausible sideslip: median |beta| {sideslip['median_abs_deg']:.0f} deg while moving (u "
                   f"{sideslip['median_u_mps']:.2f} m/s, |v| {sideslip['median_abs_v_mps']:.2f} m/s), no boat's; "
                   f"likely cause: {cause}")
    return tuple(out)


def estimate(log: FieldLog, settings: EstimateSettings = EstimateSettings(),
             vessel: Vessel | None = None) -> EstimateResult:
    """Estimate the state of a run (forward EKF, then the extended RTS smoother).

    ``vessel`` (dynamic model): defaults to the log's own vessel, else the built-in one.

    Parameters
    ----------
    log : FieldLog
        The run. Needs ``/gnss/fix`` (lat_deg, lon_deg, optional cov_*_m2); uses
        ``/compass/heading`` (heading_rad, optional std_rad and reference) unless it is
        missing, judged dead, still while the track turns or ``settings.gps_only`` (then
        GNSS only, see :func:`build_problem`); the dynamic model also needs
        ``/thrust/command`` (thrust_left_n / thrust_right_n in N, or commands through the
        vessel's thruster map). A compass the gate rejects more than
        :data:`COMPASS_REJECT_LIMIT` of the time is dropped and the run made again from
        GNSS alone; a filter that diverges is re-initialised from the measurements
        (counted in ``report.reinits``).
    settings : EstimateSettings, optional
        Model, noise, gating, smoother and tuning (default ``EstimateSettings()``: the
        kinematic model with the smoother on).
    vessel : Vessel, optional
        Model parameters and thruster map; not used by the kinematic model except to
        convert thrust commands for the yaw-jump term.

    Returns
    -------
    EstimateResult
        ``state`` on a grid of ``settings.output_step_s`` s from the first to the last
        measurement (positions in m about the log's datum or its first fix, heading in
        rad, velocities in m/s and rad/s), the forward filter, the innovations and a
        report. ``result.to_log(log)`` adds them to a copy of the log.

    Raises
    ------
    usvlog.errors.InputError
        If a needed channel is missing or empty, time goes backwards in one, it has no
        valid record, or thrust commands cannot be converted to forces.
    usvlog.errors.UnusableResultError
        If the filter kept diverging (more than :data:`REINIT_LIMIT` re-initialisations) or
        a state is still not finite or has a position one-sigma beyond
        :data:`POSITION_STD_LIMIT_M`: no estimate is returned rather than garbage.

    Examples
    --------
    >>> res = estimate(log, EstimateSettings(model="dynamic"))     # doctest: +SKIP
    >>> res.state[["n_m", "e_m", "psi_rad"]].head()                # doctest: +SKIP
    """
    if vessel is None:
        vessel = log.vessel or default_vessel()
    found = heading_offset_of(log, settings) if not settings.gps_only else None
    settings, offset_source = apply_heading_offset(settings, found, vessel)
    pb = build_problem(log, settings, vessel)
    run_settings, raw, tuned, latency, pb, q = _solve(pb, settings, log, vessel)
    why = _compass_disagrees(pb, raw)
    if why:   # a heading source the track contradicts: GNSS only
        settings = replace(settings, gps_only=True)
        pb = build_problem(log, settings, vessel)
        run_settings, raw, tuned, latency, pb, q = _solve(pb, settings, log, vessel)
        pb = replace(pb, mode_reason=why)
    settings = run_settings
    reinits = _reinits(raw, pb, settings, log.source or "log")
    _check_finite(raw, pb, settings, log.source or "log")
    state = _grid_frame(pb, raw.XS, raw.SDs, raw.PBs)
    gone = np.zeros((0, 0))   # the step arrays already in a frame are let go (memory): only innov is used below
    raw = replace(raw, X=gone, SDf=gone, PBf=gone, XS=gone, SDs=gone, PBs=gone)
    # the forward frame when first asked for: the forward pass made again, or (no smoother) the state's
    make_forward = _ForwardFrame(pb, q, settings) if settings.smoother else state.copy
    innov = frame_from_columns(
        {"sensor": StrCodes.of(SENSORS, pb.mkind),
         "res_0": raw.innov[:, 0].copy(), "res_1": raw.innov[:, 1].copy(), "nis": raw.innov[:, 2].copy(),
         "accepted": raw.accepted > 0},
        pb.m_t_ns, channel_spec(INNOVATION_TOPIC), copy=False)   # (fresh arrays: taken as they are)
    reps = []
    for k in range(len(SENSORS)):
        sel = pb.mkind == k
        if not sel.any():
            continue
        acc = raw.accepted[sel] > 0
        nis = raw.innov[sel, 2][acc]
        reps.append(SensorReport(sensor=SENSORS[k], dim=SENSOR_DIM[k], accepted=int(acc.sum()),
                                 rejected=int((~acc).sum()), forced=int((raw.accepted[sel] == 2).sum()),
                                 mean_nis=float(nis.mean()) if len(nis) else float("nan"),
                                 skipped=pb.skipped.get(SENSORS[k], 0)))
    sd = settings.to_dict()
    sd["vessel"] = vessel.name if settings.model == "dynamic" else None
    if settings.model == "dynamic":
        sd["vessel_params"] = vessel.params.to_dict()
    slip = sideslip_figures(state) if pb.mode == "gnss+compass" else None
    offset = {"detected": found.to_dict() if found is not None else None,
              "text": found.describe() if found is not None else "",
              "applied_deg": math.degrees(settings.compass_offset_rad), "source": offset_source}
    report = EstimateReport(model=settings.model, states=pb.nx, steps=len(pb.t_ns),
                            duration_s=float((pb.t_ns[-1] - pb.t_ns[0]) * 1e-9), sensors=tuple(reps),
                            dropouts=pb.dropouts, loglik=raw.loglik,
                            thrust_skipped=pb.skipped.get("thrust", 0), settings=sd, tuned=tuned,
                            mode=pb.mode, mode_reason=pb.mode_reason, reinits=reinits, latency=latency,
                            heading_offset=offset, sideslip=slip, gnss_noise=pb.gnss_noise,
                            blocking=heading_blocking(found, settings.compass_offset_rad, pb.mode, slip))
    return EstimateResult(state=state, innovations=innov, report=report, settings=settings, vessel=vessel,
                          _make_forward=make_forward)
