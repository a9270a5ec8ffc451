"""Catalogue thruster maps (Blue Robotics T200) and reversed channels, against independent truth.

Truth used here: the published points themselves (T200-Public-Performance-Data-10-20V-September-2019,
values typed from the sheets below, not read from the module), Blue Robotics' summary figures
(maximum forward/reverse thrust at 12, 16, 20 V), linear interpolation in voltage done by hand, and
round trips.
"""

from __future__ import annotations

import numpy as np
import pytest

from usvlog.errors import ConfigError
from usvlog.model import thruster_curves as tc
from usvlog.model.vessel import Thrusters, Vessel, vessel_from_toml

G = 9.80665
KGF_RES_N = 0.01 * G   # the published table's resolution (0.01 kgf)


def t200(volts: float, **kw) -> Thrusters:
    return Thrusters(map="t200", supply_v=volts, **kw)


def force_n(thr: Thrusters, pwm_us, side: str | None = None):
    return thr.command_to_force(np.asarray(pwm_us, float), "pwm_us", side=side)


# --- the published points ---------------------------------------------------------------------
# rows typed from the spreadsheet: (volts, pwm_us, kgf)
SHEET_ROWS = [
    (12, 1100, -2.90), (12, 1460, -0.04), (12, 1540, 0.04), (12, 1600, 0.39), (12, 1900, 3.71),
    (14, 1100, -3.52), (14, 1464, -0.03), (14, 1700, 1.55), (14, 1800, 2.99),
    (16, 1100, -4.07), (16, 1300, -1.44), (16, 1468, -0.04), (16, 1532, 0.04), (16, 1700, 1.82),
    (16, 1800, 3.42), (16, 1900, 5.25),
    (18, 1200, -2.96), (18, 1800, 3.72), (18, 1900, 6.02),
    (20, 1100, -5.04), (20, 1472, -0.04), (20, 1532, 0.06), (20, 1800, 3.96), (20, 1900, 6.72),
    (10, 1100, -2.31), (10, 1800, 1.91), (10, 1900, 2.93),
]


@pytest.mark.parametrize("volts,pwm,kgf", SHEET_ROWS)
def test_map_reproduces_typed_published_rows(volts, pwm, kgf):
    assert force_n(t200(volts), pwm) == pytest.approx(kgf * G, abs=KGF_RES_N + 1e-9)


def test_map_reproduces_every_published_point_within_stated_accuracy():
    volts, pwm, force = tc.published_points("t200")
    assert list(volts) == [10, 12, 14, 16, 18, 20]
    assert pwm[0] == 1100 and pwm[-1] == 1900 and np.all(np.diff(pwm) == 4) and force.shape == (6, 201)
    assert tc.T200_ACCURACY_N == pytest.approx(KGF_RES_N)
    for k, v in enumerate(volts):
        err = np.abs(force_n(t200(float(v)), pwm) - force[k])
        assert err.max() <= tc.T200_ACCURACY_N + 1e-9, (v, pwm[np.argmax(err)])
        # most points are reproduced exactly; only the few that step back are pooled
        assert np.count_nonzero(err > 1e-9) <= 4


@pytest.mark.parametrize("volts,fwd_kgf,rev_kgf", [(12, 3.71, 2.92), (16, 5.25, 4.1), (20, 6.7, 5.05)])
def test_limits_are_the_published_maxima(volts, fwd_kgf, rev_kgf):
    t = t200(volts)
    # Blue Robotics' summary figures (rounded to ~0.05 kgf in the summaries)
    assert t.forward_n == pytest.approx(fwd_kgf * G, abs=0.05 * G)
    assert t.reverse_n == pytest.approx(rev_kgf * G, abs=0.05 * G)
    assert t.saturate([1e3, -1e3]).tolist() == [t.forward_n, -t.reverse_n]
    assert force_n(t, [1100, 1900]).tolist() == pytest.approx([-t.reverse_n, t.forward_n])


def test_fifteen_volts_lies_halfway_between_the_14_and_16_volt_curves():
    pwm = np.arange(1100.0, 1901.0, 4.0)
    f14, f15, f16 = (force_n(t200(v), pwm) for v in (14.0, 15.0, 16.0))
    np.testing.assert_allclose(f15, 0.5 * (f14 + f16), atol=1e-12)
    assert np.all(np.minimum(f14, f16) <= f15 + 1e-12) and np.all(f15 <= np.maximum(f14, f16) + 1e-12)
    # by hand from the sheets: 1700 us is 1.55 kgf at 14 V and 1.82 kgf at 16 V
    assert force_n(t200(15.0), 1700.0) == pytest.approx(0.5 * (1.55 + 1.82) * G, abs=1e-9)
    # 14.5 V: a quarter of the way from 14 to 16 V
    assert force_n(t200(14.5), 1800.0) == pytest.approx((0.75 * 2.99 + 0.25 * 3.42) * G, abs=1e-9)


@pytest.mark.parametrize("volts", [10.0, 12.0, 15.0, 16.0, 20.0])
def test_no_thrust_inside_the_deadband(volts):
    t = t200(volts)
    assert np.all(force_n(t, np.arange(1476.0, 1525.0, 0.5)) == 0.0)
    assert force_n(t, 1100.0) < 0 < force_n(t, 1900.0)


def test_deadband_edges_at_16_volts():
    t = t200(16.0)
    assert np.all(force_n(t, np.arange(1472.0, 1528.1, 1.0)) == 0.0)
    assert force_n(t, 1468.0) < 0 and force_n(t, 1532.0) > 0


@pytest.mark.parametrize("volts", [10.0, 12.0, 14.0, 16.0, 18.0, 20.0])
def test_forward_about_1_3_times_reverse(volts):
    t = t200(volts)
    assert 1.2 < t.forward_n / t.reverse_n < 1.4
    offsets = np.array([150.0, 250.0, 350.0, 400.0])
    ratio = force_n(t, 1500.0 + offsets) / -force_n(t, 1500.0 - offsets)
    assert np.all((ratio > 1.1) & (ratio < 1.5))


@pytest.mark.parametrize("volts", [10.0, 11.3, 13.7, 16.0, 19.99, 20.0])
def test_monotone_and_non_linear(volts):
    t = t200(volts)
    pwm = np.linspace(1000.0, 2000.0, 4001)
    f = force_n(t, pwm)
    assert np.all(np.diff(f) >= 0.0)
    assert f[0] == -t.reverse_n and f[-1] == t.forward_n      # held at full command beyond the range
    # roughly quadratic, not linear: half the offset gives well under half the force
    assert 0.2 * t.forward_n < force_n(t, 1700.0) < 0.45 * t.forward_n
    assert 0.2 * t.reverse_n < -force_n(t, 1300.0) < 0.45 * t.reverse_n


def test_vectorised_any_shape():
    t = t200(16.0)
    cmd = np.array([[1100.0, 1500.0], [1700.0, 1900.0]])
    out = force_n(t, cmd)
    assert out.shape == (2, 2)
    assert out[0, 1] == 0.0 and out[1, 1] == pytest.approx(5.25 * G)
    assert np.asarray(force_n(t, 1700.0)).shape == ()


def test_normalized_and_counts_commands_read_on_the_same_curve():
    t = t200(16.0)
    c = np.array([-1.0, -0.3, 0.0, 0.5, 1.0])
    np.testing.assert_allclose(t.command_to_force(c, "normalized"), force_n(t, 1500.0 + 400.0 * c))
    np.testing.assert_allclose(t.command_to_force(255.0 * c, "counts", full_scale=255.0),
                               force_n(t, 1500.0 + 400.0 * c))
    # another PWM range: neutral 1490, full command at +-500 us
    t2 = t200(16.0, pwm_neutral_us=1490.0, pwm_span_us=500.0)
    np.testing.assert_allclose(force_n(t2, 1490.0 + 500.0 * c), force_n(t, 1500.0 + 400.0 * c))


def test_force_to_command_inverts_the_map():
    t = t200(15.0)
    f = np.linspace(-t.reverse_n, t.forward_n, 301)
    for unit in ("pwm_us", "normalized"):
        cmd = t.force_to_command(f, unit)
        np.testing.assert_allclose(t.command_to_force(cmd, unit), f, atol=1e-9)
    assert t.force_to_command(0.0, "pwm_us") == 1500.0
    assert t.force_to_command([1e3, -1e3], "pwm_us").tolist() == [1900.0, 1100.0]
    # the smallest thrust needs a command just past the deadband's edge
    assert 1528.0 < t.force_to_command(0.01, "pwm_us") < 1536.0


def test_force_from_pwm_compiles_with_numba():
    numba = pytest.importorskip("numba")
    pwm, f = tc.curve("t200", 16.0)
    jitted = numba.njit(tc.force_from_pwm)
    x = np.array([1100.0, 1450.0, 1500.0, 1612.5, 1900.0])
    np.testing.assert_allclose(jitted(x, pwm, f), tc.force_from_pwm(x, pwm, f))


# --- reversed channels ----------------------------------------------------------------------------
@pytest.mark.parametrize("kind", ["t200", "linear", "quadratic"])
def test_reversed_flag_flips_that_thruster_only(kind):
    kw = {"supply_v": 16.0} if kind == "t200" else {"forward_n": 20.0, "reverse_n": 12.0}
    plain = Thrusters(map=kind, **kw)
    rev = Thrusters(map=kind, reversed_left=True, **kw)
    cmd = np.array([1100.0, 1300.0, 1500.0, 1650.0, 1900.0])
    mirror = 3000.0 - cmd
    # left: 1100 us now means full forward; right: unchanged
    np.testing.assert_allclose(rev.command_to_force(cmd, "pwm_us", side="left"),
                               plain.command_to_force(mirror, "pwm_us", side="left"))
    np.testing.assert_allclose(rev.command_to_force(cmd, "pwm_us", side="right"),
                               plain.command_to_force(cmd, "pwm_us", side="right"))
    assert rev.command_to_force(1100.0, "pwm_us", side="left") == pytest.approx(plain.forward_n)
    fl, fr = rev.forces_from_commands(cmd, cmd, np.array(["pwm_us"] * len(cmd)))
    pl, pr = plain.forces_from_commands(cmd, cmd, np.array(["pwm_us"] * len(cmd)))
    np.testing.assert_allclose(fr, pr)
    np.testing.assert_allclose(fl, plain.command_to_force(mirror, "pwm_us", side="left"))
    # newtons are forces already: never flipped
    np.testing.assert_allclose(rev.forces_from_commands([5.0], [5.0], np.array(["newton"]))[0], [5.0])
    # and the inverse gives the reversed channel its flipped command
    f = np.array([-8.0, 0.0, 10.0])
    np.testing.assert_allclose(rev.force_to_command(f, "pwm_us", side="left"),
                               3000.0 - plain.force_to_command(f, "pwm_us"))


def test_reversed_right_turns_the_boat_the_other_way():
    rev = t200(16.0, reversed_right=True)
    # both channels commanded 1900 us: left pushes forward, reversed right pulls back -> yaw to starboard
    fl, fr = rev.forces_from_commands([1900.0], [1900.0], np.array(["pwm_us"]))
    tau_u, tau_r = rev.tau_from_forces(fl, fr)
    assert fl[0] > 0 > fr[0] and tau_r[0] > 0
    assert tau_u[0] == pytest.approx((5.25 - 4.07) * G)


def test_reversed_channel_needs_a_side():
    rev = t200(16.0, reversed_right=True)
    with pytest.raises(ConfigError, match="reversed_right"):
        rev.command_to_force([1600.0], "pwm_us")
    with pytest.raises(ConfigError, match="side"):
        rev.force_to_command([1.0], "normalized")
    with pytest.raises(ConfigError, match="left or right"):
        rev.command_to_force([1600.0], "pwm_us", side="port")
    assert rev.command_to_force([3.0], "newton").tolist() == [3.0]   # newtons need no side
    assert t200(16.0).command_to_force(1900.0, "pwm_us") == pytest.approx(5.25 * G)   # nothing reversed


# --- vessel TOML ----------------------------------------------------------------------------------
def test_toml_round_trip_catalogue_map_with_reversed_channels():
    text = """name = "twin-t200"

[thrusters]
arm_m = 0.4
map = "t200"
supply_v = 15.0
reversed_left = true
"""
    v = vessel_from_toml(text, "twin.toml")
    t = v.thrusters
    assert (t.map, t.supply_v, t.reversed_left, t.reversed_right) == ("t200", 15.0, True, False)
    assert t.forward_n == pytest.approx(0.5 * (4.525 + 5.25) * G)    # 14 V's 4.52/4.53 pooled
    assert t.reverse_n == pytest.approx(0.5 * (3.52 + 4.07) * G)
    out = v.to_toml()
    again = vessel_from_toml(out, "again.toml")
    assert again == v
    assert Vessel.from_dict(v.to_dict()) == v
    keys = {line.split("=")[0].strip() for line in out.splitlines() if "=" in line and not line.startswith("#")}
    assert {"supply_v", "reversed_left"} <= keys and not {"forward_n", "reverse_n", "reversed_right"} & keys
    assert "# forward_n" in out


def test_toml_round_trip_reversed_linear_map():
    v = Vessel(name="x", thrusters=Thrusters(map="linear", forward_n=30.0, reverse_n=20.0, reversed_right=True))
    again = vessel_from_toml(v.to_toml())
    assert again == v and again.thrusters.reversed_right and not again.thrusters.reversed_left
    assert Vessel.from_dict(v.to_dict()) == v


def test_default_vessel_files_unchanged():
    out = Vessel().to_toml()
    assert "supply_v" not in out and "reversed" not in out
    assert not any(k.endswith(("supply_v", "reversed_left", "reversed_right")) for k in Vessel().to_dict())


def test_catalogue_limits_may_be_given_if_they_agree():
    t = t200(16.0)
    text = f'[thrusters]\nmap = "t200"\nsupply_v = 16.0\nforward_n = {t.forward_n!r}\nreverse_n = {t.reverse_n!r}\n'
    assert vessel_from_toml(text).thrusters == t
    with pytest.raises(ConfigError, match=r"boat\.toml.*forward_n = 20.0 N contradicts the t200 map"):
        vessel_from_toml('[thrusters]\nmap = "t200"\nsupply_v = 16.0\nforward_n = 20.0\n', "boat.toml")


@pytest.mark.parametrize("volts", [9.9, 20.5, 24.0, 5.0])
def test_voltage_outside_the_published_range_is_refused(volts):
    with pytest.raises(ConfigError, match=r"boat\.toml.*supply_v = .* outside the published range 10\.\.20 V"):
        vessel_from_toml(f'[thrusters]\nmap = "t200"\nsupply_v = {volts}\n', "boat.toml")


@pytest.mark.parametrize("thrusters,match", [
    ('map = "t200"', r"needs supply_v.*10\.\.20 V"),
    ('map = "t300"\nsupply_v = 16.0', r"thruster map 't300' is not one of .*t200"),
    ('map = "t500"\nsupply_v = 16.0', r"t500.*not bundled"),
    ('map = "t200"\nsupply_v = "16"', r"supply_v"),
    ('map = "t200"\nsupply_v = 16.0\nreversed_left = "yes"', r"reversed_left = 'yes' must be true or false"),
    ('map = "linear"\nsupply_v = -3.0', r"supply_v = -3.0 must be > 0"),
])
def test_config_errors_name_the_file_and_field(thrusters, match):
    with pytest.raises(ConfigError, match=match) as err:
        vessel_from_toml("[thrusters]\n" + thrusters + "\n", "boat.toml")
    assert str(err.value).startswith("boat.toml: ")


def test_curve_module_refuses_unknown_names_and_bad_voltages():
    with pytest.raises(ConfigError, match="not in the catalogue"):
        tc.curve("t100", 12.0)
    with pytest.raises(ConfigError, match="needs supply_v"):
        tc.curve("t200", float("nan"))
    assert tc.voltage_range("t200") == (10.0, 20.0)
    with pytest.raises(ConfigError, match="not a catalogue map"):
        Thrusters(map="linear").curve()
