"""The extended 3-DOF model (separate surge/sway inertia, quadratic damping, thruster lag):
its special case is the paper's model, the simulators follow it, the shipped catamaran reads."""

import math
import subprocess
import sys

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from usvlog.errors import ConfigError
from usvlog.io.config import load_vessel
from usvlog.model.vessel import (
    ExtendedParams,
    Thrusters,
    Vessel,
    VesselParams,
    extended_vessel,
    nu_dot,
    nu_dot_ext,
    vessel_from_toml,
)
from usvlog.sim.closed_loop import closed_loop, make_controller
from usvlog.sim.plant import PlantStepper
from usvlog.sim.scenario import load_scenario
from usvlog.sim.simulate import SimSettings, simulate

CAT = dict(m11=85.0, m22=160.0, m26=12.0, m66=43.0, d11=77.0, d11q=8.0, d22=160.0, d22q=200.0,
           d33=43.0, d33q=430.0)


def _ext_nu_dot_by_matrices(nu, tau_u, tau_r, p):
    """M^-1 (tau - C(nu) nu - D(nu) nu), Fossen's 3-DOF matrices written out (independent truth)."""
    u, v, r = nu
    M = np.array([[p["m11"], 0, 0], [0, p["m22"], p["m26"]], [0, p["m26"], p["m66"]]])
    a = p["m22"] * v + p["m26"] * r
    C = np.array([[0, 0, -a], [0, 0, p["m11"] * u], [a, -p["m11"] * u, 0]])
    D = np.diag([p["d11"] + p["d11q"] * abs(u), p["d22"] + p["d22q"] * abs(v), p["d33"] + p["d33q"] * abs(r)])
    return np.linalg.solve(M, np.array([tau_u, 0.0, tau_r]) - C @ nu - D @ nu)


def test_extended_with_paper_values_is_the_paper_model():
    rng = np.random.default_rng(5)
    nu = rng.normal(0, [1.0, 0.3, 0.4], (500, 3))
    tu, tr = rng.normal(0, 5, 500), rng.normal(0, 2, 500)
    for p in (VesselParams(), VesselParams(m=50, Iz=14, d11=7, d22=30, d33=3, xg=-0.2)):
        ref = nu_dot(nu, tu, tr, p)
        got = nu_dot_ext(nu, tu, tr, ExtendedParams.from_paper(p))
        assert np.max(np.abs(got - ref) / (1 + np.abs(ref))) < 1e-14


def test_extended_nu_dot_is_fossens_matrix_form():
    rng = np.random.default_rng(6)
    p = ExtendedParams(**CAT)
    for _ in range(50):
        nu = rng.normal(0, [1.0, 0.3, 0.4])
        tu, tr = rng.normal(0, 50), rng.normal(0, 20)
        assert np.allclose(nu_dot_ext(nu, tu, tr, p), _ext_nu_dot_by_matrices(nu, tu, tr, CAT), rtol=1e-12,
                           atol=1e-12)


def _augmented_rhs(p, lag, cmd, current):
    """[n, e, psi, u, v, r, F_u, F_r]: eqs. (1), the extended model, T dF/dt = cmd - F."""
    def f(t, x):
        psi, nu, F = x[2], x[3:6], x[6:8]
        c, s = math.cos(psi), math.sin(psi)
        eta_dot = [c * nu[0] - s * nu[1] + current[0], s * nu[0] + c * nu[1] + current[1], nu[2]]
        return np.concatenate([eta_dot, _ext_nu_dot_by_matrices(nu, F[0], F[1], p), (cmd - F) / lag])
    return f


def test_plant_step_of_the_extended_model_with_lag_matches_solve_ivp():
    lag, dt, current = 0.3, 0.01, (0.15, -0.1)
    v = extended_vessel("cat", ExtendedParams(**CAT), Thrusters(lag_s=lag))
    step = PlantStepper(v, dt, current, rk4=True)
    rng = np.random.default_rng(7)
    x = (1.0, -2.0, 0.3, 0.2, 0.0, 0.0)
    xi = np.array([*x, 0.0, 0.0])
    for seg in range(12):  # commands held 1 s each
        cmd = np.array([rng.uniform(20, 80), rng.uniform(-30, 30)])
        for _ in range(100):
            x = step(x, float(cmd[0]), float(cmd[1]))
        sol = solve_ivp(_augmented_rhs(CAT, lag, cmd, current), (0, 1.0), xi, rtol=1e-11, atol=1e-11,
                        method="DOP853")
        xi = sol.y[:, -1]
        assert np.allclose(x, xi[:6], atol=1e-8), seg
        assert np.allclose(step.force, xi[6:], atol=1e-8)


def test_simulated_catamaran_run_matches_solve_ivp():
    cat = load_vessel("catamaran")
    st = SimSettings(vessel=cat, duration_s=80.0, current_mps=0.2, current_dir_deg=60.0)
    log = simulate("turns", st, seed=2)
    tr = log["/truth/state"]
    thr = log["/thrust/command"]
    t = (tr.index.to_numpy() - tr.index[0]) / 1e9
    tc = (thr.index.to_numpy() - tr.index[0]) / 1e9
    fl, fr = thr["left"].to_numpy(), thr["right"].to_numpy()  # newtons (identity map)
    cmd_u, cmd_r = fl + fr, cat.thrusters.arm_m * (fl - fr)
    assert np.all(np.isin(np.round(np.diff(tc[np.flatnonzero(np.diff(cmd_u) != 0)]), 6) % 40, 0))
    p = {k: getattr(cat.extended, k) for k in CAT}
    xi = np.zeros(8)
    for t0, t1 in ((0.0, 40.0), (40.0, 80.0 - 0.01)):
        k = np.searchsorted(tc, t0)
        sol = solve_ivp(_augmented_rhs(p, cat.thrusters.lag_s, np.array([cmd_u[k], cmd_r[k]]), st.current_ne),
                        (t0, t1), xi, rtol=1e-10, atol=1e-10, method="DOP853", dense_output=True,
                        max_step=0.5)   # the dense output between steps of several s is off by ~1 mN in F
                                        # (machine-dependent step choice); 0.5 s steps: converged, 0.2 s agrees
        xi = sol.y[:, -1]
        sel = (t >= t0) & (t <= t1)
        ref = sol.sol(t[sel]).T
        got = tr[["n_m", "e_m", "psi_rad", "u_mps", "v_mps", "r_radps"]].to_numpy()[sel]
        dpsi = np.angle(np.exp(1j * (got[:, 2] - ref[:, 2])))
        assert np.abs(dpsi).max() < 1e-4
        # the logged commands are rounded to 1 mN: positions agree to well below a millimetre
        assert np.abs(got[:, :2] - ref[:, :2]).max() < 1e-3 and np.abs(got[:, 3:] - ref[:, 3:6]).max() < 1e-5
        assert np.abs(tr["tau_u_n"].to_numpy()[sel][1:] - ref[1:, 6]).max() < 1e-3  # the applied, lagged force


def test_compiled_closed_loop_follows_the_extended_plant():
    cat = load_vessel("catamaran")
    scen = load_scenario("paper-circle", vessel=cat)
    path = scen.path(scen.sim.datum)
    kw = dict(duration_s=30.0, dt_s=scen.sim.dt_s, integrator="rk4", current_ne=(0.1, 0.05), eta0=scen.sim.eta0,
              nu0=scen.sim.nu0, schedule=scen.schedule, rate_hz=scen.guidance.rate_hz)
    compiled = closed_loop(path, cat, make_controller(scen, path), **kw)
    stepped = closed_loop(path, cat, make_controller(scen, path), estimator=lambda k, x, tau: np.array(x), **kw)
    assert np.allclose(compiled.states, stepped.states, atol=1e-9)
    assert np.allclose(compiled.applied, stepped.applied, atol=1e-9)
    # the lag: the applied force trails the command
    assert np.abs(compiled.applied - compiled.tau).max() > 1.0
    # the compiled loop's states are the extended plant's under its commands
    step = PlantStepper(cat, kw["dt_s"], kw["current_ne"], rk4=True)
    x = tuple(float(a) for a in (*scen.sim.eta0, *scen.sim.nu0))
    for k in range(len(compiled.t)):
        assert np.allclose(compiled.states[k], x, atol=1e-9)
        x = step(x, float(compiled.tau[k, 0]), float(compiled.tau[k, 1]))


def test_shipped_catamaran_reads_by_name_and_round_trips():
    cat = load_vessel("catamaran")
    assert load_vessel("catamaran.toml") == cat
    assert cat.structure == "extended" and cat.extended.m22 > 1.5 * cat.extended.m11 and cat.extended.d33q > 0
    assert 75 <= cat.extended.m11 <= 90 and cat.thrusters.lag_s > 0
    p = cat.params  # the paper terms the controller and the estimator use
    assert (p.m, p.Iz, p.xg) == (cat.extended.m11, cat.extended.m66, cat.extended.m26 / cat.extended.m11)
    assert p.d33 == pytest.approx(cat.extended.d33 + cat.extended.d33q * cat.extended.map_r_radps)
    assert vessel_from_toml(cat.to_toml()) == cat
    assert Vessel.from_dict(cat.to_dict()) == cat
    # a paper vessel's files are as they were: no lag key, no extended table
    assert "lag_s" not in Vessel().to_toml() and "thrusters.lag_s" not in Vessel().to_dict()


@pytest.mark.parametrize("text, message", [
    ('structure = "extended"\n[model]\nm = 3\n[extended]\nm11=1\n', "not [model]"),
    ('structure = "extended"\n', "needs an [extended] table"),
    ('[extended]\nm11=80\nm22=100\nm26=0\nm66=10\nd11=1\nd22=1\n', "lacks d33"),
    ('[extended]\nm11=80\nm22=100\nm26=40\nm66=10\nd11=1\nd22=1\nd33=1\n', "positive definite"),
    ('[extended]\nm11=80\nm22=100\nm26=0\nm66=10\nd11=1\nd22=1\nd33=1\nd33q=-1\n', "d33q = -1.0 must be >= 0"),
    ('[extended]\nm11=80\nm22=100\nm26=0\nm66=10\nd11=1\nd22=1\nd33=1\nIz=3\n', "unknown key 'Iz'"),
    ('structure = "paper"\n[extended]\nm11=80\n', "needs structure"),
    ('structure = "box"\n', "not paper or extended"),
    ('[thrusters]\nlag_s = -0.1\n', "lag_s = -0.1"),
])
def test_bad_extended_vessel_files_are_one_line_config_errors(text, message):
    with pytest.raises(ConfigError, match="^boat.toml: .*" + message.replace("[", r"\[").replace("]", r"\]")):
        vessel_from_toml(text, source="boat.toml")


def test_cli_simulates_the_catamaran_into_a_log_that_carries_it(tmp_path):
    out = tmp_path / "cat.mcap"
    r = subprocess.run([sys.executable, "-m", "usvlog", "simulate", "turns", "--vessel", "catamaran.toml",
                        "--duration-s", "20", "--out", str(out)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    from usvlog.api import load

    log = load(out)
    assert log.vessel == load_vessel("catamaran")
    u = log["/truth/state"]["u_mps"].to_numpy()
    assert 0.2 < u[-1] < 2.0  # the scaled scenario moves the heavy boat at paper-like speeds
