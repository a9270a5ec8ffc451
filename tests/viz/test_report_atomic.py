"""A report directory is complete or absent: a failure in the last figure leaves nothing behind."""

from __future__ import annotations

import pytest

from usvlog.sim.simulate import SimSettings, simulate
from usvlog.view import report as rp
from usvlog.view.report import FIGURES, PAGE, write_report


@pytest.fixture(scope="module")
def raw_log():
    return simulate("excitation", SimSettings(duration_s=20.0), seed=2)


def _boom(*a, **k):
    raise KeyboardInterrupt  # as Ctrl-C or SIGTERM (turned into an exception) would arrive


def test_failed_last_figure_leaves_no_directory(tmp_path, view_log, monkeypatch):
    monkeypatch.setattr(rp, "_fig_fit_track", _boom)  # the last figure of the list
    with pytest.raises(KeyboardInterrupt):
        write_report(view_log, tmp_path / "rep")
    assert list(tmp_path.iterdir()) == []  # no report directory, no hidden temporary one


def test_failed_replacement_keeps_the_earlier_report(tmp_path, raw_log, view_log, monkeypatch):
    out = tmp_path / "rep"
    write_report(raw_log, out)
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    assert set(before) == {PAGE, "fig4_path.png"}   # a raw log: its GPS track
    monkeypatch.setattr(rp, "_fig_fit_track", _boom)
    with pytest.raises(KeyboardInterrupt):
        write_report(view_log, out, force=True)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    assert [p.name for p in tmp_path.iterdir()] == ["rep"]
    monkeypatch.undo()
    write_report(view_log, out, force=True)  # replaced whole: every figure of the full log
    assert {p.name for p in out.iterdir()} == {PAGE, *FIGURES}
    assert [p.name for p in tmp_path.iterdir()] == ["rep"]


def test_shared_directory_keeps_other_files(tmp_path, raw_log, view_log):
    (tmp_path / "notes.txt").write_text("mine")
    write_report(view_log, tmp_path)
    assert {p.name for p in tmp_path.iterdir()} == {"notes.txt", PAGE, *FIGURES}
    write_report(raw_log, tmp_path, force=True)  # fewer figures: the earlier report's others go
    assert {p.name for p in tmp_path.iterdir()} == {"notes.txt", PAGE, "fig4_path.png"}
    assert (tmp_path / "notes.txt").read_text() == "mine"
