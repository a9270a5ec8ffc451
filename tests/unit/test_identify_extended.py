"""Equation error of the extended model and its compiled free run, against simulated truth."""

import numpy as np

from usvlog.identify.data import run_data
from usvlog.identify.extended import ext_regressors, fit_extended_equation_error, free_run
from usvlog.io.config import load_vessel
from usvlog.model.vessel import ExtendedParams, Thrusters, extended_vessel, nu_dot_ext
from usvlog.sim.simulate import SimSettings, simulate


def _truth_run():
    ext = load_vessel("catamaran").extended
    boat = extended_vessel("cat-no-lag", ext, Thrusters(arm_m=0.395, forward_n=119.7, reverse_n=66.7))
    log = simulate("excitation", SimSettings(vessel=boat, duration_s=300.0), seed=9)
    return boat, log


def test_regressors_times_parameters_are_the_model():
    rng = np.random.default_rng(1)
    p = load_vessel("catamaran").extended
    nu = rng.normal(0, [1.0, 0.2, 0.3], (200, 3))
    tu, tr = rng.normal(40, 10, 200), rng.normal(0, 20, 200)
    nd = nu_dot_ext(nu, tu, tr, p)
    A = ext_regressors(nu, nd)
    lhs = A @ p.as_array()
    assert np.allclose(lhs[0], tu, atol=1e-9) and np.allclose(lhs[1], 0, atol=1e-9)
    assert np.allclose(lhs[2], tr, atol=1e-9)


def test_equation_error_recovers_the_catamaran_from_its_true_states():
    boat, log = _truth_run()
    tr = log["/truth/state"]
    t = (tr.index.to_numpy() - tr.index[0]) / 1e9
    nu = tr[["u_mps", "v_mps", "r_radps"]].to_numpy()
    nd = np.gradient(nu, t, axis=0)
    # the applied force is held over each step: the central difference sees its mean over two steps
    tu = tr["tau_u_n"].to_numpy()
    tq = tr["tau_r_nm"].to_numpy()
    tu = np.convolve(tu, [0.5, 0.5], "same")
    tq = np.convolve(tq, [0.5, 0.5], "same")
    k = slice(200, -200)
    fit = fit_extended_equation_error(nu[k], nd[k], tu[k], tq[k])
    truth = boat.extended.as_array()
    rel = np.abs(fit.theta - truth) / np.maximum(np.abs(truth), 1.0)
    assert rel.max() < 0.03, dict(zip(fit.to_dict(), rel))
    assert fit.params == ExtendedParams(**{**fit.to_dict()})


def test_free_run_of_the_true_model_follows_the_simulated_boat():
    boat, log = _truth_run()
    run = run_data(log, boat)
    tr = log["/truth/state"]
    t = (tr.index.to_numpy() - run.t0_ns) / 1e9
    nu = tr[["u_mps", "v_mps", "r_radps"]].to_numpy()
    sel = (t >= 20.0) & (t <= run.t_thrust[-1])
    sim = free_run(run, boat.extended.as_array(), nu[sel][0], t[sel][0], t[sel])
    # the logged thrust is rounded to 1 mN: the free run agrees far below the sensors' noise
    assert np.abs(sim - nu[sel]).max(0).tolist() < [1e-3, 1e-3, 1e-3]
