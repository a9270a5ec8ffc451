"""A free run may start between two thrust commands (a log whose thrust and navigation are stamped
apart, as a ROS bag's are): it starts from the command in force then, never a NaN first row (which
made every candidate's free run "diverged" on the VantTec bags)."""

from __future__ import annotations

import numpy as np

from usvlog.identify.data import RunData
from usvlog.identify.output import simulate_run

THETA = np.array([33.0, 10.0, 5.0, 5.0, 5.0, 0.1])


def _run():
    t = np.arange(0.0, 20.0, 0.01) + 0.0037          # 100 Hz commands, off the 10 Hz grid
    z = np.zeros(2)
    return RunData(t0_ns=0, t_thrust=t, tau_u=np.full(len(t), 10.0), tau_r=np.full(len(t), 1.0), t_gps=z,
                   n_gps=z, e_gps=z, sigma_gps=z + 1, t_compass=z, psi_compass=z, sigma_compass=z + 0.1)


def test_a_free_run_between_two_commands_starts_from_the_state_given():
    run = _run()
    x0 = np.array([1.0, 2.0, 0.3, 0.5, 0.0, 0.0])
    t0 = 5.0                                           # between the commands at 4.9937 and 5.0037 s
    times = t0 + 0.1 * np.arange(50)
    sim = simulate_run(run, THETA, (0.0, 0.0), x0, t0, times)
    assert np.all(np.isfinite(sim))
    np.testing.assert_allclose(sim[0], x0, atol=5e-3)   # x0 held at the command before t0: 6 ms early
    # the same as a run started on the grid (the command is constant): within one command interval
    on_grid = simulate_run(run, THETA, (0.0, 0.0), x0, run.t_thrust[500], times + (run.t_thrust[500] - t0))
    np.testing.assert_allclose(sim[:, 3:], on_grid[:, 3:], atol=2e-3)
