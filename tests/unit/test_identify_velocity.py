"""Velocity output error (usvlog.identify.velocity) and the checks made before any fit.

Truth: runs of usvlog's simulator with the paper's vessel and known parameters. The velocity fit
must land on the same answer from starting guesses a tenth to ten times the truth (the issue: the
answer must not hang on the user's guess), find a current it was given, and the identifier must
refuse, naming the fix, a log whose left and right thrust are swapped.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from usvlog.errors import UnusableResultError
from usvlog.identify import Identifier
from usvlog.identify.data import run_data
from usvlog.identify.smooth import kinematic_states
from usvlog.identify.velocity import data_scales, fit_velocity_error
from usvlog.model.vessel import default_vessel
from usvlog.sim.simulate import SimSettings, simulate


@pytest.fixture(scope="module")
def sim_run():
    """A 300 s excitation run of the paper's vessel with a 0.2 m/s current toward 60 deg."""
    log = simulate("excitation", SimSettings(duration_s=300.0, current_mps=0.2, current_dir_deg=60.0), seed=11)
    run = run_data(log, log.vessel)
    return log, run, kinematic_states(log, run, log.vessel)


def test_same_answer_from_a_tenth_to_ten_times_the_truth(sim_run):
    log, run, ks = sim_run
    truth = default_vessel().params.as_array()
    fits = [fit_velocity_error([run], [ks], truth * np.array([f, f, f, f, f, 0.0]))
            for f in (0.1, 1.0, 10.0)]
    th = np.array([f.theta for f in fits])
    assert not any(f.diverged for f in fits)
    # the same basin whatever the start: the parameters agree within 2 % of each other
    spread = (th[:, :5].max(0) - th[:, :5].min(0)) / th[:, :5].mean(0)
    assert np.all(spread < 0.02), th
    # and near the truth: d11 and d33 (the steady responses) within 15 %, Iz within 35 %; m within
    # 60 %: the smoothed u lags the true one (GPS noise smoothed over seconds), and a fit to it reads
    # that lag as a slower surge, a larger m (46 % here). That bias is why this fit is one candidate
    # among others, picked only when it validates better, not the answer by itself
    rel = np.abs(th[1] / truth - 1)
    assert rel[2] < 0.15 and rel[4] < 0.15 and rel[1] < 0.35 and rel[0] < 0.6, (th[1], truth)


def test_current_found(sim_run):
    _, run, ks = sim_run
    f = fit_velocity_error([run], [ks], data_scales([run], [ks]))
    truth = 0.2 * np.array([math.cos(math.radians(60.0)), math.sin(math.radians(60.0))])
    assert np.abs(f.currents[0] - truth).max() < 0.05, f.currents


def test_data_scales_are_of_the_right_order(sim_run):
    _, run, ks = sim_run
    sc = data_scales([run], [ks])
    truth = default_vessel().params.as_array()
    assert sc is not None
    assert np.all(np.abs(np.log(sc[:5] / truth[:5])) < math.log(10.0)), (sc, truth)


def test_swapped_thrusters_refused_with_the_fix(sim_run):
    log, _, _ = sim_run
    swapped = log.copy()
    th = swapped.channels["/thrust/command"].copy()
    cols = list(th.columns)
    left = [c for c in cols if "left" in c]
    right = [c for c in cols if "right" in c]
    assert left and right, cols
    th[left + right] = th[right + left].to_numpy()
    swapped.channels["/thrust/command"] = th
    with pytest.raises(UnusableResultError, match="left and right thrust appear swapped") as exc:
        Identifier(holdout=0.3).fit([swapped])
    assert "thrust_left" in str(exc.value)


def test_identifier_reports_ahead_fit_and_sign_checks(sim_run):
    log, _, _ = sim_run
    idf = Identifier(holdout=0.3).fit([log])
    d = idf.to_dict()
    assert set(d["fit_percent_ahead"]) == {"5", "10", "30"}
    # the true model family predicts the smoothed r well at every horizon
    assert all(d["fit_percent_ahead"][h]["r"] > 70 for h in ("5", "10", "30")), d["fit_percent_ahead"]
    assert d["sign_checks"][0]["yaw"]["sign"] == 1
    assert any(c["name"].startswith("velocity output error") for c in d["candidates"])
    assert "fit_ahead_30s_r_pct" in idf.toml_record()
