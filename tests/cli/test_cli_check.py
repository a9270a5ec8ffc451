"""``usvlog check`` end to end: a canonical log, field logs imported in memory (the 70 deg
heading offset NMEA run, a CSV whose compass is dead), ``--json`` and ``--junit`` parsed and
counted, exit codes (0 clean, 1 an error, 2 bad input)."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET

import numpy as np
import pytest

import usvlog
from tests.unit.heading_offset_runs import truth, write_nmea
from usvlog.cli import main
from usvlog.sim.simulate import SimSettings, simulate


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    d = tmp_path_factory.mktemp("check")
    log = simulate("turns", SimSettings(duration_s=200.0), seed=2)
    usvlog.save(log, d / "clean.mcap")
    write_nmea(d / "rtk.nmea", truth(), offset_deg=70.0, quality=4, hdop=0.7, sigma_m=0.03)
    g, th = log["/gnss/fix"], log["/thrust/command"]
    t = np.asarray(g.index, np.int64)
    i = np.searchsorted(np.asarray(th.index, np.int64), t)
    rows = ["time_s,lat,lon,heading_deg,thrust_left,thrust_right"]
    rows += [f"{t[k] / 1e9:.3f},{g['lat_deg'].iloc[k]:.8f},{g['lon_deg'].iloc[k]:.8f},123.4,"
             f"{th['left'].iloc[i[k]]:.3f},{th['right'].iloc[i[k]]:.3f}" for k in range(len(t))]
    (d / "dead.csv").write_text("\n".join(rows) + "\n")
    return d


def test_clean_log_exit_0_with_a_table(logs, capsys):
    assert main(["check", str(logs / "clean.mcap")]) == 0
    out = capsys.readouterr().out
    assert "SEVERITY  CHECK" in out and "0 error(s), 0 warning(s)" in out and "thrusters.swapped" in out


def test_70_deg_offset_nmea_imported_in_memory(logs, capsys):
    assert main(["check", str(logs / "rtk.nmea"), "--json"]) == 1
    cap = capsys.readouterr()
    d = json.loads(cap.out)
    assert d["exit_code"] == 1 and d["counts"]["error"] >= 1
    (off,) = [f for f in d["findings"] if f["code"] == "heading.mounting_offset"]
    assert off["severity"] == "error" and abs(off["numbers"]["offset_deg"] - 70.0) < 2.0
    assert "--heading-offset auto" in off["action"] and "importing" in cap.err
    q = [f for f in d["findings"] if f["code"] == "sensors.gnss_quality"]
    assert q and "RTK fixed 100%" in q[0]["evidence"]
    assert not (logs / "rtk.mcap").exists()       # nothing written: the import stays in memory


def test_dead_compass_csv(logs, capsys):
    assert main(["check", str(logs / "dead.csv")]) == 1
    out = capsys.readouterr().out
    assert "ERROR     sensors.dead        /compass/heading" in out
    assert "heading moved 0.00 deg in all while the GNSS track turned" in out


def test_json_and_junit_agree(logs, tmp_path, capsys):
    xml = tmp_path / "check.xml"
    assert main(["check", str(logs / "rtk.nmea"), "--json", "--junit", str(xml)]) == 1
    d = json.loads(capsys.readouterr().out)
    root = ET.parse(xml).getroot()
    cases = root.findall("./testsuite/testcase")
    names = {f"{c.get('classname')}.{c.get('name')}" for c in cases}
    assert set(d["checks"]) <= names and names == set(d["checks"]) | {f["check"] for f in d["findings"]}
    failed = {f"{c.get('classname')}.{c.get('name')}" for c in cases if c.find("failure") is not None}
    assert failed == {f["check"] for f in d["findings"] if f["severity"] == "error"}
    assert root.get("failures") == str(len(failed)) and root.get("tests") == str(len(cases))
    warned = {f["check"] for f in d["findings"] if f["severity"] == "warning"}
    for c in cases:
        name = f"{c.get('classname')}.{c.get('name')}"
        assert c.find("skipped") is None
        if name in warned:
            assert "WARNING" in c.find("system-out").text
    # the file exists now: without --force it is refused before any work
    assert main(["check", str(logs / "clean.mcap"), "--junit", str(xml)]) == 2
    assert "exists" in capsys.readouterr().err
    assert main(["check", str(logs / "clean.mcap"), "--junit", str(xml), "--force"]) == 0
    root = ET.parse(xml).getroot()
    assert root.get("failures") == "0" and len(root.findall(".//failure")) == 0


@pytest.mark.parametrize("content", [None, "not a log at all\n"])
def test_bad_input_exit_2_one_line(tmp_path, capsys, content):
    p = tmp_path / "x.txt"
    if content is not None:
        p.write_text(content)
    assert main(["check", str(p)]) == 2
    err = capsys.readouterr().err
    assert "usvlog check: error:" in err and "Traceback" not in err


def test_report_and_rrd_show_the_findings(tmp_path):
    from rerun.chunk import RrdReader

    from usvlog.sim.simulate import SensorSettings

    st = SimSettings(duration_s=200.0, sensors=SensorSettings(gps_dropouts=((100.0, 12.0),)))
    usvlog.save(simulate("turns", st, seed=2), tmp_path / "gap.mcap")
    page = usvlog.report(tmp_path / "gap.mcap", tmp_path / "report")
    text = page.read_text()
    assert "<h2 id='findings'>Findings (0 error(s), 1 warning(s)" in text
    assert "<td>sensors.gaps</td><td>/gnss/fix</td><td>99.9-112.0 s</td>" in text   # the fixes around the gap
    rrd = usvlog.to_rrd(tmp_path / "gap.mcap", tmp_path / "gap.rrd")
    entries = []
    for c in RrdReader(rrd).stream().to_chunks():
        if c.entity_path.endswith("/check"):
            d = c.to_record_batch().to_pydict()
            entries += [(t, lv[0], tx[0]) for t, lv, tx in zip(d["time"], d["TextLog:level"], d["TextLog:text"])]
    assert entries and all(lv in ("ERROR", "WARN", "INFO") for _, lv, _ in entries)
    (gap,) = [(t, tx) for t, lv, tx in entries if lv == "WARN"]
    assert gap[1].startswith("sensors.gaps /gnss/fix (99.9-112.0 s)")
    start = min(t for t, _, _ in entries)
    assert (gap[0] - start).total_seconds() == pytest.approx(99.9, abs=0.05)


def test_held_gnss_csv_and_inspect_say_the_same(tmp_path, capsys):
    """A CSV resampled to 10 Hz whose fixes are held for 2 rows: the in-memory import keeps one row
    per update and check says how many it dropped; inspect of the imported 70 deg run prints the
    health record's findings in check's words."""
    log = simulate("turns", SimSettings(duration_s=120.0), seed=3)
    g, c = log["/gnss/fix"], log["/compass/heading"]
    t = np.asarray(g.index, np.int64)
    held = (np.arange(len(t)) // 2) * 2
    hd = np.degrees(np.interp(t, np.asarray(c.index, np.int64), np.unwrap(c["heading_rad"].to_numpy()))) % 360
    rows = ["time_s,lat,lon,heading_deg"] + [
        f"{t[k] / 1e9:.3f},{g['lat_deg'].iloc[held[k]]:.8f},{g['lon_deg'].iloc[held[k]]:.8f},{hd[k]:.2f}"
        for k in range(len(t))]
    (tmp_path / "held.csv").write_text("\n".join(rows) + "\n")
    assert main(["check", str(tmp_path / "held.csv"), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    (h,) = [f for f in d["findings"] if f["code"] == "sensors.held"]
    assert h["channel"] == "/gnss/fix" and h["numbers"]["held_repeats"] == pytest.approx(len(t) / 2, abs=2)


def test_inspect_prints_the_health_findings(logs, tmp_path, capsys):
    assert main(["import", str(logs / "rtk.nmea"), "--out", str(tmp_path / "rtk.mcap")]) == 0
    capsys.readouterr()
    assert main(["inspect", str(tmp_path / "rtk.mcap")]) == 0
    out = capsys.readouterr().out
    assert "ERROR heading.mounting_offset /compass/heading (whole run): heading - course over ground +70.0" in out
