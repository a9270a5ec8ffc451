"""The view and the report read only the channels they draw, and the log's time range stays the
whole file's (checked against a full read of the same real MCAP file)."""

from __future__ import annotations

import numpy as np
import pytest

from usvlog.io.mcap import read_log, write_log
from usvlog.io.mcap.reader import chunk_spans
from usvlog.log.channels import channel_spec, frame_from_columns
from usvlog.sim.simulate import SimSettings, simulate
from usvlog.view.source import REPORT_TOPICS, VIEW_TOPICS, read_drawn


@pytest.fixture(scope="module")
def sim_log():
    return simulate("excitation", SimSettings(duration_s=8.0), seed=2)


def _with_yaw_rate(log, path, shift_s: float):
    t = log["/truth/state"].index.to_numpy() + int(shift_s * 1e9)
    r = log["/truth/state"]["r_radps"].to_numpy()
    log = log.copy()
    log.set("/imu/yaw_rate", frame_from_columns({"stamp_ns": t, "r_radps": r}, t, channel_spec("/imu/yaw_rate")))
    write_log(log, path, chunk_size=1 << 14)   # many chunks, each holding every channel of its time
    return path


@pytest.mark.parametrize("shift_s", [0.0, 5.0])
def test_undrawn_channel_skipped_only_inside_the_time_range(tmp_path, sim_log, shift_s):
    path = _with_yaw_rate(sim_log, tmp_path / "a.mcap", shift_s)
    spans = chunk_spans(path)
    assert len(spans) > 4
    # the same chunks as the mcap library's summary reader finds
    from mcap.reader import make_reader

    with open(path, "rb") as fh:
        lib = make_reader(fh).get_summary()
    topic = {cid: ch.topic for cid, ch in lib.channels.items()}
    assert spans == [(c.message_start_time, c.message_end_time, frozenset(topic[k] for k in c.message_index_offsets))
                     for c in sorted(lib.chunk_indexes, key=lambda c: c.chunk_start_offset)]
    full = read_log(path)
    for topics in (VIEW_TOPICS, REPORT_TOPICS):
        log = read_drawn(path, topics, read_log)
        assert log.time_range() == full.time_range()
        assert ("/imu/yaw_rate" in log.channels) == (shift_s > 0)   # read only to widen the range
        for t in set(full.channels) & set(topics):
            assert np.array_equal(log[t].index.to_numpy(), full[t].index.to_numpy())
    assert "/thrust/command" in read_drawn(path, VIEW_TOPICS, read_log).channels
    assert "/thrust/command" in read_drawn(path, REPORT_TOPICS, read_log).channels   # the report's manoeuvres


def test_chunk_spans_of_a_file_without_a_usable_summary_is_none(tmp_path, sim_log):
    path = _with_yaw_rate(sim_log, tmp_path / "a.mcap", 0.0)
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(path.read_bytes()[:-100])     # footer and part of the summary gone
    assert chunk_spans(cut) is None
    (tmp_path / "x.mcap").write_bytes(b"not an mcap file")
    assert chunk_spans(tmp_path / "x.mcap") is None


SPLIT_SCRIPT = r'''
import json, os, sys
from usvlog.io.mcap import read_log
from usvlog.view import source
from usvlog.view.forked import two_cores

path, parent, fork = sys.argv[1], os.getpid(), two_cores()
ref = source.read_drawn(path, source.VIEW_TOPICS, read_log)
out = {"fork": fork}
for fail in (False, True):   # a copy that fails leaves the channel to this process
    calls = []

    def read(p, topics=None):
        if fail and os.getpid() != parent:
            raise RuntimeError("the copy fails")
        return read_log(p, topics=topics)

    got = source.read_drawn(path, source.Drawn(source.VIEW_TOPICS, late=("/no/such", "/thrust/command"),
                                               meanwhile=lambda: calls.append(os.getpid())), read)
    out[f"fail={fail}"] = {
        "same": sorted(ref.channels) == sorted(got.channels) and ref.time_range() == got.time_range()
        and all(ref[t].equals(got[t]) and ref[t].index.equals(got[t].index)
                and list(ref[t].dtypes) == list(got[t].dtypes) for t in ref.channels)
        and all(ref.schemas.get(t) == got.schemas.get(t) for t in ref.channels),
        "meanwhile once": calls == [parent], "thrust": "/thrust/command" in got.channels}
print(json.dumps(out))
'''


def test_channel_read_by_a_forked_copy_gives_the_same_log(tmp_path, sim_log):
    """A channel read by a forked copy while this process does other work (``Drawn.late``) gives
    the log read in one go; a copy that fails leaves the channel to this process. In a fresh
    interpreter: a copy is forked only when no other thread runs (a test worker has threads)."""
    import json
    import os
    import subprocess
    import sys
    from pathlib import Path

    import usvlog

    path = _with_yaw_rate(sim_log, tmp_path / "a.mcap", 0.0)
    root = Path(usvlog.__file__).resolve().parents[1]
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(root), *filter(None, [os.environ.get("PYTHONPATH")])]))
    r = subprocess.run([sys.executable, "-c", SPLIT_SCRIPT, str(path)], capture_output=True, text=True, env=env,
                       cwd=root, timeout=300)
    assert r.returncode == 0, r.stderr
    got = json.loads(r.stdout.strip().splitlines()[-1])
    for case in ("fail=False", "fail=True"):
        assert got[case] == {"same": True, "meanwhile once": True, "thrust": True}, got
    if not got["fork"]:
        pytest.skip("no forked copy here (one CPU, USVLOG_THREADS=1 or not Linux): compared in-process only")


def test_compass_read_only_for_a_log_without_a_state(tmp_path, sim_log):
    """The view draws the compass only when no state channel is there: a log holding one is read
    without it (its time range still the whole file's), one without a state reads it."""
    from usvlog.view.source import VIEW_READ, Drawn

    drawn = Drawn(VIEW_TOPICS, unless=VIEW_READ.unless)   # no forked copy, no rerun import
    raw = sim_log.copy()
    del raw.channels["/truth/state"]
    for log, name, compass in ((sim_log, "a.mcap", False), (raw, "b.mcap", True)):
        path = tmp_path / name
        write_log(log, path, chunk_size=1 << 14)
        got = read_drawn(path, drawn, read_log)
        assert ("/compass/heading" in got.channels) == compass
        assert got.time_range() == read_log(path).time_range()
