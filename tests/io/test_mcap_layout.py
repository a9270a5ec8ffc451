"""The file layout: chunks by channel, reads that skip the others, copies that take chunks whole."""

import os

import numpy as np
import pandas as pd
import pytest
from mcap.reader import make_reader

from usvlog.errors import InputError
from usvlog.io.mcap import read_log, write_log
from usvlog.io.mcap.reader import chunks_decompressed

SMALL = {"chunk_size": 1 << 14, "slice_messages": 3000}   # many chunks and slices on a 120 s log


@pytest.fixture(scope="module")
def small_file(tmp_path_factory, excitation_log):
    path = tmp_path_factory.mktemp("layout") / "src.mcap"
    write_log(excitation_log, path, **SMALL)
    return path


def _chunks(path) -> list[tuple[bytes, list[str]]]:
    """(the Chunk record's bytes, the topics its message indexes name) of every chunk, by the
    mcap library's reading of the summary."""
    data = path.read_bytes()
    with open(path, "rb") as fh:
        summary = make_reader(fh).get_summary()
    topic = {c.id: c.topic for c in summary.channels.values()}
    return [(data[c.chunk_start_offset:c.chunk_start_offset + c.chunk_length],
             [topic[i] for i in c.message_index_offsets]) for c in summary.chunk_indexes]


def test_a_new_file_has_one_channel_per_chunk_and_reads_in_time_order(small_file, excitation_log):
    chunks = _chunks(small_file)
    assert all(len(topics) == 1 for _rec, topics in chunks)
    assert {t for _rec, topics in chunks for t in topics} == set(excitation_log.topics)
    # the mcap library (as Foxglove reads) merges the chunks, overlapping in time, into time order
    times: dict[str, list[int]] = {}
    last = -1
    with open(small_file, "rb") as fh:
        for _schema, channel, message in make_reader(fh).iter_messages(log_time_order=True):
            assert message.log_time >= last
            last = message.log_time
            times.setdefault(channel.topic, []).append(message.log_time)
    for topic in excitation_log.topics:   # every message, each channel in its row order
        assert times[topic] == excitation_log[topic].index.tolist()


def test_a_topics_read_decompresses_only_the_wanted_channels_chunks(small_file, excitation_log):
    wanted = ["/gnss/fix", "/compass/heading"]
    chunks = _chunks(small_file)
    n_wanted = sum(topics[0] in wanted for _rec, topics in chunks)
    assert 0 < n_wanted < len(chunks) // 2
    before = chunks_decompressed()
    log = read_log(small_file, topics=wanted)
    assert chunks_decompressed() - before == n_wanted
    assert log.topics == sorted(wanted) and log.recovery is None
    for t in wanted:
        pd.testing.assert_frame_equal(log[t], excitation_log[t], check_freq=False)


def _with_result(log):
    """``log`` plus a derived channel, as a verb adds one."""
    out = log.copy()
    fix = log["/gnss/fix"]
    out.set("/test/derived", pd.DataFrame({"x_m": np.arange(len(fix), dtype=float) * 0.5}, index=fix.index))
    return out


def test_a_copy_takes_the_source_chunks_as_they_are(tmp_path, small_file, excitation_log):
    lazy = read_log(small_file, topics=["/gnss/fix"], defer=True)
    out = tmp_path / "out.mcap"
    write_log(_with_result(lazy), out, **SMALL)
    copied = set(lazy.channels.deferred_topics())
    src = {rec for rec, topics in _chunks(small_file) if topics[0] in copied}
    ours = {rec for rec, topics in _chunks(out) if topics[0] in copied}
    assert src and ours == src   # the copied channels' Chunk records byte for byte
    back = read_log(out)
    for t in excitation_log.topics:
        pd.testing.assert_frame_equal(back[t], excitation_log[t], check_freq=False)


def test_a_copy_refuses_a_source_chunk_damaged_since_reading(tmp_path, small_file):
    path = tmp_path / "src.mcap"
    data = bytearray(small_file.read_bytes())
    path.write_bytes(data)
    lazy = read_log(path, topics=["/gnss/fix"], defer=True)
    st = os.stat(path)
    with open(path, "rb") as fh:
        summary = make_reader(fh).get_summary()
    truth = next(c.id for c in summary.channels.values() if c.topic == "/truth/state")
    c = [c for c in summary.chunk_indexes if list(c.message_index_offsets) == [truth]][3]
    data[c.chunk_start_offset + c.chunk_length - 8] ^= 0xFF   # in a chunk copied whole otherwise
    path.write_bytes(data)
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns))       # same size and time: found by its CRC check
    with pytest.raises(InputError, match="damaged"):
        write_log(_with_result(lazy), tmp_path / "out.mcap", **SMALL)
    assert not (tmp_path / "out.mcap").exists()


def test_reading_and_writing_start_no_thread(tmp_path, small_file, monkeypatch):
    """With or without a spare CPU (USVLOG_THREADS=2 or 1) reading and writing a log start no
    thread (the chunks are compressed in the calling thread), and the files are byte for byte
    the same."""
    import threading

    outs = {}
    for threads in ("2", "1"):
        monkeypatch.setenv("USVLOG_THREADS", threads)
        started: list[str] = []
        threading.settrace(lambda *_a, started=started: started.append(threading.current_thread().name))
        try:
            lazy = read_log(small_file, topics=["/gnss/fix"], defer=True)
            outs[threads] = tmp_path / f"out{threads}.mcap"
            write_log(_with_result(lazy), outs[threads], **SMALL)
        finally:
            threading.settrace(None)
        names = {n.split("_")[0] for n in started}
        assert names == set(), names
    assert outs["1"].read_bytes() == outs["2"].read_bytes()
