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
        assert w > 400 and h > 300 and png.stat().st_size > 15_000, name
        assert f"src='{name}'" in html
    # the metrics table carries the log's own numbers
    ct = view_log["/control/state"]["cross_track_m"].to_numpy()
    assert f"{np.sqrt(np.mean(ct ** 2)):.3f}" in html
    assert "GPS fixes rejected by the estimator</td><td class='num'>2<" in html


def test_report_raw_log_draws_what_it_can(tmp_path):
    log = simulate("excitation", SimSettings(duration_s=20.0), seed=2)
    page = write_report(log, tmp_path / "raw")
    html = page.read_text()
    drawn = set(re.findall(r"src='([^']+)'", html))
    assert drawn == {"fig1_track.png", "fig4_path.png"}
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
