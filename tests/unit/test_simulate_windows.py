"""The open-loop scenarios simulated a time window at a time (``usvlog simulate`` with an output):
the same frames as the whole run, and the same file byte for byte."""

import numpy as np
import pytest

from tests.unit.sim_windows import joined
from usvlog.sim import simulate as sim
from usvlog.sim.simulate import SensorSettings, SimSettings, simulate, simulate_windows

SENSORS = SensorSettings(gps_jumps=((30.0, 20.0), (30.0, 5.0), (71.3, 8.0)), gps_dropouts=((40.0, 25.0),),
                         gps_bias_sigma_m=2.0, truth_rate_hz=7.0, compass_bias_deg=3.0, gps_delay_s=0.05)


@pytest.mark.parametrize("scenario,sensors", [("excitation", SENSORS), ("excitation", SensorSettings()),
                                              ("turns", SENSORS), ("straight", SensorSettings(truth_rate_hz=3.0))])
def test_windows_give_the_whole_runs_frames(scenario, sensors):
    """Windows of 997 steps (no sensor's period divides it; a whole window without GPS fixes)
    put together are the whole run's channels, the same numbers: the plant's and the
    zig-zag's state go on across windows, the random draws are made in the whole run's order."""
    st = SimSettings(duration_s=150.0, current_mps=0.2, current_dir_deg=40.0, sensors=sensors)
    whole = simulate(scenario, st, seed=4)
    head, windows = simulate_windows(scenario, st, seed=4, window_steps=997)
    n, parts = joined(windows)
    assert n == -(-st.n_steps // 997)
    assert head.meta == {k: v for k, v in whole.meta.items()}
    assert list(parts) == list(whole.channels)
    for topic, got in parts.items():
        ref = whole[topic]
        assert np.array_equal(got.index, ref.index), topic
        assert got.equals(ref), topic
    if scenario == "excitation":   # the zig-zag switched both ways across windows
        tr = whole["/truth/state"]["tau_r_nm"].to_numpy()
        assert (tr > 0.5).any() and (tr < -0.5).any()


def test_simulate_verb_writes_the_whole_logs_file(tmp_path, monkeypatch):
    """api.simulate with ``out`` writes in windows (through a spool) the file ``save`` writes
    for the whole run's log, byte for byte, in more than one time slice of the writer; the
    spool is gone after, and the log returned is the file's."""
    from usvlog import api
    from usvlog.api.simulation import _sim_settings

    kw = dict(duration_s=400.0, gps_jumps=[(12.0, 9.0)], gps_dropouts=[(100.0, 30.0)], compass_bias_deg=2.0)
    st = _sim_settings(current_mps=0.0, current_dir_deg=0.0, vessel=None, gps_noise_m=None, compass_noise_deg=None,
                       gps_bias_m=None, truth_rate_hz=None, **kw)
    ref = tmp_path / "whole.mcap"
    api.save(simulate("excitation", st, seed=2), ref)
    monkeypatch.setattr(sim, "WINDOW_STEPS", 4099)
    calls = []
    real = sim.simulate_windows
    monkeypatch.setattr(sim, "simulate_windows", lambda *a, **k: calls.append(1) or real(*a, **k))
    out = tmp_path / "windows.mcap"
    log = api.simulate("excitation", out, seed=2, **kw)
    assert calls, "the verb did not simulate in windows"
    assert out.read_bytes() == ref.read_bytes()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["whole.mcap", "windows.mcap"]
    assert len(log["/truth/state"]) == st.n_steps
    assert log.vessel == st.vessel
