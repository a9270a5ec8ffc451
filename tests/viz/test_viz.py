"""The .rrd read back with rerun.chunk.RrdReader: entities, blueprint, values."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from rerun.chunk import RrdReader

from usvlog.cli import main
from usvlog.errors import OutputExistsError
from usvlog.io.mcap import read_log
from usvlog.model.frames import ssa
from usvlog.sim.simulate import SimSettings, simulate
from usvlog.view import data as vd
from usvlog.view.rrd import OVERLAY_HZ, to_rrd, viewer_command


def read_rrd(path):
    """{entity: {"static": {column: pylist}, "rows": {column: pylist}}} of the recording,
    and the blueprint's chunks as {entity: {column: pylist}}."""
    r = RrdReader(path)
    ents: dict = {}
    for c in r.stream().to_chunks():
        d = ents.setdefault(c.entity_path, {"static": {}, "rows": {}})
        part = d["static"] if c.is_static else d["rows"]
        for k, v in c.to_record_batch().to_pydict().items():
            part.setdefault(k, []).extend(v)
    bps = r.blueprints()
    bp = {}
    if bps:
        for c in r.stream(store=bps[0]).to_chunks():
            for k, v in c.to_record_batch().to_pydict().items():
                bp.setdefault(c.entity_path, {}).setdefault(k, []).extend(v)
    return ents, bp


def _ns(ts):
    import pandas as pd

    return np.array([pd.Timestamp(x).value for x in ts], dtype=np.int64)


@pytest.fixture(scope="module")
def rrd(tmp_path_factory, view_log):
    out = tmp_path_factory.mktemp("rrd") / "circle.rrd"
    assert to_rrd(view_log, out, names=["circle"]) == out
    return read_rrd(out)


def test_expected_entities_and_blueprint(rrd):
    ents, bp = rrd
    p = "/runs/circle"
    for sub in ("map/gps", "map/gps_rejected", "map/path", "map/estimate", "map/truth", "map/whatif", "map/boat",
                "local/gps", "local/path", "local/estimate", "local/whatif", "local/boat",
                "local/ctl_control/closest", "local/ctl_control/carrot", "local/ctl_control/arrows",
                "local/ctl_whatif/arrows", "ts/u/estimate", "ts/u/u_d_control", "ts/psi/estimate",
                "ts/psi/psi_d_control", "ts/v/estimate", "ts/r/estimate", "ts/tau_u/recorded",
                "ts/tau_u/control", "ts/tau_r/recorded", "ts/cross_track/control", "ts/nis/gnss",
                "ts/nis/compass", "ts/current/n_estimate", "ts/saturation/control", "ts/fit/u_model",
                "ts/fit/r_measured", "events"):
        assert f"{p}/{sub}" in ents, sub
    # a blueprint with the views, whose contents name entities that exist
    names = [n for e in bp.values() for row in e.get("ViewBlueprint:display_name", []) for n in row]
    assert "Map" in names and any(n.startswith("Local NED") for n in names)
    assert any(n.startswith("Surge speed") for n in names) and "Events" in names
    queries = [q for e in bp.values() for qs in e.get("ViewContents:query", []) for q in qs]
    listed = {q.lstrip("+ ").strip() for q in queries}
    assert f"{p}/map/gps" in listed and f"{p}/ts/u/u_d_control" in listed
    assert all(q in ents for q in listed if q.startswith("/runs/")), listed - set(ents)


def test_gps_and_path_values(rrd, view_log):
    ents, _ = rrd
    gps = view_log["/gnss/fix"]
    pts = np.array(ents["/runs/circle/map/gps"]["static"]["GeoPoints:positions"][0])
    assert pts.shape == (len(gps), 2)
    assert pts[0] == pytest.approx([gps["lat_deg"].iloc[0], gps["lon_deg"].iloc[0]], abs=1e-12)
    assert pts[-1] == pytest.approx([gps["lat_deg"].iloc[-1], gps["lon_deg"].iloc[-1]], abs=1e-12)
    # local 2D: x = east, y = -north (north up on screen); the path is the circle of radius 8
    strip = np.array(ents["/runs/circle/local/path"]["static"]["LineStrips2D:strips"][0][0])
    poly = np.array(json.loads(view_log.meta["usvlog.path"]["polyline_ne"]))
    assert strip[:, 0] == pytest.approx(poly[:, 1]) and strip[:, 1] == pytest.approx(-poly[:, 0])
    # and on the map the path goes back to the same metres through the datum
    from usvlog.model.frames import geodetic_to_ned
    ll = np.array(ents["/runs/circle/map/path"]["static"]["GeoLineStrings:line_strings"][0][0])
    n, e, _ = geodetic_to_ned(ll[:, 0], ll[:, 1], 0.0, datum=view_log.datum)
    assert np.hypot(n, e) == pytest.approx(8.0, abs=1e-6)
    # the rejected fix is the 25 m jump at t = 50 s
    rej = np.array(ents["/runs/circle/map/gps_rejected"]["static"]["GeoPoints:positions"][0])
    k = int(np.argmin(np.abs(gps.index.to_numpy() - (gps.index[0] + 50_000_000_000))))
    assert [gps["lat_deg"].iloc[k], gps["lon_deg"].iloc[k]] in rej.tolist()


def test_series_values_and_timelines(rrd, view_log):
    ents, _ = rrd
    ctl = view_log["/control/state"]
    ud = ents["/runs/circle/ts/u/u_d_control"]["rows"]
    assert len(ud["Scalars:scalars"]) == len(ctl)
    assert ud["Scalars:scalars"][-1] == [pytest.approx(ctl["u_d_mps"].iloc[-1])] == [pytest.approx(0.2)]
    assert _ns(ud["time"])[-1] == ctl.index[-1]
    assert "elapsed" not in ud  # one log: the UTC timeline only
    # cross-track error is the controller's, sample for sample
    ct = np.array(ents["/runs/circle/ts/cross_track/control"]["rows"]["Scalars:scalars"]).ravel()
    assert ct == pytest.approx(ctl["cross_track_m"].to_numpy())
    # recorded thrust -> tau through the vessel geometry equals what the controller applied
    tu = np.array(ents["/runs/circle/ts/tau_u/recorded"]["rows"]["Scalars:scalars"]).ravel()
    thr = view_log["/thrust/command"]
    assert tu == pytest.approx(thr["thrust_left_n"].to_numpy() + thr["thrust_right_n"].to_numpy(), abs=1e-12)
    assert tu == pytest.approx(ctl["tau_u_n"].to_numpy(), abs=2.1e-3)  # forces are recorded to 1 mN
    # heading: wrapped degrees in [-180, 180), the line broken (one NaN sample) where it wraps, every
    # other sample the log's heading
    est = view_log["/estimate/state"]
    for ent, truth in (("psi/estimate", est["psi_rad"]), ("psi/psi_d_control", ctl["psi_d_rad"])):
        y = np.array(ents[f"/runs/circle/ts/{ent}"]["rows"]["Scalars:scalars"]).ravel()
        ok = np.isfinite(y)
        assert ok.sum() == len(truth) and (y[ok] >= -180.0).all() and (y[ok] < 180.0).all()
        assert ssa(np.radians(y[ok]) - truth.to_numpy()) == pytest.approx(0.0, abs=1e-9)
        wraps = int((np.abs(np.diff(y[ok])) > 180.0).sum())
        assert (~ok).sum() == wraps and not (~ok[:-1] & ~ok[1:]).any()   # one break per wrap
        seg = np.split(y, np.nonzero(~ok)[0])
        assert all(np.abs(np.diff(s[np.isfinite(s)])).max(initial=0) < 20.0 for s in seg)  # no jump inside a line
    fit = view_log["/identify/fit"]
    r_model = np.array(ents["/runs/circle/ts/fit/r_model"]["rows"]["Scalars:scalars"]).ravel()
    assert r_model == pytest.approx(np.degrees(fit["r_sim_radps"].to_numpy()))
    sat = np.array(ents["/runs/circle/ts/saturation/control"]["rows"]["Scalars:scalars"]).ravel()
    assert sat == pytest.approx(ctl["saturated"].to_numpy().astype(float))


def test_per_tick_overlay(rrd, view_log):
    ents, _ = rrd
    ctl = view_log["/control/state"]
    car = ents["/runs/circle/local/ctl_control/carrot"]["rows"]
    t = _ns(car["time"])
    assert len(t) == pytest.approx(OVERLAY_HZ * 90, abs=2)          # thinned to 10 Hz
    k = np.searchsorted(ctl.index.to_numpy(), t)
    xy = np.array([p[0] for p in car["Points2D:positions"]])
    assert xy[:, 0] == pytest.approx(ctl["carrot_e_m"].to_numpy()[k])
    assert xy[:, 1] == pytest.approx(-ctl["carrot_n_m"].to_numpy()[k])
    arr = ents["/runs/circle/local/ctl_control/arrows"]["rows"]
    vec = np.array(arr["Arrows2D:vectors"][-1])   # heading, desired heading, course over ground
    assert vec.shape == (3, 2)
    psi_d = ctl["psi_d_rad"].iloc[-1]
    d = vec[1] / np.linalg.norm(vec[1])
    assert d == pytest.approx([np.sin(psi_d), -np.cos(psi_d)], abs=1e-6)  # float32 in the file
    org = np.array(arr["Arrows2D:origins"][-1])
    truth = view_log["/truth/state"]  # the closed-loop controller steers the simulated truth
    assert org[0] == pytest.approx([truth["e_m"].iloc[-1], -truth["n_m"].iloc[-1]], abs=1e-5)


def test_events(rrd, view_log):
    ents, _ = rrd
    ev = ents["/runs/circle/events"]["rows"]
    text, t = [x[0] for x in ev["TextLog:text"]], _ns(ev["time"])
    t0 = view_log["/truth/state"].index[0]
    rej = [tt for tt, s in zip(t, text) if s.startswith("GPS fix rejected")]
    assert (rej[0] - t0) / 1e9 == pytest.approx(50.0, abs=0.06)
    drop = [(tt, s) for tt, s in zip(t, text) if s.startswith("GPS dropout")]
    assert len(drop) == 1 and (drop[0][0] - t0) / 1e9 == pytest.approx(29.9, abs=0.06)
    steps = [(tt, s) for tt, s in zip(t, text) if "speed step" in s and "closed-loop" in s]
    assert len(steps) == 1 and (steps[0][0] - t0) / 1e9 == pytest.approx(45.0) and "0.40 -> 0.20" in steps[0][1]
    sat_start = [tt for tt, s in zip(t, text) if "closed-loop" in s and s.endswith("saturated")]
    spans = vd.saturation_spans(view_log["/control/state"])
    assert sat_start == [a for a, _ in spans] and spans


def test_speed_step_events_count_ramps_once():
    import pandas as pd

    t = np.arange(300) * 10_000_000
    ud = np.r_[np.full(100, 0.4), np.linspace(0.4, 0.2, 50), np.full(100, 0.2), np.full(50, 0.5)]
    f = pd.DataFrame({"u_d_mps": ud}, index=pd.Index(t, name="t_ns"))
    steps = vd.speed_steps(f)
    assert [(a, round(b, 3), round(c, 3)) for a, b, c in steps] == [(t[101], 0.4, 0.2), (t[250], 0.2, 0.5)]


def test_several_logs_overlay(tmp_path, view_log, excitation_log):
    out = tmp_path / "two.rrd"
    to_rrd([view_log, excitation_log], out, names=["after", "before"])
    ents, bp = read_rrd(out)
    assert "/runs/after/ts/u/u_d_control" in ents and "/runs/before/map/gps" in ents
    assert "/runs/before/ts/u/truth" in ents and "/runs/before/ts/u/u_d_control" not in ents
    names = [n for e in bp.values() for row in e.get("ViewBlueprint:display_name", []) for n in row]
    assert "after: local" in names and "before: local" in names
    assert bp["/time_panel"]["TimePanelBlueprint:timeline"] == [["elapsed"]]
    ud = ents["/runs/after/ts/u/u_d_control"]["rows"]
    assert ud["elapsed"][-1].value == view_log["/control/state"].index[-1] - view_log.time_range()[0]
    g = excitation_log["/gnss/fix"]
    pts = np.array(ents["/runs/before/map/gps"]["static"]["GeoPoints:positions"][0])
    assert pts[0] == pytest.approx([g["lat_deg"].iloc[0], g["lon_deg"].iloc[0]], abs=1e-12)


def test_raw_log_draws_what_it_has(tmp_path):
    log = simulate("excitation", SimSettings(duration_s=20.0), seed=1)
    del log.channels["/truth/state"]
    out = tmp_path / "raw.rrd"
    to_rrd(log, out)
    ents, _ = read_rrd(out)
    have = {e.split("/", 3)[-1] for e in ents if e.startswith("/runs/")}
    assert {"map/gps", "local/gps", "map/boat", "ts/psi/compass", "ts/tau_u/recorded"} <= have
    assert not any(h.startswith(("ts/u/", "local/ctl_", "map/path")) for h in have)
    with pytest.raises(OutputExistsError):
        to_rrd(log, out)
    to_rrd(log, out, force=True)


def test_viewer_command_binds_localhost():
    cmd = viewer_command("x.rrd", serve=True, port=9091)
    assert cmd[cmd.index("--bind") + 1] == "127.0.0.1" and "--web-viewer-port" in cmd and cmd[-1] == "x.rrd"
    cmd = viewer_command("x.rrd", serve=True, host="0.0.0.0")
    assert cmd[cmd.index("--bind") + 1] == "0.0.0.0"
    assert "--serve-web" not in viewer_command("x.rrd")


def test_cli_view_writes_rrd_next_to_log(view_file, capsys):
    assert main(["view", str(view_file)]) == 0
    out = view_file.with_suffix(".rrd")
    assert capsys.readouterr().out.strip() == str(out)
    ents, bp = read_rrd(out)
    log = read_log(view_file)
    ud = ents["/runs/circle/ts/u/u_d_control"]["rows"]["Scalars:scalars"]
    assert ud[-1] == [pytest.approx(log["/control/state"]["u_d_mps"].iloc[-1])]
    r = subprocess.run([sys.executable, "-m", "usvlog", "view", str(view_file)], capture_output=True, text=True)
    assert r.returncode == 2 and "exists" in r.stderr and len(r.stderr.strip().splitlines()) == 1


def test_default_names_are_distinct(view_log):
    from usvlog.view.rrd import default_names

    a, b, c = view_log.copy(), view_log.copy(), view_log.copy()
    a.source, b.source, c.source = "/x/run 1.mcap", "/y/run 1.mcap", None
    assert default_names([a, b, c]) == ["run_1", "run_1_2", "run2"]


def test_guidance_lines_join_boat_closest_and_carrot(rrd, view_log):
    ents, _ = rrd
    g = ents["/runs/circle/local/ctl_control/guidance"]["rows"]
    strip = np.array(g["LineStrips2D:strips"][-1][0])
    ctl, truth = view_log["/control/state"], view_log["/truth/state"]
    expect = [[truth["e_m"].iloc[-1], -truth["n_m"].iloc[-1]],
              [ctl["closest_e_m"].iloc[-1], -ctl["closest_n_m"].iloc[-1]],
              [ctl["carrot_e_m"].iloc[-1], -ctl["carrot_n_m"].iloc[-1]]]
    assert strip == pytest.approx(np.array(expect), abs=1e-5)


def test_map_zoom_fits_the_extent():
    from usvlog.view.rrd import map_zoom

    # 1 km east-west at the equator on 500 px: 2 m/px -> 156543 / 2^z = 2 -> z = log2(78271.5)
    box = np.array([[0.0, 0.0, 0.0, 1000.0 / 111_320.0]])
    assert map_zoom(box) == pytest.approx(np.log2(156_543.03 / 2.0), abs=1e-9)
    # at 60 deg latitude a pixel of a given zoom covers half the metres: one level less
    box60 = np.array([[60.0, 0.0, 60.0, 1000.0 / (111_320.0 * 0.5)]])
    assert map_zoom(box60) == pytest.approx(np.log2(156_543.03 / 2.0) - 1.0, abs=1e-3)


def test_scalar_column_is_rerun_s_own():
    """The time series' column built with its offsets at once holds what ``rr.Scalars.columns`` gives."""
    import rerun as rr

    from usvlog.view.rrd import scalar_column

    y = np.r_[np.random.default_rng(3).normal(size=1000), np.nan, 1e300, -0.0]
    for n in (0, 1, len(y)):
        ref, got = list(rr.Scalars.columns(scalars=y[:n])), list(scalar_column(y[:n]))
        assert len(ref) == len(got) == 1
        assert ref[0].component_descriptor() == got[0].component_descriptor()
        a, b = ref[0].as_arrow_array(), got[0].as_arrow_array()
        assert a.type == b.type and a.null_count == b.null_count == 0 and a.offsets.equals(b.offsets)
        assert a.values.to_numpy().tobytes() == b.values.to_numpy().tobytes()   # NaN (a break in the line) too
