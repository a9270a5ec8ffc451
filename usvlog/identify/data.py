"""Arrays an identification needs, taken from one field log.

Thrust -> forces through the vessel's thruster map and geometry (the logged
``thrust_left_n``/``thrust_right_n`` when present), GPS fixes -> local NED about the
log's datum, compass headings; all times in seconds from the run's first thrust sample.
:func:`lag_thrust` puts the forces through a first-order thruster lag (the identifier's
``lag_s`` or ``fit_lag``; the vessel's ``[thrusters] lag_s`` is the simulated plant's).
GNSS and compass times are the stamps minus the sensor latency an estimate stored in the
log (``usvlog.estimate.latency.stored_delays``; ``with_delays`` sets a known one).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import pandas as pd

from .._jit import njit
from ..errors import ConfigError, InputError
from ..estimate.latency import stored_delays
from ..estimate.layout import COMPASS_TOPIC, GNSS_TOPIC, THRUST_TOPIC, VELOCITY_TOPIC, YAW_RATE_TOPIC
from ..estimate.problem import TAU_COLUMNS, THRUST_RECORDS, ThrustFrames
from ..log.fieldlog import FieldLog
from ..log.positions import LOCAL_TOPIC, local_positions, uses_local
from ..model.frames import Datum, geodetic_to_ned, ssa
from ..model.vessel import Vessel, default_vessel

DEFAULT_GPS_SIGMA_M = 1.5
DEFAULT_LOCAL_SIGMA_M = 0.3   # the estimate's local_noise_m: positions in metres from an INS or motion capture

INPUT_TOPICS = (THRUST_TOPIC, GNSS_TOPIC, COMPASS_TOPIC, VELOCITY_TOPIC, YAW_RATE_TOPIC, LOCAL_TOPIC)
"""The channels an identification reads: the thrust, and the sensors the kinematic smoother
(:func:`usvlog.estimate.estimate`) fuses. A verb that writes no copy of the log loads only
these (:func:`usvlog.io.mcap.read_log` ``topics=``): the derived channels of an estimate
(``/estimate/state``, ``/estimate/innovations``) or a simulation (``/truth/state``) are
never looked at and were most of the file's decoding."""
DEFAULT_COMPASS_SIGMA_RAD = math.radians(2.0)


@dataclass(frozen=True, kw_only=True)
class RunData:
    """One run as arrays (times in s from ``t0_ns``).

    ``t0_ns``: the run's first thrust sample, ns since the Unix epoch. ``t_thrust`` with
    ``tau_u`` (N) and ``tau_r`` (N m): the thrust, held over each step (the grid the model
    is integrated on). ``t_gps`` with ``n_gps``, ``e_gps`` (m about the log's datum) and
    ``sigma_gps`` (m, one sigma per fix and axis). ``t_compass`` with ``psi_compass``
    (rad, true heading wrapped to [-pi, pi)) and ``sigma_compass`` (rad).
    ``thrust_source``: ``"logged newtons"`` or how forces were made from commands;
    ``thrust_skipped``: non-finite thrust records skipped; ``source``: the log's name;
    ``gnss_delay_s``, ``compass_delay_s``: the latencies (s) taken off the GNSS and compass
    stamps (a record stamped t describes the boat at t - delay).
    """

    t0_ns: int
    t_thrust: np.ndarray      # grid the model is integrated on (thrust held over each step)
    tau_u: np.ndarray
    tau_r: np.ndarray
    t_gps: np.ndarray
    n_gps: np.ndarray
    e_gps: np.ndarray
    sigma_gps: np.ndarray      # one sigma per fix and axis, m
    t_compass: np.ndarray
    psi_compass: np.ndarray
    sigma_compass: np.ndarray  # rad
    thrust_source: str = "newton"   # "logged newtons" or the map used
    thrust_skipped: int = 0         # non-finite thrust records skipped
    source: str = ""
    gnss_delay_s: float = 0.0
    compass_delay_s: float = 0.0

    @property
    def duration_s(self) -> float:
        """Length of the thrust record in s."""
        return float(self.t_thrust[-1] - self.t_thrust[0])

    def thrust_index_at(self, t0: float) -> int:
        """Index of the thrust command in force at ``t0`` (s): the last sample at or before it (a
        log whose thrust and navigation are stamped apart, e.g. a ROS bag's, starts a free run
        between two commands); the first sample before the record."""
        return int(np.clip(np.searchsorted(self.t_thrust, t0 + 1e-9, side="right") - 1, 0, len(self.t_thrust) - 1))

    def window(self, t_lo: float, t_hi: float) -> RunData:
        """The part of the run in [t_lo, t_hi] (s), same time origin (views of the run's
        arrays where their times are sorted: :func:`within`)."""
        k, g, c = (within(t, t_lo, t_hi) for t in (self.t_thrust, self.t_gps, self.t_compass))
        return replace(self, t_thrust=self.t_thrust[k], tau_u=self.tau_u[k], tau_r=self.tau_r[k],
                       t_gps=self.t_gps[g], n_gps=self.n_gps[g], e_gps=self.e_gps[g],
                       sigma_gps=self.sigma_gps[g], t_compass=self.t_compass[c],
                       psi_compass=self.psi_compass[c], sigma_compass=self.sigma_compass[c])


def within(t: np.ndarray, t_lo: float, t_hi: float) -> slice | np.ndarray:
    """The samples of ``t`` in [t_lo, t_hi]: a slice when ``t`` is sorted (indexing with it
    gives views, not copies), else a mask; the same samples in the same order either way."""
    if len(t) and bool(np.all(t[1:] >= t[:-1])):
        return slice(int(np.searchsorted(t, t_lo, "left")), int(np.searchsorted(t, t_hi, "right")))
    return (t >= t_lo) & (t <= t_hi)


def thrust_forces(log: FieldLog, vessel: Vessel) -> tuple[np.ndarray, np.ndarray, np.ndarray, str]:
    """(t_ns, f_left, f_right, how): per-thruster forces in newtons.

    Parameters
    ----------
    log : FieldLog
        Must have ``/thrust/command``.
    vessel : Vessel
        Thruster map for records without logged ``thrust_left_n``/``thrust_right_n``.

    Returns
    -------
    t_ns : numpy.ndarray of int64
        Record times, ns since the Unix epoch.
    f_left, f_right : numpy.ndarray
        Port and starboard forces in N (NaN where a record is not finite).
    how : str
        ``"logged newtons"``, ``"newton"`` or ``"<map> map"``.

    Raises
    ------
    usvlog.errors.InputError
        If the log has no ``/thrust/command`` channel.
    usvlog.errors.ConfigError
        If commands cannot be converted with the vessel's thruster map.
    """
    fr = log["/thrust/command"]
    t_ns = np.asarray(fr.index, dtype=np.int64)
    fl = np.full(len(fr), np.nan)
    frr = np.full(len(fr), np.nan)
    if "thrust_left_n" in fr and "thrust_right_n" in fr:
        fl = np.asarray(fr["thrust_left_n"].to_numpy(), float).copy()
        frr = np.asarray(fr["thrust_right_n"].to_numpy(), float).copy()
    logged = np.isfinite(fl) & np.isfinite(frr)
    if logged.all():
        return t_ns, fl, frr, "logged newtons"
    # rows without logged forces: the commands through the thruster map
    units = fr["unit"].astype(str).to_numpy() if "unit" in fr else np.array(["newton"] * len(fr))
    need = ~logged
    try:
        fl[need], frr[need] = vessel.thrusters.forces_from_commands(
            fr["left"].to_numpy(float)[need], fr["right"].to_numpy(float)[need], units[need])
    except ConfigError as err:   # say which log and channel, and what would help
        raise ConfigError(f"{log.source or 'log'} /thrust/command: {err} (give --vessel with the boat's "
                          "thruster map)") from err
    how = "newton" if set(np.unique(units[need])) == {"newton"} else f"{vessel.thrusters.map} map"
    return t_ns, fl, frr, how


def run_data(log: FieldLog, vessel: Vessel | None = None) -> RunData:
    """Extract :class:`RunData` from a field log (needs thrust, GNSS and compass).

    Parameters
    ----------
    log : FieldLog
        Needs ``/thrust/command``, ``/gnss/fix`` and ``/compass/heading``.
    vessel : Vessel, optional
        Thruster map and geometry (default the log's vessel, else the built-in one).

    Returns
    -------
    RunData
        GNSS and compass samples inside the thrust record only, at their stamps minus the
        latencies stored in the log (:func:`usvlog.estimate.latency.stored_delays`).

    Raises
    ------
    usvlog.errors.InputError
        If a channel is missing, with fewer than 10 usable thrust samples, no valid GNSS fix, or fewer than 10
        fixes or headings inside the thrust record.
    """
    vessel = vessel or log.vessel or default_vessel()
    src = log.source or "log"
    t_ns, fl, frr, how = thrust_forces(log, vessel)
    # a bad record is skipped (counted): the command before it stays in force
    good = np.isfinite(fl) & np.isfinite(frr)
    skipped = int((~good).sum())
    if skipped:   # (copies of 100 Hz records only where needed: memory)
        t_ns, fl, frr = t_ns[good], fl[good], frr[good]
    if len(t_ns) < 10:
        raise InputError(f"{src} /thrust/command: only {len(t_ns)} samples")
    if not np.all(t_ns[1:] > t_ns[:-1]):   # in time order, the first record of a repeated stamp kept
        order = np.argsort(t_ns, kind="stable")
        t_ns, fl, frr = t_ns[order], fl[order], frr[order]
        keep = np.concatenate([[True], np.diff(t_ns) > 0])
        t_ns, fl, frr = t_ns[keep], fl[keep], frr[keep]
    tau_u, tau_r = vessel.thrusters.tau_from_forces(fl, frr)
    t0 = int(t_ns[0])

    delay = stored_delays(log)
    lp = local_positions(log) if uses_local(log) else None
    if lp is not None:   # positions in metres (an INS pose, motion capture) instead of fixes
        tg, n, e = lp.t_ns, lp.n_m, lp.e_m
        sig = np.where(np.isfinite(lp.var_m2), np.sqrt(lp.var_m2), DEFAULT_LOCAL_SIGMA_M)
        ok = np.ones(len(tg), bool)
    else:
        g = log["/gnss/fix"]
        tg = np.asarray(g.index, dtype=np.int64) - int(round(delay.get("gnss", 0.0) * 1e9))
        lat, lon = g["lat_deg"].to_numpy(float), g["lon_deg"].to_numpy(float)
        ok = np.isfinite(lat) & np.isfinite(lon)
        datum = log.datum
        if datum is None:
            if not ok.any():
                raise InputError(f"{src} /gnss/fix: no valid fix")
            datum = Datum(lat_deg=float(lat[ok][0]), lon_deg=float(lon[ok][0]))
        n, e, _ = geodetic_to_ned(lat, lon, 0.0, datum=datum)
        sig = np.full(len(g), DEFAULT_GPS_SIGMA_M)
        if "cov_nn_m2" in g and "cov_ee_m2" in g:
            var = 0.5 * (g["cov_nn_m2"].to_numpy(float) + g["cov_ee_m2"].to_numpy(float))
            good = np.isfinite(var) & (var > 0)
            if "cov_type" in g:
                good &= g["cov_type"].to_numpy() != 0
            sig[good] = np.sqrt(var[good])
    ok &= (tg >= t_ns[0]) & (tg <= t_ns[-1])

    c = log["/compass/heading"]
    tc = np.asarray(c.index, dtype=np.int64) - int(round(delay.get("compass", 0.0) * 1e9))
    hd = c["heading_rad"].to_numpy(float)
    sc = c["std_rad"].to_numpy(float) if "std_rad" in c else np.full(len(c), np.nan)
    sc = np.where(np.isfinite(sc) & (sc > 0), sc, DEFAULT_COMPASS_SIGMA_RAD)
    okc = np.isfinite(hd) & (tc >= t_ns[0]) & (tc <= t_ns[-1])
    if ok.sum() < 10 or okc.sum() < 10:
        raise InputError(f"{src}: too few GNSS fixes ({int(ok.sum())}) or compass headings "
                         f"({int(okc.sum())}) inside the thrust record")
    return RunData(t0_ns=t0, t_thrust=(t_ns - t0) / 1e9, tau_u=np.asarray(tau_u, float),
                   tau_r=np.asarray(tau_r, float), t_gps=(tg[ok] - t0) / 1e9, n_gps=n[ok], e_gps=e[ok],
                   sigma_gps=sig[ok], t_compass=(tc[okc] - t0) / 1e9, psi_compass=ssa(hd[okc]),
                   sigma_compass=sc[okc], thrust_source=how, thrust_skipped=skipped, source=src,
                   gnss_delay_s=delay.get("gnss", 0.0), compass_delay_s=delay.get("compass", 0.0))


def runs_and_lean_logs(logs: list[FieldLog], vessel: Vessel, keep_thrust: bool = False
                       ) -> tuple[list[RunData], list[FieldLog]]:
    """(:func:`run_data` of each log, each log without its ``/thrust/command`` channel). Raises what
    :func:`run_data` raises, for the first log that fails.

    Memory: the run's arrays are the fit's one copy of the 100 Hz thrust; the kinematic smoother
    and the free runs' logs take it from them (:func:`run_thrust`). ``keep_thrust`` (a fit that
    reads the logs' thrust itself: filter error) keeps the channel."""
    runs, lean = [], []
    for log in logs:
        runs.append(run_data(log, vessel))
        if not keep_thrust:
            log = log.copy()
            del log.channels[THRUST_TOPIC]
        lean.append(log)
    return runs, lean


def run_thrust(run: RunData, lo_ns: int | None = None, hi_ns: int | None = None,
               records: int = THRUST_RECORDS) -> ThrustFrames:
    """The run's thrust as the estimator takes a log's (:data:`usvlog.estimate.problem.ThrustFrames`):
    frames of ``records`` records with the surge force and yaw moment
    (:data:`~usvlog.estimate.problem.TAU_COLUMNS`) on their stamps (ns since the epoch), those
    stamped in [lo_ns, hi_ns] only when given. Made a frame at a time from the run's arrays, so
    the smoother needs no copy of the channel; the stamps are the log's own (``t0_ns`` plus the
    time in s, rounded to the ns: exact for runs of up to weeks)."""
    lo_ns = np.iinfo(np.int64).min if lo_ns is None else int(lo_ns)
    hi_ns = np.iinfo(np.int64).max if hi_ns is None else int(hi_ns)
    # the records' span in s, a little wide (their stamps in ns decide)
    i0 = int(np.searchsorted(run.t_thrust, (lo_ns - run.t0_ns) / 1e9 - 1e-6, "left"))
    i1 = int(np.searchsorted(run.t_thrust, (hi_ns - run.t0_ns) / 1e9 + 1e-6, "right"))

    def frames():
        for i in range(i0, i1, records):
            j = min(i + records, i1)
            t_ns = run.t0_ns + np.round(run.t_thrust[i:j] * 1e9).astype(np.int64)
            keep = (t_ns >= lo_ns) & (t_ns <= hi_ns)
            yield pd.DataFrame({TAU_COLUMNS[0]: run.tau_u[i:j][keep], TAU_COLUMNS[1]: run.tau_r[i:j][keep]},
                               index=pd.Index(t_ns[keep], name="t_ns"))
    return frames


@njit
def _lag_kernel(t, tau, lag_s, out):
    """Mean over each step [t[k], t[k+1]) of a first-order lag's response to ``tau[k]`` held
    there, into ``out``; the lag starts settled on the first command."""
    f = tau[0]
    for k in range(len(t)):
        dt = t[k + 1] - t[k] if k + 1 < len(t) else 0.0
        if dt <= 0.0:
            out[k] = f
            continue
        a = math.exp(-dt / lag_s)
        out[k] = tau[k] + (f - tau[k]) * (lag_s / dt) * (1.0 - a)
        f = tau[k] + (f - tau[k]) * a


def lag_thrust(run: RunData, lag_s: float) -> RunData:
    """The run with its surge force and yaw moment through a first-order lag.

    Parameters
    ----------
    run : RunData
        The run (thrust held over each step of ``t_thrust``).
    lag_s : float
        Time constant (s); 0 returns ``run`` itself.

    Returns
    -------
    RunData
        ``run`` with ``tau_u``, ``tau_r`` replaced by the mean over each step of the lagged
        force and moment (the lag settled on the first command).
    """
    if not lag_s > 0.0:
        return run
    t = np.ascontiguousarray(run.t_thrust, dtype=np.float64)
    out = []
    for tau in (run.tau_u, run.tau_r):
        y = np.empty(len(t))
        _lag_kernel(t, np.ascontiguousarray(tau, dtype=np.float64), float(lag_s), y)
        out.append(y)
    return replace(run, tau_u=out[0], tau_r=out[1])


def coarse_thrust(t, tau_u, tau_r, step_s: float):
    """Thrust held over steps of about ``step_s`` s: the mean of the held thrust over each
    (the same impulse), so a fit integrates one RK4 step per step instead of per record.

    Parameters
    ----------
    t : numpy.ndarray, shape (N,)
        Thrust times, s (each value held until the next).
    tau_u, tau_r : numpy.ndarray, shape (N,)
        Surge force (N) and yaw moment (N m).
    step_s : float
        Target step, s (the fit's integration step, its ``MAX_DT``).

    Returns
    -------
    (numpy.ndarray, numpy.ndarray, numpy.ndarray)
        Coarse times (a subset of ``t`` with its first and last) and the mean forces held from each.
    """
    dt = float(np.median(np.diff(t))) if len(t) > 1 else step_s
    k = max(1, int(step_s / max(dt, 1e-9) + 1e-9))
    if k == 1:
        return t, tau_u, tau_r
    idx = np.arange(0, len(t), k)
    if idx[-1] != len(t) - 1:
        idx = np.append(idx, len(t) - 1)
    out = [t[idx]]
    for tau in (tau_u, tau_r):
        cum = np.concatenate([[0.0], np.cumsum(tau[:-1] * np.diff(t))])[idx]
        mean = np.diff(cum) / np.maximum(np.diff(t[idx]), 1e-12)
        out.append(np.ascontiguousarray(np.append(mean, tau[-1])))
    return out[0], out[1], out[2]
