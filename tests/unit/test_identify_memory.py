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
def test_a_log_without_its_thrust_smooths_with_the_runs_to_the_same_numbers(run_120s, kind):
    """The fit's logs lose their thrust channel (runs_and_lean_logs): the smoother, and the free runs'
    smoothing of the whole run and of a held-out window, take the run's thrust instead, to the same
    numbers as from the channel (a bad record skipped in both)."""
    from dataclasses import replace

    from usvlog.identify.data import runs_and_lean_logs
    from usvlog.model.thrusters import Thrusters

    log, _, _ = run_120s
    boat = default_vessel()
    if kind != "logged newtons":
        log = _pwm_version(log)
        boat = replace(boat, thrusters=Thrusters(map="t200", supply_v=16.0))
    (run,), (lean,) = runs_and_lean_logs([log], boat)
    assert "/thrust/command" not in lean and "/thrust/command" in log   # the caller's log is not touched
    assert run.thrust_skipped == (kind != "logged newtons")
    a, b = smooth.kinematic_states(log, run, boat), smooth.kinematic_states(lean, run, boat)   # (as the fit does)
    for name in ("t", "n", "e", "psi", "vn", "ve", "r"):
        np.testing.assert_array_equal(getattr(b, name), getattr(a, name))
    t, sim = _free_run(a, 60.0, 119.0)
    np.testing.assert_array_equal(b.seen(t, sim, (0.1, -0.05)), a.seen(t, sim, (0.1, -0.05)))
    held_a, held_b = a.window(70.0, np.inf).trimmed(), b.window(70.0, np.inf).trimmed()
    assert held_b.smoother.seen.thrust.t_thrust[0] < 70.0 and held_b.smoother.seen.thrust.t_thrust.base is not None
    t, sim = _free_run(held_a, 75.0, 119.0)
    np.testing.assert_array_equal(held_b.seen(t, sim, (0.1, -0.05)), held_a.seen(t, sim, (0.1, -0.05)))


def test_run_thrust_gives_the_logs_records_in_a_span_on_their_own_stamps(run_120s):
    """run_thrust's frames: the log's stamps exactly (ns), the forces of run_data, only the records
    stamped in [lo, hi] (both ends kept), in windows of any size."""
    from dataclasses import replace

    from usvlog.estimate.problem import TAU_COLUMNS
    from usvlog.identify.data import run_thrust

    log, run, _ = run_120s
    t_log = np.asarray(log["/thrust/command"].index, np.int64)
    lo, hi = int(t_log[1234]), int(t_log[5678])
    for records in (100, 4444, 1 << 20):
        got = pd.concat(list(run_thrust(run, lo, hi, records=records)()))
        np.testing.assert_array_equal(np.asarray(got.index, np.int64), t_log[1234:5679])
        np.testing.assert_array_equal(got[TAU_COLUMNS[0]].to_numpy(), run.tau_u[1234:5679])
        np.testing.assert_array_equal(got[TAU_COLUMNS[1]].to_numpy(), run.tau_r[1234:5679])
    whole = pd.concat(list(run_thrust(run)()))
    np.testing.assert_array_equal(np.asarray(whole.index, np.int64), t_log)
    # the stamps come back exact from the run's seconds, weeks into a run and for any t0
    rng = np.random.default_rng(1)
    t0 = 1_780_000_000_123_456_789
    t_ns = t0 + np.sort(rng.integers(0, 21 * 86400 * 10**9, 100_000))
    far = replace(run, t0_ns=t0, t_thrust=(t_ns - t0) / 1e9, tau_u=np.zeros(len(t_ns)), tau_r=np.zeros(len(t_ns)))
    np.testing.assert_array_equal(np.asarray(pd.concat(list(run_thrust(far)())).index, np.int64), t_ns)


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


@pytest.fixture(scope="module")
def fitted_with_holdout():
    """The paper's vessel identified from a 240 s excitation run, its last 40 % held out."""
    from usvlog.identify import Identifier

    log = simulate("excitation", SimSettings(duration_s=240.0, vessel=default_vessel()), seed=11)
    return Identifier("output-error", holdout=0.4).fit([log])


def test_candidates_keep_their_figures_and_their_free_runs_are_made_again_to_the_same_numbers(
        fitted_with_holdout):
    """A candidate keeps its validations' summaries only (fit %, score: ~8 MB a validation of a 3-hour
    log's held-out part let go); the free runs made again where they are needed (the returned
    candidate's, the smoother-bias check's) give the figures the candidate was picked by, exactly."""
    idf = fitted_with_holdout
    ok = [c for c in idf.candidates_ if not c.failed]
    assert len(ok) >= 3
    for c in ok:
        kept = list(c.validations)
        if c is not idf.chosen_:
            assert all(not v.has_arrays and v.measured is None and v.seen is None for v in kept)
            with pytest.raises(ValueError, match="summary"):
                kept[0].to_dataframe()
        again = idf.candidate_validations(c)
        assert [v.has_arrays for v in again] == [True] * len(kept)
        for s, v in zip(kept, again):
            assert v.fit_percent == s.fit_percent and v.score == s.score and v.to_dict() == s.to_dict()
            assert v.to_dataframe().shape[0] == len(v.t) > 100
    # what the verdict and the reports read: the chosen candidate's validations, with their arrays
    assert idf.validations_ and all(v.has_arrays for v in idf.validations_)
    assert [v.fit_percent for v in idf.validations_] == [v.fit_percent for v in idf.chosen_.validations]
