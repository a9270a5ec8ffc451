"""The paper's plant and sensor models -> synthetic field logs.

Runs the plant of :mod:`usvlog.sim.plant` (eqs. (1)-(3), RK4 or first-order like the paper's
Section IV, on the velocity relative to the water when there is a current) under the open-loop
scenarios' commands, compiled in windows of steps, then samples GPS
(10 Hz, noise, optional wandering bias, optional jumps and dropouts), compass
(20 Hz, noise, optional constant bias) and thrust commands (100 Hz). Everything
random comes from one seeded numpy Generator, so a seed reproduces a run bit for bit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
import pandas as pd

from .._jit import jitable, njit
from ..errors import ConfigError
from ..log.channels import StrCodes, channel_spec, frame_from_columns
from ..log.fieldlog import FieldLog, parse_time
from ..model.frames import Datum, ned_to_geodetic, ssa
from ..model.vessel import Vessel, default_vessel
from .plant import plant_advance, plant_form

DEFAULT_START_UTC = "2026-06-01T12:00:00+00:00"
DEFAULT_DATUM = Datum(lat_deg=43.4723, lon_deg=-80.5449, alt_m=0.0)  # a lake near Clearpath's home


@dataclass(frozen=True, kw_only=True)
class SensorSettings:
    """Sensor models: rates, noise (one sigma), biases, faults.

    Sensors sample the plant at its steps, so a rate is rounded to a whole number of
    integration steps.

    Parameters
    ----------
    gps_rate_hz : float, default 10.0
        GNSS fix rate, Hz (> 0).
    gps_noise_m : float, default 1.5
        White GNSS noise per axis (north, east), one sigma in m (>= 0).
    gps_bias_sigma_m : float, default 0.0
        Stationary one sigma of a slowly wandering (Gauss-Markov) GNSS bias, m (>= 0).
    gps_bias_tau_s : float, default 300.0
        Correlation time of that bias, s (> 0).
    gps_jumps : tuple of (float, float), default ()
        Single-fix outliers: (time in s from the start, size in m), random direction.
    gps_dropouts : tuple of (float, float), default ()
        Gaps without fixes: (start in s from the start, duration in s).
    compass_rate_hz : float, default 20.0
        Compass rate, Hz (> 0).
    compass_noise_deg : float, default 2.0
        White compass noise, one sigma in degrees (>= 0).
    compass_bias_deg : float, default 0.0
        Constant compass bias, degrees.
    thrust_rate_hz : float, default 100.0
        Rate of the recorded thrust commands, Hz (> 0).
    truth_rate_hz : float or None, default None
        Rate of ``/truth/state``, Hz (None: every integration step).
    gps_delay_s : float, default 0.0
        GNSS latency, s (>= 0): a fix describing the boat at t is stamped t + gps_delay_s.
    compass_delay_s : float, default 0.0
        Compass latency, s (>= 0), likewise.

    Raises
    ------
    usvlog.errors.ConfigError
        If a rate or time constant is not positive or a noise level is negative.
    """

    gps_rate_hz: float = 10.0
    gps_noise_m: float = 1.5
    gps_bias_sigma_m: float = 0.0      # stationary std of a slowly wandering (Gauss-Markov) bias
    gps_bias_tau_s: float = 300.0      # its correlation time
    gps_jumps: tuple[tuple[float, float], ...] = ()      # (time_s, size_m) single-fix outliers
    gps_dropouts: tuple[tuple[float, float], ...] = ()   # (start_s, duration_s): no fixes
    compass_rate_hz: float = 20.0
    compass_noise_deg: float = 2.0
    compass_bias_deg: float = 0.0
    thrust_rate_hz: float = 100.0
    truth_rate_hz: float | None = None   # rate of /truth/state (None: every integration step)
    gps_delay_s: float = 0.0             # latency: a fix describing time t is stamped t + delay
    compass_delay_s: float = 0.0

    def __post_init__(self):
        if self.truth_rate_hz is not None and not self.truth_rate_hz > 0:
            raise ConfigError(f"sensor setting truth_rate_hz = {self.truth_rate_hz} must be > 0")
        for name in ("gps_rate_hz", "compass_rate_hz", "thrust_rate_hz", "gps_bias_tau_s"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"sensor setting {name} = {getattr(self, name)} must be > 0")
        for name in ("gps_noise_m", "compass_noise_deg", "gps_bias_sigma_m", "gps_delay_s", "compass_delay_s"):
            if not getattr(self, name) >= 0:
                raise ConfigError(f"sensor setting {name} = {getattr(self, name)} must be >= 0")


@dataclass(frozen=True, kw_only=True)
class SimSettings:
    """What to simulate: vessel, duration, step, current, start time, datum, sensors.

    Parameters
    ----------
    vessel : Vessel, default default_vessel()
        Plant model and thrusters.
    duration_s : float, default 600.0
        Length of the run, s (> 0).
    dt_s : float, default 0.01
        Integration step, s, in (0, 1].
    integrator : {"rk4", "euler"}, default "rk4"
        ``euler`` is the paper's Section IV first-order integration.
    current_mps : float, default 0.0
        Water current speed, m/s (>= 0); the model acts on water-relative velocity.
    current_dir_deg : float, default 0.0
        Direction the water flows towards, degrees clockwise from north.
    start_utc : str, default "2026-06-01T12:00:00+00:00"
        ISO 8601 time of the first sample.
    datum : Datum, default DEFAULT_DATUM
        Origin of the local NED frame the positions are converted from.
    sensors : SensorSettings, default SensorSettings()
    eta0 : (float, float, float), default (0, 0, 0)
        Initial pose n (m), e (m), psi (rad).
    nu0 : (float, float, float), default (0, 0, 0)
        Initial velocity u (m/s), v (m/s), r (rad/s), relative to the water.

    Raises
    ------
    usvlog.errors.ConfigError
        If a value is out of range or ``start_utc`` is not ISO 8601.
    """

    vessel: Vessel = field(default_factory=default_vessel)
    duration_s: float = 600.0
    dt_s: float = 0.01
    integrator: str = "rk4"            # "rk4" or "euler" (the paper's Section IV)
    current_mps: float = 0.0
    current_dir_deg: float = 0.0       # direction the water flows towards, clockwise from north
    start_utc: str = DEFAULT_START_UTC
    datum: Datum = DEFAULT_DATUM
    sensors: SensorSettings = field(default_factory=SensorSettings)
    eta0: tuple[float, float, float] = (0.0, 0.0, 0.0)
    nu0: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self):
        if not (self.duration_s > 0 and math.isfinite(self.duration_s)):
            raise ConfigError(f"duration_s = {self.duration_s} must be > 0")
        if not (0 < self.dt_s <= 1.0):
            raise ConfigError(f"dt_s = {self.dt_s} must be in (0, 1]")
        if self.integrator not in ("rk4", "euler"):
            raise ConfigError(f"integrator {self.integrator!r} is not rk4 or euler")
        if not (self.current_mps >= 0 and math.isfinite(self.current_mps)):
            raise ConfigError(f"current_mps = {self.current_mps} must be >= 0")
        start_ns(self.start_utc)

    @property
    def current_ne(self) -> tuple[float, float]:
        """Current as (north, east) velocity, m/s."""
        a = math.radians(self.current_dir_deg)
        return self.current_mps * math.cos(a), self.current_mps * math.sin(a)

    @property
    def n_steps(self) -> int:
        """Number of integration steps, round(duration_s / dt_s)."""
        return int(round(self.duration_s / self.dt_s))


def start_ns(iso: str) -> int:
    """ISO 8601 time -> int ns since the Unix epoch (UTC); ConfigError if it does not parse."""
    try:
        return parse_time(iso)
    except ValueError as err:
        raise ConfigError(f"start time {iso!r} is not ISO 8601") from err


def excitation_scale(vessel: Vessel) -> tuple[float, float]:
    """Factors on the open-loop scenarios' surge thrust and yaw moment for a vessel.

    The scenarios were designed for the paper's vessel (damping 5); a vessel of the
    extended structure gets them scaled by its linearised damping (the paper terms)
    over 5, so it reaches the same speeds and turn rates. Vessels of the paper's
    structure keep the scenarios as they are.

    Parameters
    ----------
    vessel : Vessel

    Returns
    -------
    (float, float)
        Surge and yaw factors (1, 1 for the paper's structure).
    """
    if vessel.extended is None:
        return 1.0, 1.0
    return vessel.params.d11 / 5.0, vessel.params.d33 / 5.0


@jitable
def ieee_remainder(x, y):
    """``math.remainder(x, y)`` (IEEE 754 remainder: x - n y, n the nearest integer to x / y,
    ties to even), callable from compiled kernels; finite x, finite nonzero y.

    The arithmetic of CPython's own implementation (every step is exact).

    Parameters
    ----------
    x, y : float
        Dividend and divisor (e.g. an angle and 2 pi, rad).

    Returns
    -------
    float
        The remainder, in [-|y| / 2, |y| / 2].
    """
    absx = abs(x)
    absy = abs(y)
    m = absx % absy   # fmod: exact, and both are >= 0
    c = absy - m
    if m < c:
        r = m
    elif m > c:
        r = -c
    else:   # half way: the even multiple
        r = m - 2.0 * ((0.5 * (absx - m)) % absy)
    return math.copysign(1.0, x) * r


@njit
def _open_loop_kernel(x0, force0, sign0, base0, k0, tau_u, tau_r, prm, ext, ext_prm, dt, cn, ce, rk4, zigzag,
                      zz_prm):
    """The open-loop plant (:func:`plant_step`, or :func:`plant_step_ext` with ``ext``, at every
    step, as :class:`PlantStepper` steps it), compiled; the same kernel for every open-loop
    scenario.

    ``x0``: initial state (6-tuple); ``tau_u`` (N), ``tau_r`` (N m) per step, held over it;
    ``prm`` the vessel parameters (PARAM_NAMES order), ``ext_prm`` those of
    :func:`plant_step_ext` (:func:`plant_form`); ``dt`` s; ``cn``, ``ce`` the current
    (m/s); ``rk4`` or forward Euler. With ``zigzag`` the yaw moment is the excitation run's
    20/20 zig-zag plus ``tau_r`` and both are realised by the saturated thrusters:
    ``zz_prm`` = (steps per 90 deg turn of the base course, zig-zag angle rad, yaw moment
    N m, thruster arm m, forward limit N, reverse limit N). Returns the states at every
    step (N, 6), the commanded tau_u, tau_r (the inputs as given without ``zigzag``) and
    the force and moment the plant felt (N, 2) (lagged by the thrusters), then the state to go on
    from: the state, the lagged force, the zig-zag's sign and base course after the last step.

    A run in time windows: ``force0`` (0, 0), ``sign0`` 1, ``base0`` the initial heading and
    ``k0`` 0 at the start, then each window from the state the one before ended in, ``k0`` its
    first step's number in the run (the same numbers as the whole run at once).
    """
    n = len(tau_u)
    states = np.empty((n, 6))
    tu_out = np.empty(n)
    tr_out = np.empty(n)
    applied = np.empty((n, 2))
    force = force0
    period_steps, zz, yaw_moment, arm, fwd, rev = zz_prm
    x = x0
    sign = sign0
    base = base0
    for j in range(n):
        k = k0 + j
        tu = tau_u[j]
        tr = tau_r[j]
        if zigzag:
            if k and k % period_steps == 0:
                base += math.pi / 2
            dev = ieee_remainder(x[2] - base, 2 * math.pi)
            if sign > 0 and dev > zz:
                sign = -1.0
            elif sign < 0 and dev < -zz:
                sign = 1.0
            tr = sign * yaw_moment + tr
            # realisable by the thrusters (Thrusters.forces_from_tau, saturate, tau_from_forces)
            d = tr / arm
            fl = min(max(0.5 * (tu + d), -rev), fwd)
            fr = min(max(0.5 * (tu - d), -rev), fwd)
            tu = fl + fr
            tr = arm * (fl - fr)
        tu_out[j] = tu
        tr_out[j] = tr
        for i in range(6):
            states[j, i] = x[i]
        x, force, au, ar = plant_advance(x, force, tu, tr, ext, prm, ext_prm, dt, cn, ce, rk4)
        applied[j, 0] = au
        applied[j, 1] = ar
    return states, tu_out, tr_out, applied, x, force, sign, base


def _start_state(st: SimSettings) -> tuple:
    """The open-loop kernel's state at the start of a run: (x, lagged force, zig-zag sign, base course)."""
    x0 = (*map(float, st.eta0), *map(float, st.nu0))
    return x0, (0.0, 0.0), 1.0, x0[2]


def _run_kernel(st: SimSettings, tau_u, tau_r, zigzag: bool, zz_prm, state: tuple | None = None, k0: int = 0):
    """:func:`_open_loop_kernel` on a run's vessel, current, step and integrator: (states, tau_u,
    tau_r, applied), from the start of the run; with ``state`` (:func:`_start_state`, or the
    one a window ended in) and ``k0`` (the window's first step), a window of the run:
    (states, tau_u, tau_r, applied, state at its end)."""
    ext, ext_prm = plant_form(st.vessel)
    cn, ce = st.current_ne
    x0, f0, s0, b0 = _start_state(st) if state is None else state
    *out, x, force, sign, base = _open_loop_kernel(
        x0, f0, float(s0), float(b0), int(k0), np.ascontiguousarray(tau_u, float), np.ascontiguousarray(tau_r, float),
        tuple(st.vessel.params.as_array().tolist()), ext, ext_prm if ext else (0.0,) * 11,
        float(st.dt_s), float(cn), float(ce), st.integrator == "rk4", zigzag, zz_prm)
    return tuple(out) if state is None else (*out, (x, force, sign, base))


def _multisine(t: np.ndarray, freqs: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    phases = rng.uniform(0, 2 * np.pi, len(freqs))
    y = _sines(t, freqs, phases)
    return y / np.max(np.abs(y))


def _sines(t: np.ndarray, freqs: np.ndarray, phases: np.ndarray) -> np.ndarray:
    """The sum of the sines of ``freqs`` (Hz) and ``phases`` (rad) at ``t`` (s), not scaled."""
    return np.sin(2 * np.pi * freqs[None, :] * t[:, None] + phases[None, :]).sum(1)


WINDOW_STEPS = 1 << 16
"""Plant steps :func:`simulate_windows` simulates at a time (about 11 minutes at 0.01 s)."""


def _step_windows(n: int, dt: float, size: int):
    """(first step, step times in s) of consecutive windows of ``size`` of a run's ``n`` steps."""
    for a in range(0, n, size):
        yield a, np.arange(a, min(n, a + size)) * dt


def _multisine_plan(n: int, dt: float, freqs: list[float], rng: np.random.Generator):
    """:func:`_multisine` of a run's ``n`` steps a window at a time: its phases drawn now, its
    scale (the largest magnitude over the run) from a pass over the run in windows; returns
    t -> the multisine at ``t`` (the numbers :func:`_multisine` gives there)."""
    f = np.array(freqs)
    phases = rng.uniform(0, 2 * np.pi, len(f))
    top = max((float(np.max(np.abs(_sines(t, f, phases)))) for _a, t in _step_windows(n, dt, WINDOW_STEPS)),
              default=1.0)
    return lambda t: _sines(t, f, phases) / top


def excitation_run(settings: SimSettings, seed: int = 0) -> FieldLog:
    """Open-loop identification run: multisine surge thrust plus a 20/20 zig-zag in yaw.

    The zig-zag is the classic manoeuvre: full yaw moment one way until the heading is
    20 deg off the base course, then the other way; the base course turns by 90 deg
    every 150 s so the run covers all headings (which separates current from drag).
    Thrust and moment are scaled by :func:`excitation_scale` (1 for the paper's structure).

    Parameters
    ----------
    settings : SimSettings
    seed : int, default 0
        Seed of the one random generator (multisine phases and sensor noise).

    Returns
    -------
    FieldLog
        See :func:`field_log_from_run` for the channels.
    """
    return _whole("excitation", settings, seed)


def _excitation_plan(st: SimSettings, rng: np.random.Generator):
    """The excitation run's commands (its random draws made now): (window's step times ->
    (tau_u, tau_r extra), zig-zag, its parameters) for :func:`_open_loop_kernel`."""
    n = st.n_steps
    su, sr = excitation_scale(st.vessel)
    ms_u = _multisine_plan(n, st.dt_s, [0.004, 0.011, 0.023, 0.041, 0.07, 0.12], rng)
    ms_r = _multisine_plan(n, st.dt_s, [0.05, 0.13, 0.29], rng)

    def tau(t):
        tau_u = 3.0 + 1.5 * ms_u(t)
        tau_r_extra = 0.25 * ms_r(t)
        if su != 1.0 or sr != 1.0:
            tau_u, tau_r_extra = su * tau_u, sr * tau_r_extra
        return tau_u, tau_r_extra

    thr = st.vessel.thrusters
    zz_prm = (int(round(150.0 / st.dt_s)), math.radians(20.0), 1.2 * sr, float(thr.arm_m), float(thr.forward_n),
              float(thr.reverse_n))
    return tau, True, zz_prm


# -----------------------------------------------------------------------------
# sensors -> field log
# -----------------------------------------------------------------------------

# Sensor resolution (decimal places) of the recorded values: 1e-8 deg (~1 mm), 1 mm,
# 1e-4 rad (0.006 deg), 1 mN, 1e-4 of full command. Far below the noise, and it keeps
# logs small (short decimals compress well).
_QUANTUM = {"latlon": 8, "alt": 3, "heading": 4, "thrust": 3, "normalized": 4}


def _every(t: np.ndarray, rate_hz: float, dt: float) -> np.ndarray:
    step = max(1, int(round(1.0 / (rate_hz * dt))))
    return np.arange(0, len(t), step)


def draw_sensor_noise(st: SimSettings, t: np.ndarray, rng: np.random.Generator) -> dict:
    """Every random sensor error of a run (they do not depend on the states), in draw order.

    GPS: white noise, wandering bias, jumps (sample index, dn, de), dropouts (a keep mask);
    compass: white noise (rad). Indices are plant steps at which each sensor samples.

    Parameters
    ----------
    st : SimSettings
    t : numpy.ndarray
        Plant step times, s from the start.
    rng : numpy.random.Generator

    Returns
    -------
    dict
        ``gps_index``, ``gps_noise`` (K, 2) m, ``gps_bias`` (K, 2) m, ``gps_keep`` (K,)
        bool, ``gps_jumps`` list of (fix index, dn m, de m), ``compass_index``,
        ``compass_noise`` (rad).
    """
    sn = st.sensors
    gi = _every(t, sn.gps_rate_hz, st.dt_s)
    tg = t[gi]
    noise = rng.normal(0.0, 1.0, (len(gi), 2)) * sn.gps_noise_m
    bias = np.zeros((len(gi), 2))
    if sn.gps_bias_sigma_m > 0:
        a = math.exp(-1.0 / (sn.gps_rate_hz * sn.gps_bias_tau_s))
        w = rng.normal(0.0, sn.gps_bias_sigma_m * math.sqrt(1 - a * a), (len(gi), 2))
        b = rng.normal(0.0, sn.gps_bias_sigma_m, 2)
        for k in range(len(gi)):
            b = a * b + w[k]
            bias[k] = b
    keep = np.ones(len(gi), bool)
    for (start, dur) in sn.gps_dropouts:
        keep &= ~((tg >= start) & (tg < start + dur))
    jumps = []
    for (tj, size) in sn.gps_jumps:
        k = int(np.argmin(np.abs(tg - tj)))
        ang = rng.uniform(0, 2 * np.pi)
        jumps.append((k, size * math.cos(ang), size * math.sin(ang)))
    ci = _every(t, sn.compass_rate_hz, st.dt_s)
    std = math.radians(sn.compass_noise_deg)
    return {"gps_index": gi, "gps_noise": noise, "gps_bias": bias, "gps_keep": keep, "gps_jumps": jumps,
            "compass_index": ci, "compass_noise": rng.normal(0.0, 1.0, len(ci)) * std}


def field_log_from_run(st: SimSettings, t: np.ndarray, states: np.ndarray, tau_u: np.ndarray,
                       tau_r: np.ndarray, rng: np.random.Generator, *, producer: str,
                       scenario: str, seed: int, extra_settings: dict | None = None,
                       noise: dict | None = None, tau_applied: np.ndarray | None = None) -> FieldLog:
    """Turn a simulated trajectory (states at times t, thrust held over each step) into a log.

    ``noise``: sensor noise drawn beforehand by :func:`draw_sensor_noise` (a closed loop
    whose estimator must see the very measurements the log records); None draws it here.

    Parameters
    ----------
    st : SimSettings
    t : numpy.ndarray, shape (N,)
        Step times, s from ``st.start_utc``.
    states : numpy.ndarray, shape (N, 6)
        n (m), e (m), psi (rad), u (m/s), v (m/s), r (rad/s) at ``t``.
    tau_u, tau_r : numpy.ndarray, shape (N,)
        Surge force (N) and yaw moment (N m) commanded over each step (recorded as
        ``/thrust/command``; also the applied ones unless ``tau_applied`` is given).
    rng : numpy.random.Generator
    producer, scenario : str
        Provenance: the producing command and the scenario name.
    seed : int
        Recorded in the provenance.
    extra_settings : dict, optional
        More provenance settings.
    noise : dict, optional
        From :func:`draw_sensor_noise`.
    tau_applied : numpy.ndarray, shape (N, 2), optional
        The force and moment the plant felt at each step (a thruster lag), recorded in
        ``/truth/state``; default the commanded ones.

    Returns
    -------
    FieldLog
        Channels ``/truth/state``, ``/thrust/command`` (newtons for the identity map,
        else normalized commands; forces in thrust_*_n), ``/gnss/fix`` and
        ``/compass/heading`` (true heading), timestamps in ns since the Unix epoch;
        the datum, the vessel and a provenance record.
    """
    if noise is None:
        noise = draw_sensor_noise(st, t, rng)
    log = _header_log(st, producer=producer, scenario=scenario, seed=seed, extra_settings=extra_settings)
    for topic, frame in window_frames(st, 0, t, states, tau_u, tau_r, noise, tau_applied).items():
        log.set(topic, frame)
    return log


def _header_log(st: SimSettings, *, producer: str, scenario: str, seed: int,
                extra_settings: dict | None = None) -> FieldLog:
    """A simulated run's log without its channels: the datum, the vessel and the provenance record."""
    sn = st.sensors
    log = FieldLog()
    log.datum = st.datum
    log.vessel = st.vessel
    settings = {"scenario": scenario, "seed": seed, "duration_s": st.duration_s, "dt_s": st.dt_s,
                "integrator": st.integrator, "current_mps": st.current_mps,
                "current_dir_deg": st.current_dir_deg, "start_utc": st.start_utc,
                "sensors": {k: getattr(sn, k) for k in sn.__dataclass_fields__}}
    settings.update(extra_settings or {})
    log.add_provenance(producer=producer, source="simulation", settings=settings)
    return log


def _in_window(a: int, m: int, rate_hz: float, dt: float) -> np.ndarray:
    """The steps of a window (m steps from the run's step a, numbered from 0 in the window) at
    which a sensor of ``rate_hz`` samples: those :func:`_every` picks from the whole run."""
    step = max(1, int(round(1.0 / (rate_hz * dt))))
    return np.arange((-a) % step, m, step)


def window_frames(st: SimSettings, a: int, t: np.ndarray, states: np.ndarray, tau_u: np.ndarray,
                  tau_r: np.ndarray, noise: dict, tau_applied: np.ndarray | None = None) -> dict:
    """The channels of :func:`field_log_from_run` over a window of a run: its steps a, a+1, ...

    Parameters
    ----------
    st : SimSettings
    a : int
        The window's first step in the run (0: the whole run, or its first window).
    t, states, tau_u, tau_r, tau_applied
        As :func:`field_log_from_run`, over the window's steps alone (``t`` in s from the
        start of the run).
    noise : dict
        :func:`draw_sensor_noise` of the whole run (its indices are the run's steps).

    Returns
    -------
    dict
        Topic -> frame (``/truth/state``, ``/thrust/command``, ``/gnss/fix``,
        ``/compass/heading``): the rows of the whole run's frames in the window, the same
        numbers (windows one after another give the whole run's frames).
    """
    t0 = start_ns(st.start_utc)
    t_ns = t0 + np.round(t * 1e9).astype(np.int64)
    m = len(t)
    sn = st.sensors
    cn, ce = st.current_ne
    out = {}

    # every column below is a fresh array of its own: the frames take them as they are (copy=False)
    # truth at every step (or thinned to truth_rate_hz)
    si = np.arange(m) if sn.truth_rate_hz is None else _in_window(a, m, sn.truth_rate_hz, st.dt_s)
    truth = {"n_m": states[si, 0], "e_m": states[si, 1], "psi_rad": ssa(states[si, 2]),
             "u_mps": states[si, 3], "v_mps": states[si, 4], "r_radps": states[si, 5],
             "current_n_mps": np.full(len(si), cn), "current_e_mps": np.full(len(si), ce),
             "tau_u_n": np.asarray(tau_u, float)[si], "tau_r_nm": np.asarray(tau_r, float)[si]}
    if tau_applied is not None:
        truth["tau_u_n"], truth["tau_r_nm"] = tau_applied[si, 0], tau_applied[si, 1]
    out["/truth/state"] = frame_from_columns(truth, t_ns[si], channel_spec("/truth/state"), copy=False)

    # thrust commands as recorded
    thr = st.vessel.thrusters
    ti = _in_window(a, m, sn.thrust_rate_hz, st.dt_s)
    fl, fr = thr.forces_from_tau(np.asarray(tau_u)[ti], np.asarray(tau_r)[ti])
    unit = "newton" if thr.map == "identity" else "normalized"
    cmd_l = thr.force_to_command(fl, unit, side="left")
    cmd_r = thr.force_to_command(fr, unit, side="right")
    q = _QUANTUM["thrust"] if unit == "newton" else _QUANTUM["normalized"]
    thrust = {"stamp_ns": t_ns[ti], "left": np.round(np.asarray(cmd_l, float), q),
              "right": np.round(np.asarray(cmd_r, float), q), "unit": StrCodes.repeat(unit, len(ti)),
              "thrust_left_n": np.round(fl, _QUANTUM["thrust"]), "thrust_right_n": np.round(fr, _QUANTUM["thrust"])}
    out["/thrust/command"] = frame_from_columns(thrust, t_ns[ti], channel_spec("/thrust/command"), copy=False)

    # GPS: the run's fixes in the window
    j0, j1 = (int(j) for j in np.searchsorted(noise["gps_index"], [a, a + m]))
    gi = noise["gps_index"][j0:j1] - a
    pn = states[gi, 0] + noise["gps_noise"][j0:j1, 0] + noise["gps_bias"][j0:j1, 0]
    pe = states[gi, 1] + noise["gps_noise"][j0:j1, 1] + noise["gps_bias"][j0:j1, 1]
    keep = noise["gps_keep"][j0:j1]
    for k, dn, de in noise["gps_jumps"]:
        if j0 <= k < j1:
            pn[k - j0] += dn
            pe[k - j0] += de
    lat, lon, alt = ned_to_geodetic(pn, pe, np.zeros_like(pn), datum=st.datum)
    var = sn.gps_noise_m ** 2
    z = np.zeros(len(gi))
    tg_ns = t_ns[gi] + int(round(sn.gps_delay_s * 1e9))   # stamped late by the latency
    gps = {"stamp_ns": tg_ns, "frame_id": StrCodes.repeat("gnss", len(gi)),
           "lat_deg": np.round(lat, _QUANTUM["latlon"]), "lon_deg": np.round(lon, _QUANTUM["latlon"]),
           "alt_m": np.round(alt, _QUANTUM["alt"]),
           "cov_ee_m2": z + var, "cov_en_m2": z, "cov_eu_m2": z, "cov_ne_m2": z, "cov_nn_m2": z + var,
           "cov_nu_m2": z, "cov_ue_m2": z, "cov_un_m2": z, "cov_uu_m2": z + 4 * var,
           "cov_type": np.full(len(gi), 2, dtype=np.int64)}
    gps = {k: v[keep] for k, v in gps.items()}
    out["/gnss/fix"] = frame_from_columns(gps, tg_ns[keep], channel_spec("/gnss/fix"), copy=False)

    # compass
    c0, c1 = (int(j) for j in np.searchsorted(noise["compass_index"], [a, a + m]))
    ci = noise["compass_index"][c0:c1] - a
    std = math.radians(sn.compass_noise_deg)
    hd = ssa(states[ci, 2] + math.radians(sn.compass_bias_deg) + noise["compass_noise"][c0:c1])
    tc_ns = t_ns[ci] + int(round(sn.compass_delay_s * 1e9))
    comp = {"stamp_ns": tc_ns.copy(), "heading_rad": np.round(hd, _QUANTUM["heading"]),
            "reference": StrCodes.repeat("true", len(ci)),
            "std_rad": np.full(len(ci), std)}
    out["/compass/heading"] = frame_from_columns(comp, tc_ns, channel_spec("/compass/heading"), copy=False)
    return out


def _open_loop_plan(st: SimSettings, tau_of_t):
    """The plan of an open-loop run through thrust ``tau_of_t(t) -> (tau_u, tau_r)`` (realised by
    the thrusters: forces saturated), as :func:`_excitation_plan` returns it."""
    su, sr = excitation_scale(st.vessel)
    thr = st.vessel.thrusters

    def tau(t):
        tu_cmd, tr_cmd = tau_of_t(t)
        if su != 1.0 or sr != 1.0:
            tu_cmd, tr_cmd = su * tu_cmd, sr * tr_cmd
        fl, fr = thr.forces_from_tau(tu_cmd, tr_cmd)
        fl, fr = thr.saturate(fl), thr.saturate(fr)
        return thr.tau_from_forces(fl, fr)

    return tau, False, (1, 0.0, 0.0, 1.0, 0.0, 0.0)


def _open_loop(settings: SimSettings, seed: int, tau_of_t, scenario: str) -> FieldLog:
    """Integrate the plant through thrust ``tau_of_t(t, rng) -> (tau_u, tau_r)`` (realised by the
    thrusters: forces saturated) and sample the sensors, the whole run at once."""
    rng = np.random.default_rng(seed)
    st = settings
    t = np.arange(st.n_steps) * st.dt_s
    tau, _, zz_prm = _open_loop_plan(st, lambda t: tau_of_t(t, rng))
    tau_u, tau_r = tau(t)
    states, _, _, applied = _run_kernel(st, tau_u, tau_r, False, zz_prm)
    return field_log_from_run(st, t, states, tau_u, tau_r, rng, producer=f"usvlog simulate {scenario}",
                              scenario=scenario, seed=seed, tau_applied=applied)


def _segments(st: SimSettings, seconds: float) -> int:
    """Segments of ``seconds`` a run's steps fall in (the last step's segment + 1)."""
    return int(max(st.n_steps - 1, 0) * st.dt_s // seconds) + 1


def _turns_plan(st: SimSettings, rng: np.random.Generator):
    tu = rng.uniform(1.5, 4.5, _segments(st, 40.0))
    tr = rng.choice([-0.9, -0.4, 0.0, 0.4, 0.9], len(tu))

    def tau(t):
        k = (t // 40.0).astype(int)
        return tu[k], tr[k]
    return _open_loop_plan(st, tau)


def _straight_plan(st: SimSettings, rng: np.random.Generator):
    tu = rng.uniform(1.5, 4.5, _segments(st, 30.0))
    return _open_loop_plan(st, lambda t: (tu[(t // 30.0).astype(int)], np.zeros_like(t)))


def turns_run(settings: SimSettings, seed: int = 0) -> FieldLog:
    """Open-loop steps in surge thrust and turning circles both ways (a different manoeuvre
    from ``excitation``, for validation): every 40 s a new surge thrust (1.5-4.5 N) and a new
    yaw moment (0, +-0.4 or +-0.9 N m), held.

    Parameters and return as :func:`excitation_run`."""
    return _whole("turns", settings, seed)


def straight_run(settings: SimSettings, seed: int = 0) -> FieldLog:
    """Straight line: steps in surge thrust with equal thrusters, no yaw moment at all
    (the yaw dynamics are not excited: identification must say so).

    Parameters and return as :func:`excitation_run`."""
    return _whole("straight", settings, seed)


_PLANS = {"excitation": _excitation_plan, "turns": _turns_plan, "straight": _straight_plan}


def simulate_windows(scenario: str, settings: SimSettings | None = None, seed: int = 0, *,
                     window_steps: int | None = None):
    """A built-in open-loop scenario simulated a time window at a time (memory flat in the run's length).

    The plant's state (and the zig-zag's) goes on from window to window, every random draw
    is made before the first window in the order of the whole run: the windows' frames one
    after another are :func:`simulate`'s channels, the same numbers.

    Parameters
    ----------
    scenario : {"excitation", "turns", "straight"}
    settings : SimSettings, optional
    seed : int, default 0
    window_steps : int, optional
        Plant steps per window (default :data:`WINDOW_STEPS`).

    Returns
    -------
    log : FieldLog
        The run's log without its channels (datum, vessel, provenance).
    windows : iterator of dict
        Topic -> frame of the window (:func:`window_frames`), windows in time order.

    Raises
    ------
    usvlog.errors.ConfigError
        On an unknown scenario name.
    """
    if scenario not in _PLANS:
        raise ConfigError(f"unknown scenario {scenario!r} (known: {', '.join(sorted(SCENARIOS))})")
    st = settings or SimSettings()
    rng = np.random.default_rng(seed)
    tau, zigzag, zz_prm = _PLANS[scenario](st, rng)
    n = st.n_steps
    noise = draw_sensor_noise(st, np.arange(n) * st.dt_s, rng)   # small: the sensors' samples only
    log = _header_log(st, producer=f"usvlog simulate {scenario}", scenario=scenario, seed=seed)

    def windows():
        state = _start_state(st)
        for a, t in _step_windows(n, st.dt_s, max(1, int(window_steps or WINDOW_STEPS))):
            tu, tr = tau(t)
            states, tu, tr, applied, state = _run_kernel(st, tu, tr, zigzag, zz_prm, state, a)
            yield window_frames(st, a, t, states, tu, tr, noise, applied)

    return log, windows()


def _whole(scenario: str, st: SimSettings, seed: int) -> FieldLog:
    """:func:`simulate_windows` in one window: the whole run's log."""
    log, windows = simulate_windows(scenario, st, seed, window_steps=max(1, st.n_steps))
    for frames in windows:
        for topic, frame in frames.items():
            log.set(topic, frame)
    return log


SCENARIOS = {"excitation": excitation_run, "turns": turns_run, "straight": straight_run}


def simulate(scenario: str, settings: SimSettings | None = None, seed: int = 0) -> FieldLog:
    """Run a built-in scenario by name.

    Parameters
    ----------
    scenario : {"excitation", "turns", "straight"}
        Open-loop manoeuvre: :func:`excitation_run` (multisine surge and 20/20 zig-zag,
        for identification), :func:`turns_run` (thrust steps and turning circles) or
        :func:`straight_run` (no yaw excitation).
    settings : SimSettings, optional
        Vessel, duration, step, current, sensors (default ``SimSettings()``: the paper's
        vessel, 600 s at 0.01 s, no current).
    seed : int, default 0
        A seed reproduces a run bit for bit.

    Returns
    -------
    FieldLog
        Sensors, thrust and ``/truth/state``; see :func:`field_log_from_run`.

    Raises
    ------
    usvlog.errors.ConfigError
        On an unknown scenario name.

    See Also
    --------
    usvlog.sim.closed_loop.simulate_scenario : closed-loop runs of a :class:`~usvlog.sim.scenario.Scenario`.
    """
    try:
        fn = SCENARIOS[scenario]
    except KeyError:
        raise ConfigError(f"unknown scenario {scenario!r} (known: {', '.join(sorted(SCENARIOS))})") from None
    return fn(settings or SimSettings(), seed)


__all__ = ["SensorSettings", "SimSettings", "excitation_run", "turns_run", "straight_run",
           "field_log_from_run", "draw_sensor_noise", "excitation_scale", "window_frames", "simulate_windows",
           "WINDOW_STEPS",
           "simulate", "start_ns", "SCENARIOS", "replace", "pd"]
