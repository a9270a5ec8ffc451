"""View and report on the real closed-loop channels."""

from __future__ import annotations

import numpy as np
import pytest

from usvlog.sim.closed_loop import simulate_scenario
from usvlog.sim.scenario import load_scenario
from usvlog.view.report import write_report
from usvlog.view.rrd import to_rrd

from .test_viz import read_rrd


@pytest.fixture(scope="module")
def circle_logs():
    scen = load_scenario("paper-circle")
    full = simulate_scenario(scen, duration_s=110.0)
    base = simulate_scenario(scen, controller="baseline", duration_s=110.0)
    return full, base


def test_paper_circle_rrd(tmp_path, circle_logs):
    full, base = circle_logs
    out = to_rrd([full, base], tmp_path / "pc.rrd", names=["full", "baseline"])
    ents, bp = read_rrd(out)
    ctl = full["/control/state"]
    ud = ents["/runs/full/ts/u/u_d_control"]["rows"]["Scalars:scalars"]
    assert ud[-1] == [pytest.approx(ctl["u_d_mps"].iloc[-1])]
    assert "/runs/baseline/local/ctl_control/carrot" in ents and "/runs/full/map/path" in ents
    g = full["/gnss/fix"]
    pts = np.array(ents["/runs/full/map/gps"]["static"]["GeoPoints:positions"][0])
    assert pts[0] == pytest.approx([g["lat_deg"].iloc[0], g["lon_deg"].iloc[0]], abs=1e-12)
    steps = [x[0] for x in ents["/runs/full/events"]["rows"]["TextLog:text"] if "speed step" in x[0]]
    assert steps and "0.10 -> 0.20" in steps[0]


def test_paper_circle_report(tmp_path, circle_logs):
    full, base = circle_logs
    page = write_report(full, tmp_path / "rep", baseline=base)
    html = page.read_text()
    for name in ("fig1_track.png", "fig2_errors.png", "fig5_speed_heading.png"):
        assert (tmp_path / "rep" / name).stat().st_size > 15_000 and f"src='{name}'" in html
    assert "baseline PI/PID" in html and "Baseline log" in html
