"""Open-loop runs with the manoeuvres of the shared Fossen Otter runs (speed steps, a zig-zag,
turning circles both ways, a coast, pivot turns, a random segment, a coast), for identification
tests on hulls of another form: usvlog.sim's plant, the truth (/truth/state) in each log."""

from __future__ import annotations

import numpy as np

from usvlog.model.vessel import Vessel
from usvlog.sim.simulate import SensorSettings, SimSettings, _open_loop

OTTER_RUN_S = 592.0    # the shared Otter run b's length: the manoeuvres' times are scaled to a run from it


def otter_like_thrust(duration_s: float):
    """``tau(t, rng) -> (tau_u, tau_r)`` of the manoeuvres over ``duration_s``, in the paper vessel's
    units (the simulator scales them to the boat); the random segment changes every 5 s."""
    f = duration_s / OTTER_RUN_S

    def tau(t, rng):
        tu, tr = np.zeros_like(t), np.zeros_like(t)
        for k, a in enumerate((1.0, 2.0, 3.0, 4.5, 6.0)):
            tu[t >= f * (10 + 39 * k)] = a

        def part(lo, hi, u, r):
            m = (t >= f * lo) & (t < f * hi)
            tu[m], tr[m] = u, r(t[m]) if callable(r) else r
            return m

        part(205, 266, 4.0, lambda s: 0.9 * np.sign(np.sin(2 * np.pi * (s - f * 205) / (f * 20))))
        part(266, 306, 4.0, 0.9)
        part(306, 321, 4.0, 0.0)
        part(321, 361, 4.0, -0.9)
        part(361, 386, 0.0, 0.0)
        part(386, 406, 0.0, 0.9)
        part(406, 426, 0.0, -0.9)
        m = part(426, 576, 0.0, 0.0)
        k = ((t[m] - f * 426) // 5).astype(int)
        tu[m] = rng.choice([2.0, 4.0, 6.0], k.max() + 1)[k]
        tr[m] = rng.choice([-0.9, 0.0, 0.9], k.max() + 1)[k]
        part(576, 1e9, 0.0, 0.0)
        return tu, tr
    return tau


def otter_like_run(vessel: Vessel, *, duration_s: float, seed: int, current_mps: float = 0.0,
                   current_dir_deg: float = 200.0, gps_rate_hz: float = 10.0):
    """A simulated log of ``vessel`` through the manoeuvres (compass at twice the GNSS rate)."""
    st = SimSettings(duration_s=duration_s, vessel=vessel, current_mps=current_mps, current_dir_deg=current_dir_deg,
                     sensors=SensorSettings(gps_rate_hz=gps_rate_hz, compass_rate_hz=2 * gps_rate_hz))
    return _open_loop(st, seed, otter_like_thrust(duration_s), "otter-like")
