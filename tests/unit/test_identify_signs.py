"""Signs and scales decided from the data (usvlog.identify.signs).

Runs are simulated with usvlog's own 3-DOF model (:func:`usvlog.identify.output.simulate_run`)
from known thruster forces, so the truth is known: tau_u = T_left + T_right and
tau_r = arm (T_left - T_right), more port thrust turning the boat to starboard.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from usvlog.identify.data import RunData
from usvlog.identify.output import simulate_run
from usvlog.identify.signs import heading_rate_agreement, surge_sign, thrust_yaw_sign
from usvlog.model.frames import ssa

THETA = np.array([33.0, 10.0, 5.0, 5.0, 5.0, 0.1])   # usvlog's default vessel, m Iz d11 d22 d33 xg
ARM_M = 0.3
DT = 0.1


def _simulate(t_left, t_right, seed=0):
    """(t, tau_u, tau_r, states (N, 6)) of the model driven by the thruster forces (held every DT)."""
    t = np.arange(len(t_left)) * DT
    tau_u, tau_r = t_left + t_right, ARM_M * (t_left - t_right)
    z = np.zeros(2)
    run = RunData(t0_ns=0, t_thrust=t, tau_u=tau_u, tau_r=tau_r, t_gps=z, n_gps=z, e_gps=z, sigma_gps=z + 1,
                  t_compass=z, psi_compass=z, sigma_compass=z + 0.1)
    x = simulate_run(run, THETA, (0.0, 0.0), np.array([0.0, 0, 0, 0.5, 0, 0]), 0.0, t)
    return t, tau_u, tau_r, x


def _steps(rng, n, every_s, lo, hi):
    k = np.arange(n) // int(every_s / DT)
    return rng.uniform(lo, hi, k.max() + 1)[k]


@pytest.fixture(scope="module")
def manoeuvres():
    """300 s of random thrust steps on both thrusters (turns both ways)."""
    rng = np.random.default_rng(1)
    n = 3000
    return _simulate(_steps(rng, n, 6.0, 0.0, 20.0), _steps(rng, n, 6.0, 0.0, 20.0))


def test_correct_yaw_sign_detected_through_noise(manoeuvres):
    t, _, tau_r, x = manoeuvres
    rng = np.random.default_rng(2)
    for seed in range(5):    # 0.01 rad/s of noise on r does not flip it
        r = x[:, 5] + 0.01 * np.random.default_rng(seed).standard_normal(len(t))
        res = thrust_yaw_sign(t, tau_r, r)
        assert res.sign == 1 and res.t_stat > 10 and res.correlation > 0.5
    # the gain is the yaw row's, 1 / (Iz - m xg^2); the decay is d33 / Iz plus the coupling
    # m xg u r of C(nu) (about 0.3 u / Iz more at speed u)
    res = thrust_yaw_sign(t, tau_r, x[:, 5] + 0.001 * rng.standard_normal(len(t)))
    m, iz, xg = THETA[0], THETA[1], THETA[5]
    assert res.gain == pytest.approx(1 / (iz - m * xg * xg), rel=0.1)
    assert THETA[4] / iz < res.decay_per_s < 3 * THETA[4] / iz
    assert "as expected" in res.message and res.to_dict()["sign"] == 1


def test_swapped_thrusters_detected(manoeuvres):
    t, _, tau_r, x = manoeuvres
    r = x[:, 5] + 0.01 * np.random.default_rng(4).standard_normal(len(t))
    res = thrust_yaw_sign(t, -tau_r, r)           # the log's "left" is the starboard thruster
    assert res.sign == -1 and res.t_stat < -10
    assert res.message.startswith("left and right thrust appear swapped: the yaw rate follows T_right - T_left "
                                  f"(correlation {res.correlation:.2f} over {res.duration_s:.0f} s)")
    assert res.correlation < -0.5 and res.duration_s == pytest.approx(300, abs=3)


def test_pure_surge_run_leaves_the_yaw_sign_undetermined():
    rng = np.random.default_rng(5)
    thrust = _steps(rng, 3000, 10.0, 0.0, 20.0)
    t, tau_u, tau_r, x = _simulate(thrust, thrust)
    assert np.all(tau_r == 0)
    r = x[:, 5] + 0.01 * rng.standard_normal(len(t))
    res = thrust_yaw_sign(t, tau_r, r)
    assert res.sign == 0
    assert res.message.startswith("the yaw response to differential thrust is not determined (no differential")
    # a small thruster mismatch unrelated to the yaw rate: still undetermined, not a sign
    res = thrust_yaw_sign(t, 0.05 * rng.standard_normal(len(t)), r)
    assert res.sign == 0 and abs(res.t_stat) < 4 and "|t| >= 4 needed" in res.message


def test_closed_loop_heading_control_keeps_the_sign():
    """A PD heading controller sets tau_r from the (noisy) heading and yaw rate: the fit's decay
    term keeps the open-loop sign."""
    rng = np.random.default_rng(6)
    iz, d33, dt, sub = THETA[1], THETA[4], DT, 10
    n = 3000
    psi_ref = np.repeat(rng.uniform(-1.5, 1.5, n // 200 + 1), 200)[:n]
    psi = r = 0.0
    r_log, tau_log = np.zeros(n), np.zeros(n)
    for i in range(n):
        r_meas = r + 0.01 * rng.standard_normal()
        tau = float(np.clip(8.0 * ssa(psi_ref[i] - psi) - 6.0 * r_meas, -6, 6))
        for _ in range(sub):   # Euler on a fine step, the moment held
            r += dt / sub * (tau - d33 * r) / iz
            psi += dt / sub * r
        r_log[i], tau_log[i] = r_meas, tau
    t = np.arange(n) * dt
    assert thrust_yaw_sign(t, tau_log, r_log).sign == 1
    assert thrust_yaw_sign(t, -tau_log, r_log).sign == -1


def test_surge_sign(manoeuvres):
    t, tau_u, _, x = manoeuvres
    u = x[:, 3] + 0.02 * np.random.default_rng(7).standard_normal(len(t))
    res = surge_sign(t, tau_u, u)
    assert res.sign == 1 and res.channel == "surge"
    res = surge_sign(t, -tau_u, u)          # both channels reversed
    assert res.sign == -1 and "surge thrust appears reversed" in res.message and "-tau_u" in res.message
    assert surge_sign(t, np.full(len(t), 20.0), u).sign == 0   # no change of thrust


def test_heading_rate_agreement(manoeuvres):
    t, _, _, x = manoeuvres
    rng = np.random.default_rng(8)
    compass = ssa(x[:, 2] + math.radians(2.0) * rng.standard_normal(len(t)))   # wrapped, 2 deg noise
    gyro = x[:, 5] + 0.005 * rng.standard_normal(len(t)) + 0.01                # 0.01 rad/s bias
    ok = heading_rate_agreement(t, compass, gyro)
    assert ok.sign == 1 and ok.agree and ok.scale == pytest.approx(1.0, abs=0.05)
    assert ok.bias_radps == pytest.approx(0.01, abs=0.005)
    assert "agrees" in ok.message
    deg = heading_rate_agreement(t, compass, np.degrees(gyro))    # deg/s in a rad/s column
    assert deg.sign == 1 and not deg.agree
    assert deg.scale == pytest.approx(180 / math.pi, rel=0.05)
    assert "deg/s logged as rad/s" in deg.message
    small = heading_rate_agreement(t, compass, np.radians(gyro))
    assert small.scale == pytest.approx(math.pi / 180, rel=0.05) and "as if it were deg/s" in small.message
    rev = heading_rate_agreement(t, compass, -gyro)
    assert rev.sign == -1 and not rev.agree and rev.scale == pytest.approx(-1.0, abs=0.05)
    assert "reversed" in rev.message


def test_heading_rate_undetermined_without_turns():
    t = np.arange(3000) * DT
    rng = np.random.default_rng(9)
    res = heading_rate_agreement(t, 0.5 + 0.03 * rng.standard_normal(len(t)), 0.002 * rng.standard_normal(len(t)))
    assert res.sign == 0 and "not determined" in res.message and math.isnan(res.scale)


def _channels(manoeuvres):
    """(t, T_left, T_right, u, r) of the simulated run, each channel's force recovered from tau."""
    t, tau_u, tau_r, x = manoeuvres
    return t, 0.5 * (tau_u + tau_r / ARM_M), 0.5 * (tau_u - tau_r / ARM_M), x[:, 3], x[:, 5]


@pytest.mark.parametrize("fault, verdict", [(None, "ok"), ("right", "right reversed"), ("left", "left reversed"),
                                            ("both", "both reversed"), ("swap", "swapped")])
def test_channel_signs_name_a_reversed_or_swapped_channel(manoeuvres, fault, verdict):
    from usvlog.identify.signs import channel_signs

    t, fl, fr, u, r = _channels(manoeuvres)
    rng = np.random.default_rng(4)
    u = u + 0.01 * rng.standard_normal(len(t))
    r = r + 0.01 * rng.standard_normal(len(t))
    if fault == "right":
        fr = -fr
    elif fault == "left":
        fl = -fl
    elif fault == "both":
        fl, fr = -fl, -fr
    elif fault == "swap":
        fl, fr = fr, fl
    res = channel_signs(t, fl, fr, u, r)
    assert res.verdict == verdict, res.message
    if fault is None:   # the truth: both push forward, left turns to starboard, right to port
        assert min(res.surge_t) > 0 and res.yaw_t[0] > 4 and res.yaw_t[1] < -4


def test_channel_signs_undetermined_without_differential_thrust():
    from usvlog.identify.signs import channel_signs

    rng = np.random.default_rng(5)
    f = _steps(rng, 3000, 6.0, 0.0, 20.0)
    t, tau_u, tau_r, x = _simulate(f, f)    # equal thrust on both: the channels cannot be told apart
    res = channel_signs(t, 0.5 * tau_u, 0.5 * tau_u, x[:, 3], x[:, 5])
    assert res.verdict == "undetermined"


def test_identify_refuses_a_log_whose_right_channel_is_reversed():
    """The recorded right forces negated (a reversed ESC): refused before any fit, naming the fix."""
    from usvlog.errors import UnusableResultError
    from usvlog.identify import Identifier
    from usvlog.sim.simulate import SimSettings, simulate

    log = simulate("excitation", SimSettings(duration_s=240.0), seed=3)
    th = log["/thrust/command"]
    th["thrust_right_n"] = -th["thrust_right_n"]
    th["right"] = -th["right"]
    with pytest.raises(UnusableResultError, match="reversed_right = true"):
        Identifier(method="equation-error").fit([log])
