"""read_log allocates each column once from the summary's message counts (issue 32): the same
frames as without the counts, as the reference path, and on a damaged file (fewer messages
than the summary says: the columns trimmed)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from mcap.reader import make_reader

from usvlog.io.mcap import container, read_log, write_log
from usvlog.io.mcap.reference import read_log_reference
from usvlog.sim.simulate import SimSettings, simulate


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    log = simulate("excitation", SimSettings(duration_s=30.0), seed=5)
    path = tmp_path_factory.mktemp("sized") / "s.mcap"
    write_log(log, path, chunk_size=64 * 1024)
    return path


def same(a, b) -> None:
    assert list(a.channels) == list(b.channels)
    for k in a.channels:
        pd.testing.assert_frame_equal(a.channels[k], b.channels[k], check_exact=True)
        assert list(a.channels[k].dtypes) == list(b.channels[k].dtypes)


def test_summary_counts_are_the_statistics(small):
    data = small.read_bytes()
    s = container._read_summary(data, container._find_footer(data))
    with open(small, "rb") as fh:
        stats = make_reader(fh).get_summary().statistics
    assert s.counts == dict(stats.channel_message_counts)


def test_sized_decode_same_frames_with_and_without_counts(small, monkeypatch):
    sized = read_log(small)
    same(sized, read_log_reference(small))
    monkeypatch.setattr(container, "_channel_counts", lambda *_a: None)   # no statistics: today's path
    same(sized, read_log(small))
    for frame in sized.channels.values():   # handed to the frame: one array per column, not copied again
        for c in frame.columns:
            a = frame[c].to_numpy()
            if a.dtype != object:
                assert len(a) == len(frame)


def test_damaged_file_with_summary_trims_columns(small, tmp_path):
    """A chunk lost in the middle, summary intact: fewer messages than the summary's counts."""
    data = bytearray(small.read_bytes())
    with open(small, "rb") as fh:
        index = sorted(make_reader(fh).get_summary().chunk_indexes, key=lambda c: c.chunk_start_offset)
    ci = index[len(index) // 2]
    data[ci.chunk_start_offset + ci.chunk_length // 2] ^= 0x10
    p = tmp_path / "d.mcap"
    p.write_bytes(bytes(data))
    got = read_log(p)
    assert got.recovery is not None and got.recovery.lost_chunks
    same(got, read_log_reference(p))
    clean = read_log(small)
    assert sum(map(len, got.channels.values())) < sum(map(len, clean.channels.values()))
    for k, frame in got.channels.items():
        assert np.isin(frame.index.to_numpy(), clean.channels[k].index.to_numpy()).all()
