import json

import numpy as np
import pytest

from usvlog.cli import main
from usvlog.io.config import load_vessel
from usvlog.io.mcap import read_log
from usvlog.model.vessel import PARAM_NAMES


def test_identify_equation_error_writes_vessel_json_and_fit_channel(excitation_file, tmp_path, capsys):
    out, fit = tmp_path / "p.toml", tmp_path / "fit.mcap"
    # --force: written whatever the verdict (equation error on 84 s predicts u poorly), and marked
    rc = main(["identify", str(excitation_file), "--method", "equation-error", "--fix", "m=33.0",
               "--holdout", "0.3", "--out", str(out), "--out-log", str(fit), "--json", "--force"])
    d = json.loads(capsys.readouterr().out)
    assert rc == (0 if d["usable"] else 1) and d["verdict"] in ("usable", "usable with caveats", "unusable")
    assert f"usable = {'true' if d['usable'] else 'false'}" in out.read_text()
    assert d["method"] == "equation-error"
    assert set(d["params"]) == set(PARAM_NAMES) == set(d["stderr"]) == set(d["ci95"])
    assert set(d["fit_percent"]) >= {"u", "v", "r"}
    assert d["params"]["m"] == 33.0 and d["fit_percent_on"] == "validation"
    v = load_vessel(out)   # drops into the other verbs
    assert v.params.to_dict() == pytest.approx(d["params"])
    log = read_log(fit)
    f = log["/identify/fit"]
    assert {"u_mps", "u_sim_mps", "v_mps", "v_sim_mps", "r_radps", "r_sim_radps", "n_m", "n_sim_m",
            "e_m", "e_sim_m", "psi_rad", "psi_sim_rad"} <= set(f.columns)
    # the smoothed measured track follows the truth
    tr = log["/truth/state"]
    n_true = np.interp(f.index.to_numpy(), tr.index.to_numpy(), tr["n_m"].to_numpy())
    assert np.sqrt(np.mean((f["n_m"].to_numpy() - n_true) ** 2)) < 1.0


def test_identify_refuses_existing_output_bad_holdout_and_bad_fix(excitation_file, tmp_path, capsys):
    out = tmp_path / "p.toml"
    out.write_text("x")
    assert main(["identify", str(excitation_file), "--out", str(out)]) == 2
    assert "exists" in capsys.readouterr().err
    assert main(["identify", str(excitation_file), "--holdout", "0.95", "--out", str(tmp_path / "q.toml")]) == 2
    assert "holdout" in capsys.readouterr().err
    assert main(["identify", str(excitation_file), "--fix", "mass=3", "--out", str(tmp_path / "q.toml")]) == 2
    assert "--fix" in capsys.readouterr().err
    assert out.read_text() == "x"


def test_identify_output_error_validate_on_another_manoeuvre(tmp_path, capsys):
    from usvlog.io.mcap import write_log
    from usvlog.sim.simulate import SensorSettings, SimSettings, simulate

    sens = SensorSettings(gps_noise_m=0.5, compass_noise_deg=1.0)
    ex, tu = tmp_path / "ex.mcap", tmp_path / "turns.mcap"
    write_log(simulate("excitation", SimSettings(duration_s=240.0, current_mps=0.1, sensors=sens), seed=41), ex)
    write_log(simulate("turns", SimSettings(duration_s=200.0, current_mps=0.1, sensors=sens), seed=42), tu)
    out, fit = tmp_path / "boat.toml", tmp_path / "fit.mcap"
    assert main(["identify", str(ex), "--validate", str(tu), "--out", str(out), "--out-log", str(fit), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["method"] == "output-error" and d["fit_percent_on"] == "validation"
    assert d["params"]["Iz"] == pytest.approx(10.0, rel=0.03) and d["params"]["d33"] == pytest.approx(5.0, rel=0.02)
    assert d["fit_percent"]["r"] > 80 and d["fit_percent"]["track"] > 80, d["fit_percent"]
    lo, hi = d["ci95"]["d11"]
    assert lo < d["params"]["d11"] < hi
    f = read_log(fit)["/identify/fit"]
    # the fitted model's track follows the measured one to about the GPS noise
    err = np.hypot(f["n_m"] - f["n_sim_m"], f["e_m"] - f["e_sim_m"]).to_numpy()
    assert np.sqrt(np.mean(err ** 2)) < 1.0


def test_real_px4_log_without_a_thruster_map_is_refused_as_unusable(tmp_path, capsys):
    """The real PX4 log's motor outputs are RC pulse widths and its boat barely turns: with
    no thruster map the fit runs in command units and identify exits 1: the verdict is unusable,
    said in one line, and no TOML is written (never a confident number)."""
    from pathlib import Path

    from usvlog.cli import main

    ulg = Path(__file__).resolve().parents[1] / "data" / "real" / "px4_sample_log_small.ulg"
    log = tmp_path / "px4.mcap"
    assert main(["import", str(ulg), "--out", str(log)]) == 0
    capsys.readouterr()
    out = tmp_path / "v.toml"
    assert main(["identify", str(log), "--out", str(out)]) == 1
    # the candidates validate (their free runs start from the command in force), and the verdict says no
    cap = capsys.readouterr()
    err = [x for x in cap.err.splitlines() if x.startswith("usvlog identify: error:")]
    assert "verdict: unusable" in cap.out
    assert len(err) == 1 and "unusable" in err[0] and "nothing written" in err[0]
    assert not out.exists()
