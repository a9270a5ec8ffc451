"""``demo --out`` and ``regress --junit`` follow the --force rule of every verb."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET

import pytest

from usvlog.cli import main
from usvlog.cli.demo import MARKER, Owned
from usvlog.errors import OutputExistsError
from usvlog.resources import replay_dir


def _one_line_error(capsys, *words):
    err = capsys.readouterr().err.strip().splitlines()
    assert [x for x in err if "error" in x] == err[-1:], err
    for w in words:
        assert w in err[-1], err[-1]


def test_regress_junit_needs_force(tmp_path, capsys):
    junit = tmp_path / "junit.xml"
    junit.write_text("mine")
    scenario = str(replay_dir() / "imported-nmea.toml")
    assert main(["regress", scenario, "--junit", str(junit)]) == 2
    _one_line_error(capsys, "junit.xml", "output exists", "--force")
    assert junit.read_text() == "mine"
    assert main(["regress", scenario, "--junit", str(junit), "--force"]) == 0
    assert ET.parse(junit).getroot().get("tests") == "5"


def test_demo_refuses_an_output_it_did_not_write(tmp_path, capsys):
    out = tmp_path / "d"
    out.mkdir()
    (out / "estimate.mcap").write_bytes(b"someone else's run")
    assert main(["demo", "--out", str(out), "--duration-s", "10"]) == 2
    _one_line_error(capsys, "estimate.mcap", "not a file an earlier usvlog demo wrote", "--force")
    assert sorted(p.name for p in out.iterdir()) == ["estimate.mcap"]  # refused before any work


def test_demo_ownership_is_proven_by_checksums(tmp_path):
    out = tmp_path / "d"
    (out / "report").mkdir(parents=True)
    (out / "excitation.mcap").write_bytes(b"run")
    (out / "report" / "report.html").write_text("<html>")
    (out / "notes.txt").write_text("the user's")  # not an output of the demo: never looked at
    with pytest.raises(OutputExistsError):
        Owned(out).check(force=False)
    Owned(out).check(force=True)
    own = Owned(out)
    own.claim("excitation.mcap", "report")
    marker = json.loads((out / MARKER).read_text())
    assert set(marker["files"]) == {"excitation.mcap", "report/report.html"}
    Owned(out).check(force=False)  # the demo's own files: a re-run may replace them
    (out / "report" / "fig1_track.png").write_bytes(b"added by hand")
    with pytest.raises(OutputExistsError, match="fig1_track.png"):
        Owned(out).check(force=False)
    (out / "report" / "fig1_track.png").unlink()
    (out / "excitation.mcap").write_bytes(b"edited")
    with pytest.raises(OutputExistsError, match="excitation.mcap"):
        Owned(out).check(force=False)
    (out / MARKER).write_text("not json")  # a damaged marker proves nothing
    (out / "excitation.mcap").write_bytes(b"run")
    with pytest.raises(OutputExistsError):
        Owned(out).check(force=False)


@pytest.mark.slow
def test_demo_rerun_replaces_its_own_files(tmp_path):
    out = tmp_path / "d"
    assert main(["demo", "--out", str(out), "--duration-s", "30"]) == 0
    own = json.loads((out / MARKER).read_text())["files"]
    assert {"excitation.mcap", "demo.rrd", "report/report.html", "csv/gnss__fix.csv"} <= set(own)
    assert main(["demo", "--out", str(out), "--duration-s", "30"]) == 0  # its own files: no --force needed
