"""The four VantTec bags (tests/data/real/vanttec/, MIT, see LICENSE.vanttec_usv.txt): a twin-thruster
USV whose INS publishes a local geometry_msgs/Pose2D (x north, y east in metres, theta in rad) and no
latitude/longitude anywhere, beside controller topics named like a heading that are not angles.

Truth: the bags' own messages, read here with rosbags independently of usvlog's importer.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from rosbags.highlevel import AnyReader

from usvlog.estimate.core import estimate
from usvlog.estimate.settings import EstimateSettings
from usvlog.io.importers import import_file
from usvlog.model.frames import ssa

BAGS = sorted((Path(__file__).parents[1] / "data" / "real" / "vanttec").glob("*.bag"))
POSE = "/vectornav/ins_2d/NED_pose"
NOT_HEADINGS = ("heading_gain", "heading_sigma", "heading_error", "desired_heading")


def _pose(bag: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(record t_ns, x, y, theta) of every pose message of the bag."""
    times, rows = [], []
    with AnyReader([bag]) as r:
        conns = [c for c in r.connections if c.topic == POSE]
        for c, t, raw in r.messages(connections=conns):
            m = r.deserialize(raw, c.msgtype)
            times.append(t)
            rows.append((m.x, m.y, m.theta))
    a = np.array(rows, dtype=float)
    return np.array(times, np.int64), a[:, 0], a[:, 1], a[:, 2]


def test_four_bags_are_there():
    assert len(BAGS) == 4


@pytest.fixture(scope="module", params=BAGS, ids=[b.stem for b in BAGS])
def imported(request):
    return request.param, import_file(request.param)


def test_no_mapping_takes_the_pose_for_position_and_theta_for_heading(imported):
    bag, res = imported
    m = res.report.mapping
    assert (m["local_n"], m["local_e"]) == (f"{POSE}.x", f"{POSE}.y")
    assert m["heading"] == f"{POSE}.theta"
    assert not any(w in v for v in m.values() for w in NOT_HEADINGS)
    assert "gnss" not in m and res.report.guesses["thrust_unit"] == "newton"
    assert res.report.guesses["local_frame"] == "ned"


def test_local_positions_and_heading_are_the_bags_values(imported):
    bag, res = imported
    t, x, y, th = _pose(bag)
    lp = res.log["/local/position"]
    k = np.searchsorted(t, np.asarray(lp.index, np.int64))
    assert np.array_equal(t[k], np.asarray(lp.index, np.int64))     # each kept record is one of the bag's
    np.testing.assert_allclose(lp["n_m"], x[k], atol=1e-9)
    np.testing.assert_allclose(lp["e_m"], y[k], atol=1e-9)
    assert not lp["geo"].any() and res.log.datum is None               # no datum given: local only
    h = res.log["/compass/heading"]
    kh = np.searchsorted(t, np.asarray(h.index, np.int64))
    np.testing.assert_allclose(ssa(h["heading_rad"].to_numpy() - th[kh]), 0.0, atol=1e-9)


def test_estimate_follows_the_pose_and_its_heading(imported):
    bag, res = imported
    t, x, y, th = _pose(bag)
    est = estimate(res.log, EstimateSettings())
    st = est.state
    ts = np.asarray(st.index, np.int64)
    n = np.interp(t, ts, st["n_m"].to_numpy())
    e = np.interp(t, ts, st["e_m"].to_numpy())
    rms = float(np.sqrt(np.mean((n - x) ** 2 + (e - y) ** 2)))
    psi = np.interp(t, ts, np.unwrap(st["psi_rad"].to_numpy()))
    med = float(np.degrees(np.median(np.abs(ssa(psi - th)))))
    print(f"{bag.name}: position RMS {rms:.3f} m, heading median {med:.2f} deg, status {est.report.status}")
    assert rms < 0.5, rms
    assert med < 3.0, med
    assert "/local/position" in est.report.gnss_noise


def test_datum_geo_references_the_pose(tmp_path):
    res = import_file(BAGS[-1], datum="25.6514,-100.2895")
    assert res.log["/local/position"]["geo"].all()
    assert res.log.datum.lat_deg == pytest.approx(25.6514) and res.log.datum.lon_deg == pytest.approx(-100.2895)


def test_a_pose_held_between_ins_updates_is_one_measurement(imported):
    """06-08 runs: the INS pose is republished at 100 Hz but updated 6.5-8.3 times a second; every
    repeat of the position before it is collapsed (counted), each real update kept."""
    bag, res = imported
    t, x, y, _ = _pose(bag)
    changed = np.r_[True, (np.diff(x) != 0) | (np.diff(y) != 0)]
    lp = res.log["/local/position"]
    assert len(lp) == int(changed.sum())
    assert res.report.skipped.get("local_held_repeat", 0) == len(t) - int(changed.sum())
    rate = len(lp) / ((t[-1] - t[0]) * 1e-9)
    if "06-08" in bag.name:
        assert 6.0 < rate < 9.0, rate
    else:
        assert rate > 100.0, rate


def test_the_pictures_call_local_positions_positions(imported):
    """The report and the view label what the log measured: an INS pose is not 'GPS fixes'."""
    from usvlog.sim.simulate import SimSettings, simulate
    from usvlog.view.data import fixes_name, metrics

    _, res = imported
    assert fixes_name(res.log) == "positions"
    assert ("positions", str(len(res.log["/local/position"])), "") in metrics(res.log)
    assert fixes_name(simulate("straight", SimSettings(duration_s=10.0), seed=1)) == "GPS fixes"
