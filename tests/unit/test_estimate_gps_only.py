"""GNSS-only estimation (no, dead or still compass) against simulated truth, and the
divergence guard: restarts from the measurements, or a refusal, never NaN written."""

import json
import math

import numpy as np
import pytest

from usvlog.errors import UnusableResultError
from usvlog.estimate import EstimateSettings, build_problem, estimate
from usvlog.estimate.layout import process_noise
from usvlog.estimate.run import run_fast, run_reference_path
from usvlog.io.mcap import read_log, write_log
from usvlog.log.status import EstimateStatus, estimate_status, set_estimate_status
from usvlog.model.frames import ssa
from usvlog.model.vessel import default_vessel
from usvlog.sim.simulate import SensorSettings, SimSettings, simulate
from usvlog.view import data as vd

STATE6 = ["n_m", "e_m", "psi_rad", "u_mps", "v_mps", "r_radps"]


def _rms(a):
    a = np.asarray(a, float)
    a = a[np.isfinite(a)]
    return float(np.sqrt(np.mean(a ** 2)))


def _over_ground(f):
    """Speed (m/s) and course (rad) over ground from psi and the body velocities u, v (+ no current)."""
    psi, u, v = (f[c].to_numpy() for c in ("psi_rad", "u_mps", "v_mps"))
    c, s = np.cos(psi), np.sin(psi)
    vn, ve = c * u - s * v, s * u + c * v
    return np.hypot(vn, ve), np.arctan2(ve, vn)


def _sog_cog_errors(res, truth):
    """RMS speed-over-ground error (m/s) and course error (deg) where the true speed > 0.5 m/s."""
    tr = truth.reindex(res.state.index)
    sog, cog = _over_ground(res.state)
    sog_t, cog_t = _over_ground(tr)
    moving = sog_t > 0.5
    assert moving.mean() > 0.1   # the run moves enough to judge the course
    return _rms(sog - sog_t), math.degrees(_rms(ssa(cog - cog_t)[moving]))


def _no_compass(log):
    out = log.copy()
    del out.channels["/compass/heading"]
    return out


def _dead_compass(log):
    out = log.copy()
    comp = out["/compass/heading"].copy()
    comp["heading_rad"] = 0.7                  # reads one value the whole run
    out.set("/compass/heading", comp)
    return out


@pytest.fixture(scope="module")
def turns_10hz():
    return simulate("turns", SimSettings(duration_s=300.0), seed=3)


@pytest.fixture(scope="module")
def turns_1hz():
    return simulate("turns", SimSettings(duration_s=300.0, sensors=SensorSettings(gps_rate_hz=1.0)), seed=3)


def test_gps_only_kinematic_10hz_meets_the_issue(turns_10hz):
    """Without a compass channel: GNSS only, said so; speed over ground <= 0.05 m/s and course
    <= 4 deg RMS (where moving > 0.5 m/s) on a turning run with 10 Hz, 1.5 m GNSS."""
    res = estimate(_no_compass(turns_10hz), EstimateSettings())
    rep = res.report
    assert rep.mode == "gps-only" and "no heading channel" in rep.mode_reason
    assert rep.states == 9 and [r.sensor for r in rep.sensors] == ["gnss"]
    assert rep.status == "degraded" and rep.status_reasons()[0].startswith("gps-only")
    assert any("sideslip is not observable" in x for x in rep.mode_notes())
    assert "gps-only" in rep.format().splitlines()[0]
    sog, cog = _sog_cog_errors(res, turns_10hz["/truth/state"])
    assert sog <= 0.05 and cog <= 4.0, (sog, cog)
    # heading = course over ground: no sideslip in the over-ground body velocity while moving
    st = res.state
    assert np.isfinite(st[STATE6].to_numpy()).all()
    moving = st["u_mps"] > 0.5
    assert np.abs(st["v_mps"][moving]).max() < 1e-9


def test_gps_only_kinematic_1hz_meets_the_issue(turns_1hz):
    res = estimate(_no_compass(turns_1hz), EstimateSettings())
    assert res.report.mode == "gps-only"
    sog, cog = _sog_cog_errors(res, turns_1hz["/truth/state"])
    assert sog <= 0.10 and cog <= 8.0, (sog, cog)


def test_dead_compass_is_detected_not_fused_same_as_gps_only(turns_10hz, turns_1hz):
    """A compass reading one value while the track turns: detected in the estimator (no
    import audit ran), not fused; the estimate is the GNSS-only one exactly."""
    for log in (turns_10hz, turns_1hz):
        dead = estimate(_dead_compass(log), EstimateSettings())
        none = estimate(_no_compass(log), EstimateSettings())
        assert dead.report.mode == "gps-only" and "moved 0.00 deg" in dead.report.mode_reason
        assert "not fused" in dead.report.mode_reason
        np.testing.assert_array_equal(dead.state[STATE6].to_numpy(), none.state[STATE6].to_numpy())
    # a compass that moves is fused
    assert estimate(turns_10hz, EstimateSettings()).report.mode == "gnss+compass"


def test_compass_the_import_audit_judged_dead_is_not_fused(turns_10hz):
    """The audit's verdict (the health record in the import's provenance) is followed even
    when the channel was kept (--keep-dead) and moves."""
    log = turns_10hz.copy()
    health = {"version": 1, "dead": ["/compass/heading"], "suspect": [],
              "channels": {"/compass/heading": {"status": "dead", "why": "heading moved 0.00 deg in all"}}}
    log.add_provenance(producer="usvlog import", source="x.csv", health=health)
    res = estimate(log, EstimateSettings())
    assert res.report.mode == "gps-only" and "health audit judged /compass/heading dead" in res.report.mode_reason
    assert "compass" not in [r.sensor for r in res.report.sensors]


@pytest.mark.parametrize("scenario,seed", [("excitation", 3), ("turns", 5)])
def test_gps_only_dynamic_estimates_heading_through_the_model(scenario, seed):
    """Dynamic model, the true vessel and thrust, no compass: heading RMS <= 3 deg at 10 Hz
    (sideslip included: the model's heading, not the course), on the excitation zig-zag and
    on a turning run whose boat turns as it sets off (the first 10 m leg's course is
    157 deg from the start heading: the start is the kinematic smoother's course)."""
    log = simulate(scenario, SimSettings(duration_s=300.0), seed=seed)
    res = estimate(_no_compass(log), EstimateSettings(model="dynamic"))
    assert res.report.mode == "gps-only"
    assert any("through the vessel model" in x and "where the boat first moves" in x
               for x in res.report.mode_notes())
    tr = log["/truth/state"].reindex(res.state.index)
    err = math.degrees(_rms(ssa(res.state["psi_rad"].to_numpy() - tr["psi_rad"].to_numpy())))
    assert err <= 3.0, err


def test_gps_only_dynamic_start_heading_is_the_first_moving_course():
    """The dynamic model's start heading without a compass: the kinematic smoother's course
    where the boat first moves (both paths alike), near the true heading, where the first
    10 m leg of a boat turning as it sets off points far away."""
    from usvlog.estimate.core import gps_only_start
    from usvlog.estimate.modes import initial_course

    log = _no_compass(simulate("turns", SimSettings(duration_s=300.0), seed=5))
    s = EstimateSettings(model="dynamic")
    pb = build_problem(log, s, default_vessel())
    g = pb.mkind == 0
    assert pb.x0[2] == initial_course(pb.m_t_ns[g], pb.mz[g, 0], pb.mz[g, 1])
    fast = gps_only_start(log, s, default_vessel(), pb)
    ref = gps_only_start(log, EstimateSettings(model="dynamic", fast=False), default_vessel(), pb)
    assert abs(fast.x0[2] - ref.x0[2]) < 1e-8
    np.testing.assert_array_equal(np.delete(fast.x0, 2), np.delete(pb.x0, 2))
    psi0 = log["/truth/state"]["psi_rad"].iloc[0]
    assert abs(math.degrees(ssa(pb.x0[2] - psi0))) > 120          # the first leg's course
    assert abs(math.degrees(ssa(fast.x0[2] - psi0))) < 45         # the first moving course
    with_compass = build_problem(simulate("turns", SimSettings(duration_s=5.0), seed=5), s, default_vessel())
    assert gps_only_start(log, s, default_vessel(), with_compass) is with_compass


# -----------------------------------------------------------------------------
# divergence guard
# -----------------------------------------------------------------------------

def _offset_gnss(log, after_s, by_m):
    """Every fix after ``after_s`` moved ``by_m`` north (a receiver that jumped and stayed)."""
    out = log.copy()
    g = out["/gnss/fix"].copy()
    t = (g.index.to_numpy() - g.index[0]) * 1e-9
    g.loc[t > after_s, "lat_deg"] += by_m / 111_320.0
    out.set("/gnss/fix", g)
    return out


@pytest.mark.parametrize("model", ["kinematic", "dynamic"])
def test_restart_from_the_measurements_fast_path_equals_reference(model):
    """A track that jumps 400 m and stays: rejected by the gate until forced in with a NIS far
    beyond it, then the filter restarts at the fix; both paths restart at the same step and
    agree to 1e-8, and the smoother does not smooth across the restart."""
    log = _offset_gnss(simulate("excitation", SimSettings(duration_s=25.0), seed=2), 10.0, 400.0)
    s = EstimateSettings(model=model)
    pb = build_problem(log, s, default_vessel())
    q = process_noise(s)
    fast = run_fast(pb, q, s.max_consecutive_rejects, True)
    ref = run_reference_path(pb, q, s.max_consecutive_rejects, True)
    np.testing.assert_array_equal(fast.resets, ref.resets)
    k = np.flatnonzero(fast.resets)
    assert len(k) == 1 and fast.resets[k[0]] == 3   # REINIT_RESIDUALS
    assert 14.5 < (pb.t_ns[k[0]] - pb.t_ns[0]) * 1e-9 < 16.0   # 50 rejected fixes after the jump
    for a, b in ((fast.X, ref.X), (fast.XS, ref.XS), (fast.SDs, ref.SDs)):
        np.testing.assert_allclose(a, b, atol=1e-8, rtol=1e-8)
    np.testing.assert_array_equal(fast.XS[k[0] - 1], fast.X[k[0] - 1])   # a new segment ends there
    res = estimate(log, s)
    assert len(res.report.reinits) == 1 and "GNSS residuals" in res.report.reinits[0][1]
    assert res.report.status == "degraded" and "1 re-initialisation" in res.report.status_reasons()[0]
    d = res.report.to_dict()
    assert d["reinitialisations"][0]["t_ns"] == int(pb.t_ns[k[0]]) and d["status"] == "degraded"
    assert "re-initialisations after divergence: 1" in res.report.format()
    st = res.state
    assert np.isfinite(st[STATE6].to_numpy()).all()
    after = st.index > pb.t_ns[k[0]] + int(3e9)
    assert (st["n_m"][after] - log["/truth/state"].reindex(st.index)["n_m"][after]).abs().median() > 350


def _absurd_thrust(log):
    out = log.copy()
    th = out["/thrust/command"].copy()
    for c in ("left", "right", "thrust_left_n", "thrust_right_n"):
        th[c] = np.where(np.arange(len(th)) % 2 == 0, 1e300, -1e300)
    out.set("/thrust/command", th)
    return out


def _rough_compass(log, seed=0):
    """A magnetometer heading with 1 rad noise and 20 % wild readings."""
    out = log.copy()
    c = out["/compass/heading"].copy()
    rng = np.random.default_rng(seed)
    wild = np.where(rng.random(len(c)) < 0.2, rng.uniform(-3, 3, len(c)), 0.0)
    c["heading_rad"] = ssa(c["heading_rad"].to_numpy() + rng.normal(0, 1.0, len(c)) + wild)
    out.set("/compass/heading", c)
    return out


@pytest.fixture(scope="module")
def short_run():
    return simulate("excitation", SimSettings(duration_s=60.0), seed=1)


def test_absurd_thrust_dynamic_cannot_recover_exit_1(short_run):
    with pytest.raises(UnusableResultError, match=r"could not recover: re-initialised from the measurements \d+ times"):
        estimate(_absurd_thrust(short_run), EstimateSettings(model="dynamic"))


@pytest.mark.parametrize("q,model", [(1e300, "dynamic"), (1e300, "kinematic"), (1e-300, "kinematic"),
                                     (1e-300, "dynamic"), (1e10, "dynamic")])
def test_wild_tuning_ends_finite_or_refused(short_run, q, model):
    """Absurd process noise: a finite estimate (restarts reported, the status degraded when it
    is not consistent) or a refusal, never NaN."""
    try:
        res = estimate(short_run, EstimateSettings(model=model, q_uv=q, q_r=q))
    except UnusableResultError as err:
        assert "could not recover" in str(err) or "diverged" in str(err)
        return
    assert np.isfinite(res.state[STATE6].to_numpy()).all()
    assert np.isfinite(res.state[[c + "_std" for c in STATE6]].to_numpy()).all()
    st = res.report
    if st.reinits:
        assert st.status == "degraded" and "re-initialisation" in st.status_reasons()[0]
    if q == 1e300:
        pytest.fail("q = 1e300 cannot give a finite estimate")


@pytest.mark.parametrize("kw", [{}, {"sway_damping": False}, {"model": "dynamic"}])
def test_bad_heading_source_is_dropped_and_the_estimate_stays_on_the_track(short_run, kw):
    """A magnetometer heading with wild errors (the gate rejects most of it): not fused, the
    run is made again from GNSS alone and says why; finite and on the track."""
    res = estimate(_rough_compass(short_run), EstimateSettings(**kw))
    assert np.isfinite(res.state[STATE6].to_numpy()).all()
    rep = res.report
    assert rep.mode == "gps-only" and "disagrees with the track" in rep.mode_reason
    assert rep.status == "degraded" and "compass" not in [r.sensor for r in rep.sensors]
    tr = short_run["/truth/state"].reindex(res.state.index)
    pos = _rms(np.hypot(res.state["n_m"] - tr["n_m"], res.state["e_m"] - tr["e_m"]))
    assert pos < 1.0, pos


def test_implausible_states_restart_the_filter():
    """The guard's plausibility limits: a velocity or yaw rate beyond any boat restarts the
    filter at once (the same in both paths), long before its covariance blows up."""
    from usvlog.estimate import kernels
    from usvlog.estimate.reference import _health

    P = np.eye(9)
    for i, v in ((3, 60.0), (4, -60.0), (5, 7.0)):
        x = np.zeros(9)
        x[i] = v
        assert kernels.health(x, P, 1e8) == kernels.REINIT_IMPLAUSIBLE == _health(x, P, 1e8)
    x = np.zeros(9)
    x[3], x[5] = 20.0, 3.0
    assert kernels.health(x, P, 1e8) == 0 == _health(x, P, 1e8)
    P[0, 0] = 2e8
    assert kernels.health(x, P, 1e8) == kernels.REINIT_COVARIANCE == _health(x, P, 1e8)
    P[2, 7] = np.nan
    assert kernels.health(x, P, 1e8) == kernels.REINIT_NONFINITE == _health(x, P, 1e8)


# -----------------------------------------------------------------------------
# status in the log, downstream
# -----------------------------------------------------------------------------

def test_status_stored_in_the_log_and_flagged_downstream(tmp_path, capsys):
    from usvlog.cli import main

    run = simulate("turns", SimSettings(duration_s=30.0), seed=3)   # short: the report draws every figure
    res = estimate(_no_compass(run), EstimateSettings())
    path = tmp_path / "gps.mcap"
    write_log(res.to_log(_no_compass(run)), path)
    back = read_log(path)
    st = estimate_status(back)
    assert st == EstimateStatus(status="degraded", mode="gps-only", reasons=tuple(res.report.status_reasons()))
    words = vd.warnings(back)
    assert words[0].startswith("estimate DEGRADED (gps-only): gps-only: the log has no heading channel")
    assert main(["report", str(path), "--out", str(tmp_path / "rep")]) == 0
    html = (tmp_path / "rep" / "report.html").read_text()
    assert html.index("estimate DEGRADED") < html.index("<h2>Figures</h2>")
    assert "warning: estimate DEGRADED" in capsys.readouterr().err
    # a clean estimate: ok, nothing flagged
    ok = estimate(run, EstimateSettings()).to_log(run)
    assert estimate_status(ok).status == "ok" and vd.warnings(ok) == []
    # a failed one is refused by both verbs, exit 1
    set_estimate_status(back, EstimateStatus(status="failed", mode="gps-only", reasons=("diverged",)))
    bad = tmp_path / "failed.mcap"
    write_log(back, bad)
    assert main(["report", str(bad), "--out", str(tmp_path / "rep2")]) == 1
    assert "estimate FAILED (gps-only): diverged" in capsys.readouterr().err
    assert main(["view", str(bad), "--out", str(tmp_path / "v.rrd")]) == 1
    assert not (tmp_path / "v.rrd").exists()


def test_cli_estimate_prints_mode_and_restarts(tmp_path, capsys):
    from usvlog.cli import main

    log = _offset_gnss(_no_compass(simulate("excitation", SimSettings(duration_s=25.0), seed=2)), 10.0, 400.0)
    src = tmp_path / "jump.mcap"
    write_log(log, src)
    assert main(["estimate", str(src), "--out", str(tmp_path / "o.mcap")]) == 0
    text = capsys.readouterr().out
    assert "gps-only" in text.splitlines()[0] and "status degraded" in text.splitlines()[0]
    assert "re-initialisations after divergence: 1" in text
    assert main(["estimate", str(src), "--out", str(tmp_path / "o.mcap"), "--force", "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["mode"] == "gps-only" and rep["status"] == "degraded"
    assert len(rep["reinitialisations"]) == 1 and "GNSS residuals" in rep["reinitialisations"][0]["reason"]
    # --gps-only on a log with a working compass
    write_log(simulate("excitation", SimSettings(duration_s=20.0), seed=2), tmp_path / "c.mcap")
    assert main(["estimate", str(tmp_path / "c.mcap"), "--out", str(tmp_path / "c_o.mcap"), "--gps-only",
                 "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["mode"] == "gps-only" and "asked for" in rep["mode_reason"]


def _with_ground_velocity(log, rate_hz=10.0, noise_mps=0.05, seed=9):
    """/gnss/velocity from the truth: speed and course over ground with 0.05 m/s noise per
    NED component (course unknown below 0.1 m/s, as receivers report)."""
    from usvlog.log.channels import channel_spec, frame_from_columns

    tr = log["/truth/state"]
    step = int(round(1.0 / (rate_hz * 0.01)))
    tr = tr.iloc[::step]
    psi, u, v = (tr[c].to_numpy() for c in ("psi_rad", "u_mps", "v_mps"))
    rng = np.random.default_rng(seed)
    vn = np.cos(psi) * u - np.sin(psi) * v + rng.normal(0, noise_mps, len(tr))
    ve = np.sin(psi) * u + np.cos(psi) * v + rng.normal(0, noise_mps, len(tr))
    sog = np.hypot(vn, ve)
    cog = np.where(sog > 0.1, np.arctan2(ve, vn), np.nan)
    t = tr.index.to_numpy()
    out = log.copy()
    out.set("/gnss/velocity", frame_from_columns({"stamp_ns": t, "sog_mps": sog, "cog_rad": cog}, t,
                                                 channel_spec("/gnss/velocity")))
    return out


def test_gnss_velocity_is_fused_without_a_compass(turns_10hz):
    """Speed and course over ground from the receiver sharpen the GNSS-only course; both
    paths agree on them."""
    log = _with_ground_velocity(_no_compass(turns_10hz))
    res = estimate(log, EstimateSettings(gnss_velocity_noise_mps=0.05))
    rep = res.report
    assert [r.sensor for r in rep.sensors] == ["gnss", "gnss_velocity"]
    vel = rep.sensor("gnss_velocity")
    assert vel.skipped > 0 and vel.accepted > 2500 and 1.0 < vel.mean_nis < 3.0
    sog, cog = _sog_cog_errors(res, turns_10hz["/truth/state"])
    base_sog, base_cog = _sog_cog_errors(estimate(_no_compass(turns_10hz), EstimateSettings()),
                                         turns_10hz["/truth/state"])
    assert sog < 0.5 * base_sog and cog < 0.5 * base_cog, (sog, cog, base_sog, base_cog)
    short = _with_ground_velocity(_no_compass(simulate("turns", SimSettings(duration_s=15.0), seed=3)))
    s = EstimateSettings()
    pb = build_problem(short, s, default_vessel())
    assert (pb.mkind == 3).sum() > 100
    from usvlog.estimate.layout import gps_only_settings

    q = process_noise(gps_only_settings(s))
    fast, ref = run_fast(pb, q, 50, True), run_reference_path(pb, q, 50, True)
    np.testing.assert_allclose(fast.XS, ref.XS, atol=1e-8, rtol=1e-8)
    np.testing.assert_allclose(fast.innov, ref.innov, atol=1e-8, rtol=1e-8, equal_nan=True)


def test_yaw_rate_gyro_is_fused_without_a_compass():
    """GNSS only: /imu/yaw_rate is used without being asked for (the kinematic model's r is
    then the gyro's, not the course rate)."""
    from usvlog.log.channels import channel_spec, frame_from_columns

    log = _no_compass(simulate("turns", SimSettings(duration_s=120.0), seed=3))
    truth = log["/truth/state"]
    tr = truth.iloc[::2]
    t = tr.index.to_numpy()
    gyro = log.copy()
    r = tr["r_radps"].to_numpy() + np.random.default_rng(1).normal(0, 0.01, len(t))
    gyro.set("/imu/yaw_rate", frame_from_columns({"stamp_ns": t, "r_radps": r}, t, channel_spec("/imu/yaw_rate")))
    with_gyro, without = estimate(gyro, EstimateSettings()), estimate(log, EstimateSettings())
    assert [s.sensor for s in with_gyro.report.sensors] == ["gnss", "yaw_rate"]

    def r_err(res):
        return math.degrees(_rms(res.state["r_radps"] - truth.reindex(res.state.index)["r_radps"]))

    assert r_err(with_gyro) < 0.3 and r_err(with_gyro) < 0.1 * r_err(without)
