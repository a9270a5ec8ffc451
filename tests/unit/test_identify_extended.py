"""The extended model identified by output error, alone and against the paper's model (``--model``).

The boat is the shipped 2 m, 80 kg catamaran (``vessels/catamaran.toml``: surge and sway inertia
differ, quadratic yaw and sway damping, thruster lag), simulated with the issue's sensors: GPS
1.5 m at 10 Hz, compass 2 deg at 20 Hz, no current, the last 40 % held out.

The u and r fit % of the target are judged against the simulation's truth (``/truth/state``):
the smoothed u the validation compares with by default fits the true u only about 30-37 % on
this boat (GPS noise differentiated), so any model's "measured u" fit % is low; the held-out
track fit (positions, whose noise is small beside the track's extent) is checked as well.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from usvlog.cli import main
from usvlog.cli.identify import format_report
from usvlog.identify import Identifier
from usvlog.io.config import load_vessel
from usvlog.io.mcap import read_log, write_log
from usvlog.model.stats import fit_percent
from usvlog.model.vessel import vessel_from_toml
from usvlog.sim.simulate import SimSettings, simulate


def _truth_fit(log, idf, v) -> dict:
    """Fit % of a held-out free run against the true u, v, r after its initial window."""
    tr = log["/truth/state"]
    tt = (tr.index.to_numpy() - idf.runs_[0].t0_ns) / 1e9
    after = v.t > v.t[0] + v.init_window_s
    return {k: fit_percent(np.interp(v.t[after], tt, tr[col].to_numpy()), v.simulated[after, i])
            for k, col, i in (("u", "u_mps", 3), ("v", "v_mps", 4), ("r", "r_radps", 5))}


@pytest.mark.slow   # a target's proof of ~1 min CPU: run with `pytest -m slow` (fast suite < 5 min)
def test_catamaran_extended_model_meets_the_target_and_both_models_are_compared():
    """``model="both"``: the extended model's best candidate predicts the held-out 40 % with
    u >= 90 % and r >= 80 % against the truth and a held-out track fit >= 90 %, finds no
    current (<= 0.05 m/s); the comparison names the model whose candidate validates better
    and the one returned (the paper's when the extended one wins by less than a point); an
    extended result is written as an [extended] vessel
    that reads back."""
    cat = load_vessel("catamaran")
    log = simulate("excitation", SimSettings(duration_s=600.0, vessel=cat, current_mps=0.0), seed=5)
    idf = Identifier("output-error", holdout=0.4, model="both").fit([log])
    ext = [c for c in idf.candidates_ if c.start.model == "extended" and not c.failed]
    best = max(ext, key=lambda c: c.score)
    val = idf.candidate_validations(best)[0]
    assert val.fit_percent == best.validations[0].fit_percent   # made again: the same numbers
    truth = _truth_fit(log, idf, val)
    track = val.fit_percent["track"]
    assert truth["u"] >= 90 and truth["r"] >= 80 and track >= 90, (truth, track, best.start.name)
    assert math.hypot(*best.currents[0]) <= 0.05, best.currents
    mc = idf.model_comparison_
    paper = max((c for c in idf.candidates_ if c.start.model == "paper" and not c.failed), key=lambda c: c.score)
    assert mc["winner"] == ("extended" if best.score > paper.score else "paper")
    assert mc["margin"] == abs(best.score - paper.score)
    # returned: the winner, or the simpler paper model when the extended one wins by less than a point
    assert mc["returned"] == idf.chosen_.start.model
    assert mc["returned"] == mc["winner"] or (mc["winner"] == "extended" and mc["margin"] < 1.0)
    assert "at least 1 point" in mc["rule"] and f"{mc['margin']:.1f} points" in mc["why"], mc
    text = format_report(idf.to_dict())
    assert f"returned: {mc['returned']} ({mc['why']})" in text and f"rule: {mc['rule']}" in text
    d = idf.to_dict()
    assert d["model_comparison"]["winner"] == mc["winner"]
    if idf.extended_ is not None:
        back = vessel_from_toml(idf.to_vessel().to_toml() + idf.toml_record())
        assert back.extended == idf.extended_ and d["structure"] == "extended"
        assert back.params == idf.extended_.paper_terms()


def test_cli_model_extended_writes_an_extended_vessel(tmp_path, capsys):
    """``usvlog identify --model extended`` on a logged run: the TOML is an extended vessel whose
    parameters are the JSON's, the JSON says so, and the text report lists the extended terms."""
    cat = load_vessel("catamaran")
    log = simulate("excitation", SimSettings(duration_s=300.0, vessel=cat, current_mps=0.0), seed=3)
    mcap = tmp_path / "cat.mcap"
    write_log(log, mcap)
    out = tmp_path / "id.toml"
    rc = main(["identify", str(mcap), "--model", "extended", "--out", str(out), "--json"])
    d = json.loads(capsys.readouterr().out)
    assert rc == (0 if d["usable"] else 1)
    assert d["model"] == "extended" and d["structure"] == "extended"
    assert all(c["model"] == "extended" for c in d["candidates"])
    v = vessel_from_toml(out.read_text())
    assert v.extended is not None
    assert v.extended.to_dict() == d["extended"]["params"]
    # the verdict judges the extended model's own terms, not only their paper-term combinations
    for k in ("m22", "m26", "d11", "d22", "d33"):
        val, se = d["extended"]["params"][k], d["extended"]["stderr"][k]
        named = [r for r in d["reasons"] if r.startswith(f"extended term {k} ")]
        assert bool(named) == (not math.isfinite(se) or se <= 1e-9 * abs(val) or se > 0.1 * abs(val)), (k, named)
    assert read_log(mcap).get("/gnss/fix") is not None
    text = format_report(d)   # the console's text, made from the same result as the JSON
    assert "extended model (the parameters above are its paper terms)" in text and "d33q" in text


def test_block_solve_matches_a_dense_solve():
    """The Schur-complement solve of the extended fit's normal equations (global unknowns, then
    6x6 blocks per segment) equals a dense solve of the same system."""
    from usvlog.identify.extended_oe import _block_solve

    rng = np.random.default_rng(0)
    ng, ns = 5, 4
    n = ng + 6 * ns
    H = (lambda J: J.T @ J)(rng.normal(size=(200, n)))
    for k in range(ns):
        for j in range(ns):
            if k != j:
                H[ng + 6 * k:ng + 6 * k + 6, ng + 6 * j:ng + 6 * j + 6] = 0.0
    b = rng.normal(size=n)
    np.testing.assert_allclose(_block_solve(H, b, ng), np.linalg.solve(H, b), rtol=1e-9, atol=1e-12)


def test_model_comparison_says_which_model_is_returned_and_why():
    """The rule of ``--model both`` in plain words: the extended model by less than a point is
    not returned (the simpler paper model is), by more it is; equation error says so."""
    from usvlog.identify.candidates import PREFER_WITHIN, Candidate, Start, _returned

    def cand(model, kind="output-error"):
        return Candidate(start=Start(name="x", kind=kind, theta=np.zeros(6), model=model), theta=np.zeros(6),
                         currents=np.zeros((1, 2)), fitted=None, validations=[])

    close = _returned({"winner": "extended", "margin": 0.4 * PREFER_WITHIN}, cand("paper"))
    assert close["returned"] == "paper" and "simpler paper model" in close["why"] and "0.4" in close["why"]
    far = _returned({"winner": "extended", "margin": 3.0}, cand("extended"))
    assert far["returned"] == "extended" and far["why"] == "it validates better by 3.0 points"
    assert "equation error" in _returned({"winner": "paper", "margin": 2.0}, cand("paper", "equation-error"))["why"]
    assert close["rule"] == far["rule"] and f"{PREFER_WITHIN:g} point" in far["rule"]
