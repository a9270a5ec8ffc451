"""The view and the report of a log drawn a time window at a time (usvlog.view.windowed) equal the
whole log's: the same recording read back, the same page; the report's figures differ only by the
decimation, which keeps every bucket's extremes."""

from __future__ import annotations

import json
import re

import numpy as np
import pandas as pd
import pytest

from usvlog.estimate import EstimateSettings, estimate
from usvlog.io.mcap import read_log, write_log
from usvlog.sim.simulate import SimSettings, simulate
from usvlog.view import data as vd
from usvlog.view import manoeuvres as vman
from usvlog.view import rrd_windows, windowed
from usvlog.view.report import write_report
from usvlog.view.report_windows import Decimator, bucket_extremes
from usvlog.view.rrd import to_rrd
from usvlog.view.source import REPORT_TOPICS, SMALL, VIEW_READ, VIEW_TOPICS, Drawn, read_drawn

from .test_viz import read_rrd

WINDOWED = Drawn(VIEW_TOPICS, unless=VIEW_READ.unless, small=SMALL)   # VIEW_READ without its forked read
WHOLE = Drawn(VIEW_TOPICS, unless=VIEW_READ.unless)


@pytest.fixture(scope="module")
def turns_file(tmp_path_factory):
    """An estimated run with turns (two pivot turns found), saved."""
    log = simulate("turns", SimSettings(duration_s=150.0), seed=3)
    path = tmp_path_factory.mktemp("windows") / "turns.mcap"
    write_log(estimate(log, EstimateSettings()).to_log(log), path)
    return path


@pytest.fixture
def small_blocks(monkeypatch):
    """Windows on a short log: blocks of 1,777 rows (15,000 a channel: nine blocks, cut anywhere)."""
    monkeypatch.setattr(windowed, "MIN_ROWS", 1000)
    monkeypatch.setattr(windowed, "BLOCK_ROWS", 1777)


def _same(a, b) -> bool:
    if len(a) != len(b):
        return False
    for x, y in zip(a, b):
        if isinstance(x, list) and x and isinstance(x[0], float):
            if not np.array_equal(np.asarray(x, float), np.asarray(y, float), equal_nan=True):
                return False
        elif x != y:
            return False
    return True


def _blueprint(bp) -> list[str]:
    """The blueprint's values without the ids and times each recording draws anew."""
    out = []
    for cols in bp.values():
        for k, v in cols.items():
            if "RowId" not in k and k not in ("log_time", "log_tick") and "root_container" not in k:
                out.append(re.sub(r"[0-9a-f]{8}-[0-9a-f-]{27}", "U", json.dumps([k, v], default=str)))
    return sorted(out)


def _assert_same_recording(a_path, b_path) -> None:
    a, bpa = read_rrd(a_path)
    b, bpb = read_rrd(b_path)
    assert sorted(a) == sorted(b)
    for ent in a:
        for part in ("static", "rows"):
            ca, cb = a[ent][part], b[ent][part]
            assert sorted(ca) == sorted(cb), ent
            for k in ca:
                if "RowId" not in k:
                    assert _same(ca[k], cb[k]), (ent, part, k)
    assert _blueprint(bpa) == _blueprint(bpb)


def test_view_windowed_equals_whole(tmp_path, turns_file, small_blocks):
    win = read_drawn(turns_file, WINDOWED, read_log)
    whole = read_drawn(turns_file, WHOLE, read_log)
    assert isinstance(win, windowed.WindowedLog) and not isinstance(whole, windowed.WindowedLog)
    assert set(win.windowed) == {"/estimate/state", "/truth/state", "/thrust/command"}
    assert win.channels.deferred_topics() == ["/compass/heading", "/estimate/state", "/thrust/command",
                                              "/truth/state"]   # the compass is not drawn beside a state
    assert win.time_range() == whole.time_range()
    # the survey: the whole log's analyses, from the blocks
    sv = win.survey
    found = vman.of_log(whole)
    assert len(found) == 2 and vman.html_section(sv.manoeuvres) == vman.html_section(found)
    for (n, e), (n0, e0) in zip(sv.stretches, vman.stretches(whole, found)):
        assert np.array_equal(n, n0, equal_nan=True) and np.array_equal(e, e0, equal_nan=True)
    assert sv.findings.findings == windowed.findings_of(whole).findings
    assert sv.current == vd.mean_current(whole["/estimate/state"])
    for t in sv.steps:   # the tracks' thinning of each state channel: thin_indices' step
        k = vd.thin_indices(whole[t].index.to_numpy(np.int64), vd.OVERLAY_HZ)
        assert k[1] - k[0] == sv.steps[t] and sv.rows[t] == len(whole[t])
    a = to_rrd(whole, tmp_path / "whole.rrd", names=["turns"])
    b = to_rrd(win, tmp_path / "win.rrd", names=["turns"])
    _assert_same_recording(a, b)


def test_channel_gathered_from_its_blocks_equals_the_read(turns_file, small_blocks):
    """The commands the findings check, gathered a block at a time: the frame read whole (its text
    column as categories of the same values)."""
    win = read_drawn(turns_file, WINDOWED, read_log)
    whole = read_log(turns_file, topics=["/thrust/command"])["/thrust/command"]
    got = windowed.gathered(win, "/thrust/command", len(whole))
    assert isinstance(got["unit"].dtype, pd.CategoricalDtype)
    assert got["unit"].astype(str).tolist() == whole["unit"].astype(str).tolist()
    pd.testing.assert_frame_equal(got.drop(columns="unit"), whole.drop(columns="unit"))
    with pytest.raises(windowed.NotWindowed):
        windowed.gathered(win, "/thrust/command", len(whole) + 1)


def test_view_windowed_overlay_equals_whole(tmp_path, turns_file, small_blocks):
    """Two runs overlaid (the ``elapsed`` timeline, colours by run): the same recording either way."""
    win = [read_drawn(turns_file, WINDOWED, read_log) for _ in range(2)]
    whole = [read_drawn(turns_file, WHOLE, read_log) for _ in range(2)]
    a = to_rrd(whole, tmp_path / "whole.rrd", names=["a", "b"])
    b = to_rrd(win, tmp_path / "win.rrd", names=["a", "b"])
    _assert_same_recording(a, b)


def test_view_falls_back_to_the_whole_log(tmp_path, turns_file, small_blocks, monkeypatch):
    """A file that cannot be read in windows after all (here: after the first block) is drawn whole."""
    real = windowed.blocks

    def broken(log, topics=None, rows=None):
        for i, blk in enumerate(real(log, topics, rows)):
            if i == 1:
                raise windowed.NotWindowed("changed")
            yield blk

    win = read_drawn(turns_file, WINDOWED, read_log)
    monkeypatch.setattr(rrd_windows, "blocks", broken)
    b = to_rrd(win, tmp_path / "win.rrd", names=["turns"])
    a = to_rrd(read_drawn(turns_file, WHOLE, read_log), tmp_path / "whole.rrd", names=["turns"])
    _assert_same_recording(a, b)


def test_short_or_controlled_logs_read_whole(turns_file, view_file):
    assert not isinstance(read_drawn(turns_file, WINDOWED, read_log), windowed.WindowedLog)   # 15,000 rows
    assert not isinstance(read_drawn(view_file, WINDOWED, read_log), windowed.WindowedLog)   # controllers


def test_report_windowed_equals_whole(tmp_path, turns_file, small_blocks):
    drawn = Drawn(REPORT_TOPICS, small=SMALL)
    win = read_drawn(turns_file, drawn, read_log)
    assert isinstance(win, windowed.WindowedLog)
    a = write_report(read_drawn(turns_file, Drawn(REPORT_TOPICS), read_log), tmp_path / "whole")
    b = write_report(win, tmp_path / "win")
    assert a.read_text() == b.read_text()   # every number, table and caption
    names = sorted(p.name for p in a.parent.iterdir())
    assert names == sorted(p.name for p in b.parent.iterdir()) and "estimate_series.png" in names


def test_decimation_keeps_every_buckets_extremes():
    rng = np.random.default_rng(5)
    n = 20_000
    t = np.cumsum(rng.integers(5_000_000, 15_000_000, n))   # jittered 100 Hz, ns
    y = np.cumsum(rng.normal(size=n))
    y[rng.integers(0, n, 40)] += rng.normal(scale=50.0, size=40)   # spikes one sample wide
    y[3000:3100] = np.nan
    y[rng.integers(0, n, 30)] = np.nan
    f = pd.DataFrame({"u_mps": y}, index=pd.Index(t, name="t_ns"))
    dec = Decimator(int(t[0]), int(t[-1]), buckets=512)
    at = 0
    for size in rng.integers(1, 3000, 100):   # blocks of any size, cut anywhere
        dec.add(f.iloc[at:at + size])
        at += size
        if at >= n:
            break
    kept = dec.frame()
    assert kept.index.is_monotonic_increasing and kept.index.isin(f.index).all()
    b, bk = dec._bucket(f), dec._bucket(kept)
    yk = kept["u_mps"].to_numpy()
    for k in np.unique(b):
        full, part = y[b == k], yk[bk == k]
        if np.isfinite(full).any():
            assert np.nanmin(part) == np.nanmin(full) and np.nanmax(part) == np.nanmax(full)
        assert np.isnan(part).any() == np.isnan(full).any()   # a break stays a break
    assert kept.index[0] == t[0] and kept.index[-1] == t[-1]
    # one bucket, one run: its first, last, smallest and largest rows
    rows = bucket_extremes(np.zeros(5, np.int64), np.array([2.0, 1.0, 5.0, 5.0, 3.0]))
    assert sorted(set(rows.tolist())) == [0, 1, 2, 4]


def test_thin_step_from_counted_steps():
    rng = np.random.default_rng(2)
    for scale, n in ((10_000_000, 5001), (37_000_000, 5002), (150_000_000, 5001)):   # even and odd counts of steps
        t = np.cumsum(rng.integers(scale // 2, scale * 3 // 2, n))
        steps = windowed._Steps()
        for a in range(0, len(t), 700):
            steps.add(t[a:a + 700])
        k = vd.thin_indices(t, vd.OVERLAY_HZ)
        assert steps.thin_step(vd.OVERLAY_HZ) == (k[1] - k[0])
