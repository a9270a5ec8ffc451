import json

import numpy as np
import pytest

from usvlog.cli import main
from usvlog.io.mcap import read_log, write_log
from usvlog.sim.simulate import SimSettings, simulate


@pytest.fixture(scope="module")
def current_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("est") / "run.mcap"
    write_log(simulate("excitation", SimSettings(duration_s=60.0, current_mps=0.2), seed=2), path)
    return path


def test_estimate_dynamic_json(current_file, tmp_path, capsys):
    out = tmp_path / "est.mcap"
    assert main(["estimate", str(current_file), "--out", str(out), "--model", "dynamic", "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["model"] == "dynamic" and rep["states"] == 8
    assert rep["sensors"]["gnss"]["accepted"] + rep["sensors"]["gnss"]["rejected"] == 600
    assert rep["sensors"]["compass"]["accepted"] + rep["sensors"]["compass"]["rejected"] == 1200
    assert 1.5 < rep["sensors"]["gnss"]["mean_nis"] < 2.5
    log = read_log(out)
    assert {"/estimate/state", "/estimate/innovations", "/gnss/fix", "/truth/state"} <= set(log.topics)
    st, tr = log["/estimate/state"], log["/truth/state"]
    t = tr.reindex(st.index)
    assert np.sqrt(np.mean((st["current_n_mps"] - t["current_n_mps"]).iloc[3000:] ** 2)) < 0.02
    assert log.provenance[-1]["producer"] == "usvlog estimate"
    # the output exists: refused without --force, one line, exit 2
    assert main(["estimate", str(current_file), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "exists" in err[0]


def test_estimate_kinematic_text_and_no_current(current_file, tmp_path, capsys):
    out = tmp_path / "k.mcap"
    assert main(["estimate", str(current_file), "--out", str(out), "--tune"]) == 0
    text = capsys.readouterr().out
    assert "gnss" in text and "mean NIS" in text and "tuned process noise" in text
    assert read_log(out)["/estimate/state"]["current_n_mps"].isna().all()
    assert main(["estimate", str(current_file), "--out", str(out), "--current", "--force"]) == 2
    assert "kinematic model cannot estimate a current" in capsys.readouterr().err


def test_estimate_sway_damping_flag(current_file, tmp_path, capsys):
    out = tmp_path / "s.mcap"
    assert main(["estimate", str(current_file), "--out", str(out), "--sway-damping", "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["states"] == 10 and rep["settings"]["sway_damping"] is True
    assert main(["estimate", str(current_file), "--out", str(tmp_path / "d.mcap"), "--model", "dynamic",
                 "--sway-damping"]) == 2
    assert "sway_damping is an option of the kinematic model" in capsys.readouterr().err


def test_estimate_missing_channel_one_line(tmp_path, capsys):
    log = simulate("excitation", SimSettings(duration_s=5.0), seed=1)
    del log.channels["/gnss/fix"]
    src = tmp_path / "nogps.mcap"
    write_log(log, src)
    assert main(["estimate", str(src), "--out", str(tmp_path / "o.mcap")]) == 2
    err = [ln for ln in capsys.readouterr().err.strip().splitlines() if "error" in ln]
    assert len(err) == 1 and "nogps.mcap" in err[0] and "/gnss/fix" in err[0]
    assert not (tmp_path / "o.mcap").exists()


def test_estimate_vessel_file_is_used(current_file, tmp_path, capsys):
    from usvlog.model.vessel import default_vessel

    v = default_vessel().with_params(m=40.0)
    toml = tmp_path / "boat.toml"
    toml.write_text(v.to_toml().replace('name = "paper-section-iv"', 'name = "heavier"'))
    out = tmp_path / "v.mcap"
    assert main(["estimate", str(current_file), "--out", str(out), "--model", "dynamic",
                 "--vessel", str(toml), "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["settings"]["vessel"] == "heavier" and rep["settings"]["vessel_params"]["m"] == 40.0
    # a wrong mass makes the model worse at explaining the data than the log's own vessel
    assert main(["estimate", str(current_file), "--out", str(tmp_path / "w.mcap"), "--model", "dynamic",
                 "--json"]) == 0
    own = json.loads(capsys.readouterr().out)
    assert own["settings"]["vessel"] == "paper-section-iv"
    assert own["loglik"] > rep["loglik"]


def test_a_diverged_estimate_is_refused_not_written(tmp_path, capsys):
    """Thrust of +-1e300 N drives the dynamic model to non-finite states: exit 1, one line
    naming the time, no output; the kinematic model (thrust marks only yaw steps) stays finite."""
    log = simulate("excitation", SimSettings(duration_s=30.0), seed=1)
    th = log["/thrust/command"].copy()
    for c in ("left", "right", "thrust_left_n", "thrust_right_n"):
        th[c] = np.where(np.arange(len(th)) % 2 == 0, 1e300, -1e300)
    log.set("/thrust/command", th)
    src, out = tmp_path / "absurd.mcap", tmp_path / "est.mcap"
    write_log(log, src)
    assert main(["estimate", str(src), "--out", str(out), "--model", "dynamic", "--json"]) == 1
    cap = capsys.readouterr()
    err = [x for x in cap.err.strip().splitlines() if "error" in x]   # (after the progress line)
    assert len(err) == 1 and "diverged and could not recover" in err[0] and "re-initialised" in err[0]
    assert "nothing written" in err[0]
    assert json.loads(cap.out)["kind"] == "UnusableResultError"
    assert not out.exists()
    assert main(["estimate", str(src), "--out", str(out), "--model", "kinematic"]) == 0
    st = read_log(out)["/estimate/state"]
    assert np.isfinite(st[["n_m", "e_m", "psi_rad", "u_mps", "v_mps", "r_radps"]].to_numpy()).all()


@pytest.mark.parametrize("verb", ["estimate", "replay"])
def test_a_missing_input_file_is_a_one_line_error(tmp_path, capsys, verb):
    """The verbs that read only some channels (the rest left in the file) still say plainly
    that the file is not there (exit 2), not an internal error."""
    args = [verb, str(tmp_path / "missing.mcap"), "--out", str(tmp_path / "o.mcap")]
    if verb == "replay":
        args += ["--scenario", "paper-sine"]
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    last = err.splitlines()[-1]   # after replay's progress line "reading ..."
    assert last.startswith(f"usvlog {verb}: error: ") and last.endswith("missing.mcap: no such file")
    assert "internal error" not in err
