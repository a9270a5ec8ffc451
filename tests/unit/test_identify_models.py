"""Identification's model pieces against the paper's equations and the simulator."""

import numpy as np
import pytest

from usvlog.identify.data import run_data
from usvlog.identify.equation import LIN_NAMES, fit_equation_error, regressors
from usvlog.identify.output import Problem, simulate_run, velocity_samples
from usvlog.identify.shoot import shoot
from usvlog.model.vessel import VesselParams, nu_dot
from usvlog.sim.simulate import SimSettings, simulate

P = VesselParams(m=28.0, Iz=7.5, d11=4.0, d22=9.0, d33=2.5, xg=-0.15)


def _lin(p):
    return np.array([p.m, p.m * p.xg, p.Iz, p.d11, p.d22, p.d33])


def test_three_equations_match_nu_dot():
    """A(nu, nu_dot) @ (m, m xg, Iz, d11, d22, d33) = (tau_u, 0, tau_r) exactly when nu_dot is eq. (3)."""
    rng = np.random.default_rng(0)
    nu = rng.normal(0, [1.0, 0.3, 0.4], (500, 3))
    tu, tr = rng.normal(0, 5, 500), rng.normal(0, 1, 500)
    nd = nu_dot(nu, tu, tr, P)
    lhs = regressors(nu, nd) @ _lin(P)
    np.testing.assert_allclose(lhs[0], tu, atol=1e-12)
    np.testing.assert_allclose(lhs[1], 0.0, atol=1e-12)
    np.testing.assert_allclose(lhs[2], tr, atol=1e-12)
    # and they are not satisfied by other parameters
    other = _lin(VesselParams(m=30.0, Iz=7.5, d11=4.0, d22=9.0, d33=2.5, xg=-0.15))
    assert np.abs(regressors(nu, nd) @ other - np.stack([tu, 0 * tu, tr])).max() > 0.1
    assert LIN_NAMES == ("m", "mxg", "Iz", "d11", "d22", "d33")


@pytest.mark.parametrize("fix", [{}, {"m": 28.0}, {"xg": -0.15}, {"m": 28.0, "xg": -0.15, "d22": 9.0}])
def test_equation_error_exact_on_noise_free_states(fix):
    rng = np.random.default_rng(1)
    nu = rng.normal(0, [1.0, 0.3, 0.4], (800, 3))
    tu, tr = rng.normal(0, 5, 800), rng.normal(0, 1, 800)
    res = fit_equation_error(nu, nu_dot(nu, tu, tr, P), tu, tr, fix=fix)
    np.testing.assert_allclose(res.theta, P.as_array(), rtol=1e-9, atol=1e-12)
    assert res.valid


def test_equation_error_on_truth_of_a_simulated_run():
    log = simulate("excitation", SimSettings(duration_s=120.0, current_mps=0.2), seed=2)
    tr = log["/truth/state"]
    nu = tr[["u_mps", "v_mps", "r_radps"]].to_numpy()
    tu, trr = tr["tau_u_n"].to_numpy(), tr["tau_r_nm"].to_numpy()
    # central differences of the logged truth (thrust held over each step)
    t = tr.index.to_numpy() / 1e9
    nd = np.diff(nu, axis=0) / np.diff(t)[:, None]
    mid = 0.5 * (nu[1:] + nu[:-1])
    res = fit_equation_error(mid, nd, tu[:-1], trr[:-1])
    np.testing.assert_allclose(res.theta, VesselParams().as_array(), rtol=2e-3)


def test_shooting_reproduces_the_simulator_exactly():
    log = simulate("excitation", SimSettings(duration_s=60.0, current_mps=0.2, current_dir_deg=40.0), seed=4)
    run = run_data(log)
    tr = log["/truth/state"]
    X = tr[["n_m", "e_m", "psi_rad", "u_mps", "v_mps", "r_radps"]].to_numpy()
    t = (tr.index.to_numpy() - run.t0_ns) / 1e9
    cur = np.array([0.2 * np.cos(np.radians(40.0)), 0.2 * np.sin(np.radians(40.0))])
    sim = simulate_run(run, VesselParams().as_array(), cur, X[0], 0.0, t[::7])
    sim_raw = sim.copy()
    sim[:, 2] = (sim[:, 2] + np.pi) % (2 * np.pi) - np.pi
    # the log records thrust to 1 mN, the only difference from the simulator's own thrust
    np.testing.assert_allclose(sim, X[::7], atol=5e-3)
    wrong = simulate_run(run, VesselParams(m=34.0).as_array(), cur, X[0], 0.0, t[::7])
    assert np.abs(wrong[:, :2] - X[::7, :2]).max() > 0.1
    # X[0] is a strided row (X is in column order) and a parameter vector may be strided too: the
    # kernel is still called with C-ordered arrays, so numba has one signature for it, not one per
    # layout (each compiled and cached apart)
    assert not X[0].flags.c_contiguous
    theta = np.stack([VesselParams().as_array()] * 2, axis=1)[:, 0]
    assert not theta.flags.c_contiguous
    np.testing.assert_array_equal(simulate_run(run, theta, cur, X[0], 0.0, t[::7]), sim_raw)
    layouts = {str(sig[k]) for sig in shoot.signatures for k in (5, 6, 7)}
    assert layouts <= {"array(float64, 2d, C)", "array(float64, 1d, C)"}, layouts


def test_sensitivities_match_finite_differences():
    """The Jacobian rows the kernel writes (GPS, compass: weighted rows of the state's
    sensitivities; velocity rows made from its rows psi, u, v, r) against central differences
    of the residuals themselves; the two-thread run gives the same bits as one thread."""
    log = simulate("excitation", SimSettings(duration_s=60.0, current_mps=0.1), seed=6)
    run = run_data(log)
    tr = log["/truth/state"]
    X = tr[["n_m", "e_m", "psi_rad", "u_mps", "v_mps", "r_radps"]].to_numpy()
    tt = (tr.index.to_numpy() - run.t0_ns) / 1e9
    vel = velocity_samples(tt, X[:, 3], X[:, 4], X[:, 5])   # any values: the rows' derivatives are checked
    prob = Problem([run], 20.0, [vel])
    prob.set_sensor_scale([0.8, 1.3, 1.1, 0.7])
    assert set(prob.r_sensor) == {0, 1, 2, 3} and prob.n_seg == 3
    x0s = prob.initial_states(lambda i, t: X[np.searchsorted(tt, t - 1e-9)])
    th = np.array([31.0, 9.0, 5.5, 4.0, 6.0, 0.12])
    cur = np.array([[0.05, -0.08]])

    def jac(threads):
        prob.threads = threads
        ox, rows = prob.simulate(th, cur, x0s)
        return ox, prob.jac_rows(rows, ox).copy()

    ox, J = jac(False)
    prob.simulate(1.1 * th, -cur, x0s + 0.1)   # the problem's buffer: this leaves no trace in the next
    ox2, J2 = jac(True)
    assert ox2.tobytes() == ox.tobytes() and J2.tobytes() == J.tobytes()
    for col in range(14):
        h = 1e-6 * (1 + (abs(th[col - 6]) if 6 <= col < 12 else 1.0))
        res = []
        for sign in (1, -1):
            x2, t2, c2 = x0s.copy(), th.copy(), cur.copy()
            if col < 6:
                x2[:, col] += sign * h
            elif col < 12:
                t2[col - 6] += sign * h
            else:
                c2[0, col - 12] += sign * h
            res.append(prob.residuals(prob.simulate(t2, c2, x2, sens=False)[0], c2))
        fd = (res[0] - res[1]) / (2 * h)
        scale = max(np.abs(fd).max(), 1e-3)
        assert np.abs(fd - J[:, col]).max() < 1e-5 * scale, col
