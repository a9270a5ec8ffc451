"""Replay from a file to a file a time window at a time (usvlog.replay.replay_file): the same
numbers and the same bytes as the whole log replayed in memory and written (replay_log +
write_log), over many windows of the input, of the ticks and of the what-if run."""

import importlib

import numpy as np
import pandas as pd
import pytest

from usvlog.io.mcap import read_log, write_log
from usvlog.io.mcap.windows import iter_windows
from usvlog.sim.closed_loop import closed_loop, closed_loop_windows, make_controller
from usvlog.sim.scenario import load_scenario

R = importlib.import_module("usvlog.replay")   # (usvlog.replay is also the API function's name)


def test_windows_joined_are_the_channels_read_whole(tmp_path, excitation_log):
    path = tmp_path / "x.mcap"
    write_log(excitation_log, path, chunk_size=1 << 14)   # many chunks: many windows
    topics = ["/truth/state", "/thrust/command", "/gnss/fix"]
    wins = list(iter_windows(path, topics))
    assert len(wins) > 10
    whole = read_log(path, topics=topics)
    last = -1
    for topic in topics:
        parts = [w[topic] for w in wins if topic in w]
        joined = parts[0] if len(parts) == 1 else pd.concat(parts)
        assert joined.equals(whole[topic]), topic
    for w in wins:   # windows in time order: every row of a window before every row of the next
        lo = min(int(f.index[0]) for f in w.values())
        assert lo > last
        last = max(int(f.index[-1]) for f in w.values())


def test_unwrap_a_window_at_a_time_is_numpy_unwrap():
    rng = np.random.default_rng(1)
    psi = np.angle(np.exp(1j * np.cumsum(rng.normal(0, 1.5, 5000))))   # jumps both ways, often
    whole = np.unwrap(psi)
    out, prev, carry = [], None, 0.0
    for part in np.array_split(psi, [1, 7, 100, 2500, 2501, 4000]):
        u, carry = R._unwrap(part, prev, carry)
        if len(part):
            prev = float(part[-1])
        out.append(u)
    assert np.array_equal(np.concatenate(out), whole)


def test_closed_loop_windows_joined_are_the_closed_loop():
    scen = load_scenario("paper-sine")
    path = scen.path()
    kw = dict(duration_s=30.0, dt_s=0.01, integrator="rk4", current_ne=(0.1, -0.05), eta0=(0.0, 1.0, 0.2),
              nu0=(0.5, 0.0, 0.0), schedule=scen.schedule, rate_hz=50.0)
    ref = closed_loop(path, scen.sim.vessel, make_controller(scen, path), **kw)
    runs = list(closed_loop_windows(path, scen.sim.vessel, make_controller(scen, path), window_ticks=97, **kw))
    assert len(runs) > 10
    assert np.array_equal(np.concatenate([r.states for _, r in runs]), ref.states)
    assert np.array_equal(np.concatenate([r.tau for _, r in runs]), ref.tau)
    assert np.array_equal(np.concatenate([r.ctrl for _, r in runs]), ref.ctrl)
    assert np.array_equal(np.concatenate([k0 + r.tick for k0, r in runs]), ref.tick)


def _closed_loop_log():
    from usvlog.sim.closed_loop import simulate_scenario

    return simulate_scenario(load_scenario("paper-sine"), duration_s=90.0)   # with /control/state


@pytest.mark.parametrize("case", ["excitation", "no-commands", "closed-loop"])
def test_replay_file_is_replay_log_written(tmp_path, excitation_log, monkeypatch, case):
    log = _closed_loop_log() if case == "closed-loop" else excitation_log.copy()
    if case == "no-commands":   # ticks at the scenario's rate from the first state to the last
        del log.channels["/thrust/command"]
    src = tmp_path / "in.mcap"
    write_log(log, src, chunk_size=1 << 15)
    monkeypatch.setattr(R, "WHATIF_WINDOW_TICKS", 333)
    scen = load_scenario("paper-sine")
    res = R.replay_file(src, scen, tmp_path / "r.mcap")
    assert res is not None                                   # it ran window by window
    assert res.metrics == R.replay_log(read_log(src), scen).metrics
    # the file the replay verb wrote before: the channels it reads decoded, the others copied
    ref = R.replay_log(read_log(src, topics=["/estimate/state", "/thrust/command", "/control/state"], defer=True),
                       scen, release_inputs=True)
    if case == "closed-loop":
        assert ref.metrics.decisions_compared > 1000
    if case == "no-commands":
        assert ref.metrics.command_unit is None and ref.metrics.n_commands_compared == 0
    write_log(ref.log, tmp_path / "whole.mcap")
    assert (tmp_path / "r.mcap").read_bytes() == (tmp_path / "whole.mcap").read_bytes()
    back = read_log(tmp_path / "r.mcap")
    for topic in log.topics:                                 # every input message is there
        assert back[topic].equals(log[topic]), topic
    assert not list(tmp_path.glob(".*spool"))                # the spools are gone


def test_replay_file_gives_way_where_a_channel_is_out_of_order(tmp_path, excitation_log):
    import usvlog

    log = excitation_log.copy()
    cmd = log["/thrust/command"]
    t = cmd.index.to_numpy().copy()
    t[[100, 101]] = t[[101, 100]]                   # two commands stored out of time order
    log.set("/thrust/command", cmd.set_axis(t))
    src = tmp_path / "in.mcap"
    write_log(log, src, chunk_size=1 << 15)
    scen = load_scenario("paper-sine")
    assert R.replay_file(src, scen, tmp_path / "r.mcap") is None   # nothing written: replayed whole instead
    assert not (tmp_path / "r.mcap").exists() and not list(tmp_path.glob(".*spool"))
    res = usvlog.replay(str(src), "paper-sine", tmp_path / "r.mcap")
    assert res.metrics == R.replay_log(read_log(src), scen).metrics


def test_small_chunks_copied_whole_are_all_kept(tmp_path, excitation_log):
    # a recorder flushes small chunks: copied whole into a file of larger ones, one after
    # another of the same channel, each was written (the writer once kept only the last)
    src = tmp_path / "in.mcap"
    write_log(excitation_log, src, chunk_size=1 << 13)
    log = read_log(src, topics=[], defer=True)
    write_log(log, tmp_path / "out.mcap")
    back = read_log(tmp_path / "out.mcap")
    for topic in excitation_log.topics:
        assert back[topic].equals(excitation_log[topic]), topic


def test_replay_file_refuses_an_output_directory_that_is_missing(tmp_path, excitation_file):
    from usvlog.errors import StorageError

    with pytest.raises(StorageError):
        R.replay_file(excitation_file, load_scenario("paper-sine"), tmp_path / "no" / "r.mcap")

