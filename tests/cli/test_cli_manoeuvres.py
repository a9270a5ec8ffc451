"""``usvlog manoeuvres``: JSON and text output, exit codes, and the manoeuvres in the report and the .rrd.

A simulated turning circle (GPS 1.5 m, compass 2 deg): the verb estimates a log without an
estimate itself, and its numbers agree with the same definitions on the log's /truth/state.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import pytest
from rerun.chunk import RrdReader

import usvlog
from usvlog.cli import main
from usvlog.trials import find_manoeuvres

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "unit"))
import manoeuvre_runs as R  # noqa: E402


@pytest.fixture(scope="module")
def circle(tmp_path_factory):
    """(the raw log's path, the estimated log's path, the truth's manoeuvres)."""
    d = tmp_path_factory.mktemp("manoeuvres")
    log = R.turning_circle_run()
    raw, est = d / "circle.mcap", d / "circle-est.mcap"
    usvlog.save(log, raw)
    usvlog.estimate(raw, est)
    truth = find_manoeuvres(log["/truth/state"], log["/thrust/command"], log.time_range()[0], source="/truth/state")
    return raw, est, truth


def _finite_numbers(obj) -> bool:
    if isinstance(obj, dict):
        return all(_finite_numbers(v) for v in obj.values())
    if isinstance(obj, list):
        return all(_finite_numbers(v) for v in obj)
    if isinstance(obj, float):
        return math.isfinite(obj)
    return True


def test_json_without_a_stored_estimate(circle, capsys):
    raw, _est, truth = circle
    assert main(["manoeuvres", str(raw), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out) == {"t0_ns", "source", "count", "manoeuvres"} and out["count"] == 1
    assert _finite_numbers(out)
    m = out["manoeuvres"][0]
    assert m["kind"] == "turning_circle" and m["direction"] == "starboard"
    assert abs(m["start_s"] - R.RUN_IN_S) < 3.0 and m["end_s"] > m["start_s"]
    t = truth.items[0]
    for name in ("tactical_diameter_m", "advance_m"):
        assert set(m["metrics"][name]) == {"value", "std"} and m["metrics"][name]["std"] > 0
        assert abs(m["metrics"][name]["value"] / t.value(name) - 1) < 0.05


def test_text_with_the_stored_estimate(circle, capsys):
    raw, est, _truth = circle
    assert main(["manoeuvres", str(est)]) == 0
    text = capsys.readouterr().out
    assert text.startswith("1. turning circle to starboard: 30.0 s") and "tactical_diameter_m" in text
    # the stored estimate is used as it is; the raw log gets the manoeuvres' own estimate (one that
    # follows fast turns): both measure the circle the truth drove, within 5 %
    from usvlog.trials import find_manoeuvres

    stored = usvlog.load(est)
    tr = stored.time_range()
    direct = find_manoeuvres(stored["/estimate/state"], stored["/thrust/command"], int(tr[0]))
    assert usvlog.manoeuvres(est).to_dict()["manoeuvres"] == direct.to_dict()["manoeuvres"]
    t = _truth.items[0]
    for m in (usvlog.manoeuvres(est).items[0], usvlog.manoeuvres(raw).items[0]):
        assert abs(m.value("tactical_diameter_m") / t.value("tactical_diameter_m") - 1) < 0.05


def test_none_found_and_bad_input(tmp_path, capsys):
    log = usvlog.simulate("paper-circle", tmp_path / "cl.mcap", duration_s=40)   # closed loop: no long holds
    assert main(["manoeuvres", str(tmp_path / "cl.mcap")]) == 0
    assert capsys.readouterr().out.strip() == "no standard manoeuvre found"
    assert main(["manoeuvres", str(tmp_path / "missing.mcap")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "missing.mcap" in err[0]
    del log.channels["/thrust/command"]
    usvlog.save(log, tmp_path / "nothrust.mcap")
    assert main(["manoeuvres", str(tmp_path / "nothrust.mcap"), "--json"]) == 2
    cap = capsys.readouterr()
    assert "no /thrust/command" in cap.err and "Traceback" not in cap.err
    assert json.loads(cap.out)["kind"] == "InputError"
    (tmp_path / "notmcap.mcap").write_text("time,lat\n0,1\n")
    assert main(["manoeuvres", str(tmp_path / "notmcap.mcap")]) == 2
    assert "Traceback" not in capsys.readouterr().err


def test_report_and_rrd_show_them(circle, tmp_path):
    _raw, est, _truth = circle
    assert main(["report", str(est), "--out", str(tmp_path / "rep")]) == 0
    page = (tmp_path / "rep" / "report.html").read_text()
    assert "<h2 id='manoeuvres'>Manoeuvres (1)</h2>" in page and "1. turning circle to starboard" in page
    assert "tactical_diameter_m" in page and "fig4_path.png" in page
    out = tmp_path / "c.rrd"
    assert main(["view", str(est), "--out", str(out)]) == 0
    texts, strips = [], []
    for c in RrdReader(out).stream().to_chunks():
        cols = c.to_record_batch().to_pydict()
        if c.entity_path.endswith("/manoeuvres") and not c.entity_path.endswith("/local/manoeuvres"):
            texts += [t for row in cols.get("TextLog:text", []) for t in (row or [])]
        if c.entity_path.endswith("/local/manoeuvres"):
            strips += [s for row in cols.get("LineStrips2D:strips", []) for s in (row or [])]
    assert len(texts) == 2 and texts[0].startswith("1. turning circle to starboard: 30.0 s")
    assert "tactical_diameter_m" in texts[0] and texts[1].endswith(": end")
    assert len(strips) == 1 and len(strips[0]) > 100


def test_a_failed_estimate_is_refused(tmp_path, capsys):
    from usvlog.sim.simulate import SensorSettings, SimSettings, simulate

    # a compass 70 deg off: the estimate's sideslip is no boat's, its status failed
    log = simulate("turns", SimSettings(duration_s=120, sensors=SensorSettings(compass_bias_deg=70)), seed=1)
    usvlog.save(log, tmp_path / "bad.mcap")
    assert main(["manoeuvres", str(tmp_path / "bad.mcap")]) == 1        # estimated here: refused
    assert "the estimate failed (implausible sideslip" in capsys.readouterr().err
    usvlog.save(usvlog.estimate(log).to_log(log), tmp_path / "bad-est.mcap")
    assert main(["manoeuvres", str(tmp_path / "bad-est.mcap"), "--json"]) == 1   # stored flagged failed: refused
    cap = capsys.readouterr()
    assert "estimate FAILED" in cap.err and json.loads(cap.out)["kind"] == "UnusableResultError"
