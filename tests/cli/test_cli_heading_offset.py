"""``usvlog import`` and ``usvlog estimate`` on NMEA logs (GGA + RMC + VTG + HDT) of a boat on
straight legs: a 70 deg dual-antenna heading offset is found, reported and applied; a cross
current is not called an offset; RTK fixes get centimetre noise (truth: heading_offset_runs)."""

import json
import math

import numpy as np
import pytest

from tests.unit.heading_offset_runs import truth, write_nmea
from usvlog.cli import main
from usvlog.io.importers.audit import health_of
from usvlog.io.mcap import read_log
from usvlog.log.status import estimate_status


@pytest.fixture(scope="module")
def offset_run(tmp_path_factory):
    d = tmp_path_factory.mktemp("hdt")
    run = truth()
    write_nmea(d / "rtk.nmea", run, offset_deg=70.0, quality=4, hdop=0.7, sigma_m=0.03)
    assert main(["import", str(d / "rtk.nmea"), "--out", str(d / "rtk.mcap")]) == 0
    return run, d


def _heading_error_deg(log, run) -> np.ndarray:
    st = log["/estimate/state"]
    t = np.asarray(st.index, np.int64)
    psi = np.interp((t - t[0]) * 1e-9, run.t_s, np.unwrap(run.psi_rad))
    return np.degrees(np.abs(np.angle(np.exp(1j * (st["psi_rad"].to_numpy() - psi)))))


def test_import_reports_the_offset(offset_run, capsys):
    run, d = offset_run
    assert main(["import", str(d / "rtk.nmea"), "--out", str(d / "again.mcap")]) == 0
    out = capsys.readouterr().out
    assert "heading: mounting offset +70.0" in out and "--heading-offset auto" in out
    log = read_log(d / "rtk.mcap")
    rec = health_of(log)["heading_offset"]
    assert rec["decided"] and abs(rec["offset_deg"] - 70.0) < 2.0 and rec["courses"] == 4
    q = log["/gnss/quality"]
    assert len(q) == len(log["/gnss/fix"]) and (q["fix_quality"] == 4).all() and np.allclose(q["hdop"], 0.7)
    assert main(["inspect", str(d / "rtk.mcap")]) == 0
    assert "heading mounting offset +70.0" in capsys.readouterr().out


def test_estimate_without_the_offset_is_refused_with_the_fix(offset_run, capsys):
    run, d = offset_run
    out = d / "bad.mcap"
    assert main(["estimate", str(d / "rtk.mcap"), "--out", str(out)]) == 1
    cap = capsys.readouterr()
    assert "implausible sideslip" in cap.err and "--heading-offset auto" in cap.err and "+70.0" in cap.err
    assert "status failed" in cap.out
    assert estimate_status(read_log(out)).status == "failed"   # written, flagged: later stages refuse it


@pytest.mark.parametrize("given", ["auto", "70"])
def test_estimate_with_the_offset_matches_the_truth(offset_run, given, tmp_path, capsys):
    run, d = offset_run
    out = tmp_path / "good.mcap"
    assert main(["estimate", str(d / "rtk.mcap"), "--out", str(out), "--heading-offset", given, "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["status"] != "failed" and abs(rep["heading_offset"]["applied_deg"] - 70.0) < 2.0
    assert rep["heading_offset"]["source"] == ("auto" if given == "auto" else "given")
    assert rep["sideslip"]["median_abs_deg"] < 3.0 and rep["sideslip"]["median_abs_v_mps"] < 0.1
    # RTK fixes: centimetres, and the GNSS NIS near its dimension (it was 0.03 with the 2 m default)
    assert "RTK fixed 3 cm on 100 %" in rep["gnss_noise"]
    assert 1.0 < rep["sensors"]["gnss"]["mean_nis"] < 4.0
    log = read_log(out)
    assert np.median(_heading_error_deg(log, run)) < 2.0


def test_a_cross_current_is_not_an_offset(tmp_path, capsys):
    run = truth(current_ne=(0.0, 0.3))      # 0.3 m/s at 1.2 m/s: crab up to 14.5 deg
    write_nmea(tmp_path / "cur.nmea", run, offset_deg=0.0, quality=1, hdop=1.0, sigma_m=1.5)
    assert main(["import", str(tmp_path / "cur.nmea"), "--out", str(tmp_path / "cur.mcap")]) == 0
    assert "mounting offset" not in capsys.readouterr().out
    assert main(["estimate", str(tmp_path / "cur.mcap"), "--out", str(tmp_path / "e.mcap"), "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert not rep["heading_offset"]["detected"]["decided"] and rep["status"] != "failed"
    assert "GPS 1.5 m on 100 %" in rep["gnss_noise"]      # quality 1, HDOP 1: metres
    assert 1.0 < rep["sensors"]["gnss"]["mean_nis"] < 4.0
    crab = math.degrees(math.asin(0.3 / 1.2))
    assert rep["sideslip"]["median_abs_deg"] < crab + 3
