"""Open-loop runs driven by PWM pulse widths, as an RC receiver or autopilot drives real ESCs.

The other open-loop scenarios (:mod:`usvlog.sim.simulate`) choose forces and record the
commands that would give them; here the commands come first: each thruster gets a pulse
width (whole microseconds), its force is the vessel's thruster map of it (a catalogue map
such as ``t200`` with its deadband about 1500 us, its forward/reverse asymmetry and its
shape), and the log records the pulse widths in ``pwm_us`` with no forces (an ESC log has
none), as a real boat's log would.
"""

from __future__ import annotations

import numpy as np

from ..errors import ConfigError
from ..log.channels import StrCodes, channel_spec, frame_from_columns
from ..log.fieldlog import FieldLog
from .simulate import SimSettings, _every, _multisine, _run_kernel, field_log_from_run, start_ns

SURGE_FREQS_HZ = (0.004, 0.009, 0.017, 0.031, 0.053, 0.09)
"""Frequencies (Hz) of the multisine of the common command (both thrusters)."""

TURN_FREQS_HZ = (0.006, 0.021, 0.047, 0.11)
"""Frequencies (Hz) of the multisine of the differential command (port minus starboard)."""


def pwm_commands(t, rng: np.random.Generator, *, surge_us: tuple[float, float] = (-100.0, 160.0),
                 turn_us: float = 80.0, neutral_us: float = 1500.0) -> tuple[np.ndarray, np.ndarray]:
    """Port and starboard pulse widths: a multisine common command plus a multisine differential.

    Parameters
    ----------
    t : array_like, shape (K,)
        Times of the command samples, s.
    rng : numpy.random.Generator
        Draws the multisine phases.
    surge_us : (float, float), default (-100, 160)
        Range of the common command's offset from ``neutral_us``, us (low < high): a range
        about neutral sweeps the thrusters through the deadband, one far from it never
        enters it.
    turn_us : float, default 80
        Amplitude of the differential offset, us (>= 0): port gets +, starboard - this.
    neutral_us : float, default 1500
        Pulse width of a stopped thruster, us.

    Returns
    -------
    left_us, right_us : numpy.ndarray, shape (K,)
        Pulse widths in whole microseconds, clipped to neutral +- 400 us.

    Raises
    ------
    usvlog.errors.ConfigError
        If ``surge_us`` is not increasing or ``turn_us`` is negative.
    """
    lo, hi = map(float, surge_us)
    if not (hi > lo) or not turn_us >= 0:
        raise ConfigError(f"PWM excitation: surge_us = {surge_us} must be (low, high) with low < high and "
                          f"turn_us = {turn_us} >= 0")
    t = np.asarray(t, float)
    s = 0.5 * (lo + hi) + 0.5 * (hi - lo) * _multisine(t, np.array(SURGE_FREQS_HZ), rng)
    d = float(turn_us) * _multisine(t, np.array(TURN_FREQS_HZ), rng)
    left = np.clip(np.round(neutral_us + s + d), neutral_us - 400.0, neutral_us + 400.0)
    right = np.clip(np.round(neutral_us + s - d), neutral_us - 400.0, neutral_us + 400.0)
    return left, right


def pwm_run(settings: SimSettings, seed: int = 0, *, surge_us: tuple[float, float] = (-100.0, 160.0),
            turn_us: float = 80.0) -> FieldLog:
    """Open-loop run whose thrusters are driven by pulse widths (:func:`pwm_commands`).

    The commands are drawn at the sensors' thrust rate and held in between; each thruster's
    force is ``vessel.thrusters.command_to_force(pwm, "pwm_us", side=...)`` (the map's
    deadband, asymmetry, shape, reversed channels and saturation), and the plant is the
    open-loop kernel of the other scenarios (thruster lag included).

    Parameters
    ----------
    settings : SimSettings
        Its vessel's thrusters must turn pulse widths into forces (not the ``identity`` map).
    seed : int, default 0
        Seed of the one random generator (multisine phases, then the sensor noise).
    surge_us, turn_us : see :func:`pwm_commands`

    Returns
    -------
    FieldLog
        As :func:`usvlog.sim.simulate.field_log_from_run`, but ``/thrust/command`` holds the
        pulse widths (``unit = "pwm_us"``, whole us) and null forces; the forces the plant
        felt are in ``/truth/state`` (``tau_u_n``, ``tau_r_nm``).

    Raises
    ------
    usvlog.errors.ConfigError
        If the vessel's map cannot turn pulse widths into forces, or a command setting is
        out of range.
    """
    rng = np.random.default_rng(seed)
    st = settings
    thr = st.vessel.thrusters
    if thr.map == "identity":
        raise ConfigError("a PWM-driven run needs a thruster map that turns pulse widths into forces "
                          "(linear, quadratic or a catalogue map such as t200), not identity")
    n = st.n_steps
    t = np.arange(n) * st.dt_s
    ti = _every(t, st.sensors.thrust_rate_hz, st.dt_s)
    left, right = pwm_commands(t[ti], rng, surge_us=surge_us, turn_us=turn_us, neutral_us=thr.pwm_neutral_us)
    fl = thr.command_to_force(left, "pwm_us", side="left")
    fr = thr.command_to_force(right, "pwm_us", side="right")
    held = np.searchsorted(ti, np.arange(n), side="right") - 1     # the command in force at each step
    tau_u, tau_r = thr.tau_from_forces(fl[held], fr[held])
    states, _, _, applied = _run_kernel(st, tau_u, tau_r, False, (1, 0.0, 0.0, 1.0, 0.0, 0.0))
    log = field_log_from_run(st, t, states, tau_u, tau_r, rng, producer="usvlog simulate pwm", scenario="pwm",
                             seed=seed, tau_applied=applied,
                             extra_settings={"surge_us": list(map(float, surge_us)), "turn_us": float(turn_us)})
    t_ns = start_ns(st.start_utc) + np.round(t[ti] * 1e9).astype(np.int64)
    nan = np.full(len(ti), np.nan)
    cols = {"stamp_ns": t_ns.copy(), "left": left, "right": right, "unit": StrCodes.repeat("pwm_us", len(ti)),
            "thrust_left_n": nan, "thrust_right_n": nan.copy()}
    log.set("/thrust/command", frame_from_columns(cols, t_ns, channel_spec("/thrust/command"), copy=False))
    return log


__all__ = ["SURGE_FREQS_HZ", "TURN_FREQS_HZ", "pwm_commands", "pwm_run"]
