"""``usvlog identify --json`` on a T200 boat logged in PWM pulse widths, its map unknown: the
deadband and the reverse/forward ratio identified from the data, printed, and in the TOML."""

from __future__ import annotations

import json

import pytest

from usvlog.cli import main
from usvlog.cli.identify import format_report
from usvlog.io.config import load_vessel
from usvlog.io.mcap import write_log
from usvlog.model import thruster_curves
from usvlog.model.vessel import Thrusters, Vessel
from usvlog.sim.pwm import pwm_run
from usvlog.sim.simulate import SimSettings


def t200_truth(volts: float) -> tuple[float, float]:
    """Half-width of the curve's zero-force interval (us), and the least-squares rho with
    reverse(-o) = rho forward(o) over o = 4..400 us (as tests/unit/test_thrust_map.py)."""
    pwm, force = thruster_curves.curve("t200", volts)
    zero = pwm[force == 0.0]
    offset = pwm - 1500.0
    fwd, rev = force[offset > 0], -force[offset < 0][::-1]
    return float(zero.max() - zero.min()) / 2.0, float(rev @ fwd / (fwd @ fwd))


def test_identify_finds_the_t200_map_from_pwm_commands(tmp_path, capsys):
    log_path, guess, out = tmp_path / "t200.mcap", tmp_path / "guess.toml", tmp_path / "boat.toml"
    # ten minutes: the ratio's own 95 % interval from five is about +-12 %
    write_log(pwm_run(SimSettings(vessel=Vessel(thrusters=Thrusters(map="t200", supply_v=16.0)), duration_s=600.0),
                      seed=1), log_path)
    guess.write_text(Vessel(name="guess", thrusters=Thrusters(map="quadratic", known=False)).to_toml())
    # --quadratic-surge: not tried in command units, and said so (the rest is the same fit)
    rc = main(["identify", str(log_path), "--vessel", str(guess), "--out", str(out), "--json", "--quadratic-surge"])
    d = json.loads(capsys.readouterr().out)
    assert rc == (0 if d["usable"] else 1)
    assert any(r.startswith("the paper model with quadratic surge damping (--quadratic-surge) was not tried")
               for r in d["reasons"]), d["reasons"]
    assert not any("quadratic surge" in c["name"] for c in d["candidates"])
    ts = d["thrust_scale"]
    truth_db, truth_rho = t200_truth(16.0)
    assert ts["case"] == "command units" and ts["map_from"] == "equation error profile" and ts["deadband_determined"]
    assert abs(ts["deadband_us"] - truth_db) <= 10.0, ts                # measured: 31.3 us for 28
    assert abs(ts["ratio"] / truth_rho - 1) < 0.05, ts                  # measured: 0.798 (output error) for 0.783
    assert ts["ratio_from"] == "output error" and ts["shape"] == "mixed"
    lo, hi = ts["deadband_ci95_us"]
    assert lo < ts["deadband_us"] < hi
    boat = load_vessel(out)   # the TOML carries the identified map
    t = boat.thrusters
    assert (t.map, t.scale, t.forward_n) == ("mixed", "command", 1.0)
    assert t.deadband_us == pytest.approx(ts["deadband_us"])
    assert t.quadratic_share == pytest.approx(ts["quadratic_share"])
    assert t.reverse_n == pytest.approx(ts["ratio"])
    text = format_report(d)
    assert f"no thrust within +-{ts['deadband_us']:.3g} us of neutral" in text
    assert any("thruster map identified from the PWM commands" in r for r in d["reasons"])
