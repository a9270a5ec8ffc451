"""What identification keeps of a log: a window of the run keeps only its own part, and smooths
its free runs exactly as the whole run's smoother does (usvlog.identify.seen.SeenLog,
KinStates.trimmed)."""

from __future__ import annotations

import importlib

import numpy as np
import pandas as pd
import pytest

from usvlog.identify.data import run_data
from usvlog.identify.seen import SeenLog, free_run_log
from usvlog.model.vessel import default_vessel
from usvlog.sim.simulate import SimSettings, simulate

# the module, not the verb function the package exports under the same name
smooth = importlib.import_module("usvlog.identify.smooth")


@pytest.fixture(scope="module")
def run_120s():
    """120 s excitation run of the paper's vessel, its arrays and its smoothed states."""
    boat = default_vessel()
    log = simulate("excitation", SimSettings(duration_s=120.0, vessel=boat), seed=5)
    run = run_data(log, boat)
    return log, run, smooth.kinematic_states(log, run, boat)


def _free_run(ks, t_lo, t_hi):
    """A made-up free run over the states' times in [t_lo, t_hi]: the states shifted a little."""
    k = (ks.t >= t_lo) & (ks.t <= t_hi)
    sim = ks.at(ks.t[k])
    sim[:, 0] += 1.0
    sim[:, 3] *= 0.9
    return ks.t[k], sim


def test_a_window_of_the_log_records_a_free_run_as_the_whole_log(run_120s):
    log, run, ks = run_120s
    t, sim = _free_run(ks, 80.0, 119.0)
    whole = free_run_log(log, run, t, sim, (0.1, -0.05))
    part = SeenLog.of(log, run).window(80.0, np.inf)
    assert len(part.channels["/thrust/command"]) < 0.5 * len(log.get("/thrust/command"))
    windowed = part.free_run_log(t, sim, (0.1, -0.05))
    assert sorted(windowed.channels) == sorted(whole.channels)
    for topic, frame in whole.channels.items():
        pd.testing.assert_frame_equal(windowed.channels[topic], frame)


def test_trimmed_states_smooth_a_free_run_to_the_same_numbers(run_120s):
    _, _, ks = run_120s
    held = ks.window(80.0, np.inf)
    trimmed = held.trimmed()
    assert trimmed.smoother is not held.smoother
    t, sim = _free_run(held, 80.0, np.inf)
    np.testing.assert_array_equal(trimmed.seen(t, sim, (0.1, -0.05)), held.seen(t, sim, (0.1, -0.05)))
