"""``--gnss-delay-s`` / ``--compass-delay-s`` of estimate and identify, on real MCAP files."""

import json

import numpy as np
import pytest

from usvlog.cli import main
from usvlog.estimate.latency import stored_delays
from usvlog.io.mcap import read_log, write_log
from usvlog.sim.simulate import SensorSettings, SimSettings, simulate


@pytest.fixture(scope="module")
def late_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("lat") / "run.mcap"
    sens = SensorSettings(gps_delay_s=0.2)
    write_log(simulate("excitation", SimSettings(duration_s=60.0, sensors=sens), seed=4), path)
    return path


def test_given_delay_is_applied_stored_and_read_by_identify(late_file, tmp_path, capsys):
    est = tmp_path / "est.mcap"
    assert main(["estimate", str(late_file), "--out", str(est), "--gnss-delay-s", "0.2", "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["settings"]["gnss_delay_s"] == 0.2 and rep["settings"]["compass_delay_s"] == 0.0
    assert rep["latency"] == []
    log = read_log(est)
    assert stored_delays(log) == {"gnss": 0.2, "compass": 0.0}
    # the innovations sit at the times the fixes describe: the stamps minus 0.2 s
    inn = log["/estimate/innovations"]
    t_inn = np.asarray(inn.index[inn["sensor"] == "gnss"], np.int64)
    np.testing.assert_array_equal(t_inn, np.asarray(log["/gnss/fix"].index, np.int64) - 200_000_000)

    vt = tmp_path / "v.toml"
    # exit 1 when this short run's verdict is unusable: --force writes the TOML all the same
    assert main(["identify", str(est), "--method", "equation-error", "--out", str(vt), "--force", "--json"]) in (0, 1)
    assert json.loads(capsys.readouterr().out)["gnss_delay_s"] == [0.2] and vt.exists()
    vt.unlink()
    assert main(["identify", str(est), "--method", "equation-error", "--out", str(vt), "--force",
                 "--gnss-delay-s", "0.25"]) in (0, 1) and vt.exists()
    assert "GNSS delay taken off the fix stamps: 0.250 s" in capsys.readouterr().out


def test_auto_with_the_kinematic_model_is_reported_not_identifiable(late_file, tmp_path, capsys):
    est = tmp_path / "k.mcap"
    assert main(["estimate", str(late_file), "--out", str(est), "--no-sway-damping", "--gnss-delay-s", "auto"]) == 0
    out = capsys.readouterr().out
    assert "gnss delay not identifiable" in out and "0.000 s kept" in out
    assert stored_delays(read_log(est))["gnss"] == 0.0


@pytest.mark.parametrize("value", ["soon", "nan", "7"])
def test_bad_delay_is_a_one_line_error(late_file, tmp_path, capsys, value):
    with pytest.raises(SystemExit) as exc:   # argparse's usage error
        main(["estimate", str(late_file), "--out", str(tmp_path / "x.mcap"), "--gnss-delay-s", value])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--gnss-delay-s" in err[0] and not (tmp_path / "x.mcap").exists()
