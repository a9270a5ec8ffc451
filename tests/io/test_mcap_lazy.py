"""Deferred channels: a log read with a subset of its channels decoded, the rest copied undecoded."""

import os

import numpy as np
import pandas as pd
import pytest

import usvlog
from usvlog.errors import InputError
from usvlog.io.mcap import read_log, write_log

READ = ["/gnss/fix"]
SMALL = {"chunk_size": 1 << 14, "slice_messages": 3000}   # many chunks and slices on a 120 s log


def _with_result(log):
    """``log`` plus a derived channel, as a verb adds one (a copy; the log's frames shared)."""
    out = log.copy()
    fix = log["/gnss/fix"]
    out.set("/test/derived", pd.DataFrame({"x_m": np.arange(len(fix), dtype=float) * 0.5}, index=fix.index))
    return out


@pytest.fixture(scope="module")
def source(tmp_path_factory, excitation_log):
    path = tmp_path_factory.mktemp("lazy") / "src.mcap"
    write_log(excitation_log, path, chunk_size=1 << 14)
    return path


def test_copied_channels_give_the_file_written_after_decoding(tmp_path, source):
    whole = read_log(source)
    lazy = read_log(source, topics=READ, defer=True)
    assert lazy.topics == whole.topics and lazy.schemas.keys() == whole.schemas.keys()
    left = lazy.channels.deferred_topics()
    assert left == sorted(set(whole.topics) - set(READ))
    write_log(_with_result(whole), tmp_path / "decoded.mcap", **SMALL)
    out = _with_result(lazy)
    write_log(out, tmp_path / "copied.mcap", **SMALL)
    assert out.channels.deferred_topics() == left           # written without decoding them
    assert (tmp_path / "copied.mcap").read_bytes() == (tmp_path / "decoded.mcap").read_bytes()
    back = usvlog.load(tmp_path / "copied.mcap")
    assert back.equals(_with_result(whole))


def test_a_touched_channel_decodes_and_is_written_as_changed(tmp_path, source):
    whole = read_log(source)
    lazy = read_log(source, topics=READ, defer=True)
    assert "/compass/heading" in lazy and "/compass/heading" in lazy.channels.deferred_topics()
    heading = lazy["/compass/heading"]                      # decoded now, from the file
    pd.testing.assert_frame_equal(heading, whole["/compass/heading"])
    assert "/compass/heading" not in lazy.channels.deferred_topics()
    heading.iloc[0, 0] += 1.0                              # changed in memory: the file's bytes are stale
    write_log(lazy, tmp_path / "out.mcap", **SMALL)
    back = read_log(tmp_path / "out.mcap")
    assert back["/compass/heading"].iloc[0, 0] == whole["/compass/heading"].iloc[0, 0] + 1.0
    for t in set(whole.topics) - {"/compass/heading"}:
        pd.testing.assert_frame_equal(back[t], whole[t])


def test_a_source_changed_since_reading_is_refused(tmp_path, source, excitation_log):
    path = tmp_path / "src.mcap"
    path.write_bytes(source.read_bytes())
    lazy = read_log(path, topics=READ, defer=True)
    st = os.stat(path)
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000_000))   # same bytes, another time
    with pytest.raises(InputError, match="changed since it was read"):
        write_log(lazy, tmp_path / "out.mcap")
    with pytest.raises(InputError, match="changed since it was read"):
        lazy["/compass/heading"]
    assert not (tmp_path / "out.mcap").exists()


def test_a_source_damaged_since_reading_is_refused_while_copying(tmp_path, source):
    from mcap.reader import make_reader

    path = tmp_path / "src.mcap"
    data = bytearray(source.read_bytes())
    path.write_bytes(data)
    lazy = read_log(path, topics=READ, defer=True)
    st = os.stat(path)
    with open(path, "rb") as fh:
        chunks = make_reader(fh).get_summary().chunk_indexes
    c = chunks[len(chunks) // 2]
    data[c.chunk_start_offset + c.chunk_length - 8] ^= 0xFF   # in a chunk's compressed records
    path.write_bytes(data)
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns))       # same size and time: found by the copy's CRC check
    with pytest.raises(InputError, match="damaged"):
        write_log(_with_result(lazy), tmp_path / "out.mcap", **SMALL)
    assert not (tmp_path / "out.mcap").exists()


def test_a_damaged_source_is_read_whole(tmp_path, source):
    data = source.read_bytes()
    path = tmp_path / "cut.mcap"
    path.write_bytes(data[:len(data) * 2 // 3])
    lazy = read_log(path, topics=READ, defer=True)
    whole = read_log(path)
    assert lazy.recovery is not None and lazy.deferred is None
    assert lazy.recovery == whole.recovery and lazy.equals(whole)


def test_redeferred_channels_are_copied_and_decode_again(tmp_path, source):
    whole = read_log(source)
    lazy = read_log(source, topics=READ, defer=True)
    out = _with_result(lazy)
    out.channels.redefer(READ)
    assert out.channels.deferred_topics() == sorted(set(whole.topics))
    write_log(out, tmp_path / "copied.mcap", **SMALL)
    write_log(_with_result(whole), tmp_path / "decoded.mcap", **SMALL)
    assert (tmp_path / "copied.mcap").read_bytes() == (tmp_path / "decoded.mcap").read_bytes()
    pd.testing.assert_frame_equal(out["/gnss/fix"], whole["/gnss/fix"])


def test_a_channel_out_of_time_order_in_its_file_is_decoded_instead(tmp_path, excitation_log):
    from usvlog.io.mcap import McapWriter

    fix, heading = excitation_log["/gnss/fix"], excitation_log["/compass/heading"]
    half = len(heading) // 2
    path = tmp_path / "unsorted.mcap"
    with open(path, "wb") as fh:   # the heading's second half first: its rows do not rise in time
        w = McapWriter(fh, chunk_size=1 << 12)
        w.add_frames({"/gnss/fix": fix, "/compass/heading": heading.iloc[half:]})
        w.add_frames({"/compass/heading": heading.iloc[:half]})
        w.finish()
        w.close()
    whole = read_log(path)
    lazy = read_log(path, topics=READ, defer=True)
    write_log(_with_result(whole), tmp_path / "decoded.mcap", **SMALL)
    out = _with_result(lazy)
    write_log(out, tmp_path / "copied.mcap", **SMALL)
    assert out.channels.deferred_topics() == []            # decoded to be written
    assert (tmp_path / "copied.mcap").read_bytes() == (tmp_path / "decoded.mcap").read_bytes()
