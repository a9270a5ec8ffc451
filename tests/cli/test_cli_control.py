import json

import numpy as np
import pytest

import usvlog
from usvlog.cli import main
from usvlog.control.paths import path_from_json
from usvlog.replay import replay_log
from usvlog.resources import replay_dir
from usvlog.sim.closed_loop import simulate_scenario
from usvlog.sim.scenario import load_scenario

PC = str(replay_dir() / "paper-circle.toml")

BAD_GAINS = """
[gains]   # condition 3 fails: KPpsi (d33 + KDpsi) = 5 < KIpsi (Iz - m xg^2) = 19.34
KPu = 5.0
KIu = 0.5
KPpsi = 1.0
KIpsi = 2.0
KDpsi = 0.0
"""


def test_gains_accepts_the_paper_and_rejects_condition_3(tmp_path, capsys):
    assert main(["gains", "--gains", PC]) == 0
    out = capsys.readouterr().out
    assert "OK" in out and "-0.063167" in out  # slow surge eigenvalue of A_e
    bad = tmp_path / "bad.toml"
    bad.write_text(BAD_GAINS)
    assert main(["gains", "--gains", str(bad), "--json"]) == 1
    res = json.loads(capsys.readouterr().out)
    assert res["ok"] is False and "condition 3" in res["verdict"]
    assert [c["name"] for c in res["conditions"] if not c["holds"]] == ["condition 3"]
    assert main(["gains", "--gains", str(bad)]) == 1
    assert "FAIL condition 3" in capsys.readouterr().out
    # a gains file with a typo is a config error (exit 2, one line)
    bad.write_text("[gains]\nKPu = 5\nKIpsy = 1\n")
    assert main(["gains", "--gains", str(bad)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "KIpsy" in err[0] and "bad.toml" in err[0]


def test_gains_bound_18(capsys):
    assert main(["gains", "--gains", PC, "--delta", "0.01", "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    P = np.array(r["P"])
    lp = np.linalg.eigvalsh(P)
    b = 2 * lp.max() / 1.0 * np.sqrt(lp.max() / lp.min()) * 0.01 / 0.5
    assert r["bound"] == pytest.approx(b, rel=1e-12)


def test_simulate_paper_circle_and_replay(tmp_path, capsys):
    run = tmp_path / "pc.mcap"
    assert main(["simulate", "paper-circle", "--duration-s", "30", "--out", str(run)]) == 0
    log = usvlog.load(run)
    for topic in ("/gnss/fix", "/compass/heading", "/thrust/command", "/truth/state", "/control/state"):
        assert topic in log and len(log[topic])
    path = path_from_json(log.meta["usvlog.path"]["spec"])
    poly = np.array(json.loads(log.meta["usvlog.path"]["polyline_ne"]))
    assert np.allclose(np.hypot(*poly.T), 4.0, atol=1e-3) and path.spec["direction"] == "ccw"
    out = tmp_path / "rp.mcap"
    capsys.readouterr()
    assert main(["replay", str(run), "--scenario", "paper-circle", "--whatif-controller", "baseline",
                 "--out", str(out), "--json"]) == 0
    m = json.loads(capsys.readouterr().out)
    assert m["state_source"] == "/truth/state" and m["decisions_max_abs"] < 1e-9
    assert m["whatif_controller"] == "baseline" and m["whatif"]["n_ticks"] > 0
    rp = usvlog.load(out)
    assert {"/replay/controller", "/replay/whatif/state", "/replay/whatif/controller"} <= set(rp.topics)
    # no overwrite without --force
    assert main(["replay", str(run), "--scenario", "paper-circle", "--out", str(out)]) == 2
    # unknown scenario name: one line naming what exists
    assert main(["simulate", "no-such-scenario", "--out", str(tmp_path / "x.mcap")]) == 2
    assert "paper-circle" in capsys.readouterr().err


def test_paper_sine_runs_on_the_ekf_and_replays_exactly():
    scen = load_scenario("paper-sine")
    log = simulate_scenario(scen, duration_s=60.0)
    tr, es = log["/truth/state"], log["/estimate/state"]
    assert len(es) == len(tr)
    err = np.hypot(es["n_m"].to_numpy() - tr["n_m"].to_numpy(), es["e_m"].to_numpy() - tr["e_m"].to_numpy())
    assert np.sqrt(np.mean(err[1000:] ** 2)) < 0.6          # GPS noise is 1 m per axis
    # the controller's decisions came from the estimate: replay on it reproduces them
    res = replay_log(log, scen, whatif=False)
    assert res.metrics.state_source == "/estimate/state"
    assert res.metrics.decisions_max_abs < 1e-9


def test_replay_without_recorded_commands_ticks_at_the_controller_rate():
    scen = load_scenario("paper-sine")
    log = simulate_scenario(scen, duration_s=20.0)
    log.channels.pop("/thrust/command")
    log.channels.pop("/control/state")
    res = replay_log(log, scen, whatif=False)
    m = res.metrics
    assert m.command_rms is None and m.decisions_max_abs is None and m.command_unit is None
    rc = res.log["/replay/controller"]
    assert np.allclose(np.diff(rc.index.to_numpy()), 10_000_000)   # 100 Hz
    log.channels.pop("/estimate/state")
    log.channels.pop("/truth/state")
    with pytest.raises(usvlog.UsvlogError, match="no /estimate/state or /truth/state"):
        replay_log(log, scen)


@pytest.mark.parametrize("text,msg", [
    ("[scenaro]\nname = 'x'\n", "unknown section \\[scenaro\\]"),
    ("[path]\ntype = 'circle'\nradius_m = 4\n[gains]\nKPu = 1\n[speed]\nu_d = 0.3\n[simulation]\ndt = 0.1\n",
     "\\[simulation\\] has unknown key\\(s\\) dt"),
    ("[path]\ntype = 'circle'\nradius_m = 4\n[gains]\nKPu = 1\n", "\\[speed\\] needs"),
    ("[path]\ntype = 'circle'\nradius_m = 4\n[gains]\nKPu = -1\n[speed]\nu_d = 0.3\n", "KPu = -1"),
    ("[path]\ntype = 'circle'\nradius_m = 4\n[gains]\n[speed]\nschedule = [[10, 0.3], [5, 0.2]]\n", "increase"),
])
def test_bad_scenarios_name_file_and_key(tmp_path, text, msg):
    p = tmp_path / "s.toml"
    p.write_text(text)
    with pytest.raises(usvlog.UsvlogError, match=msg) as err:
        load_scenario(p)
    assert "s.toml" in str(err.value)


def test_reserved_regression_sections_and_vessel_file(tmp_path):
    (tmp_path / "boat.toml").write_text("name = 'boat'\n[model]\nm = 40.0\n[thrusters]\nforward_n = 30.0\n")
    (tmp_path / "s.toml").write_text(
        "[vessel]\nfile = 'boat.toml'\n[path]\ntype = 'line'\nlength_m = 50\n[gains]\n[speed]\nu_d = 0.5\n"
        "[dataset]\nlog = 'x.mcap'\n[baseline]\nfile = 'b.json'\n")
    s = load_scenario(tmp_path / "s.toml")
    assert s.sim.vessel.params.m == 40.0 and s.sim.vessel.thrusters.forward_n == 30.0
    assert s.doc["dataset"]["log"] == "x.mcap"
