"""A free run that starts between two thrust commands (a log whose thrust and navigation are stamped
apart, as a ROS bag's are) has the command in force there, in both model structures.

Before, the extended model's free runs started at the first command after the start, so their first
output was NaN and every extended candidate of a real VantTec bag "diverged". Truth: the paper model's
own free run (``free_run.simulate_run``, its own kernel), which the extended model with the paper's
values (:meth:`ExtendedParams.from_paper`) must reproduce from the same start.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from usvlog.identify.data import run_data
from usvlog.identify.extended import free_run as free_run_velocity
from usvlog.identify.extended_oe import free_run_full
from usvlog.identify.free_run import simulate_run
from usvlog.model.vessel import ExtendedParams, default_vessel
from usvlog.sim.simulate import SimSettings, simulate


def _run_stamped_apart():
    log = simulate("excitation", SimSettings(duration_s=60.0), seed=5)
    run = run_data(log, default_vessel())
    return replace(run, t_thrust=run.t_thrust + 0.004)   # every command 4 ms after the navigation grid


def test_the_free_run_starts_with_the_command_in_force():
    run = _run_stamped_apart()
    p = default_vessel().params
    ext = ExtendedParams.from_paper(p).as_array()
    t0 = 20.0                                              # between the commands at 19.994 and 20.004
    assert run.t_thrust[run.thrust_index_at(t0)] < t0 < run.t_thrust[run.thrust_index_at(t0) + 1]
    times = t0 + np.arange(0.0, 30.0, 0.1)
    x0 = np.array([1.0, -2.0, 0.3, 0.8, 0.05, 0.02])
    cur = (0.1, -0.05)
    paper = simulate_run(run, p.as_array(), cur, x0, t0, times)
    full = free_run_full(run, ext, cur, x0, t0, times)
    vel = free_run_velocity(run, ext, x0[3:], t0, times)
    assert np.all(np.isfinite(full)) and np.all(np.isfinite(vel)) and np.all(np.isfinite(paper))
    np.testing.assert_allclose(full, paper, atol=2e-3)
    np.testing.assert_allclose(vel, paper[:, 3:], atol=2e-3)
