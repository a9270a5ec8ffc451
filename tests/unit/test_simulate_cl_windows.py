"""The closed-loop scenarios simulated a time window at a time (``usvlog simulate`` with an output):
the same frames as the whole run, and the same file byte for byte."""

from dataclasses import replace

import numpy as np
import pytest

from tests.unit.sim_windows import joined
from usvlog.sim import closed_loop as cl
from usvlog.sim.closed_loop import scenario_topics, scenario_windows, simulate_scenario
from usvlog.sim.scenario import load_scenario
from usvlog.sim.simulate import SensorSettings


def _lagged(scen):
    """The scenario's vessel with a thruster lag (the extended plant step, its force carried)."""
    v = scen.sim.vessel
    return replace(scen, sim=replace(scen.sim, vessel=replace(v, thrusters=replace(v.thrusters, lag_s=0.4))))


def _thinned_at_20_hz(scen):
    """Truth thinned to 7 Hz, GPS faults, the controller at 20 Hz (a tick every 5 steps)."""
    sens = SensorSettings(truth_rate_hz=7.0, gps_jumps=((30.0, 20.0),), gps_dropouts=((40.0, 25.0),),
                          gps_bias_sigma_m=1.0)
    return replace(scen, sim=replace(scen.sim, sensors=sens), guidance=replace(scen.guidance, rate_hz=20.0))


CASES = {"circle": ("paper-circle", None, None), "circle-baseline": ("paper-circle", "baseline", None),
         "circle-lag": ("paper-circle", None, _lagged), "sine-ekf": ("paper-sine", None, None),
         "sine-ekf-20hz": ("paper-sine", None, _thinned_at_20_hz), "sine-ekf-lag": ("paper-sine", None, _lagged)}


@pytest.mark.parametrize("case", list(CASES))
def test_windows_give_the_whole_runs_frames(case):
    """Windows of 997 steps (no sensor's period divides it) put together are the whole run's
    channels, the same numbers: the plant, its thruster lag, the controller and the onboard
    EKF go on across windows; the sensor noise is drawn in the whole run's order."""
    name, controller, change = CASES[case]
    scen = load_scenario(name)
    scen = change(scen) if change else scen
    whole = simulate_scenario(scen, controller=controller, seed=5, duration_s=120.0)
    head, windows = scenario_windows(scen, controller=controller, seed=5, duration_s=120.0, window_steps=997)
    n, parts = joined(windows)
    assert n > 10
    assert head.meta == whole.meta
    assert list(parts) == list(whole.channels) == scenario_topics(scen)
    for topic, got in parts.items():
        ref = whole[topic]
        assert np.array_equal(got.index, ref.index), topic
        assert got.equals(ref), topic


def test_simulate_verb_writes_the_whole_logs_file(tmp_path, monkeypatch):
    """api.simulate with ``out`` writes a closed-loop scenario in windows (through a spool) as the
    file ``save`` writes for the whole run's log, byte for byte, in more than one time slice of
    the writer; the spool is gone after, and the log returned is the file's."""
    from usvlog import api

    ref = tmp_path / "whole.mcap"
    api.save(simulate_scenario(load_scenario("paper-sine"), seed=2, duration_s=400.0), ref)
    calls = []
    real = cl.scenario_windows
    monkeypatch.setattr(cl, "scenario_windows", lambda *a, **k: calls.append(1) or real(*a, **k, window_steps=4099))
    out = tmp_path / "windows.mcap"
    log = api.simulate("paper-sine", out, seed=2, duration_s=400.0)
    assert calls, "the verb did not simulate in windows"
    assert out.read_bytes() == ref.read_bytes()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["whole.mcap", "windows.mcap"]
    assert sorted(log.channels) == sorted(scenario_topics(load_scenario("paper-sine")))
    assert len(log["/control/state"]) == 40000
