"""A first-order thruster lag: applied as the simulator's plant has it, and identified.

Truth: the exact response of a first-order lag to a step (mean over each step), and the
simulator's plant (:mod:`usvlog.sim.simulate`, a lag of ``[thrusters] lag_s``) with known
parameters.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from usvlog.identify.data import RunData, lag_thrust
from usvlog.identify.identifier import Identifier
from usvlog.model.vessel import PARAM_NAMES, default_vessel
from usvlog.sim.simulate import SimSettings, simulate


def _run(t, tau_u, tau_r) -> RunData:
    z = np.zeros(0)
    return RunData(t0_ns=0, t_thrust=np.asarray(t, float), tau_u=np.asarray(tau_u, float),
                   tau_r=np.asarray(tau_r, float), t_gps=z, n_gps=z, e_gps=z, sigma_gps=z, t_compass=z,
                   psi_compass=z, sigma_compass=z)


def test_lag_thrust_is_the_mean_of_the_exact_step_response():
    T = 0.4
    t = np.concatenate([[-1.0, -0.5], np.cumsum(np.r_[0.0, np.full(40, 0.013), np.full(20, 0.21)])])
    cmd = np.where(t >= 0.0, 3.0, 1.0)   # a step from 1 to 3 at t = 0, uneven steps after it
    out = lag_thrust(_run(t, cmd, -2 * cmd), T)
    a, b = t[2:-1], t[3:]
    exact = 3.0 - 2.0 * T * (np.exp(-a / T) - np.exp(-b / T)) / (b - a)   # mean of 3 - 2 exp(-t/T) over [a, b]
    np.testing.assert_allclose(out.tau_u[2:-1], exact, rtol=1e-12)
    np.testing.assert_allclose(out.tau_r, -2 * out.tau_u, rtol=1e-12)
    np.testing.assert_allclose(out.tau_u[:2], 1.0)          # settled on the first command
    assert lag_thrust(out, 0.0) is out                       # no lag: the run itself


LAG_S = 0.8


@pytest.fixture(scope="module")
def lagged_log():
    v = default_vessel()
    v = replace(v, thrusters=replace(v.thrusters, lag_s=LAG_S))
    return simulate("excitation", SimSettings(vessel=v, duration_s=300.0), seed=3), v


def test_a_known_lag_is_applied(lagged_log):
    log, v = lagged_log
    truth = default_vessel().params
    idf = Identifier("output-error", holdout=0.25, lag_s=LAG_S).fit([log], v)
    err = {k: abs(getattr(idf.params_, k) / getattr(truth, k) - 1) for k in PARAM_NAMES}
    assert all(err[k] < tol for k, tol in {"m": 0.05, "Iz": 0.03, "d11": 0.02, "d33": 0.02}.items()), err
    assert idf.to_dict()["thruster_lag_s"] == LAG_S and idf.to_dict()["thruster_lag"] is None
    # the same log fitted as if the forces came at once: the inertia and damping absorb the lag
    wrong = Identifier("output-error", holdout=0.25).fit([log], v)
    assert abs(wrong.params_.Iz / truth.Iz - 1) > 0.3, wrong.params_
    # validated on another log, the same lag goes into its thrust
    val = idf.validate(simulate("turns", SimSettings(vessel=v, duration_s=200.0), seed=8))
    assert val.fit_percent["r"] > 80, val.fit_percent


def test_the_lag_is_identified(lagged_log):
    log, v = lagged_log
    idf = Identifier("output-error", holdout=0.25, fit_lag=True).fit([log], v)
    lag = idf.thruster_lag_
    assert abs(lag.lag_s - LAG_S) < 0.1, lag
    assert lag.ci95[0] <= LAG_S <= lag.ci95[1], lag
    assert idf.vessel_in_.thrusters.lag_s == lag.lag_s
    assert idf.to_vessel().thrusters.lag_s == lag.lag_s          # written to the identified vessel
    assert abs(idf.params_.Iz / default_vessel().params.Iz - 1) < 0.06, idf.params_
    assert any(r.startswith("thruster lag identified: ") for r in idf.reasons_), idf.reasons_
    assert idf.to_dict()["thruster_lag"]["lag_s"] == lag.lag_s
    # one minimum, and the lag (0.8 s) shorter than the hull's surge time constant (m / d11 = 6.6 s): no doubt said
    assert math.isnan(lag.other_lag_s) and idf.to_dict()["thruster_lag"]["other_lag_s"] is None
    assert not [r for r in idf.reasons_ if "interchangeable" in r or "two minima" in r], idf.reasons_
    # a lag longer than that time constant could be the hull's own: said, with the figure
    idf.thruster_lag_ = replace(lag, lag_s=9.0, ci95=(8.0, 10.0))
    reasons, _ = idf._verdict(idf.vessel_in_, idf.runs_, idf._kin)
    t_surge = idf.params_.m / idf.params_.d11
    line = [r for r in reasons if "interchangeable" in r]
    assert len(line) == 1 and f"m / d11 = {t_surge:.2f} s" in line[0], reasons


def test_a_profile_with_two_minima_spans_both():
    """The 95 % interval is where the profile is within 1.92 of its best, crossings interpolated linearly;
    a second dip inside that level (a lag between the two above it) is reported and spanned."""
    from usvlog.identify.lag import _interval, _other_minimum

    one = [(0.0, 9.0), (0.2, 4.0), (0.4, 1.0), (0.6, 0.0), (0.8, 1.0), (1.0, 3.92)]
    lo, hi = _interval(one, 0.6)
    assert lo == pytest.approx(0.2 + 0.2 * (4.0 - 1.92) / (4.0 - 1.0))   # 4.0 at 0.2 down to 1.0 at 0.4
    assert hi == pytest.approx(0.8 + 0.2 * (1.92 - 1.0) / (3.92 - 1.0))
    assert math.isnan(_other_minimum(one, 0.6))
    two = [(0.0, 5.0), (0.2, 1.5), (0.4, 3.0), (0.8, 0.0), (1.6, 6.0)]
    assert _other_minimum(two, 0.8) == 0.2
    lo, hi = _interval(two, 0.8)
    assert lo == pytest.approx(0.2 * (5.0 - 1.92) / (5.0 - 1.5))
    assert hi == pytest.approx(0.8 + 0.8 * 1.92 / 6.0)


def test_bad_lag_settings_refused():
    from usvlog.errors import ConfigError

    with pytest.raises(ConfigError, match="thruster lag"):
        Identifier("filter-error", fit_lag=True)
    with pytest.raises(ConfigError, match="not both"):
        Identifier(fit_lag=True, lag_s=0.2)
    with pytest.raises(ConfigError, match="lag_s"):
        Identifier(lag_s=-1.0)


def test_cli_fit_lag_on_a_boat_without_one(tmp_path, capsys):
    """``usvlog identify --fit-lag --json`` on the paper's vessel (no lag): a lag near 0, printed,
    in the JSON and in the TOML written."""
    import json

    from usvlog.cli import main
    from usvlog.io.config import load_vessel
    from usvlog.io.mcap import write_log

    path, out = tmp_path / "run.mcap", tmp_path / "boat.toml"
    write_log(simulate("excitation", SimSettings(duration_s=300.0), seed=4), path)
    rc = main(["identify", str(path), "--fit-lag", "--out", str(out), "--json"])
    d = json.loads(capsys.readouterr().out)
    assert rc == 0 and d["usable"], d["reasons"]
    assert d["thruster_lag"]["lag_s"] < 0.1 and d["thruster_lag_s"] == d["thruster_lag"]["lag_s"]
    assert load_vessel(out).thrusters.lag_s == pytest.approx(d["thruster_lag_s"])
    assert "thruster_lag_s = " in out.read_text()
