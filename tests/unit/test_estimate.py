"""State estimation: models against the vessel module and finite differences, the fast
path against the filterpy reference, accuracy against simulated truth, robustness."""

import math
import pickle

import numpy as np
import pandas as pd
import pytest

from usvlog.errors import ConfigError, InputError
from usvlog.estimate import (
    EstimateSettings,
    OnlineEKF,
    build_problem,
    estimate,
    kernels,
)
from usvlog.estimate.layout import process_noise, yaw_jump_variance
from usvlog.estimate.reference import jacobian as ref_jacobian
from usvlog.estimate.reference import rhs as ref_rhs
from usvlog.estimate.run import run_fast, run_reference_path
from usvlog.estimate.settings import Q_R_KINEMATIC_NO_JUMPS
from usvlog.model.frames import ssa
from usvlog.model.vessel import VesselParams, default_vessel
from usvlog.sim.simulate import SensorSettings, SimSettings, simulate

T0 = pd.Timestamp("2026-06-01T12:00:00Z").value


def _rms(a):
    a = np.asarray(a, float)
    a = a[np.isfinite(a)]
    return float(np.sqrt(np.mean(a ** 2))) if len(a) else math.nan


def _errors(frame, truth):
    """RMS errors of an estimate frame against /truth/state at the same times."""
    tr = truth.reindex(frame.index)
    out = {c: _rms(frame[c] - tr[c]) for c in ("n_m", "e_m", "u_mps", "v_mps",
                                                "current_n_mps", "current_e_mps")}
    out["r_degps"] = math.degrees(_rms(frame["r_radps"] - tr["r_radps"]))
    out["psi_deg"] = math.degrees(_rms(ssa(frame["psi_rad"] - tr["psi_rad"])))
    out["pos_m"] = _rms(np.hypot(frame["n_m"] - tr["n_m"], frame["e_m"] - tr["e_m"]))
    return out


# -----------------------------------------------------------------------------
# models
# -----------------------------------------------------------------------------

def _kernel_f_F(x, tau, prm, model):
    nx = len(x)
    f, F = np.zeros(nx), np.zeros((nx, nx))
    kernels.process(np.asarray(x, float), tau[0], tau[1], prm, model, f, F)
    return f, F


@pytest.mark.parametrize("model,nx", [(kernels.KINEMATIC, 9), (kernels.KINEMATIC_SWAY, 10), (kernels.DYNAMIC, 6),
                                      (kernels.DYNAMIC, 8)])
def test_process_jacobian_matches_finite_difference_and_vessel_model(model, nx):
    rng = np.random.default_rng(7)
    p = VesselParams(m=30.0, Iz=8.0, d11=4.0, d22=9.0, d33=3.0, xg=0.2)
    prm = p.as_array()
    for _ in range(5):
        x = rng.normal(size=nx)
        x[2] = rng.uniform(-math.pi, math.pi)
        tau = tuple(rng.normal(size=2) * 3)
        f, F = _kernel_f_F(x, tau, prm, model)
        # central finite differences of the compiled rhs
        h = 1e-6
        Fd = np.zeros((nx, nx))
        for j in range(nx):
            dx = np.zeros(nx)
            dx[j] = h
            Fd[:, j] = (_kernel_f_F(x + dx, tau, prm, model)[0] - _kernel_f_F(x - dx, tau, prm, model)[0]) / (2 * h)
        np.testing.assert_allclose(F, Fd, atol=1e-7)
        # and the reference path built on usvlog.vessel.plant_rhs / plant_jacobian
        dyn = model == kernels.DYNAMIC
        np.testing.assert_allclose(f, ref_rhs(x, *tau, p, dyn), atol=1e-12)
        np.testing.assert_allclose(F, ref_jacobian(x, p, dyn), atol=1e-12)


def test_dynamic_model_is_the_papers_equation_3():
    # M nu_dot + C(nu) nu + D nu = tau with the matrices (4)-(6), solved independently
    p = default_vessel().params
    u, v, r, tu, tr = 0.8, -0.1, 0.2, 4.0, 1.5
    M = np.array([[p.m, 0, 0], [0, p.m, p.m * p.xg], [0, p.m * p.xg, p.Iz]])
    C = np.array([[0, 0, -p.m * (p.xg * r + v)], [0, 0, p.m * u], [p.m * (p.xg * r + v), -p.m * u, 0]])
    D = np.diag([p.d11, p.d22, p.d33])
    nu = np.array([u, v, r])
    expect = np.linalg.solve(M, np.array([tu, 0, tr]) - C @ nu - D @ nu)
    f, _ = _kernel_f_F(np.array([0, 0, 0.3, u, v, r]), (tu, tr), p.as_array(), kernels.DYNAMIC)
    np.testing.assert_allclose(f[3:], expect, rtol=1e-12)


def test_sway_damping_model_is_body_frame_kinematics():
    # x = [n, e, psi, u, v, r, a_x, a_y, r_dot, k]: the NED velocity R(psi) [u, v] changes at
    # R(psi) [a_x, a_y - k v] (the body-frame over-ground acceleration), heading at r
    x = np.array([3.0, -2.0, 0.9, 1.2, -0.3, 0.25, 0.05, -0.02, 0.1, 0.15])
    f, _ = _kernel_f_F(x, (0.0, 0.0), default_vessel().params.as_array(), kernels.KINEMATIC_SWAY)

    def ned_velocity(y):
        c, s = math.cos(y[2]), math.sin(y[2])
        return np.array([c * y[3] - s * y[4], s * y[3] + c * y[4]])

    h = 1e-6
    dvel = (ned_velocity(x + h * f) - ned_velocity(x - h * f)) / (2 * h)
    c, s = math.cos(x[2]), math.sin(x[2])
    ax, ay = x[6], x[7] - x[9] * x[4]
    np.testing.assert_allclose(dvel, [c * ax - s * ay, s * ax + c * ay], atol=1e-8)
    np.testing.assert_allclose(f[:3], [*ned_velocity(x), x[5]], atol=1e-15)
    np.testing.assert_allclose(f[5:], [x[8], 0, 0, 0, 0], atol=1e-15)


def test_body_velocity_rotation_and_sigma():
    psi, vn, ve = 0.7, 0.4, -0.3
    u, v = kernels.body_velocity(np.array([psi]), np.array([vn]), np.array([ve]))
    R = np.array([[math.cos(psi), -math.sin(psi)], [math.sin(psi), math.cos(psi)]])
    np.testing.assert_allclose(np.r_[u, v], R.T @ [vn, ve], atol=1e-15)
    # one-sigma: first-order propagation checked by Monte Carlo
    P = np.array([[0.01, 0.001, 0.0], [0.001, 0.02, 0.005], [0.0, 0.005, 0.03]])
    _, _, su, sv = kernels.body_velocity(np.array([psi]), np.array([vn]), np.array([ve]), P[None])
    s = np.random.default_rng(1).multivariate_normal([psi, vn, ve], P, 200_000)
    uu, vv = kernels.body_velocity(s[:, 0], s[:, 1], s[:, 2])
    assert su[0] == pytest.approx(uu.std(), rel=0.02)
    assert sv[0] == pytest.approx(vv.std(), rel=0.02)


# -----------------------------------------------------------------------------
# fast path == filterpy reference
# -----------------------------------------------------------------------------

@pytest.mark.parametrize("model,current,sway", [("kinematic", None, False), ("kinematic", None, True),
                                                ("dynamic", True, False), ("dynamic", False, False)])
def test_fast_path_equals_filterpy_reference(model, current, sway):
    sens = SensorSettings(gps_jumps=((6.0, 30.0),))
    log = simulate("excitation", SimSettings(duration_s=20.0, current_mps=0.2, sensors=sens), seed=5)
    s = EstimateSettings(model=model, current=current, sway_damping=sway)
    pb = build_problem(log, s, default_vessel())
    assert pb.qjump.any() == (model == "kinematic")  # the zig-zag's yaw-moment steps
    q = process_noise(s)
    fast = run_fast(pb, q, s.max_consecutive_rejects, True)
    ref = run_reference_path(pb, q, s.max_consecutive_rejects, True)
    assert (ref.accepted == 0).sum() >= 1          # the jump was gated on both paths
    np.testing.assert_array_equal(fast.accepted, ref.accepted)
    for a, b in ((fast.X, ref.X), (fast.XS, ref.XS), (fast.SDf, ref.SDf), (fast.SDs, ref.SDs),
                 (fast.PBs, ref.PBs), (fast.innov, ref.innov)):
        d = np.abs(a - b)
        d[:, 2] = np.abs(ssa(a[:, 2] - b[:, 2])) if a.ndim == 2 and a.shape[1] > 4 else d[:, 2]
        assert np.nanmax(d) < 1e-9
    assert fast.loglik == pytest.approx(ref.loglik, abs=1e-9)
    # and through the public call
    a = estimate(log, s)
    b = estimate(log, EstimateSettings(model=model, current=current, sway_damping=sway, fast=False))
    np.testing.assert_allclose(a.state.to_numpy(), b.state.to_numpy(), atol=1e-9, equal_nan=True)


def test_online_filter_reproduces_the_offline_forward_pass():
    log = simulate("excitation", SimSettings(duration_s=15.0, current_mps=0.2), seed=2)
    s = EstimateSettings(model="dynamic")
    pb = build_problem(log, s, default_vessel())
    off = run_fast(pb, process_noise(s), s.max_consecutive_rejects, False)
    ekf = OnlineEKF(default_vessel(), s, x0=pb.x0, P0=pb.P0)
    j = 0
    for k in range(len(pb.dts)):
        ekf.predict(pb.dts[k], *pb.taus[k])
        while j < len(pb.mstep) and pb.mstep[j] == k:
            z, R = pb.mz[j], pb.mR[j]
            if pb.mkind[j] == kernels.GNSS:
                assert R[0] == R[2] and R[1] == 0
                ekf.update_gnss(z[0], z[1], R[0])
            else:
                ekf.update_heading(z[0], R[0])
            j += 1
    np.testing.assert_allclose(ekf.x, off.X[-1], atol=1e-12)
    assert ekf.P.shape == (8, 8) and np.allclose(ekf.P, ekf.P.T)


# -----------------------------------------------------------------------------
# accuracy against simulated truth
# -----------------------------------------------------------------------------

@pytest.fixture(scope="module")
def kinematic_run():
    log = simulate("excitation", SimSettings(duration_s=300.0), seed=3)
    return log, estimate(log, EstimateSettings(model="kinematic"))


def test_kinematic_smoother_accuracy(kinematic_run):
    log, res = kinematic_run
    truth = log["/truth/state"]
    s, f = _errors(res.state, truth), _errors(res.forward, truth)
    assert s["u_mps"] <= 0.04
    assert s["v_mps"] <= 0.08          # the issue asks 0.05: see docs/estimation.md (sway in a 20/20 zig-zag)
    assert s["r_degps"] <= 0.45
    assert s["pos_m"] <= 0.3
    for c in ("u_mps", "r_degps", "pos_m"):
        assert f[c] >= 2.0 * s[c], c   # the smoother is 2-4x better than the filter alone
    assert f["v_mps"] >= 1.8 * s["v_mps"]
    # consistent: mean NIS near the measurement dimension, stated sigmas near the errors
    assert res.report.sensor("gnss").mean_nis == pytest.approx(2.0, abs=0.2)
    assert res.report.sensor("compass").mean_nis == pytest.approx(1.0, abs=0.1)
    tr = truth.reindex(res.state.index)
    z = (res.state["n_m"] - tr["n_m"]) / res.state["n_m_std"]
    assert 0.7 < float(np.sqrt(np.mean(z ** 2))) < 1.5
    assert res.state["current_n_mps"].isna().all()


def test_dynamic_with_current_accuracy():
    log = simulate("excitation", SimSettings(duration_s=300.0, current_mps=0.2, current_dir_deg=60.0), seed=4)
    res = estimate(log, EstimateSettings(model="dynamic"), default_vessel())
    e = _errors(res.state, log["/truth/state"])
    assert e["u_mps"] <= 0.01 and e["v_mps"] <= 0.01
    assert e["r_degps"] <= 0.1
    assert e["current_n_mps"] <= 0.01 and e["current_e_mps"] <= 0.01
    assert e["pos_m"] <= 0.2
    # the truth current is 0.2 m/s towards 60 deg
    cn = res.state["current_n_mps"].iloc[len(res.state) // 2:].mean()
    ce = res.state["current_e_mps"].iloc[len(res.state) // 2:].mean()
    assert cn == pytest.approx(0.2 * math.cos(math.radians(60)), abs=0.01)
    assert ce == pytest.approx(0.2 * math.sin(math.radians(60)), abs=0.01)


def test_kinematic_smoother_with_sway_damping_meets_the_issue(kinematic_run):
    log, _ = kinematic_run
    res = estimate(log, EstimateSettings(model="kinematic", sway_damping=True))
    truth = log["/truth/state"]
    s, f = _errors(res.state, truth), _errors(res.forward, truth)
    assert s["u_mps"] <= 0.05 and s["v_mps"] <= 0.05
    assert s["r_degps"] <= 0.45
    assert s["pos_m"] <= 0.3
    for c in ("u_mps", "v_mps", "r_degps", "pos_m"):
        assert f[c] >= 2.0 * s[c], c   # the smoother is 2-6x better than the filter alone
    assert res.report.sensor("gnss").mean_nis == pytest.approx(2.0, abs=0.2)
    assert res.report.states == 10


def test_yaw_moment_steps_let_r_dot_jump(kinematic_run):
    log, res = kinematic_run
    # the variance added at a step of the yaw moment: (sigma * step / max|tau_r|)^2
    s = EstimateSettings(yaw_jump_radps2=0.3)
    tau_r = np.array([0.0, 1.0, 1.0, -2.0, -1.5, -1.5])   # tau_r[0]: before the first command
    np.testing.assert_allclose(yaw_jump_variance(tau_r, s), [0, 0, 0, (0.3 * 3 / 2) ** 2, (0.3 * 0.5 / 2) ** 2, 0])
    assert not yaw_jump_variance(tau_r, EstimateSettings(model="dynamic")).any()
    assert not yaw_jump_variance(tau_r, EstimateSettings(yaw_jump_radps2=0.0)).any()
    # without it r_dot follows the zig-zag's reversals slowly: r is 1.5x worse
    off = estimate(log, EstimateSettings(yaw_jump_radps2=0.0))
    truth = log["/truth/state"]
    assert _errors(off.state, truth)["r_degps"] > 1.5 * _errors(res.state, truth)["r_degps"]
    # a log without thrust has no steps: r_dot's own random walk is faster then
    nothrust = log.copy()
    del nothrust.channels["/thrust/command"]
    plain = estimate(nothrust)
    assert plain.report.settings["q_r"] == Q_R_KINEMATIC_NO_JUMPS > res.report.settings["q_r"]
    assert _errors(plain.state, truth)["r_degps"] <= 0.7


def test_gps_jumps_rejected_and_dropout_bridged():
    jumps = ((40.0, 30.0), (95.0, 30.0), (170.0, 30.0), (230.0, 30.0))
    sens = SensorSettings(gps_jumps=jumps, gps_dropouts=((120.0, 20.0),))
    log = simulate("excitation", SimSettings(duration_s=300.0, sensors=sens), seed=6)
    res = estimate(log, EstimateSettings(model="kinematic"))
    inn = res.innovations
    gnss = inn[inn["sensor"] == "gnss"]
    for tj, _ in jumps:
        row = gnss.loc[T0 + int(tj * 1e9)]
        assert not row["accepted"] and row["nis"] > 100
    rep = res.report.sensor("gnss")
    assert rep.rejected >= len(jumps) and rep.rejected <= len(jumps) + 2
    assert rep.rejected == int((~gnss["accepted"]).sum())
    assert res.report.dropouts_bridged == 1
    start, dur = res.report.dropouts[0]
    assert dur == pytest.approx(20.1, abs=0.01) and start == T0 + int(119.9e9)
    truth = log["/truth/state"]
    win = res.state.loc[T0 + int(119e9):T0 + int(141e9)]
    tr = truth.reindex(win.index)
    err = np.hypot(win["n_m"] - tr["n_m"], win["e_m"] - tr["e_m"])
    assert err.max() <= 2.0
    # prediction bridged it: the stated uncertainty grows into the gap and shrinks after
    mid = win["n_m_std"].loc[T0 + int(130e9)]
    assert mid > 3 * res.state["n_m_std"].loc[T0 + int(100e9)]
    assert _errors(res.state, truth)["pos_m"] <= 0.6


def test_heading_wraps_through_pi():
    # start heading just short of pi: the zig-zag crosses +-pi all the time
    log = simulate("excitation", SimSettings(duration_s=60.0, eta0=(0.0, 0.0, math.pi - 0.05)), seed=8)
    hd = log["/compass/heading"]["heading_rad"].to_numpy()
    assert np.sum(np.abs(np.diff(hd)) > math.pi) >= 6       # the measurements wrap often
    for model in ("kinematic", "dynamic"):
        res = estimate(log, EstimateSettings(model=model))
        psi = res.state["psi_rad"].to_numpy()
        assert psi.min() >= -math.pi and psi.max() < math.pi
        e = _errors(res.state, log["/truth/state"])
        assert e["psi_deg"] < 1.0 and e["r_degps"] < 1.5
        assert res.report.sensor("compass").rejected <= 2


def test_tuning_raises_the_innovation_likelihood():
    log = simulate("excitation", SimSettings(duration_s=60.0), seed=9)
    s = EstimateSettings(model="kinematic", q_uv=1e-1, q_r=1e-5, smoother=False)
    base = estimate(log, s)
    tuned = estimate(log, EstimateSettings(model="kinematic", q_uv=1e-1, q_r=1e-5, smoother=False, tune=True))
    assert tuned.report.tuned is not None
    assert tuned.report.loglik > base.report.loglik + 10
    assert tuned.report.tuned["q_r"] > 1e-4   # far from the bad start


# -----------------------------------------------------------------------------
# inputs
# -----------------------------------------------------------------------------

def test_compass_offset_and_declination():
    log = simulate("excitation", SimSettings(duration_s=30.0), seed=1)
    comp = log["/compass/heading"].copy()
    off, dec = math.radians(5.0), math.radians(-12.0)
    # a magnetic compass mounted 5 deg off: reading = true + offset - declination
    comp["heading_rad"] = ssa(comp["heading_rad"].to_numpy() + off - dec)
    comp["reference"] = pd.array(["magnetic"] * len(comp), dtype="str")
    bad = log.copy()
    bad.set("/compass/heading", comp)
    ok = estimate(bad, EstimateSettings(compass_offset_rad=off, declination_rad=dec))
    plain = estimate(log)
    np.testing.assert_allclose(ok.state["psi_rad"], plain.state["psi_rad"], atol=1e-6)


def test_time_backwards_and_missing_channels_are_one_line_errors():
    log = simulate("excitation", SimSettings(duration_s=10.0), seed=1)
    g = log["/gnss/fix"]
    t = g.index.to_numpy().copy()
    t[30], t[31] = t[31], t[30]
    bad = log.copy()
    bad.set("/gnss/fix", g.set_axis(pd.Index(t, name="t_ns")))
    bad.source = "run.mcap"
    with pytest.raises(InputError,
                       match=r"run.mcap: channel /gnss/fix: time goes backwards at message 31 \(2026-06-01T12:00:03"):
        estimate(bad)
    missing = log.copy()
    del missing.channels["/gnss/fix"]
    with pytest.raises(InputError, match="channel /gnss/fix is missing"):
        estimate(missing)
    nocompass = log.copy()
    del nocompass.channels["/compass/heading"]
    assert estimate(nocompass).report.mode == "gps-only"   # GNSS alone (tests/unit/test_estimate_gps_only.py)
    nothrust = log.copy()
    del nothrust.channels["/thrust/command"]
    estimate(nothrust)                                  # kinematic needs no thrust
    with pytest.raises(InputError, match="/thrust/command"):
        estimate(nothrust, EstimateSettings(model="dynamic"))
    with pytest.raises(ConfigError):
        EstimateSettings(model="kinematic", current=True)
    with pytest.raises(ConfigError):
        EstimateSettings(gate_probability=0.1)


def test_to_log_round_trip(tmp_path):
    import jsonschema
    import orjson

    from usvlog.io.mcap import read_log, write_log
    from usvlog.log.channels import schema_for_topic

    log = simulate("excitation", SimSettings(duration_s=10.0, current_mps=0.1), seed=1)
    res = estimate(log, EstimateSettings(model="dynamic"))
    out = res.to_log(log)
    assert set(log.topics) < set(out.topics) and "/estimate/state" not in log.topics
    assert out.provenance[-1]["producer"] == "usvlog estimate"
    write_log(out, tmp_path / "e.mcap")
    back = read_log(tmp_path / "e.mcap")
    pd.testing.assert_frame_equal(back["/estimate/state"], res.state, check_dtype=False)
    inn = back["/estimate/innovations"]
    assert list(inn["sensor"].unique()) == ["gnss", "compass"] or set(inn["sensor"]) == {"gnss", "compass"}
    assert inn["accepted"].dtype == bool and len(inn) == len(res.innovations)
    # the messages validate against the schemas
    from usvlog.io.mcap.codec import codec_for_topic
    for topic in ("/estimate/state", "/estimate/innovations"):
        msg = orjson.loads(codec_for_topic(topic).encode(out[topic].iloc[:3], topic)[1])
        jsonschema.validate(msg, schema_for_topic(topic))


def test_yaw_rate_channel_is_used():
    log = simulate("excitation", SimSettings(duration_s=60.0), seed=11)
    tr = log["/truth/state"].iloc[::2]                 # a 50 Hz gyro, 0.005 rad/s noise
    rng = np.random.default_rng(0)
    gyro = pd.DataFrame({"r_radps": tr["r_radps"].to_numpy() + rng.normal(0, 0.005, len(tr))}, index=tr.index)
    log.set("/imu/yaw_rate", gyro)
    plain = estimate(log)
    with_gyro = estimate(log, EstimateSettings(yaw_rate_topic="/imu/yaw_rate", yaw_rate_noise_radps=0.005))
    assert with_gyro.report.sensor("yaw_rate").accepted >= len(gyro) - 3
    assert with_gyro.report.sensor("yaw_rate").mean_nis == pytest.approx(1.0, abs=0.15)
    e0, e1 = (_errors(r.state, log["/truth/state"])["r_degps"] for r in (plain, with_gyro))
    assert e1 < 0.5 * e0


def test_bad_records_are_skipped_and_counted():
    log = simulate("excitation", SimSettings(duration_s=30.0, current_mps=0.1), seed=12)
    good = estimate(log, EstimateSettings(model="dynamic"))
    bad = log.copy()
    g = log["/gnss/fix"].copy()
    g.iloc[[10, 50], g.columns.get_loc("lat_deg")] = np.nan
    g.iloc[80, g.columns.get_loc("lon_deg")] = 400.0
    c = log["/compass/heading"].copy()
    c.iloc[[5, 6, 7], c.columns.get_loc("heading_rad")] = np.nan
    th = log["/thrust/command"].copy()
    th.iloc[[100, 101], th.columns.get_loc("thrust_left_n")] = np.nan
    th.iloc[[100, 101], th.columns.get_loc("left")] = np.nan
    for topic, f in (("/gnss/fix", g), ("/compass/heading", c), ("/thrust/command", th)):
        bad.set(topic, f)
    res = estimate(bad, EstimateSettings(model="dynamic"))
    rep = res.report
    assert rep.sensor("gnss").skipped == 3 and rep.sensor("gnss").accepted + rep.sensor("gnss").rejected == len(g) - 3
    assert rep.sensor("compass").skipped == 3
    assert rep.thrust_skipped == 2
    assert rep.to_dict()["sensors"]["gnss"]["skipped"] == 3
    # nothing good was lost: the estimate hardly moves
    d = (res.state["u_mps"] - good.state["u_mps"]).abs().max()
    assert d < 0.02


def test_thrust_commands_go_through_the_thruster_map():
    from dataclasses import replace as dc_replace

    v = default_vessel()
    v = dc_replace(v, thrusters=dc_replace(v.thrusters, map="quadratic"))
    log = simulate("excitation", SimSettings(duration_s=20.0, vessel=v), seed=13)
    th = log["/thrust/command"]
    assert set(th["unit"]) == {"normalized"}
    # recorded forces are rounded to 1 mN and commands to 1e-4: give the log the forces the
    # quadratic map (F = forward_n c|c|, reverse_n c|c| below zero) makes of the commands
    exact = th.copy()
    for side in ("left", "right"):
        c = th[side].to_numpy()
        exact[f"thrust_{side}_n"] = np.where(c >= 0, 20.0, 12.0) * c * np.abs(c)
    log.set("/thrust/command", exact)
    with_forces = estimate(log, EstimateSettings(model="dynamic"), v)
    only_cmd = log.copy()
    th2 = th.copy()
    th2["thrust_left_n"] = np.nan
    th2["thrust_right_n"] = np.nan
    only_cmd.set("/thrust/command", th2)
    from_map = estimate(only_cmd, EstimateSettings(model="dynamic"), v)
    np.testing.assert_allclose(from_map.state["u_mps"], with_forces.state["u_mps"], atol=1e-9)
    assert from_map.report.thrust_skipped == 0
    # the identity map cannot turn normalized commands into forces: one-line error
    with pytest.raises(InputError, match="/thrust/command: thrust commands in normalized need a thruster map"):
        estimate(only_cmd, EstimateSettings(model="dynamic"), default_vessel())


def test_consistency_in_plain_words():
    """A good run says nothing; a compass whose stated sigma is 100x too large, or one that
    reads a constant while the boat turns, is named in plain words."""
    from usvlog.estimate import EstimateSettings, estimate
    from usvlog.sim.simulate import SimSettings, simulate

    log = simulate("excitation", SimSettings(duration_s=60.0), seed=4)
    assert estimate(log, EstimateSettings()).report.consistency() == []
    over = log.copy(deep=True)
    comp = over["/compass/heading"].copy()
    comp["std_rad"] = comp["std_rad"] * 100.0
    over.set("/compass/heading", comp)
    rep = estimate(over, EstimateSettings()).report
    assert rep.sensor("compass").mean_nis < 0.1
    words = rep.consistency()
    assert len(words) == 1 and words[0].startswith("compass NIS") and "overstated or it does not move" in words[0]
    assert "warning: compass NIS" in rep.format() and rep.to_dict()["warnings"] == words
    dead = log.copy(deep=True)
    comp = dead["/compass/heading"].copy()
    comp["heading_rad"] = 0.0
    dead.set("/compass/heading", comp)
    # the kinematic smoother follows a compass it cannot check: NIS near 0, named the same way
    words = estimate(dead, EstimateSettings()).report.consistency()
    assert any(w.startswith("compass NIS 0.0") and "does not move" in w for w in words), words


def test_kinematic_model_needs_no_thruster_map():
    """The kinematic model uses the yaw moment only for its steps (scale-free): pwm_us commands
    that are an affine image of the forces, with no vessel map to convert them, give the same
    estimate as the forces themselves; the dynamic model still refuses them."""
    from usvlog.errors import InputError
    from usvlog.estimate import EstimateSettings, estimate
    from usvlog.sim.simulate import SimSettings, simulate

    log = simulate("excitation", SimSettings(duration_s=60.0), seed=1)
    ref = estimate(log, EstimateSettings(model="kinematic")).state
    th = log["/thrust/command"].copy().drop(columns=["thrust_left_n", "thrust_right_n"])
    th["left"], th["right"], th["unit"] = 1500 + 10 * th["left"], 1500 + 10 * th["right"], "pwm_us"
    log.set("/thrust/command", th)
    log.meta.pop("usvlog.vessel", None)
    got = estimate(log, EstimateSettings(model="kinematic")).state
    cols = ["n_m", "e_m", "psi_rad", "u_mps", "v_mps", "r_radps"]
    assert np.abs(got[cols].to_numpy() - ref[cols].to_numpy()).max() < 1e-9
    with pytest.raises(InputError, match="thruster map"):
        estimate(log, EstimateSettings(model="dynamic"))


def test_chi2_quantile_closed_form_equals_scipy():
    """The NIS gate's closed-form chi-square quantiles (1 and 2 degrees of freedom) are scipy's."""
    from scipy.stats import chi2

    from usvlog.estimate.layout import chi2_quantile

    for p in (0.5, 0.9, 0.99, 0.9999, 0.999999, 1 - 1e-12):
        for dof in (1, 2):
            assert chi2_quantile(p, dof) == pytest.approx(float(chi2.ppf(p, dof)), rel=1e-13)
    assert chi2_quantile(1.0, 1) == chi2_quantile(1.0, 2) == math.inf


def test_output_rows_are_the_all_step_run_bit_for_bit():
    """The memory-bounded run (some rows, the first states, the smoother re-making the forward
    posteriors block by block from checkpoints) gives exactly those rows of the all-step run,
    across several blocks and at the same first unusable step, and the smoother gives the
    filterpy reference's numbers across the block boundaries (each block's last step smoothed
    with the prior carried over from the block after it)."""
    log = simulate("excitation", SimSettings(duration_s=50.0), seed=4)
    s = EstimateSettings(sway_damping=False)
    pb = build_problem(log, s, default_vessel())
    assert len(pb.dts) > 2 * kernels.SMOOTH_BLOCK
    q = process_noise(s)
    every = run_fast(pb, q, s.max_consecutive_rejects, True)
    ref = run_reference_path(pb, q, s.max_consecutive_rejects, True)
    for a, b in ((every.XS, ref.XS), (every.SDs, ref.SDs), (every.PBs, ref.PBs)):
        d = np.abs(a - b)
        if a.ndim == 2:
            d[:, 2] = np.abs(ssa(a[:, 2] - b[:, 2]))
        assert np.nanmax(d) < 1e-9
    rows = np.zeros(len(pb.dts), bool)
    rows[::7] = rows[-1] = True
    some = run_fast(pb, q, s.max_consecutive_rejects, True, rows=rows, columns=5, covariance_block=False)
    for a, b in ((some.X, every.X), (some.XS, every.XS), (some.SDf, every.SDf), (some.SDs, every.SDs)):
        np.testing.assert_array_equal(a, b[rows, :5])
    assert some.PBs.shape == (0, 3, 3) and some.first_bad == every.first_bad == -1
    np.testing.assert_array_equal(some.innov, every.innov)
    assert some.loglik == every.loglik
    # the smoothed states alone (the forward posteriors not stored): the very same numbers
    lean = run_fast(pb, q, s.max_consecutive_rejects, True, rows=rows, columns=5, covariance_block=False,
                    forward=False)
    assert lean.X.shape == lean.SDf.shape == (0, 5) and lean.PBf.shape == (0, 3, 3)
    for a, b in ((lean.XS, some.XS), (lean.SDs, some.SDs), (lean.innov, some.innov), (lean.accepted, some.accepted)):
        np.testing.assert_array_equal(a, b)
    assert lean.loglik == some.loglik and lean.first_bad == some.first_bad
    # the estimate's forward frame, made when first asked for, is the all-step run's forward pass
    res = estimate(log, s)
    copied = pickle.loads(pickle.dumps(res))   # a result sent to another process, its forward frame not made yet
    g = pb.is_grid
    for frame, X, SD in ((res.state, every.XS, every.SDs), (res.forward, every.X, every.SDf)):
        for i, c in ((0, "n_m"), (1, "e_m"), (2, "psi_rad"), (5, "r_radps")):
            np.testing.assert_array_equal(frame[c].to_numpy(), X[g, i])
            np.testing.assert_array_equal(frame[c + "_std"].to_numpy(), SD[g, i])
    assert res.forward is res.forward   # made once
    pd.testing.assert_frame_equal(copied.forward, res.forward, check_exact=True)
