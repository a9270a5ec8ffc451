import json
import subprocess
import sys

import pytest

from usvlog.cli import main


def _usvlog(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "usvlog", *args], capture_output=True, text=True, cwd=cwd)


def test_simulate_then_inspect_json(tmp_path):
    out = tmp_path / "x.mcap"
    r = _usvlog("simulate", "excitation", "--out", str(out), "--seed", "1", "--duration-s", "60")
    assert r.returncode == 0, r.stderr
    r = _usvlog("inspect", str(out), "--json")
    assert r.returncode == 0, r.stderr
    s = json.loads(r.stdout)
    ch = s["channels"]
    assert ch["/gnss/fix"]["rate_hz"] == pytest.approx(10.0, rel=0.01)
    assert ch["/compass/heading"]["rate_hz"] == pytest.approx(20.0, rel=0.01)
    assert ch["/thrust/command"]["rate_hz"] == pytest.approx(100.0, rel=0.01)
    assert s["duration_s"] == pytest.approx(60.0, abs=0.02)
    assert s["recovery"] is None
    # the output exists now: not overwritten without --force
    r = _usvlog("simulate", "excitation", "--out", str(out), "--duration-s", "5")
    assert r.returncode == 2 and "exists" in r.stderr and len(r.stderr.strip().splitlines()) == 1


def test_bad_files_one_line_exit_2(tmp_path, capsys):
    g = tmp_path / "garbage.mcap"
    g.write_bytes(b"\x00garbage" * 100)
    assert main(["inspect", str(g)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "garbage.mcap" in err[0] and "not an MCAP file" in err[0]
    assert main(["inspect", str(tmp_path / "missing.mcap")]) == 2


def test_inspect_reports_damage(tmp_path, excitation_log, capsys):
    from usvlog.io.mcap import write_log

    p = tmp_path / "cut.mcap"
    write_log(excitation_log, tmp_path / "full.mcap", chunk_size=64 * 1024)
    data = (tmp_path / "full.mcap").read_bytes()
    p.write_bytes(data[: int(len(data) * 0.7)])
    assert main(["inspect", str(p), "--json"]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["recovery"]["bytes_lost"] > 0


def test_export_csv_round_trip(tmp_path, excitation_file):
    import pandas as pd

    from usvlog.io.mcap import read_log

    assert main(["export", str(excitation_file), "--out", str(tmp_path / "csv")]) == 0
    back = pd.read_csv(tmp_path / "csv" / "compass__heading.csv", index_col="t_ns")
    orig = read_log(excitation_file)["/compass/heading"]
    assert (back.index.to_numpy() == orig.index.to_numpy()).all()
    assert (back["heading_rad"].to_numpy() == orig["heading_rad"].to_numpy()).all()


def test_demo_runs(tmp_path):
    r = _usvlog("demo", "--out", str(tmp_path / "demo"), "--duration-s", "60")
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "demo" / "excitation.mcap").exists()
    assert "/gnss/fix" in r.stdout
    assert (tmp_path / "demo" / "demo.rrd").stat().st_size > 10_000
    assert (tmp_path / "demo" / "report" / "report.html").exists()
