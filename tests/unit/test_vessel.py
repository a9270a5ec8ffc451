import numpy as np
import pytest

from usvlog.errors import ConfigError
from usvlog.model.vessel import (
    Thrusters,
    Vessel,
    VesselParams,
    coriolis_matrix,
    damping_matrix,
    mass_matrix,
    nu_dot,
    nu_dot_jacobian,
    plant_jacobian,
    plant_rhs,
    vessel_from_toml,
)

P = VesselParams()


def test_matrices_are_the_papers_eqs_4_to_6():
    M = mass_matrix(P)
    assert np.allclose(M, [[33, 0, 0], [0, 33, 3.3], [0, 3.3, 10]])
    u, v, r = 0.4, -0.2, 0.3
    C = coriolis_matrix(np.array([u, v, r]), P)
    a = 33 * (0.1 * r + v)
    assert np.allclose(C, [[0, 0, -a], [0, 0, 33 * u], [a, -33 * u, 0]])
    assert np.allclose(C, -C.T)  # skew-symmetric, as a rigid-body Coriolis matrix must be
    assert np.allclose(damping_matrix(P), np.diag([5, 5, 5]))


def test_nu_dot_solves_eq3():
    rng = np.random.default_rng(0)
    nu = rng.normal(size=(50, 3))
    tu, tr = rng.normal(size=50), rng.normal(size=50)
    nd = nu_dot(nu, tu, tr, P)
    M, D = mass_matrix(P), damping_matrix(P)
    for i in range(50):
        lhs = M @ nd[i] + coriolis_matrix(nu[i], P) @ nu[i] + D @ nu[i]
        assert np.allclose(lhs, [tu[i], 0.0, tr[i]], atol=1e-12)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_jacobians_match_finite_differences(seed):
    rng = np.random.default_rng(seed)
    p = VesselParams(m=rng.uniform(10, 60), Iz=rng.uniform(5, 20), d11=rng.uniform(1, 10),
                     d22=rng.uniform(1, 10), d33=rng.uniform(1, 10), xg=rng.uniform(-0.3, 0.3))
    x = rng.normal(size=6)
    J = plant_jacobian(x, p)
    eps = 1e-6
    Jn = np.column_stack([(plant_rhs(x + eps * e, 1.3, -0.4, p, (0.1, 0.2))
                           - plant_rhs(x - eps * e, 1.3, -0.4, p, (0.1, 0.2))) / (2 * eps) for e in np.eye(6)])
    assert np.max(np.abs(J - Jn)) < 1e-7
    assert np.allclose(nu_dot_jacobian(x[3:], p), J[3:, 3:])


def test_thruster_geometry_sign_convention():
    t = Thrusters(arm_m=0.3)
    tau_u, tau_r = t.tau_from_forces(10.0, 4.0)
    assert tau_u == 14.0 and tau_r == pytest.approx(0.3 * 6.0)  # port harder -> positive r
    fl, fr = t.forces_from_tau(tau_u, tau_r)
    assert fl == pytest.approx(10.0) and fr == pytest.approx(4.0)


@pytest.mark.parametrize("kind", ["linear", "quadratic"])
@pytest.mark.parametrize("unit", ["normalized", "pwm_us"])
def test_thruster_map_round_trip(kind, unit):
    t = Thrusters(map=kind, forward_n=20.0, reverse_n=12.0)
    f = np.array([-12.0, -3.0, 0.0, 0.5, 7.0, 20.0])
    c = t.force_to_command(f, unit)
    assert np.allclose(t.command_to_force(c, unit), f)
    full = 1.0 if unit == "normalized" else 1900.0
    assert t.command_to_force(full, unit) == pytest.approx(20.0)


def test_identity_map_rejects_pwm():
    with pytest.raises(ConfigError, match="thruster map"):
        Thrusters().command_to_force([1500.0], "pwm_us")


def test_vessel_toml_round_trip_and_errors():
    v = Vessel(name="kf", params=VesselParams(m=30.0, Iz=8.0, d11=4.0, d22=6.0, d33=3.0, xg=-0.05),
               thrusters=Thrusters(arm_m=0.35, map="quadratic", forward_n=25.0, reverse_n=10.0))
    assert vessel_from_toml(v.to_toml()) == v
    assert Vessel.from_dict(v.to_dict()) == v
    with pytest.raises(ConfigError, match="m = -1.0"):
        vessel_from_toml("[model]\nm = -1.0\n", "bad.toml")
    with pytest.raises(ConfigError, match="unknown key 'mass'"):
        vessel_from_toml("[model]\nmass = 3\n", "bad.toml")
    with pytest.raises(ConfigError, match="bad.toml"):
        vessel_from_toml("[model\n", "bad.toml")


def test_forces_from_commands_converts_each_record_in_its_own_unit():
    from usvlog.model.vessel import Thrusters

    thr = Thrusters(map="linear", forward_n=20.0, reverse_n=12.0)
    left = np.array([0.5, 1500.0, 3.0, -1.0])
    right = np.array([-0.25, 1900.0, -3.0, 1.0])
    units = np.array(["normalized", "pwm_us", "newton", "normalized"])
    fl, fr = thr.forces_from_commands(left, right, units)
    for i, u in enumerate(units):
        assert fl[i] == thr.command_to_force(left[i:i + 1], u)[0]
        assert fr[i] == thr.command_to_force(right[i:i + 1], u)[0]
    assert fl[2] == 3.0 and fr[1] > 0
