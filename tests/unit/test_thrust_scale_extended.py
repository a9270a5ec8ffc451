"""The extended model without a known thrust scale: command units, and the gains from one fixed value.

The boat is the shipped catamaran (``vessels/catamaran.toml``: 119.7 N forward and 66.7 N reverse
per thruster) with its commands logged through a linear map and identified with a guessed one
(150 N both ways, ``known = false``), so the log has no force scale. Its thruster lag is left out
and the sensors are quiet (GPS 0.1 m, compass 0.2 deg): the test is about the scale, and with the
issue's sensors on a few minutes of data the extended model's sway terms are not identifiable even
with known forces (m22 off by 150 % on 300 s), so no ratio of them could be checked.
"""

from dataclasses import replace

import numpy as np
import pytest

from usvlog.choices import EXTENDED_PARAM_NAMES
from usvlog.cli import main
from usvlog.control.gains import Gains
from usvlog.control.law import Controller
from usvlog.errors import ConfigError
from usvlog.identify import Identifier
from usvlog.identify.thrust_scale import scale_results
from usvlog.io.config import load_vessel
from usvlog.io.mcap import write_log
from usvlog.model.vessel import ExtendedParams, extended_vessel, vessel_from_toml
from usvlog.sim.closed_loop import closed_loop
from usvlog.sim.scenario import load_scenario
from usvlog.sim.simulate import SensorSettings, SimSettings, simulate

CAT = load_vessel("catamaran")
TRUE = CAT.extended
G_F, G_R = CAT.thrusters.forward_n, CAT.thrusters.reverse_n
BOAT = replace(CAT, thrusters=replace(CAT.thrusters, map="linear", lag_s=0.0))
GUESS = replace(BOAT, thrusters=replace(BOAT.thrusters, known=False, forward_n=150.0, reverse_n=150.0))
QUIET = SensorSettings(gps_noise_m=0.1, compass_noise_deg=0.2)


def test_with_the_extended_model_fix_only_sets_an_unknown_thrust_scale():
    with pytest.raises(ConfigError, match="only sets an unknown thrust scale"):
        Identifier(model="extended", fix={"d11": 70.0})        # damping: linear or quadratic part?
    with pytest.raises(ConfigError, match="only sets an unknown thrust scale"):
        Identifier(model="extended", fix={"m11": 85.0, "m66": 40.0})
    with pytest.raises(ConfigError, match="only sets an unknown thrust scale"):
        Identifier(model="both", fix={"m22": 160.0})           # not a term of the paper's model
    log = simulate("excitation", SimSettings(duration_s=20.0, vessel=CAT), seed=1)   # forces in newtons
    with pytest.raises(ConfigError, match="thrust is in newtons"):
        Identifier("equation-error", model="extended", fix={"m11": 85.28}).fit([log])


def test_scaling_an_extended_fit_carries_the_gain_in_every_term():
    """Every extended term (inertias, m26 in kg m, linear and quadratic damping) is per unit of
    command; the fixed m11 gives the gain and the covariance follows by the delta method."""
    rng = np.random.default_rng(4)
    q = TRUE.as_array() / G_F
    names = list(EXTENDED_PARAM_NAMES) + ["current_n_0"]
    L = rng.normal(0, 1, (11, 11)) * 1e-3
    cov = L @ L.T
    theta, cov_p, names_p, g, g_se = scale_results(q, cov, names, {"m11": TRUE.m11}, "m11", EXTENDED_PARAM_NAMES, ())
    assert g == pytest.approx(G_F) and np.allclose(theta, TRUE.as_array())
    assert names_p == tuple(names[1:])

    def phys(x):
        return np.concatenate([TRUE.m11 / x[0] * x[1:10], x[10:]])
    x0 = np.append(q, 0.1)
    J = np.array([(phys(x0 + h) - phys(x0 - h)) / 2e-7 for h in np.eye(11) * 1e-7]).T
    assert np.allclose(cov_p, J @ cov @ J.T, rtol=1e-5, atol=1e-12)
    assert g_se == pytest.approx(TRUE.m11 / q[0] ** 2 * np.sqrt(cov[0, 0]))


def test_extended_model_in_command_units_says_so_and_a_fixed_mass_scales_it(tmp_path, capsys):
    """Equation error (cheap): the per-unit extended model, its TOML (command-unit thrusters, the
    [extended] table, the case recorded) and the verdict's message; ``--fix m`` (the surge inertia
    m11) scales the very same per-unit fit and gives the gains."""
    log = simulate("excitation", SimSettings(duration_s=120.0, vessel=BOAT, sensors=QUIET), seed=2)
    per_unit = Identifier("equation-error", model="extended").fit([log], GUESS)
    ts = per_unit.thrust_scale_
    assert ts.case == "command units" and ts.structure == "extended" and ts.ratio > 0
    assert per_unit.extended_ is not None and per_unit.extended_.m11 < 5.0   # per unit of command, not kg
    assert any("extended model's inertias m11, m22, m26, m66" in r for r in per_unit.reasons_)
    assert per_unit.verdict_ != "usable"
    record = per_unit.toml_record()
    saved = vessel_from_toml(per_unit.to_vessel().to_toml() + record)
    assert saved.extended == per_unit.extended_ and saved.thrusters.scale == "command"
    assert saved.thrusters.forward_n == 1.0 and saved.thrusters.reverse_n == pytest.approx(ts.ratio)
    assert 'thrust_scale = "command units"' in record
    assert per_unit.to_dict()["thrust_scale"]["structure"] == "extended"

    # the same through the command line with the surge inertia fixed: the very per-unit fit, scaled
    mcap, guess, out = tmp_path / "cat.mcap", tmp_path / "guess.toml", tmp_path / "id.toml"
    write_log(log, mcap)
    guess.write_text(GUESS.to_toml())
    rc = main(["identify", str(mcap), "--vessel", str(guess), "--method", "equation-error", "--model", "extended",
               "--fix", f"m={TRUE.m11}", "--out", str(out), "--force"])
    text = capsys.readouterr().out
    weighed = vessel_from_toml(out.read_text())
    g = weighed.thrusters.forward_n
    assert rc in (0, 1) and weighed.thrusters.scale == "known" and 'thrust_scale = "gain identified"' in out.read_text()
    assert g == pytest.approx(TRUE.m11 / per_unit.extended_.m11)
    assert weighed.thrusters.reverse_n == pytest.approx(g * ts.ratio)
    assert np.allclose(weighed.extended.as_array(), g * per_unit.extended_.as_array())
    assert f"thrust gain from the fixed m: {g:.4g} N forward" in text
    assert "(fixed)" in text and "standard errors of" not in text     # m (= m11) held, not degenerate


@pytest.mark.slow   # a target's proof of ~30 s CPU: run with `pytest -m slow` (fast suite < 5 min)
def test_extended_output_error_finds_the_gains_and_the_per_unit_ratios():
    """Output error on 200 s: the reverse/forward ratio by the extended model's own search, the gains
    from the fixed m11 within 5 % (measured +3.0 % forward, +3.9 % reverse), and the ratios of the
    determined per-unit terms to m11 within 7 % of the truth (measured 1.3-5.6 %: m22, m66, d11, d22,
    d33, d33q). The per-unit fit is the one without the fixed value (it only scales it afterwards).
    m26, d11q (truth 0) and d22q are not determined by this run, and the verdict says so."""
    log = simulate("excitation", SimSettings(duration_s=200.0, vessel=BOAT, sensors=QUIET), seed=3)
    idf = Identifier(model="extended", fix={"m11": TRUE.m11}).fit([log], GUESS)
    ts = idf.thrust_scale_
    assert ts.case == "gain identified" and ts.ratio_from == "output error of the extended model"
    assert abs(ts.forward_n / G_F - 1) < 0.05 and abs(ts.reverse_n / G_R - 1) < 0.05, ts
    e = idf.extended_
    assert e is not None and e.m11 == TRUE.m11
    for k in ("m22", "m66", "d11", "d22", "d33", "d33q"):
        ratio = getattr(e, k) / getattr(TRUE, k)
        assert abs(ratio - 1) < 0.07, (k, ratio)
    for k in ("m26", "d11q", "d22q"):
        assert any(r.startswith(f"extended term {k} poorly determined") for r in idf.reasons_), (k, idf.reasons_)
    assert any("gain identified from the fixed m11" in r for r in idf.reasons_)


def test_whatif_in_command_units_is_the_physical_run_with_gains_per_unit_too():
    """The what-if of a replay (controller on the vessel's paper terms, plant the extended model
    with its thruster lag) with the catamaran per unit of command (every term / forward gain,
    thrusters 1 forward and the gain ratio reverse, scale "command") and the controller gains
    per unit of command too is the run with the physical catamaran and the gains in newtons: the
    law and the plant are linear in the model and the gains, the force limits and the lag scale
    with them. (Gains in newtons with a command-unit vessel are a different, stiffer controller.)"""
    scen = load_scenario("paper-circle")
    per_unit = extended_vessel("per-unit", ExtendedParams(**{k: v / G_F for k, v in zip(EXTENDED_PARAM_NAMES,
                                                                                          TRUE.as_array())}),
                               replace(CAT.thrusters, map="linear", forward_n=1.0, reverse_n=G_R / G_F,
                                       scale="command"))
    phys = replace(CAT, thrusters=replace(CAT.thrusters, map="linear"))
    gains_per_unit = Gains(**{k: v / G_F for k, v in scen.gains.to_dict().items()})
    runs = []
    for ves, gains in ((phys, scen.gains), (per_unit, gains_per_unit), (per_unit, scen.gains)):
        path = scen.path(scen.sim.datum)
        ctl = Controller(path, ves, gains, scen.guidance, full=True)
        runs.append(closed_loop(path, ves, ctl, duration_s=30.0, dt_s=scen.sim.dt_s, integrator="rk4",
                                current_ne=(0.05, 0.0), eta0=scen.sim.eta0, nu0=scen.sim.nu0,
                                schedule=scen.schedule, rate_hz=scen.guidance.rate_hz))
    a, b, c = runs
    assert np.ptp(a.states[:, 5]) > 0.1                      # it turns (the yaw terms are in play)
    assert np.allclose(b.states, a.states, rtol=0, atol=1e-9)
    assert np.allclose(b.tau * G_F, a.tau, rtol=1e-9, atol=1e-9)
    assert np.abs(c.states[:, :2] - a.states[:, :2]).max() > 0.1
