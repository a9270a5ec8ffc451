"""Rerun views that read at a glance, read back from the .rrd: the recording's name, titles from
what the log holds, y ranges, distinct colours, one controller's overlays in sight, GPS under the
tracks, carrot and closest point on the map, finite series."""

from __future__ import annotations

import numpy as np
import pytest

from usvlog.estimate import EstimateSettings, estimate
from usvlog.sim.simulate import SimSettings, simulate
from usvlog.view.rrd import SERIES_PALETTE, to_rrd, y_range

from .test_viz import read_rrd


def _views(bp):
    """{view entity: {"name": ..., "contents": [...], "range": (lo, hi) or None, ...}} of the blueprint."""
    out: dict = {}
    for ent, cols in bp.items():
        if ent.startswith("/view/") and "ViewBlueprint:display_name" in cols:
            vid = ent.split("/")[2]
            out.setdefault(vid, {})["name"] = cols["ViewBlueprint:display_name"][-1][0]
            out[vid]["kind"] = cols["ViewBlueprint:class_identifier"][-1][0]
    for ent, cols in bp.items():
        if not ent.startswith("/view/"):
            continue
        vid = ent.split("/")[2]
        if vid not in out:
            continue
        if "ViewContents:query" in cols:
            out[vid]["contents"] = [q.lstrip("+ ").strip() for q in cols["ViewContents:query"][-1]]
        if "ScalarAxis:range" in cols:
            out[vid]["range"] = tuple(cols["ScalarAxis:range"][-1][0])
        if "VisibleTimeRanges:ranges" in cols:
            out[vid]["time_ranges"] = cols["VisibleTimeRanges:ranges"][-1]
        if "EntityBehavior:visible" in cols and not cols["EntityBehavior:visible"][-1][0]:
            out[vid].setdefault("hidden", []).append(ent.split("/overrides", 1)[1].rsplit("/visualizers", 1)[0])
    return out


@pytest.fixture(scope="module")
def estimated_rrd(tmp_path_factory):
    log = simulate("excitation", SimSettings(duration_s=60.0), seed=5)
    log = estimate(log, EstimateSettings()).to_log(log)
    out = to_rrd(log, tmp_path_factory.mktemp("est") / "est.rrd", names=["exc"])
    return log, read_rrd(out)


@pytest.fixture(scope="module")
def circle_rrd(tmp_path_factory, view_log):
    out = to_rrd(view_log, tmp_path_factory.mktemp("circ") / "circle.rrd", names=["circle"])
    return read_rrd(out)


def test_recording_is_named_after_the_run(estimated_rrd):
    log, (ents, _bp) = estimated_rrd
    props = ents["/__properties"]["static"]
    assert props["RecordingInfo:name"] == [["exc"]]
    assert props["RecordingInfo:start_time"] == [[log.time_range()[0]]]


def test_titles_say_what_the_plots_hold(estimated_rrd, circle_rrd):
    _log, (_ents, bp) = estimated_rrd
    names = {v["name"] for v in _views(bp).values()}
    u = next(n for n in names if n.startswith("Surge speed"))
    assert u == "Surge speed (m/s): u estimate, u truth"   # no u_d: the run had no controller
    assert not any("tau_u" in n and "replayed" in n for n in names)
    assert not any(n.startswith("Thrusters saturated") for n in names)   # never saturated: no flat zeros
    ents, bp = circle_rrd
    names = {v["name"] for v in _views(bp).values()}
    assert "Surge speed (m/s): u estimate, u truth, u what-if run".split(":")[0] in {n.split(":")[0] for n in names}
    u = next(n for n in names if n.startswith("Surge speed"))
    assert "u_d control" in u and "u_d whatif" in u


def test_every_plot_shows_the_whole_run_in_a_sensible_range(estimated_rrd):
    log, (ents, bp) = estimated_rrd
    for v in _views(bp).values():
        if v["kind"] != "TimeSeries":
            continue
        assert v["time_ranges"], v["name"]   # all of the data, wherever the time cursor is
        lo, hi = v["range"]
        vals = np.concatenate([np.array(ents[c]["rows"]["Scalars:scalars"], float).ravel()
                               for c in v["contents"] if c in ents])
        vals = vals[np.isfinite(vals)]
        assert lo <= vals.min() and vals.max() <= hi, v["name"]
        assert (vals.max() - vals.min()) >= 0.4 * (hi - lo) or hi - lo <= 1.6 * max(
            vals.max() - vals.min(), 0.2), v["name"]   # the data fill the plot unless nearly constant
    psi = next(v for v in _views(bp).values() if v["name"].startswith("Heading"))
    assert "wrapped" in psi["name"] and psi["range"][1] - psi["range"][0] < 200.0   # this run never wraps
    assert y_range("psi", -179.0, 179.5)[0] == -185.0   # one that wraps: the whole circle
    # a nearly constant speed is not blown up to its noise
    assert y_range("u", 0.19997, 0.2)[1] - y_range("u", 0.19997, 0.2)[0] >= 0.2


def test_series_of_a_plot_have_distinct_colours_and_are_finite(circle_rrd):
    ents, bp = circle_rrd
    for v in _views(bp).values():
        if v["kind"] != "TimeSeries":
            continue
        colors = [ents[c]["static"]["SeriesLines:colors"][0][0] for c in v["contents"] if c in ents]
        assert len(set(colors)) == len(colors), v["name"]
        for c in v["contents"]:
            y = np.array(ents[c]["rows"]["Scalars:scalars"], float).ravel()
            ok = np.isfinite(y)
            assert ok.sum() >= 2 and (ok[0] and ok[-1]), c   # NaN only as a break inside a wrapped heading
            if not ok.all():
                assert "/ts/psi/" in c
    assert len(SERIES_PALETTE) == len(set(SERIES_PALETTE))


def test_local_view_one_controller_gps_under_the_tracks_labels(circle_rrd):
    ents, bp = circle_rrd
    local = next(v for v in _views(bp).values() if v["name"].startswith("Local NED"))
    assert local["hidden"] == ["/runs/circle/local/ctl_whatif"]   # the closed loop in sight, the what-if toggled
    gps = ents["/runs/circle/local/gps"]["static"]
    rgba = gps["Points2D:colors"][0][0]
    assert (rgba & 0xFF) < 255   # translucent
    assert gps["Points2D:radii"][0][0] == -1.5   # 1.5 UI points (negative: UI units)
    est = ents["/runs/circle/local/estimate"]["static"]
    assert gps["Points2D:draw_order"][0][0] < est["LineStrips2D:draw_order"][0][0]
    labels = ents["/runs/circle/local/labels"]["static"]["Points2D:labels"][0]
    assert {"GPS fixes", "desired path", "smoothed estimate", "truth (simulated)", "what-if run"} <= set(labels)
    pos = np.array(ents["/runs/circle/local/labels"]["static"]["Points2D:positions"][0])
    assert len({tuple(np.round(p, 3)) for p in pos}) == len(pos)   # each label at its own place


def test_carrot_and_closest_point_on_the_map(circle_rrd, view_log):
    ents, _bp = circle_rrd
    ctl = view_log["/control/state"]
    for what in ("carrot", "closest"):
        pts = np.array(ents[f"/runs/circle/map/{what}"]["rows"]["GeoPoints:positions"], dtype=object)
        first = np.array(pts[0], float).reshape(-1, 2)[0]
        from usvlog.model.frames import ned_to_geodetic

        lat, lon, _ = ned_to_geodetic(ctl[f"{what}_n_m"].iloc[0], ctl[f"{what}_e_m"].iloc[0], 0.0,
                                      datum=view_log.datum)
        assert first == pytest.approx([float(lat), float(lon)], abs=1e-9)
