"""Open-loop runs of the paper's vessel with known manoeuvres (usvlog.sim's plant, GPS 1.5 m and
compass 2 deg noise), for the manoeuvre tests: the truth (/truth/state) is in each log."""

from __future__ import annotations

import math

import numpy as np

from usvlog.sim.simulate import SimSettings, _open_loop, _run_kernel, field_log_from_run

RUN_IN_S = 30.0          # straight run-in before every execute
TURN_TAU_U, TURN_TAU_R = 6.0, 0.4      # surge force (N) and yaw moment (N m) of the turning circle
ZIGZAG_MOMENT, ZIGZAG_DEG = 0.9, 20.0
STEPS = ((5.0, 2.0), (45.0, 4.0), (85.0, 6.0), (125.0, 3.0))   # (start s, tau_u N) of the speed steps
STOP_AT, PIVOT_AT, PIVOT_FORCE = 165.0, 205.0, 2.0


def settings(duration_s: float, **sensors) -> SimSettings:
    """The paper's vessel for ``duration_s`` with the default sensors (GPS 1.5 m, compass 2 deg)."""
    from usvlog.sim.simulate import SensorSettings

    return SimSettings(duration_s=duration_s, sensors=SensorSettings(truth_rate_hz=20.0, **sensors))


def turning_circle_run(seed: int = 1, duration_s: float = 200.0):
    """A straight run-in, then a constant differential from RUN_IN_S on (to starboard)."""
    def tau(t, rng):
        return np.full_like(t, TURN_TAU_U), np.where(t >= RUN_IN_S, TURN_TAU_R, 0.0)
    return _open_loop(settings(duration_s), seed, tau, "turning-circle")


def zigzag_run(seed: int = 2, duration_s: float = 75.0):
    """A straight run-in, then a 20/20 zig-zag: the yaw moment reversed each time the heading is
    20 deg off the initial heading (the kernel's own zig-zag, its base course held)."""
    st = settings(duration_s)
    rng = np.random.default_rng(seed)
    t = np.arange(st.n_steps) * st.dt_s
    tau_u = np.full_like(t, TURN_TAU_U)
    extra = np.where(t < RUN_IN_S, -ZIGZAG_MOMENT, 0.0)    # cancels the zig-zag's moment during the run-in
    thr = st.vessel.thrusters
    zz = (st.n_steps + 10, math.radians(ZIGZAG_DEG), ZIGZAG_MOMENT, float(thr.arm_m), float(thr.forward_n),
          float(thr.reverse_n))
    states, tu, tr, applied = _run_kernel(st, tau_u, extra, True, zz)
    return field_log_from_run(st, t, states, tu, tr, rng, producer="test zigzag", scenario="zigzag", seed=seed,
                              tau_applied=applied)


def steps_stop_pivot_run(seed: int = 3, duration_s: float = 230.0):
    """Speed steps (2 -> 4 -> 6 -> 3 N), thrust to zero (a coast-down), then a pivot turn from
    (near) rest: left +2 N, right -2 N."""
    def tau(t, rng):
        tu = np.zeros_like(t)
        for start, f in STEPS:
            tu[t >= start] = f
        tu[t >= STOP_AT] = 0.0
        tr = np.where(t >= PIVOT_AT, 0.3 * 2 * PIVOT_FORCE, 0.0)
        return tu, tr
    return _open_loop(settings(duration_s), seed, tau, "steps-stop-pivot")
