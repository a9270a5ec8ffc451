"""Heading mounting offset detection, GNSS noise from the fix quality, the vessel file's
[sensors] table and the estimate's offset, sideslip and noise-source checks, against the
truth of simulated straight-leg runs (tests/unit/heading_offset_runs.py)."""

import math

import numpy as np
import pytest

from tests.unit.heading_offset_runs import truth
from usvlog.errors import ConfigError
from usvlog.estimate import EstimateSettings, estimate
from usvlog.estimate.problem import build_problem
from usvlog.estimate.report import heading_blocking
from usvlog.log.fieldlog import FieldLog
from usvlog.model.gnss_noise import gnss_sigma_from_quality
from usvlog.model.heading_offset import HeadingOffset, detect_heading_offset
from usvlog.model.vessel import default_vessel, vessel_from_toml


def _measure(run, offset_deg=0.0, gps_sd=1.0, heading_sd_deg=1.0, seed=0):
    """GNSS at 5 Hz (noise gps_sd m) and headings at 10 Hz reading offset_deg more than the hull."""
    rng = np.random.default_rng(seed)
    g = slice(None, None, 2)
    n = run.n_m[g] + gps_sd * rng.standard_normal(len(run.n_m[g]))
    e = run.e_m[g] + gps_sd * rng.standard_normal(len(run.e_m[g]))
    hd = run.psi_rad + math.radians(offset_deg) + math.radians(heading_sd_deg) * rng.standard_normal(len(run.t_s))
    return run.t_s[g], n, e, run.t_s, hd


@pytest.mark.parametrize("offset", [70.0, -30.0, 175.0])
def test_a_constant_offset_on_four_courses_is_found_with_its_sign(offset):
    found = detect_heading_offset(*_measure(truth(), offset))
    assert found.decided, found.reason
    assert abs(math.degrees(math.remainder(math.radians(found.offset_deg - offset), 2 * math.pi))) < 2.0
    assert found.runs == 6 and found.courses == 4
    assert 0 < found.std_deg < 1.0
    assert "mounting offset" in found.describe()


@pytest.mark.parametrize("current_ne", [(0.0, 0.3), (0.3, 0.0), (-0.21, 0.21)])
def test_a_cross_current_is_not_called_an_offset(current_ne):
    """0.3 m/s of current at 1.2 m/s crabs up to 14.5 deg, with the sign changing with the course."""
    run = truth(current_ne=current_ne)
    crab = np.degrees(np.arctan2(run.v_mps, run.u_mps))
    assert np.ptp(crab) > 20     # the truth: a crab that changes with the course
    found = detect_heading_offset(*_measure(run, 0.0))
    assert not found.decided
    assert "changes with the course" in found.reason or "agrees with the course" in found.reason


def test_an_offset_under_a_light_current_is_still_found():
    found = detect_heading_offset(*_measure(truth(current_ne=(0.05, 0.05)), 70.0))
    assert found.decided and abs(found.offset_deg - 70.0) < 2.0


def test_one_course_or_no_motion_is_not_decidable():
    one = detect_heading_offset(*_measure(truth(courses_deg=(20, 20, 20)), 70.0))
    assert not one.decided and one.reason.startswith("not decidable") and one.courses == 1
    still = detect_heading_offset(*_measure(truth(speed=0.2), 70.0))
    assert not still.decided and still.runs == 0 and "not decidable" in still.reason


def test_a_small_offset_is_not_reported():
    found = detect_heading_offset(*_measure(truth(), 2.0))
    assert not found.decided and "agrees with the course" in found.reason
    assert abs(found.offset_deg - 2.0) < 1.5


def test_gnss_sigma_table():
    q = [4, 5, 2, 9, 1, 1, 1, 3, 0, 6, -1]
    h = [0.7, 1.0, 2.0, 0.8, 1.0, 0.3, np.nan, 2.0, 1.0, 1.0, 1.0]
    s = gnss_sigma_from_quality(q, h)
    assert s[:8] == pytest.approx([0.03, 0.3, 1.4, 0.7, 1.5, 1.0, 1.5, 3.0])
    assert np.isnan(s[8:]).all()


def test_vessel_sensors_table_round_trip_and_range():
    v = vessel_from_toml('name = "rtk boat"\n[sensors]\nheading_offset_deg = 70.5\n')
    assert v.heading_offset_deg == 70.5
    assert vessel_from_toml(v.to_toml()).heading_offset_deg == 70.5
    assert type(v).from_dict(v.to_dict()).heading_offset_deg == 70.5
    assert default_vessel().heading_offset_deg is None and "[sensors]" not in default_vessel().to_toml()
    with pytest.raises(ConfigError, match="heading_offset_deg"):
        vessel_from_toml("[sensors]\nheading_offset_deg = 400\n")
    with pytest.raises(ConfigError, match="unknown key"):
        vessel_from_toml("[sensors]\noffset = 4\n")


def _log(run, offset_deg, quality=None, gps_sd=0.03, seed=1):
    """A FieldLog of the run (fixes at 5 Hz, true headings + offset at 10 Hz, fix quality optional)."""
    from tests.unit.heading_offset_runs import DATUM, T0_NS
    from usvlog.log.channels import channel_spec, frame_from_columns
    from usvlog.model.frames import ned_to_geodetic

    tg, n, e, th, hd = _measure(run, offset_deg, gps_sd=gps_sd, heading_sd_deg=0.5, seed=seed)
    lat, lon, _ = ned_to_geodetic(n, e, 0.0, datum=DATUM)
    t_g, t_h = T0_NS + np.round(tg * 1e9).astype(np.int64), T0_NS + np.round(th * 1e9).astype(np.int64)
    log = FieldLog()
    k = len(t_g)
    fix = {"stamp_ns": t_g, "frame_id": np.array(["gnss"] * k, object), "lat_deg": lat, "lon_deg": lon,
           "alt_m": np.zeros(k), "cov_type": np.zeros(k, np.int64)}   # covariance unknown (all 0)
    fix.update({f"cov_{a}{b}_m2": np.zeros(k) for a in "neu" for b in "neu"})
    log.set("/gnss/fix", frame_from_columns(fix, t_g, channel_spec("/gnss/fix")))
    hdg = {"stamp_ns": t_h, "heading_rad": np.angle(np.exp(1j * hd)),
           "reference": np.array(["true"] * len(t_h), object), "std_rad": np.full(len(t_h), math.radians(0.5))}
    log.set("/compass/heading", frame_from_columns(hdg, t_h, channel_spec("/compass/heading")))
    if quality is not None:
        q = {"stamp_ns": t_g, "fix_quality": np.full(k, quality[0], np.int64), "satellites": np.full(k, 14, np.int64),
             "hdop": np.full(k, quality[1])}
        log.set("/gnss/quality", frame_from_columns(q, t_g, channel_spec("/gnss/quality")))
    return log


def test_estimate_refuses_an_unapplied_offset_and_applies_auto():
    run = truth()
    log = _log(run, 70.0)
    bad = estimate(log, EstimateSettings()).report
    assert bad.status == "failed"
    why = " ".join(bad.blocking)
    assert "--heading-offset auto" in why and "implausible sideslip" in why and "+70.0" in why
    assert bad.sideslip["median_abs_deg"] > 60      # the truth has none: the offset is the sideslip
    res = estimate(log, EstimateSettings(heading_offset_auto=True))
    rep = res.report
    assert rep.status != "failed" and not rep.blocking
    assert rep.heading_offset["source"] == "auto" and abs(rep.heading_offset["applied_deg"] - 70.0) < 2.0
    st = res.state
    t_s = (np.asarray(st.index, np.int64) - np.asarray(st.index, np.int64)[0]) * 1e-9
    psi_true = np.interp(t_s, run.t_s, np.unwrap(run.psi_rad))
    err = np.degrees(np.abs(np.angle(np.exp(1j * (st["psi_rad"].to_numpy() - psi_true)))))
    assert np.median(err) < 2.0
    assert rep.sideslip["median_abs_deg"] < 3.0 and np.median(np.abs(st["v_mps"])) < 0.1


def test_the_vessel_file_offset_is_applied_and_a_wrong_one_refused():
    log = _log(truth(), 70.0)
    ves = vessel_from_toml("[sensors]\nheading_offset_deg = 70\n")
    rep = estimate(log, EstimateSettings(), ves).report
    assert rep.heading_offset["source"] == "vessel file" and rep.status != "failed"
    wrong = estimate(log, EstimateSettings(compass_offset_rad=math.radians(40.0))).report
    assert wrong.status == "failed" and "applied +40.0" in wrong.blocking[0]


def test_no_block_without_a_fused_heading_or_a_decided_offset():
    found = HeadingOffset(False, 70.0, 1.0, 2.0, 2, 1, "not decidable")
    assert heading_blocking(found, 0.0, "gnss+compass", {"moving_s": 100, "median_abs_deg": 2.0,
                                                          "median_u_mps": 1.0, "median_abs_v_mps": 0.03}) == ()
    decided = HeadingOffset(True, 70.0, 1.0, 2.0, 6, 4)
    assert heading_blocking(decided, 0.0, "gps-only", None) == ()


def test_rtk_fixes_get_centimetre_noise_and_a_consistent_nis():
    run = truth()
    rtk = _log(run, 0.0, quality=(4, 0.7), gps_sd=0.03)
    pb = build_problem(rtk, EstimateSettings(), default_vessel())
    gn = pb.mkind == 0
    assert np.allclose(pb.mR[gn, 0], 0.03 ** 2) and np.allclose(pb.mR[gn, 2], 0.03 ** 2)
    rep = estimate(rtk, EstimateSettings()).report
    assert 1.0 < rep.sensor("gnss").mean_nis < 4.0          # dim 2
    assert "RTK fixed 3 cm on 100 %" in rep.gnss_noise
    # the same fixes without a fix quality: the default, far too large for them (the problem seen)
    del rtk.channels["/gnss/quality"]
    old = estimate(rtk, EstimateSettings()).report
    assert old.sensor("gnss").mean_nis < 0.05 and "the default 2 m" in old.gnss_noise
    gps = _log(run, 0.0, quality=(1, 1.0), gps_sd=1.5)
    pb = build_problem(gps, EstimateSettings(), default_vessel())
    assert np.allclose(pb.mR[pb.mkind == 0, 0], 1.5 ** 2)
    assert 1.0 < estimate(gps, EstimateSettings()).report.sensor("gnss").mean_nis < 4.0


def test_a_wrong_heading_over_too_short_a_motion_is_a_warning():
    """Under SIDESLIP_MIN_MOVING_S of motion the sideslip does not refuse the estimate, but a
    median beyond SIDESLIP_MAX_DEG is said in plain words and the status is degraded, not ok."""
    from usvlog.estimate.report import SIDESLIP_MAX_DEG, SIDESLIP_MIN_MOVING_S

    rep = estimate(_log(truth(courses_deg=(20,), leg_s=8.0), 70.0), EstimateSettings()).report
    sl = rep.sideslip
    assert sl["moving_s"] < SIDESLIP_MIN_MOVING_S and sl["median_abs_deg"] > SIDESLIP_MAX_DEG, sl
    assert rep.status == "degraded" and not rep.blocking
    line = [w for w in rep.consistency() if w.startswith("sideslip: ")]
    assert len(line) == 1 and f"over only {sl['moving_s']:.1f} s of motion" in line[0], rep.consistency()
    # the same boat with its heading right: nothing said
    ok = estimate(_log(truth(courses_deg=(20,), leg_s=8.0), 0.0), EstimateSettings()).report
    assert not [w for w in ok.consistency() if w.startswith("sideslip: ")]
