import numpy as np
import pytest

from usvlog.log.summary import summarize
from usvlog.model.frames import geodetic_to_ned, ssa
from usvlog.model.vessel import (
    VesselParams,
    coriolis_matrix,
    damping_matrix,
    mass_matrix,
)
from usvlog.sim.simulate import SimSettings, simulate


def _residual_of_eq3(truth, p):
    """M nu_dot + C(nu) nu + D nu - tau from the logged truth (central differences)."""
    t = truth.index.to_numpy() / 1e9
    nu = truth[["u_mps", "v_mps", "r_radps"]].to_numpy()
    dt = np.diff(t)
    # thrust is held over each step [t_k, t_k+1): the secant slope equals the mean
    # derivative over that step; compare with the model at the step's midpoint state
    nd = np.diff(nu, axis=0) / dt[:, None]
    mid = 0.5 * (nu[1:] + nu[:-1])
    tau = np.zeros_like(mid)
    tau[:, 0] = truth["tau_u_n"].to_numpy()[:-1]
    tau[:, 2] = truth["tau_r_nm"].to_numpy()[:-1]
    M, D = mass_matrix(p), damping_matrix(p)
    Cnu = np.einsum("kij,kj->ki", coriolis_matrix(mid, p), mid)
    return nd @ M.T + Cnu + mid @ D.T - tau, tau


@pytest.mark.parametrize("current", [0.0, 0.2])
def test_truth_obeys_eq3(current):
    p = VesselParams()
    log = simulate("excitation", SimSettings(duration_s=60.0, current_mps=current, current_dir_deg=30.0), seed=5)
    res, tau = _residual_of_eq3(log["/truth/state"], p)
    scale = np.abs(tau).max()
    # midpoint-rule error of a smooth trajectory at dt = 0.01 s: O(dt^2) ~ 1e-4 of the forces
    assert np.abs(res).max() < 1e-3 * scale
    # and the test can fail: wrong parameters leave a large residual
    wrong, _ = _residual_of_eq3(log["/truth/state"], VesselParams(m=36.0))
    assert np.abs(wrong).max() > 20 * np.abs(res).max()


def test_kinematics_and_current_obey_eq1():
    log = simulate("excitation", SimSettings(duration_s=30.0, current_mps=0.2, current_dir_deg=90.0), seed=2)
    tr = log["/truth/state"]
    t = tr.index.to_numpy() / 1e9
    psi = np.unwrap(tr["psi_rad"].to_numpy())
    n_dot = np.gradient(tr["n_m"].to_numpy(), t)
    e_dot = np.gradient(tr["e_m"].to_numpy(), t)
    u, v = tr["u_mps"].to_numpy(), tr["v_mps"].to_numpy()
    assert np.allclose(n_dot[1:-1], (np.cos(psi) * u - np.sin(psi) * v)[1:-1], atol=2e-4)
    assert np.allclose(e_dot[1:-1], (np.sin(psi) * u + np.cos(psi) * v + 0.2)[1:-1], atol=2e-4)
    # r_dot jumps when the zig-zag switches: central differences err by ~dt*jump/2 there
    assert np.allclose(np.gradient(psi, t)[1:-1], tr["r_radps"].to_numpy()[1:-1], atol=1e-3)


def test_sensor_rates_and_noise(excitation_log):
    s = summarize(excitation_log)
    assert s.channel("/gnss/fix").rate_hz == pytest.approx(10.0)
    assert s.channel("/compass/heading").rate_hz == pytest.approx(20.0)
    assert s.channel("/thrust/command").rate_hz == pytest.approx(100.0)
    log = excitation_log
    gps, tr = log["/gnss/fix"], log["/truth/state"]
    n, e, _ = geodetic_to_ned(gps["lat_deg"].to_numpy(), gps["lon_deg"].to_numpy(), 0.0, datum=log.datum)
    ref = tr.loc[gps.index]
    err = np.concatenate([n - ref["n_m"].to_numpy(), e - ref["e_m"].to_numpy()])
    assert np.std(err) == pytest.approx(1.5, rel=0.1)
    hd = log["/compass/heading"]
    herr = ssa(hd["heading_rad"].to_numpy() - tr.loc[hd.index, "psi_rad"].to_numpy())
    assert np.degrees(np.std(herr)) == pytest.approx(2.0, rel=0.1)


def test_excitation_excites_all_three_dof(excitation_log):
    tr = excitation_log["/truth/state"]
    assert tr["u_mps"].std() > 0.05
    assert tr["v_mps"].abs().max() > 0.1
    assert np.degrees(tr["r_radps"].abs().max()) > 5


def test_same_seed_same_log_other_seed_differs():
    a = simulate("excitation", SimSettings(duration_s=10.0), seed=7)
    b = simulate("excitation", SimSettings(duration_s=10.0), seed=7)
    c = simulate("excitation", SimSettings(duration_s=10.0), seed=8)
    assert a.equals(b)
    assert not a.equals(c)


# -- the compiled open-loop plant -------------------------------------------------------

@pytest.mark.parametrize("scenario,integrator,vessel", [("excitation", "rk4", None), ("excitation", "euler", None),
                                                        ("turns", "rk4", None), ("excitation", "rk4", "catamaran"),
                                                        ("straight", "euler", "catamaran")])
def test_compiled_open_loop_equals_python_loop(monkeypatch, scenario, integrator, vessel):
    """The compiled kernel and the same loop run as plain Python give the same log (to 1e-12),
    for the paper's vessel and one of the extended structure with a thruster lag."""
    from usvlog.io.config import load_vessel
    from usvlog.sim import simulate as sim

    st = SimSettings(duration_s=120.0, integrator=integrator, current_mps=0.2, current_dir_deg=40.0,
                     vessel=load_vessel(vessel))
    fast = simulate(scenario, st, seed=7)
    monkeypatch.setattr(sim, "_open_loop_kernel", sim._open_loop_kernel.py_func)
    ref = simulate(scenario, st, seed=7)
    assert set(fast.channels) == set(ref.channels)
    for ch in ref.channels:
        a, b = fast[ch], ref[ch]
        assert list(a.columns) == list(b.columns) and np.array_equal(a.index, b.index)
        for c in b.columns:
            if b[c].dtype.kind == "f":
                np.testing.assert_allclose(a[c].to_numpy(), b[c].to_numpy(), rtol=0, atol=1e-12, err_msg=f"{ch} {c}")
            else:
                assert np.array_equal(a[c].to_numpy(), b[c].to_numpy()), (ch, c)
    # the zig-zag switched and the thrusters saturated somewhere: the compared paths were exercised
    if scenario == "excitation":
        tr = ref["/truth/state"]["tau_r_nm"].to_numpy()
        assert (tr > 0.5).any() and (tr < -0.5).any()


def test_compiled_excitation_reproduces_the_stored_dataset():
    """tests/data/gps-faults.mcap was written by the Python loop; the compiled plant gives it again."""
    from pathlib import Path

    from usvlog.io.mcap import read_log
    from usvlog.sim.simulate import SensorSettings

    stored = read_log(Path(__file__).parents[1] / "data" / "gps-faults.mcap")
    sens = SensorSettings(gps_jumps=((40.0, 30.0), (95.0, 30.0), (150.0, 30.0)), gps_dropouts=((110.0, 20.0),),
                          truth_rate_hz=10.0)
    log = simulate("excitation", SimSettings(duration_s=200.0, vessel=stored.vessel, sensors=sens), seed=5)
    for ch in ("/truth/state", "/gnss/fix", "/compass/heading", "/thrust/command"):
        a, b = log[ch], stored[ch]
        assert np.array_equal(a.index, b.index), ch
        for c in b.columns:
            if b[c].dtype.kind == "f":
                np.testing.assert_allclose(a[c].to_numpy(), b[c].to_numpy(), rtol=0, atol=1e-9, err_msg=f"{ch} {c}")


def test_ieee_remainder_is_math_remainder():
    import math

    from usvlog.sim.simulate import ieee_remainder

    rng = np.random.default_rng(0)
    xs = list(rng.uniform(-1e4, 1e4, 20000)) + [k * math.pi for k in range(-40, 41)] + [-0.0, 0.0, 1e-300]
    for y in (2 * math.pi, 1.0, -3.5):
        for x in xs:
            assert ieee_remainder(float(x), y) == math.remainder(float(x), y)
