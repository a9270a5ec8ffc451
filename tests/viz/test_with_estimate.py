"""View and report on the real estimator's channels (/estimate/state, /estimate/innovations)."""

from __future__ import annotations

import numpy as np
import pytest

from usvlog.estimate import EstimateSettings, estimate
from usvlog.sim.simulate import SensorSettings, SimSettings, simulate
from usvlog.view.report import write_report
from usvlog.view.rrd import to_rrd

from .test_viz import read_rrd


@pytest.fixture(scope="module")
def estimated():
    sens = SensorSettings(gps_jumps=((40.0, 30.0),), gps_dropouts=((60.0, 3.0),))
    log = simulate("excitation", SimSettings(duration_s=90.0, current_mps=0.2, current_dir_deg=60.0,
                                             sensors=sens), seed=7)
    return estimate(log, EstimateSettings(model="dynamic")).to_log(log)


def test_estimate_channels_in_rrd(tmp_path, estimated):
    out = to_rrd(estimated, tmp_path / "e.rrd", names=["e"])
    ents, _ = read_rrd(out)
    inn = estimated["/estimate/innovations"]
    gn = inn[(inn["sensor"] == "gnss")]
    rejected = gn.index[~gn["accepted"].to_numpy()]
    assert len(rejected) >= 1  # the 30 m jump
    # the rejected fix is drawn where the receiver put it
    fix = estimated["/gnss/fix"].loc[rejected[0]]
    rej = np.array(ents["/runs/e/map/gps_rejected"]["static"]["GeoPoints:positions"][0])
    assert [fix["lat_deg"], fix["lon_deg"]] in rej.tolist()
    nis = np.array(ents["/runs/e/ts/nis/gnss"]["rows"]["Scalars:scalars"]).ravel()
    assert nis == pytest.approx(gn["nis"].to_numpy()[np.isfinite(gn["nis"].to_numpy())])
    est = estimated["/estimate/state"]
    cur = np.array(ents["/runs/e/ts/current/n_estimate"]["rows"]["Scalars:scalars"]).ravel()
    assert cur[-1] == pytest.approx(est["current_n_mps"].iloc[-1])
    text = [x[0] for x in ents["/runs/e/events"]["rows"]["TextLog:text"]]
    assert any(s.startswith("GPS fix rejected") for s in text)
    assert sum(s.startswith("GPS dropout") for s in text) == 1


def test_estimate_report(tmp_path, estimated):
    html = write_report(estimated, tmp_path / "r").read_text()
    assert "src='fig4_path.png'" in html and "approximate current" not in html  # the arrow is in the PNG
    assert "src='estimate_series.png'" in html
    assert "mean NIS, gnss" in html and "<h2 id='estimate'>Estimate: " in html
