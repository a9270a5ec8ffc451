"""Building the filter's :class:`~usvlog.estimate.layout.Problem` from a log.

:func:`build_problem` turns a :class:`~usvlog.log.fieldlog.FieldLog` into arrays: the
positions (GNSS fixes made NED about the datum, or positions in metres from a local frame),
the headings, yaw rates and velocities over ground that are fused, the step grid (the output
grid plus every measurement time), the thrust held between its records, each fix's noise and
where it came from (:func:`gnss_noise_source`), and the sensors' latencies
(:func:`delayed_log`). Whether the heading is fused at all is decided by
:mod:`usvlog.estimate.modes`; the filter runs are :mod:`usvlog.estimate.run`'s.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable

import numpy as np
import pandas as pd

from ..errors import ConfigError, InputError
from ..log.fieldlog import FieldLog
from ..log.positions import LOCAL_TOPIC, local_positions, uses_local
from ..model.frames import Datum, geodetic_to_ned, ssa
from ..model.gnss_noise import gnss_sigma_from_quality, quality_name
from ..model.vessel import Vessel
from .kernels import (
    COMPASS,
    DYNAMIC,
    GNSS,
    KINEMATIC,
    KINEMATIC_SWAY,
    SENSOR_DIM,
    VELOCITY,
    YAW_RATE,
)
from .layout import (
    COMPASS_TOPIC,
    GNSS_TOPIC,
    QUALITY_TOPIC,
    THRUST_TOPIC,
    VELOCITY_TOPIC,
    YAW_RATE_TOPIC,
    Problem,
    _channel,
    _col,
    _where,
    chi2_quantile,
    gps_only_settings,
    initial_covariance,
    state_size,
    yaw_jump_variance,
)
from .modes import _alive, _heading_unusable, initial_course, still_heading
from .settings import EstimateSettings

PWM_NEUTRAL_US = 1500.0
"""RC pulse width (us) of a stopped thruster: the centre of a pwm_us command."""

TAU_COLUMNS = ("tau_u_n", "tau_r_nm")
"""Columns of a :data:`ThrustFrames` frame that gives the thrust as the surge force (N) and yaw
moment (N m) on the hull, used as they are (no thruster map)."""


def _thrust_tau(log: FieldLog, frame: pd.DataFrame, vessel: Vessel, command_units: bool = False):
    """(tau_u, tau_r, ok): forces from thrust_*_n, else from the command through the
    thruster map; ``ok`` marks the usable records (tau has one entry per usable one).

    ``command_units`` (the kinematic model, which uses the yaw moment only to find its steps,
    scale-free, when the vessel's map cannot turn the commands into newtons): a moment in
    command units instead, port minus starboard about the neutral command (pwm_us: 1500),
    so no thruster map is needed.

    A frame with ``tau_u_n`` and ``tau_r_nm`` columns gives the surge force (N) and yaw moment
    (N m) on the hull already (:data:`TAU_COLUMNS`: a fit's own thrust arrays, not a log's channel)."""
    if TAU_COLUMNS[0] in frame.columns and TAU_COLUMNS[1] in frame.columns:
        tu, tr = _col(frame, TAU_COLUMNS[0]), _col(frame, TAU_COLUMNS[1])
        ok = np.isfinite(tu) & np.isfinite(tr)
        return tu[ok], tr[ok], ok
    if command_units:
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


ThrustFrames = Callable[[], Iterable[pd.DataFrame]]
"""Gives a log's ``/thrust/command`` frames in time order, each time it is called: the whole
channel, or its consecutive time windows (a long log's channel read from its file a window at a
time; see :func:`build_problem`). A frame may hold the surge force and yaw moment instead
(:data:`TAU_COLUMNS`)."""

THRUST_RECORDS = 65_536
"""Thrust records turned into forces at a time (:func:`held_thrust`) when the problem is built from
a log's decoded channel: a window's arrays, not the channel's (its unit strings and forces made
whole were ~35 MB an hour of 100 Hz thrust at the build's peak). The same numbers for any cut."""


def in_windows(frame: pd.DataFrame, records: int = THRUST_RECORDS) -> ThrustFrames:
    """A decoded ``/thrust/command`` frame as :data:`ThrustFrames`: windows of ``records`` rows (views)."""
    return lambda: (frame.iloc[i:i + records] for i in range(0, len(frame), records))


def held_thrust(log: FieldLog, t_prev: np.ndarray, frames: ThrustFrames, vessel: Vessel,
                vessel_free: bool = False, out: np.ndarray | None = None) -> tuple[np.ndarray, int]:
    """(tau_u, tau_r) of each step held from the thrust record in force at its start, and the
    records skipped.

    Zero-order hold: a step that starts at ``t_prev[k]`` (ns, rising) uses the last usable
    record at or before it, 0 before the first; a bad record is skipped (the command before
    it stays in force). The frames are taken one at a time (memory: a frame, not the
    channel), the numbers the same for any cut of the channel into frames. ``vessel_free``
    (the kinematic model): commands the vessel's map cannot turn into newtons give every
    record's moment in command units instead (:func:`_thrust_tau`).

    Returns
    -------
    tuple
        (len(t_prev), 2) array in N and N m (or command units): ``out`` when given (filled, no
        copy made), and the count of records skipped.
    """
    out = np.zeros((len(t_prev), 2)) if out is None else out
    if vessel_free:
        try:
            return _hold(log, t_prev, frames(), vessel, False, out)
        except InputError:
            out[:] = 0.0
            return _hold(log, t_prev, frames(), vessel, True, out)
    return _hold(log, t_prev, frames(), vessel, False, out)


def _hold(log: FieldLog, t_prev: np.ndarray, frames: Iterable[pd.DataFrame], vessel: Vessel,
          command_units: bool, out: np.ndarray) -> tuple[np.ndarray, int]:
    """:func:`held_thrust` of the frames given, with forces or command units, into ``out`` (zeros)."""
    skipped, k, last = 0, 0, None
    for frame in frames:
        tu, tr, ok = _thrust_tau(log, frame, vessel, command_units)
        skipped += int((~ok).sum())
        tt = np.asarray(frame.index, dtype=np.int64)[ok]
        if not len(tt):
            continue
        # the steps starting up to this frame's last record: its records, or the one in force before it
        end = int(np.searchsorted(t_prev, tt[-1], side="right"))
        i = np.searchsorted(tt, t_prev[k:end], side="right") - 1
        before = (0.0, 0.0) if last is None else last
        out[k:end, 0] = np.where(i >= 0, tu[i], before[0])
        out[k:end, 1] = np.where(i >= 0, tr[i], before[1])
        k, last = end, (tu[-1], tr[-1])
    if last is not None:
        out[k:] = last
    return out, skipped


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


def build_problem(log: FieldLog, settings: EstimateSettings, vessel: Vessel,
                  thrust: ThrustFrames | None = None) -> Problem:
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
    thrust : callable, optional
        The log's ``/thrust/command`` in time windows (:data:`ThrustFrames`), for a log that
        does not hold it decoded (the same problem as from the channel whole); default the
        log's channel.

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
    if thrust is None:
        frame = _channel(log, THRUST_TOPIC, required=s.model == "dynamic")
        thrust = None if frame is None else in_windows(frame)
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
    del parts   # (memory: the sensors' pieces, and below each array's unsorted copy, go as soon as they can)
    order = np.lexsort((mkind, m_t))
    m_t = m_t[order]
    mkind = mkind[order]
    mz = mz[order]
    mR = mR[order]

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
    if thrust is not None:   # zero-order hold: the step ending at k uses the command in force at t[k-1]
        _, skipped["thrust"] = held_thrust(log, t_ns[:-1], thrust, vessel, vessel_free=s.model == "kinematic",
                                           out=taus[1:])

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
