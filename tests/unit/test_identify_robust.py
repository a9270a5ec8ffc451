"""Identification that does not lie: a boat of another form, validation by default, the verdict.

The boat of another form is the shipped 2 m, 80 kg catamaran (``vessels/catamaran.toml``: surge
and sway added masses differ, quadratic yaw damping, thruster lag), simulated with the issue's
sensors (GPS 1.5 m at 10 Hz, compass 2 deg at 20 Hz). The paper's model cannot describe it
exactly; the fit must still predict the held-out part of the run and must not invent a current.
"""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from usvlog.cli import main
from usvlog.cli.identify import format_report
from usvlog.identify import Identifier
from usvlog.identify.candidates import physical_problem
from usvlog.identify.verdict import VERDICTS
from usvlog.io.config import load_vessel
from usvlog.model.stats import fit_percent
from usvlog.model.vessel import default_vessel
from usvlog.sim.simulate import SensorSettings, SimSettings, simulate

CUR_DIR = 60.0


def _catamaran_fit(current_mps: float, seed: int):
    cat = load_vessel("catamaran")
    log = simulate("excitation", SimSettings(duration_s=600.0, vessel=cat, current_mps=current_mps,
                                             current_dir_deg=CUR_DIR), seed=seed)
    return log, Identifier("output-error", holdout=0.4).fit([log])


def _truth_fit(log, idf) -> dict:
    """Fit % of the held-out free run against the true u, v, r (the measured ones are smoothed
    GPS and compass, whose own errors cap their fit % well below 100 for any model)."""
    v = idf.validation_
    tr = log["/truth/state"]
    tt = (tr.index.to_numpy() - idf.runs_[0].t0_ns) / 1e9
    after = v.t > v.t[0] + v.init_window_s
    return {k: fit_percent(np.interp(v.t[after], tt, tr[col].to_numpy()), v.simulated[after, i])
            for k, col, i in (("u", "u_mps", 3), ("v", "v_mps", 4), ("r", "r_radps", 5))}


def _never_worse_than_equation_error(idf):
    ee = [c for c in idf.candidates_ if c.start.kind == "equation-error"][0]
    assert ee.failed or idf.chosen_.score >= ee.score, [(c.start.name, c.score) for c in idf.candidates_]


@pytest.mark.slow   # a target's proof of ~45 s CPU: run with `pytest -m slow` (fast suite < 5 min)
def test_catamaran_without_current_paper_model_predicts_the_held_out_part():
    """The issue's case: no current, the last 40 % held out. The paper's model predicts the held-out
    surge speed (u >= 85 % against the truth) and yaw rate (r >= 70 % against the measured, more
    against the truth), and invents no current (<= 0.05 m/s). The u target is judged against the
    simulation's truth: the smoothed u fits this boat's true u only ~30 % (GPS noise differentiated,
    fast surge changes smoothed away), so no model's "measured u" fit % can show it.

    The full fit's m (~31 kg) carries the sway and yaw mismatch (true m11 85, m22 162): its surge
    speed fits the truth only ~73 %. The candidate with m from the surge equation alone validates
    better on the held-out track and is returned."""
    log, idf = _catamaran_fit(0.0, seed=5)
    fp = idf.validation_fit_percent_()
    assert idf.validation_mode_ == "holdout"
    assert fp["r"] >= 70 and fp["u"] > 0, (fp, [c.to_dict() for c in idf.candidates_])
    truth = _truth_fit(log, idf)
    assert truth["u"] >= 85 and truth["r"] >= 85, (truth, idf.chosen_.start.name)
    assert math.hypot(*idf.current_[0]) <= 0.05, idf.current_
    _never_worse_than_equation_error(idf)
    assert idf.usable_, idf.reasons_


@pytest.mark.slow   # a target's proof of ~1 min CPU: run with `pytest -m slow` (fast suite < 5 min)
def test_catamaran_with_a_current_finds_it():
    log, idf = _catamaran_fit(0.2, seed=6)
    truth = 0.2 * np.array([math.cos(math.radians(CUR_DIR)), math.sin(math.radians(CUR_DIR))])
    assert np.abs(np.array(idf.current_[0]) - truth).max() <= 0.03, idf.current_
    _never_worse_than_equation_error(idf)


def test_demo_run_is_usable_without_advice():
    """The demo's own run (600 s excitation, 0.2 m/s current, seed 1): usable, no line telling
    the user to change the run."""
    log = simulate("excitation", SimSettings(duration_s=600.0, current_mps=0.2, current_dir_deg=60.0), seed=1)
    idf = Identifier("output-error").fit([log])
    assert idf.verdict_ == "usable", idf.reasons_
    assert not [r for r in idf.reasons_ if "excite" in r or "--fix" in r or "add a" in r], idf.reasons_
    true = log.vessel.params.as_array()
    assert np.all(np.abs(idf.theta_[:5] / true[:5] - 1) < 0.05)


def test_two_logs_left_out_in_turn_never_validate_worse_than_equation_error():
    """Two logs, each left out in turn. A 0.3 m/s current, opposite in the two runs, that the fit is
    told not to model (``current=False``): output error bends the parameters to explain the drift
    of one run's track and predicts the other badly; equation error (velocities over ground, no
    track to drift) validates better on the left-out logs, so it is returned (as with one log:
    never worse than equation error), and the reasons say so. The floor is checked against an
    equation-error identifier run on its own."""
    sens = SensorSettings(gps_noise_m=0.5, compass_noise_deg=1.0)
    a = simulate("excitation", SimSettings(duration_s=90.0, current_mps=0.3, current_dir_deg=0.0, sensors=sens),
                 seed=31)
    b = simulate("turns", SimSettings(duration_s=90.0, current_mps=0.3, current_dir_deg=180.0, sensors=sens),
                 seed=32)
    idf = Identifier("output-error", current=False).fit([a, b])
    ee = Identifier("equation-error", current=False).fit([a, b])
    assert idf.validation_mode_ == "leave-one-out" and len(idf.validations_) == 2
    floor = np.mean([v.score for v in ee.validations_])
    assert np.mean([v.score for v in idf.validations_]) >= floor - 1e-9
    sw = idf.loo_switch_
    assert sw is not None and sw["equation_error_score"] > sw["score"], sw
    assert idf.chosen_.start.kind == "equation-error"
    np.testing.assert_allclose(idf.theta_, ee.theta_)
    assert any("equation error returned" in r for r in idf.reasons_), idf.reasons_
    d = idf.to_dict()
    assert d["fit_percent_on"] == "validation" and set(d["fit_percent"]) == {"u", "v", "r", "track"}
    assert d["verdict"] in VERDICTS and isinstance(d["reasons"], list) and d["chosen"] == "equation error"


def test_physically_impossible_values_are_named():
    assert physical_problem([33, 10, 5, 6, 5, 0.1]) == ""
    assert "d22" in physical_problem([33, 10, 5, -1, 5, 0.1])
    assert "finite" in physical_problem([33, np.nan, 5, 6, 5, 0.1])
    assert "Iz - m xg^2" in physical_problem([33, 10, 5, 6, 5, 1.0])


def test_report_never_prints_absurd_figures_as_meaningful():
    """A degenerate fit's stderr 1e-51 has no interval; a fit % of -4e137 prints as '< -999'."""
    d = {"method": "output-error", "chosen": "output error from equation error",
         "params": {"m": 33.0, "Iz": 1.0e6, "d11": 5.0, "d22": 6.0, "d33": 5.0, "xg": 0.1},
         "stderr": {"m": 1e-51, "Iz": float("nan"), "d11": 0.1, "d22": 0.2, "d33": 0.1, "xg": 0.01},
         "ci95": {"m": [33.0, 33.0], "Iz": [float("nan")] * 2, "d11": [4.8, 5.2], "d22": [5.6, 6.4],
                  "d33": [4.8, 5.2], "xg": [0.08, 0.12]},
         "fixed": {}, "equation_error": {"params": {"m": 30.0, "Iz": 9.0, "d11": 5.0, "d22": 1.0, "d33": 5.0,
                                                    "xg": 0.05}},
         "Iz_minus_m_xg2": 1.0e6, "current_ne_mps": [[0.1, 0.2]], "condition_number": 1e20,
         "fit_percent": {"u": -4e137, "v": None, "r": 12.345, "track": 50.0}, "fit_percent_on": "validation",
         "verdict": "unusable", "reasons": ["the reason"]}
    text = format_report(d)
    assert "[        33,         33]" not in text and "1e-51" not in text
    m_line = next(line for line in text.splitlines() if line.strip().startswith("m "))
    assert "not computable" in m_line and "n/a" in m_line
    assert "u < -999" in text and "v n/a" in text and "r 12.3" in text
    assert "verdict: unusable" in text and "  - the reason" in text
    assert max(len(w) for w in text.split()) < 30


def _csv_from_run(path, log, *, dead_compass: bool):
    """A logger CSV of a simulated run: GPS at 1 Hz, the compass stuck at 0 (dead) or true,
    thrust as integer counts -255..255 of full scale."""
    gps = log["/gnss/fix"]
    gps = gps[np.arange(len(gps)) % 10 == 0]          # 10 Hz -> 1 Hz
    hd = log["/compass/heading"]
    thr = log["/thrust/command"]
    f_max = float(np.abs(thr[["thrust_left_n", "thrust_right_n"]].to_numpy()).max())
    rows = []
    for t, lat, lon in zip(gps.index, gps["lat_deg"], gps["lon_deg"]):
        rows.append((int(t), f"{lat:.9f},{lon:.9f},,,"))
    for t, h in zip(hd.index, hd["heading_rad"]):
        rows.append((int(t), f",,{0.0 if dead_compass else math.degrees(h) % 360:.3f},,"))
    cl = np.round(255 * thr["thrust_left_n"].to_numpy() / f_max).astype(int)
    cr = np.round(255 * thr["thrust_right_n"].to_numpy() / f_max).astype(int)
    for t, a, b in zip(thr.index[::10], cl[::10], cr[::10]):
        rows.append((int(t), f",,,{a},{b}"))
    rows.sort(key=lambda r: r[0])
    path.write_text("time_s,lat,lon,heading_deg,thrust_left,thrust_right\n"
                    + "\n".join(f"{t / 1e9:.3f},{body}" for t, body in rows) + "\n")
    return path


@pytest.mark.parametrize("keep_dead", [False, pytest.param(True, marks=pytest.mark.slow)])   # --keep-dead: slow set
def test_dead_compass_and_counts_thrust_is_unusable_exit_1_no_toml(tmp_path, capsys, keep_dead):
    """Imported through the real CSV importer: the audit flags the dead compass, the thrust
    unit is guessed as counts (force scale unknown). Identify says unusable, exits 1, writes
    nothing, and the reasons name both. With --keep-dead the dead heading is fitted and judged."""
    log = simulate("excitation", SimSettings(duration_s=240.0), seed=3)
    src = _csv_from_run(tmp_path / "boat.csv", log, dead_compass=True)
    mcap = tmp_path / "boat.mcap"
    assert main(["import", str(src), "--out", str(mcap)] + (["--keep-dead"] if keep_dead else [])) == 0
    capsys.readouterr()
    out = tmp_path / "boat.toml"
    # a guessed linear map (thrusters.known = false) turns the commands into forces of unknown scale
    v = default_vessel()
    guess = tmp_path / "guess.toml"
    guess.write_text(replace(v, thrusters=replace(v.thrusters, map="linear", known=False)).to_toml())
    rc = main(["identify", str(mcap), "--out", str(out), "--vessel", str(guess), "--json"])
    cap = capsys.readouterr()
    assert rc == 1, cap.err
    assert not out.exists()
    d = json.loads(cap.out)
    assert d["verdict"] == "unusable" and d["usable"] is False
    text = " ".join(d["reasons"])
    assert "/compass/heading" in text and "dead" in text, d["reasons"]
    assert any(("force scale" in r or "thrust scale" in r) and "unknown" in r.replace("no known", "unknown")
               for r in d["reasons"]), d["reasons"]
    err = [x for x in cap.err.splitlines() if x.startswith("usvlog identify: error:")]
    assert len(err) == 1 and "unusable" in err[0], cap.err
    if keep_dead:   # --force writes it, marked
        assert main(["identify", str(mcap), "--out", str(out), "--vessel", str(guess), "--force"]) == 1
        capsys.readouterr()
        doc = out.read_text()
        assert "usable = false" in doc and 'verdict = "unusable"' in doc
        assert load_vessel(out).params.m > 0      # still a vessel file the other verbs read
