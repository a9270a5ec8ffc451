"""ArduPilot .bin and PX4 .ulg fixtures (built to the formats' specs) imported back."""

from __future__ import annotations

import numpy as np
import pytest
from import_fixtures import T0_NS, build_dataflash, build_ulog

from usvlog.cli import main
from usvlog.errors import FormatError
from usvlog.io.importers import detect_format, import_file
from usvlog.model.frames import ssa
from usvlog.model.vessel import Thrusters, Vessel


def test_dataflash_round_trip(tmp_path):
    data, tr = build_dataflash()
    p = tmp_path / "flight.bin"
    p.write_bytes(data)
    assert detect_format(p) == "dataflash"
    vessel = Vessel(thrusters=Thrusters(map="linear", forward_n=30.0, reverse_n=15.0))
    res = import_file(p, vessel=vessel)
    log = res.log
    g = log["/gnss/fix"]
    t = T0_NS + (tr["boot_us"] - tr["boot_us"][0]) * 1000
    np.testing.assert_array_equal(g.index.to_numpy(), t)
    np.testing.assert_allclose(g["lat_deg"], tr["lat_e7"] * 1e-7, atol=1e-7, rtol=0)
    np.testing.assert_allclose(g["lon_deg"], tr["lon_e7"] * 1e-7, atol=1e-7, rtol=0)
    h = log["/compass/heading"]
    np.testing.assert_array_equal(h.index.to_numpy(), t + 20_000_000)
    np.testing.assert_allclose(ssa(h["heading_rad"] - np.radians(tr["yaw_cd"] / 100.0)), 0.0, atol=1e-6)
    th = log["/thrust/command"]
    np.testing.assert_array_equal(th["left"], tr["pwm_l"])   # SERVO3_FUNCTION = 73
    np.testing.assert_array_equal(th["right"], tr["pwm_r"])  # SERVO1_FUNCTION = 74
    assert set(th["unit"]) == {"pwm_us"}
    # linear map: (pwm - 1500) / 400 of forward 30 N / reverse 15 N
    c = (tr["pwm_r"] - 1500) / 400.0
    np.testing.assert_allclose(th["thrust_right_n"], np.where(c >= 0, 30.0 * c, 15.0 * c), atol=1e-12)
    assert res.report.mapping["thrust_left"].startswith("RCOU.C3")


def test_dataflash_no_fix_counted(tmp_path):
    data, _ = build_dataflash(nofix_first=4)
    p = tmp_path / "nofix.bin"
    p.write_bytes(data)
    res = import_file(p)
    assert res.report.skipped["gnss_no_fix"] == 4 and len(res.log["/gnss/fix"]) == 26


def test_dataflash_truncated_keeps_complete_messages(tmp_path):
    data, tr = build_dataflash()
    p = tmp_path / "cut.bin"
    p.write_bytes(data[: len(data) * 2 // 3 + 5])  # cut inside a message
    res = import_file(p)
    g = res.log["/gnss/fix"]
    assert 10 < len(g) < 30
    np.testing.assert_allclose(g["lat_deg"], tr["lat_e7"][: len(g)] * 1e-7, atol=1e-7, rtol=0)


def test_ulog_round_trip(tmp_path):
    data, tr = build_ulog()
    p = tmp_path / "flight.ulg"
    p.write_bytes(data)
    assert detect_format(p) == "ulog"
    res = import_file(p)
    log = res.log
    ok = tr["fix"] >= 3
    g = log["/gnss/fix"]
    t = T0_NS + (tr["ts_us"] - tr["ts_us"][0]) * 1000
    np.testing.assert_array_equal(g.index.to_numpy(), t[ok])
    np.testing.assert_allclose(g["lat_deg"], tr["lat_e7"][ok] * 1e-7, atol=1e-7, rtol=0)
    np.testing.assert_allclose(g["lon_deg"], tr["lon_e7"][ok] * 1e-7, atol=1e-7, rtol=0)
    np.testing.assert_allclose(g["alt_m"], 12.5 + 38.0)  # above the WGS-84 ellipsoid, as /gnss/fix defines it
    assert res.report.skipped["gnss_no_fix"] == int((~ok).sum())
    h = log["/compass/heading"]
    np.testing.assert_allclose(ssa(h["heading_rad"] - tr["psi"]), 0.0, atol=1e-6)
    th = log["/thrust/command"]
    np.testing.assert_array_equal(th["left"], tr["pwm_l"] + 1)  # default output[0]
    res2 = import_file(p, topics={"thrust_left": "actuator_outputs.output[2]",
                                  "thrust_right": "actuator_outputs.output[3]"})
    np.testing.assert_array_equal(res2.log["/thrust/command"]["left"], tr["pwm_l"])
    np.testing.assert_array_equal(res2.log["/thrust/command"]["right"], tr["pwm_r"])
    assert set(res2.log["/thrust/command"]["unit"]) == {"pwm_us"}


@pytest.mark.parametrize("kind", ["bin", "ulg"])
def test_garbage_and_truncated_binary_one_line(tmp_path, capfd, kind):
    data = build_dataflash()[0] if kind == "bin" else build_ulog()[0]
    bad = tmp_path / f"bad.{kind}"
    bad.write_bytes(data[:7] + bytes(range(256)) * 4)  # right magic, garbage after it
    out = tmp_path / "o.mcap"
    rc = main(["import", str(bad), "--out", str(out)])
    cap = capfd.readouterr()  # file-descriptor level: pymavlink's C indexer writes there
    err = cap.err.strip().splitlines()
    assert rc == 2 and "bad." + kind in err[-1] and "error" in err[-1] and not out.exists()
    # nothing else but the printed mapping (progress on stderr): no library chatter
    assert all(ln.startswith(("importing", "  ")) for ln in err[:-1]), err
    assert cap.out == ""


def test_forced_wrong_format_on_binary(tmp_path):
    p = tmp_path / "f.bin"
    p.write_bytes(build_dataflash()[0])
    with pytest.raises(FormatError, match="f.bin"):
        import_file(p, "ulog")
    with pytest.raises(FormatError, match="f.bin"):
        import_file(p, "ros1")


def test_ulog_role_mapped_to_missing_topic_or_field(tmp_path):
    from usvlog.errors import InputError

    p = tmp_path / "f.ulg"
    p.write_bytes(build_ulog()[0])
    with pytest.raises(InputError, match="f.ulg: topic actuator_motors is not in the log"):
        import_file(p, topics={"thrust_left": "actuator_motors.control[0]",
                               "thrust_right": "actuator_motors.control[1]"})
    with pytest.raises(InputError, match=r"f.ulg: topic actuator_outputs has no field 'output\[40\]'"):
        import_file(p, topics={"thrust_left": "actuator_outputs.output[40]",
                               "thrust_right": "actuator_outputs.output[1]"})


def test_dataflash_gpa_accuracy_is_the_fix_covariance(tmp_path):
    """GPA (written by ArduPilot with its GPS message's TimeUS) HAcc/VAcc -> diagonal covariance, type 2."""
    from import_fixtures import _df_fmt, _df_msg

    data, tr = build_dataflash(n=10)
    gpa = (70, "GPA", "QCC", "TimeUS,HAcc,VAcc")
    hacc = 150 + 10 * np.arange(10)          # cm (format C: x 0.01 -> m)
    extra = [_df_fmt(*gpa)] + [_df_msg(70, "QCC", int(us), int(h), 2 * int(h))
                               for us, h in zip(tr["boot_us"], hacc, strict=True) if h != 180]
    p = tmp_path / "gpa.bin"
    p.write_bytes(data + b"".join(extra))
    g = import_file(p).log["/gnss/fix"]
    h_m = hacc / 100.0
    has = hacc != 180                          # one fix without its GPA: covariance unknown
    np.testing.assert_allclose(g["cov_ee_m2"][has], h_m[has] ** 2)
    np.testing.assert_allclose(g["cov_nn_m2"][has], h_m[has] ** 2)
    np.testing.assert_allclose(g["cov_uu_m2"][has], (2 * h_m[has]) ** 2)
    assert list(g["cov_type"]) == [2 if x else 0 for x in has]
    assert (g["cov_ee_m2"][~has] == 0).all()


def test_dataflash_unknown_role_and_half_thrust_refused(tmp_path):
    from usvlog.errors import InputError
    from usvlog.io.importers import dataflash

    p = tmp_path / "f.bin"
    p.write_bytes(build_dataflash()[0])
    fmts = dataflash.formats(dataflash._open(p))
    with pytest.raises(InputError, match="role 'depth' cannot be read from a DataFlash log"):
        dataflash.choose_roles(fmts, {}, {"depth": "BARO.Alt"}, p)
    ch = dataflash.choose_roles(fmts, {3: 73, 1: 74}, {}, p)
    assert ch.mapping == {"gnss": "GPS", "heading": "ATT.Yaw", "thrust_left": "RCOU.C3", "thrust_right": "RCOU.C1"}
    assert "SERVO3_FUNCTION = 73" in ch.reasons["thrust"]
