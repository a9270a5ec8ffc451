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


def _pwm_version(log):
    """The log's thrust as T200 pulse widths without logged forces, one record not finite."""
    out = log.copy()
    fr = log["/thrust/command"].copy()
    k = np.arange(len(fr))
    fr["left"] = 1500.0 + 300.0 * np.sin(k / 700.0)
    fr["right"] = 1500.0 + 250.0 * np.cos(k / 500.0)
    fr["unit"] = "pwm_us"
    fr["thrust_left_n"] = np.nan
    fr["thrust_right_n"] = np.nan
    fr.iloc[len(fr) // 2, fr.columns.get_loc("left")] = np.nan
    out.set("/thrust/command", fr)
    return out


@pytest.mark.parametrize("kind", ["logged newtons", "pwm through the t200 map"])
def test_the_thrust_as_forces_smooths_and_records_free_runs_to_the_same_numbers(run_120s, kind):
    from dataclasses import replace

    from usvlog.identify.data import thrust_as_forces, thrust_forces
    from usvlog.model.thrusters import Thrusters

    log, _, _ = run_120s
    boat = default_vessel()
    if kind != "logged newtons":
        log = _pwm_version(log)
        boat = replace(boat, thrusters=Thrusters(map="t200", supply_v=16.0))
    lean = thrust_as_forces(log, thrust_forces(log, boat))
    assert list(lean["/thrust/command"].columns) == ["thrust_left_n", "thrust_right_n"]
    assert list(log["/thrust/command"].columns) != ["thrust_left_n", "thrust_right_n"]   # the log's own is kept
    if kind == "logged newtons":
        for c in ("thrust_left_n", "thrust_right_n"):
            np.testing.assert_array_equal(lean["/thrust/command"][c], log["/thrust/command"][c])
    run = run_data(log, boat)
    assert len(lean["/thrust/command"]) == len(log["/thrust/command"]) - (kind != "logged newtons")
    a, b = smooth.kinematic_states(log, run, boat), smooth.kinematic_states(lean, run, boat)   # (as the fit does)
    for name in ("t", "n", "e", "psi", "vn", "ve", "r"):
        np.testing.assert_array_equal(getattr(b, name), getattr(a, name))
    t, sim = _free_run(a, 60.0, 119.0)
    np.testing.assert_array_equal(b.seen(t, sim, (0.1, -0.05)), a.seen(t, sim, (0.1, -0.05)))


def test_run_data_takes_the_thrust_in_time_order_first_of_a_repeated_stamp(run_120s):
    """Sorted records are used as they are; shuffled ones with repeated stamps and a bad record come
    out in time order, the first record of a stamp kept (in the channel's order), the bad one skipped."""
    log, run, _ = run_120s
    fr = log["/thrust/command"]
    n = len(fr)
    np.testing.assert_array_equal(run.t_thrust, (np.asarray(fr.index, np.int64) - fr.index[0]) / 1e9)
    rng = np.random.default_rng(3)
    k = rng.permutation(n)
    messy = fr.iloc[np.concatenate([k, k[:50]])].copy()        # every record, then 50 of them again
    messy.iloc[n:, messy.columns.get_loc("thrust_left_n")] += 7.0   # the repeats' forces differ
    messy.iloc[n // 2, messy.columns.get_loc("thrust_right_n")] = np.nan
    messy.iloc[n // 2, messy.columns.get_loc("right")] = np.nan
    out = log.copy()
    out.set("/thrust/command", messy)
    got = run_data(out, default_vessel())
    # the same by hand: pandas' stable sort, the first of each stamp, the bad record's stamp from its repeat
    want = messy[np.isfinite(messy["thrust_right_n"].to_numpy(float))]
    want = want.iloc[np.argsort(np.asarray(want.index, np.int64), kind="stable")]
    want = want[~want.index.duplicated(keep="first")]
    t_ns = np.asarray(want.index, np.int64)
    np.testing.assert_array_equal(got.t_thrust, (t_ns - t_ns[0]) / 1e9)
    tau_u = want["thrust_left_n"].to_numpy(float) + want["thrust_right_n"].to_numpy(float)
    np.testing.assert_allclose(got.tau_u, tau_u, rtol=1e-12)
    assert got.thrust_skipped == 1 and len(got.t_thrust) == n - 1   # (the bad record's stamp is not repeated)
