"""The report: PNGs and an HTML page that shows them, with the log's metrics."""

from __future__ import annotations

import re
import struct
import subprocess
import sys

import numpy as np
import pytest

from usvlog.cli import main
from usvlog.errors import OutputExistsError
from usvlog.sim.simulate import SimSettings, simulate
from usvlog.view import data as vd
from usvlog.view.report import FIGURES, write_report

from .test_metrics_consistency import tables


def _png_size(path):
    b = path.read_bytes()[:24]
    assert b[:8] == b"\x89PNG\r\n\x1a\n"
    return struct.unpack(">II", b[16:24])


def test_report_full_log(tmp_path, view_log, excitation_log):
    page = write_report([view_log, view_log], tmp_path / "rep")  # the log and a baseline
    html = page.read_text()
    for name in FIGURES:
        png = tmp_path / "rep" / name
        w, h = _png_size(png)
        assert w > 400 and h > 300, name
        assert f"src='{name}'" in html
    # the path-following table: the controller's own numbers over the whole run (no replay window here)
    ct = view_log["/control/state"]["cross_track_m"].to_numpy()
    rows = {(r[0], r[1]): r[2] for r in tables(html)["pathmetrics"][1:]}
    assert rows[("closed-loop controller", "cross_track_rms_m[whole run]")] == f"{np.sqrt(np.mean(ct ** 2)):.4f}"
    assert rows[("closed-loop controller", "cross_track_max_m[whole run]")] == f"{np.abs(ct).max():.4f}"
    log_rows = {r[0]: r[1] for r in tables(html)["logmetrics"][1:]}
    assert log_rows["GPS fixes rejected by the estimator"] == "2"
    assert not any(k.startswith("closed-loop controller") for k in log_rows)   # tracking metrics said once


def test_report_raw_log_draws_what_it_can(tmp_path):
    log = simulate("excitation", SimSettings(duration_s=20.0), seed=2)
    page = write_report(log, tmp_path / "raw")
    html = page.read_text()
    drawn = set(re.findall(r"src='([^']+)'", html))
    assert drawn == {"fig4_path.png"}   # the raw GPS fixes
    assert "Not drawn" in html and "/identify/fit" in html
    assert not (tmp_path / "raw" / "fig2_errors.png").exists()
    with pytest.raises(OutputExistsError):
        write_report(log, tmp_path / "raw")
    write_report(log, tmp_path / "raw", force=True, axes="map")


def test_metrics_match_independent_numbers(view_log):
    m = {name: value for name, value, _ in vd.metrics(view_log)}
    fit = view_log["/identify/fit"]
    err = fit["u_mps"].to_numpy() - fit["u_sim_mps"].to_numpy()
    assert float(m["identification fit: RMS u error"]) == pytest.approx(np.sqrt(np.mean(err ** 2)), abs=1e-4)
    y, ys = fit["v_mps"].to_numpy(), fit["v_sim_mps"].to_numpy()
    expect = 100 * (1 - np.sqrt(np.sum((y - ys) ** 2)) / np.sqrt(np.sum((y - y.mean()) ** 2)))
    v_fit = float(m["identification fit: v fit (100 (1 - |y - y_sim| / |y - mean y|))"])
    assert v_fit == pytest.approx(expect, abs=0.05)
    sat = view_log["/control/state"]["saturated"].to_numpy()
    assert float(m["closed-loop controller: time saturated"]) == pytest.approx(100 * sat.mean(), abs=0.05)
    assert m["GPS dropouts (> 3 periods)"] == "1"


def test_cli_report(tmp_path, view_file):
    out = tmp_path / "r"
    assert main(["report", str(view_file), "--out", str(out), "--axes", "map"]) == 0
    assert (out / "report.html").exists() and (out / "fig5_speed_heading.png").exists()
    r = subprocess.run([sys.executable, "-m", "usvlog", "report", str(view_file), "--out", str(out)],
                       capture_output=True, text=True)
    assert r.returncode == 2 and "exists" in r.stderr


def test_a_doubtful_estimate_is_flagged_in_report_view_and_on_the_console(tmp_path, capsys):
    """An estimate whose compass NIS says 'overstated or not moving' carries that warning
    into the report (first, in a box), the Rerun event log and the console of both verbs;
    a clean estimate carries none."""
    from usvlog.cli import main
    from usvlog.estimate import EstimateSettings, estimate
    from usvlog.io.mcap import write_log
    from usvlog.sim.simulate import SimSettings, simulate

    log = simulate("excitation", SimSettings(duration_s=60.0), seed=4)
    clean = estimate(log, EstimateSettings()).to_log(log)
    assert vd.warnings(clean) == []
    comp = log["/compass/heading"].copy()
    comp["heading_rad"] = 0.0                       # a compass stuck while the boat turns
    bad = log.copy(deep=True)
    bad.set("/compass/heading", comp)
    est = estimate(bad, EstimateSettings()).to_log(bad)
    words = vd.warnings(est)
    assert len(words) == 2 and words[0].startswith("estimate DEGRADED (gnss+compass)")
    assert words[1].startswith("estimate: compass NIS 0.0")
    assert [x.text for x in vd.events(est) if x.kind == "warning"] == words
    src = tmp_path / "est.mcap"
    write_log(est, src)
    assert main(["report", str(src), "--out", str(tmp_path / "rep")]) == 0
    html = (tmp_path / "rep" / "report.html").read_text()
    assert html.index("<h2>Warnings</h2>") < html.index("<h2>Figures</h2>") and "compass NIS 0.0" in html
    assert sum("warning: estimate: compass NIS" in x for x in capsys.readouterr().err.splitlines()) == 1
    assert main(["view", str(src), "--out", str(tmp_path / "v.rrd")]) == 0
    assert sum("warning:" in x and "compass NIS" in x for x in capsys.readouterr().err.splitlines()) == 1
