"""``usvlog inspect`` streams an MCAP file chunk by chunk: the same summary as loading it whole.

The independent truth is the loading path: ``summarize(read_log(path))`` (the whole log in
memory, every chunk checked the same way). Memory is measured by benchmarks/bench_inspect.py.
"""

import json
from pathlib import Path

import numpy as np
import pytest

from usvlog import api
from usvlog.cli import main
from usvlog.io.mcap import read_log, write_log
from usvlog.io.mcap.reader import iter_chunks
from usvlog.log.fieldlog import FieldLog
from usvlog.log.summary import TimeStats, format_summary, summarize, summarize_channel
from usvlog.sim.simulate import SimSettings, simulate

DATA = Path(__file__).resolve().parents[1] / "data"


def _both(path):
    """(streamed summary, summary of the whole loaded log) of one file, as dicts."""
    return api.inspect(path).to_dict(), summarize(read_log(path)).to_dict()


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    """A 60 s excitation run in ~30 chunks, and its bytes."""
    log = simulate("excitation", SimSettings(duration_s=60.0), seed=5)
    d = tmp_path_factory.mktemp("inspect")
    path = d / "clean.mcap"
    write_log(log, path, chunk_size=64 * 1024)
    return path, path.read_bytes()


@pytest.mark.parametrize("name", sorted(p.name for p in DATA.glob("*.mcap")))
def test_streamed_summary_equals_the_loaded_one_on_the_data_sets(name):
    streamed, whole = _both(DATA / name)
    assert streamed == whole
    assert streamed["channels"] and streamed["recovery"] is None


def test_streamed_summary_equals_the_loaded_one_on_damaged_files(small, tmp_path):
    path, data = small
    rng = np.random.default_rng(7)
    cases = {"cut": data[:int(len(data) * 0.7)], "trailing": data + b"garbage after the footer" * 10}
    for k in range(6):                                             # bit flips and zeroed blocks in the middle
        at = int(rng.integers(len(data) // 4, 3 * len(data) // 4))
        flipped = bytearray(data)
        flipped[at] ^= 1 << int(rng.integers(8))
        cases[f"flip{k}"] = bytes(flipped)
        zeroed = bytearray(data)
        zeroed[at:at + 4096] = bytes(4096)
        cases[f"zero{k}"] = bytes(zeroed)
    cases["no-footer-and-flip"] = cases["flip0"][:len(data) - 5000]
    seen_damage = 0
    for name, blob in cases.items():
        p = tmp_path / f"{name}.mcap"
        p.write_bytes(blob)
        s, whole = _both(p)
        assert s == whole, name
        seen_damage += s["recovery"] is not None
    assert seen_damage == len(cases)
    s, whole = _both(tmp_path / "trailing.mcap")
    assert s == whole and s["recovery"]["trailing_bytes"] == 240


def test_iter_chunks_yields_every_message_once_with_its_chunk_time_range(small):
    path, _ = small
    log = read_log(path)
    got: dict[str, list] = {}
    with iter_chunks(path) as stream:
        chunks = list(stream)
        topics = {c: ch.topic for c, ch in stream.channels.items()}
        assert stream.recovery() is None
    assert len(chunks) > 20
    for c in chunks:
        assert c.start_ns <= c.log_time_ns.min() and c.log_time_ns.max() <= c.end_ns
        for cid, t in zip(c.channel_id.tolist(), c.log_time_ns.tolist()):
            got.setdefault(topics[cid], []).append(t)
    assert {t: sorted(v) for t, v in got.items()} == {t: sorted(f.index.tolist()) for t, f in log.channels.items()}


def _stamps(rng, n):
    """Jittery 100 Hz stamps with gaps, duplicates and steps back."""
    dt = rng.integers(9_000_000, 11_000_001, n)
    dt[rng.integers(0, n, 30)] = rng.integers(50_000_000, 900_000_000, 30)    # gaps
    dt[rng.integers(0, n, 10)] = 0                                          # duplicates
    dt[rng.integers(0, n, 10)] = -5_000_000                                 # backwards
    return 1_750_000_000 * 10**9 + np.cumsum(dt)


@pytest.mark.parametrize("max_distinct", [1 << 18, 64])
@pytest.mark.parametrize("n", [1, 2, 5_000, 20_001])
def test_time_stats_equal_summarize_channel_in_batches(n, max_distinct):
    """Exact in one pass, or with a histogram and a second pass when the intervals are too varied."""
    rng = np.random.default_rng(n)
    t = _stamps(rng, n)
    seq = np.arange(n)
    cuts = np.sort(rng.integers(0, n, 12))
    st = TimeStats(max_distinct=max_distinct)
    for a in np.split(np.arange(n), cuts):
        st.add(t[a], seq[a])
    if st.needs_pass():
        assert max_distinct == 64 and st.needs_pass() == "median"
        st.start_pass()
        for a in np.split(np.arange(n), cuts):
            st.refine(t[a], seq[a])
    assert st.summary("/x", "S") == summarize_channel("/x", "S", t)


def test_time_stats_out_of_order_sequences_take_a_second_pass():
    rng = np.random.default_rng(3)
    t = _stamps(rng, 3000)
    seq = rng.permutation(3000)
    st = TimeStats()
    for a in np.array_split(np.arange(3000), 7):
        st.add(t[a], seq[a])
    assert st.needs_pass() == "all"
    st.start_pass()
    for a in np.array_split(np.arange(3000), 7):
        st.refine(t[a], seq[a])
    assert st.summary("/x", "S") == summarize_channel("/x", "S", t[np.argsort(seq, kind="stable")])


def test_inspect_exit_codes_and_damage_line(small, tmp_path, capsys):
    path, data = small
    magic = tmp_path / "magic.mcap"
    magic.write_bytes(data[:8])
    assert main(["inspect", str(magic)]) == 1                      # damaged, nothing recovered
    out, err = capsys.readouterr()
    assert "DAMAGED FILE: input damaged: nothing recovered" in out and "nothing recovered" in err
    empty = tmp_path / "empty.mcap"
    write_log(FieldLog(), empty)
    assert main(["inspect", str(empty), "--json"]) == 0            # a valid empty file
    assert json.loads(capsys.readouterr().out)["recovery"] is None
    trailing = tmp_path / "trailing.mcap"
    trailing.write_bytes(data + b"\0" * 100)
    assert main(["inspect", str(trailing)]) == 0
    out, err = capsys.readouterr()
    rec = api.inspect(trailing).recovery
    assert f"DAMAGED FILE: {rec['summary']}" in out and "100 bytes after the end of the MCAP data" in out
    assert "100 bytes of garbage after the end" in err
    assert format_summary(api.inspect(path)) == format_summary(summarize(read_log(path)))


def test_inspect_says_relative_time_when_the_source_has_no_absolute_base(tmp_path, capsys):
    from usvlog.cli import main

    src = tmp_path / "r.csv"
    src.write_text("time_s,lat_deg,lon_deg\n" + "".join(f"{i / 10:.1f},{63.43 + 1e-5 * i:.7f},10.39\n"
                                                       for i in range(50)))
    assert main(["import", str(src), "--out", str(tmp_path / "r.mcap")]) == 0
    assert main(["import", str(src), "--out", str(tmp_path / "a.mcap"), "--start-utc", "2024-05-01T10:00:00Z"]) == 0
    capsys.readouterr()
    assert main(["inspect", str(tmp_path / "r.mcap")]) == 0
    time_line = next(x for x in capsys.readouterr().out.splitlines() if x.startswith("time "))
    assert time_line.split()[1:5] == ["relative", "time", "0.000", ".."] and "4.900 s" in time_line
    assert main(["inspect", str(tmp_path / "a.mcap")]) == 0
    time_line = next(x for x in capsys.readouterr().out.splitlines() if x.startswith("time "))
    assert time_line.split()[1].startswith("2024-05-01T10:00:00")


@pytest.mark.parametrize("verb", [["inspect"], ["estimate", "--out", "x.mcap"], ["identify", "--out", "v.toml"]])
def test_json_verbs_report_a_failure_as_json_too(tmp_path, capsys, verb):
    import json

    from usvlog.cli import main

    bad = tmp_path / "g.txt"
    bad.write_text("garbage\n")
    args = [verb[0], str(bad), *[str(tmp_path / a) if a.endswith((".mcap", ".toml")) else a for a in verb[1:]]]
    assert main([*args, "--json"]) == 2
    out = capsys.readouterr()
    doc = json.loads(out.out)
    assert doc["kind"].endswith("Error") and doc["internal"] is False and str(bad) in doc["error"]
    assert len(out.err.strip().splitlines()) == 1
