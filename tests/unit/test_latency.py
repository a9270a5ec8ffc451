"""Sensor latency: the delay applied to the measurement times, its estimation from the
likelihood (against known functions and a simulated delay), storage in the output log,
and identification taking it off the GNSS stamps."""

import math

import numpy as np
import pytest

from usvlog.errors import ConfigError
from usvlog.estimate import EstimateSettings, build_problem, estimate
from usvlog.estimate.kernels import COMPASS, GNSS
from usvlog.estimate.latency import (
    META_LATENCY,
    PROFILE_DROP,
    profile_delay,
    search_window,
    stored_delays,
    with_delays,
)
from usvlog.identify import Identifier
from usvlog.identify.data import run_data
from usvlog.io.mcap import read_log, write_log
from usvlog.model.vessel import PARAM_NAMES, VesselParams, default_vessel
from usvlog.sim.simulate import SensorSettings, SimSettings, simulate

TRUE = VesselParams()
TARGET = {"m": 0.05, "Iz": 0.03, "d11": 0.02, "d22": 0.10, "d33": 0.02, "xg": 0.10}   # issue 5's


# -----------------------------------------------------------------------------
# the search against known likelihoods
# -----------------------------------------------------------------------------

@pytest.mark.parametrize("d0,sigma", [(0.2, 0.016), (0.137, 0.05), (-0.04, 0.004)])
def test_profile_recovers_a_quadratic_likelihood(d0, sigma):
    """loglik = -(d - d0)^2 / (2 sigma^2): the optimum is d0 and 1/sqrt(-loglik'') is sigma."""
    prof = profile_delay(lambda d: 7.0 - 0.5 * ((d - d0) / sigma) ** 2)
    assert prof.identifiable, prof.reason
    assert abs(prof.optimum_s - d0) < 1e-6
    assert prof.std_s == pytest.approx(sigma, rel=1e-6)
    assert prof.loglik_max == pytest.approx(7.0)
    assert prof.evaluations <= 14


def test_profile_refuses_flat_or_edge_likelihoods():
    flat = profile_delay(lambda d: -0.5 * ((d - 0.2) / 0.3) ** 2)    # drops < PROFILE_DROP in range
    assert not flat.identifiable and "flat" in flat.reason
    assert 0.5 * (0.3 / 0.3) ** 2 < PROFILE_DROP    # the range is one sigma each side: flat indeed
    edge = profile_delay(lambda d: 10 * d)                              # keeps rising
    assert not edge.identifiable and "edge of the search range" in edge.reason
    wide = profile_delay(lambda d: -0.5 * ((d - 0.2) / 0.11) ** 2)    # drops enough, sigma too large
    assert not wide.identifiable and "uncertainty" in wide.reason
    nan = profile_delay(lambda d: math.nan)
    assert not nan.identifiable


# -----------------------------------------------------------------------------
# the delay applied
# -----------------------------------------------------------------------------

@pytest.fixture(scope="module")
def delayed_run():
    """10-minute excitation run, GNSS 0.3 m stamped 0.20 s late (the simulator's latency)."""
    sens = SensorSettings(gps_noise_m=0.3, gps_delay_s=0.2)
    return simulate("excitation", SimSettings(duration_s=600.0, sensors=sens), seed=3)


def test_simulator_stamps_fixes_late(delayed_run):
    truth = delayed_run["/truth/state"]
    g = delayed_run["/gnss/fix"]
    t = np.asarray(g.index, np.int64)
    assert (t - int(0.2e9) >= truth.index[0]).all()
    assert np.isin(t - int(0.2e9), truth.index).all()      # the fix describes the plant 0.2 s earlier
    assert (g["stamp_ns"].to_numpy() == t).all()
    c = np.asarray(delayed_run["/compass/heading"].index, np.int64)
    assert c[0] == truth.index[0]                             # compass not delayed
    with pytest.raises(ConfigError):
        SensorSettings(gps_delay_s=-0.1)


def test_build_problem_moves_the_stamps_by_the_delay(delayed_run):
    v = default_vessel()
    s0 = EstimateSettings(model="dynamic")
    p0 = build_problem(delayed_run, s0, v)
    p1 = build_problem(delayed_run, EstimateSettings(model="dynamic", gnss_delay_s=0.2, compass_delay_s=0.013), v)
    for kind, d in ((GNSS, int(0.2e9)), (COMPASS, int(0.013e9))):
        np.testing.assert_array_equal(p1.m_t_ns[p1.mkind == kind], p0.m_t_ns[p0.mkind == kind] - d)
        np.testing.assert_array_equal(p1.mz[p1.mkind == kind], p0.mz[p0.mkind == kind])
    assert (np.diff(p1.m_t_ns) >= 0).all() and (p1.t_ns[p1.mstep] == p1.m_t_ns).all()
    # the output grid keeps its phase (that of the first stamp): delays do not move it
    g0, g1 = p0.t_ns[p0.is_grid], p1.t_ns[p1.is_grid]
    assert ((g1 - g0[0]) % int(0.01e9) == 0).all()
    with pytest.raises(ConfigError, match="latency"):
        EstimateSettings(gnss_delay_s=math.nan)
    with pytest.raises(ConfigError, match="not one of"):
        EstimateSettings(estimate_delays=("imu",))


def test_gnss_delay_recovered_and_stored(delayed_run, tmp_path):
    """The issue's target: a 0.20 s GNSS delay recovered within +-0.03 s (dynamic model, the
    recorded thrust, tuned process noise); its one-sigma covers the error; stored in the
    output log."""
    res = estimate(delayed_run, EstimateSettings(model="dynamic", tune=True, estimate_delays="gnss"))
    (g,) = res.report.latency
    assert g.sensor == "gnss" and g.status == "estimated", g
    assert abs(g.delay_s - 0.2) < 0.03, g
    assert 0 < g.std_s < 0.03 and abs(g.delay_s - 0.2) < 3 * g.std_s, g
    assert res.settings.gnss_delay_s == g.delay_s and g.loglik_gain > PROFILE_DROP
    assert "gnss delay" in res.report.format() and res.report.to_dict()["latency"][0]["delay_s"] == g.delay_s
    path = tmp_path / "est.mcap"
    write_log(res.to_log(delayed_run), path)
    back = read_log(path)
    assert stored_delays(back) == pytest.approx({"gnss": g.delay_s, "compass": 0.0})
    assert back.meta[META_LATENCY]["gnss_delay_status"] == "estimated"
    assert run_data(back).gnss_delay_s == g.delay_s


def test_compass_delay_recovered():
    """A compass stamped 0.05 s late, 200 s of an excitation run, default noise: the dynamic
    model ties the heading to the recorded yaw moment, so the delay is sharp; the GNSS
    delay is searched after it (none here)."""
    sens = SensorSettings(compass_delay_s=0.05)
    log = simulate("excitation", SimSettings(duration_s=200.0, sensors=sens), seed=6)
    res = estimate(log, EstimateSettings(model="dynamic", estimate_delays=("compass", "gnss")))
    c, g = res.report.latency
    assert c.status == "estimated" and abs(c.delay_s - 0.05) < 0.02 and c.std_s < 0.01, c
    assert abs(c.delay_s - 0.05) < 3 * c.std_s, c
    assert g.status == "not identifiable" or abs(g.delay_s) < 3 * g.std_s, g


def test_kinematic_model_says_the_gnss_delay_is_not_identifiable(delayed_run):
    """Heading and track are not tied together (no sway damping) nor to the thrust: flat."""
    log = search_window(delayed_run, 200.0)
    res = estimate(log, EstimateSettings(model="kinematic", sway_damping=False, estimate_delays="gnss"))
    (g,) = res.report.latency
    assert g.status == "not identifiable" and g.delay_s == 0.0 and res.settings.gnss_delay_s == 0.0
    assert "dynamic model" in g.reason and "not identifiable" in res.report.format()


def test_search_window_picks_a_part_with_turns(delayed_run):
    w = search_window(delayed_run, 200.0)
    t0, t1 = w.time_range()
    assert 199e9 < t1 - t0 < 202e9
    assert search_window(delayed_run, 600.0) is delayed_run


# -----------------------------------------------------------------------------
# identification
# -----------------------------------------------------------------------------

def test_identification_takes_the_stored_delay_off_the_fixes():
    """Issue 5's 10-minute setting (GNSS 1.5 m) with fixes stamped 0.20 s late: with the
    delay the estimate stores, output error stays inside issue 5's targets."""
    log = simulate("excitation", SimSettings(duration_s=600.0, sensors=SensorSettings(gps_delay_s=0.2)), seed=21)
    lg = with_delays(log, gnss=0.2)
    run = run_data(lg)
    np.testing.assert_allclose(run.t_gps[:5] + 0.2, run_data(log).t_gps[:5], atol=1e-9)
    idf = Identifier("output-error").fit([lg])
    err = {k: abs(getattr(idf.params_, k) / getattr(TRUE, k) - 1) for k in PARAM_NAMES}
    assert all(err[k] < TARGET[k] for k in PARAM_NAMES), err


def test_gnss_logged_past_the_last_thrust_is_validated_up_to_it():
    """Fixes stamped 0.2 s late and the delay not given: the smoothed states reach past the
    last thrust sample. The held-out free run stops with the thrust (it has no input after
    it) instead of ending in NaN and failing every candidate as "diverged"."""
    log = simulate("excitation", SimSettings(duration_s=240.0, sensors=SensorSettings(gps_delay_s=0.2)), seed=21)
    run = run_data(log)
    assert log["/gnss/fix"].index[-1] - log["/thrust/command"].index[-1] > 0.1e9   # the case: GNSS past the thrust
    idf = Identifier("equation-error").fit([log])
    (v,) = idf.validation_ if isinstance(idf.validation_, list) else [idf.validation_]
    assert not v.diverged and np.isfinite(v.simulated).all()
    assert v.t[-1] <= run.t_thrust[-1] and v.t[-1] > run.t_thrust[-1] - 0.2
    assert all(math.isfinite(x) for x in v.fit_percent.values()) and v.fit_percent["track"] > 50, v.fit_percent
