"""``usvlog.check``: one test per finding, each on a simulated run damaged to have it (the numbers
in the evidence against what was injected), and clean runs with no warning or error."""

from __future__ import annotations

import json
import math
import xml.etree.ElementTree as ET
from dataclasses import replace

import numpy as np
import pytest

from usvlog.check import check_log
from usvlog.log.channels import channel_spec, frame_from_columns
from usvlog.log.findings import Finding, findings_from_health, format_table, junit_xml, sort_findings
from usvlog.sim.simulate import SensorSettings, SimSettings, _open_loop, simulate

PERIOD_S = 60.0   # a turn of 6 s, then straight, every PERIOD_S: straight legs on every course


def legs_log(seed: int = 3, duration_s: float = 900.0, sensors: SensorSettings | None = None, first_idle_s=0.0):
    """Open loop: every 60 s a yaw moment of 0.9 N m for 6 s (about 60 deg of turn), then straight
    with a new surge thrust (3-7 N); thrust zero for the first ``first_idle_s``."""
    def tau(t, rng):
        k = (t // PERIOD_S).astype(int)
        tu = rng.uniform(3.0, 7.0, int(k.max()) + 1)[k]
        tr = np.where((t % PERIOD_S) < 6.0, 0.9, 0.0)
        idle = t < first_idle_s
        return np.where(idle, 0.0, tu), np.where(idle, 0.0, tr)
    st = SimSettings(duration_s=duration_s, sensors=sensors or SensorSettings())
    return _open_loop(st, seed, tau, "legs")


@pytest.fixture(scope="module")
def legs():
    return legs_log()


def _bad(result, code):
    return [f for f in result.by_code(code) if f.severity in ("warning", "error")]


def _set(log, topic, **cols):
    f = log[topic].copy()
    for k, v in cols.items():
        f[k] = v
    log.set(topic, f)


def _truth_at(log, t_ns, col):
    tr = log["/truth/state"]
    x = tr[col].to_numpy(float)
    if col == "psi_rad":
        x = np.unwrap(x)
    return np.interp(np.asarray(t_ns, np.int64), np.asarray(tr.index, np.int64), x)


def _thrust_at(log, t_ns):
    th = log["/thrust/command"]
    i = np.clip(np.searchsorted(np.asarray(th.index, np.int64), t_ns, side="right") - 1, 0, len(th) - 1)
    return th["left"].to_numpy(float)[i], th["right"].to_numpy(float)[i]


def _wrap(a):
    return np.angle(np.exp(1j * np.asarray(a)))


# -----------------------------------------------------------------------------
# clean runs
# -----------------------------------------------------------------------------

@pytest.mark.parametrize("which", ["legs", "excitation", "turns"])
def test_clean_simulated_runs_have_no_warning_or_error(legs, which):
    log = legs if which == "legs" else simulate(which, SimSettings(duration_s=300.0), seed=5)
    res = check_log(log)
    assert [f.line() for f in res.findings if f.severity != "info"] == []
    assert res.exit_code == 0
    sw = res.by_code("thrusters.swapped")[0]
    assert sw.numbers["sign"] == 1
    if which == "legs":   # straight legs on every course: the leg fit ran and found nothing
        dev = res.by_code("heading.deviation")[0]
        assert dev.numbers["legs"] >= 30 and dev.numbers["p"] > 1e-3


# -----------------------------------------------------------------------------
# sensors
# -----------------------------------------------------------------------------

def test_dead_compass_constant_while_the_track_turns(legs):
    log = legs.copy()
    c = log["/compass/heading"]
    _set(log, "/compass/heading", heading_rad=np.full(len(c), 1.234))
    res = check_log(log)
    (f,) = _bad(res, "sensors.dead")
    assert f.severity == "error" and f.channel == "/compass/heading"
    assert f.numbers["span_deg"] == pytest.approx(0.0) and f.numbers["track_turn_deg"] > 360
    assert res.exit_code == 1
    assert not _bad(res, "sensors.frozen")      # dead, not also frozen


def test_frozen_compass_stretch(legs):
    log = legs.copy()
    c = log["/compass/heading"]
    t = (np.asarray(c.index, np.int64) - int(c.index[0])) / 1e9
    h = c["heading_rad"].to_numpy(float).copy()
    k = (t >= 200.0) & (t < 220.0)
    h[k] = h[np.flatnonzero(k)[0]]
    _set(log, "/compass/heading", heading_rad=h)
    (f,) = _bad(check_log(log), "sensors.frozen")
    assert f.channel == "/compass/heading" and f.t0_s == pytest.approx(200.0, abs=0.1)
    assert f.numbers["frozen_s"] == pytest.approx(20.0, abs=0.2)


def test_frozen_gnss_under_thrust(legs):
    log = legs.copy()
    g = log["/gnss/fix"]
    t = (np.asarray(g.index, np.int64) - int(g.index[0])) / 1e9
    k = np.flatnonzero((t >= 300.0) & (t < 310.0))
    lat, lon = g["lat_deg"].to_numpy().copy(), g["lon_deg"].to_numpy().copy()
    lat[k], lon[k] = lat[k[0]], lon[k[0]]
    _set(log, "/gnss/fix", lat_deg=lat, lon_deg=lon)
    (f,) = _bad(check_log(log), "sensors.frozen")
    assert f.channel == "/gnss/fix" and f.t0_s == pytest.approx(300.0, abs=0.05)
    assert f.numbers["frozen_s"] == pytest.approx(9.9, abs=0.05)


def test_held_gnss_two_rows_each(legs):
    log = legs.copy()
    g = log["/gnss/fix"]
    idx = (np.arange(len(g)) // 2) * 2            # each fix held for 2 rows: 10 Hz rows, 5 Hz updates
    _set(log, "/gnss/fix", lat_deg=g["lat_deg"].to_numpy()[idx], lon_deg=g["lon_deg"].to_numpy()[idx])
    (f,) = _bad(check_log(log), "sensors.held")
    assert f.numbers["update_hz"] == pytest.approx(5.0, rel=0.02)
    assert f.numbers["row_hz"] == pytest.approx(10.0, rel=0.02)
    assert f.numbers["repeat_share"] == pytest.approx(0.5, abs=0.01)


def test_gnss_jump():
    log = legs_log(duration_s=400.0, sensors=SensorSettings(gps_jumps=((150.0, 60.0),)))
    (f,) = _bad(check_log(log), "sensors.gnss_jump")
    assert f.numbers["at_s"] == pytest.approx(150.0, abs=0.15)
    assert f.numbers["largest_m"] == pytest.approx(60.0, abs=6.0)
    assert f.t0_s == pytest.approx(150.0, abs=0.15) and f.t1_s == pytest.approx(150.1, abs=0.15)


def test_gnss_gap():
    log = legs_log(duration_s=400.0, sensors=SensorSettings(gps_dropouts=((100.0, 12.0),)))
    (f,) = _bad(check_log(log), "sensors.gaps")
    assert f.channel == "/gnss/fix" and f.numbers["longest_gap_s"] == pytest.approx(12.1, abs=0.15)
    assert f.t0_s == pytest.approx(100.0, abs=0.15)


def test_time_going_backwards(legs):
    log = legs.copy()
    c = log["/compass/heading"]
    st = c["stamp_ns"].to_numpy(np.int64).copy()
    st[1000] -= 500_000_000                          # one stamp 0.5 s before the one before
    _set(log, "/compass/heading", stamp_ns=st)
    (f,) = _bad(check_log(log), "sensors.time_backwards")
    assert f.numbers["backwards"] == 1 and f.numbers["largest_back_s"] == pytest.approx(0.45, abs=0.01)
    assert f.t0_s == pytest.approx(1000 / 20.0, abs=0.01)


def _quality_log(legs, q, hdop, sats):
    log = legs.copy()
    g = log["/gnss/fix"]
    t = np.asarray(g.index, np.int64)
    cols = {"stamp_ns": t.copy(), "fix_quality": np.asarray(q, np.int64), "satellites": np.asarray(sats, np.int64),
            "hdop": np.asarray(hdop, float)}
    log.set("/gnss/quality", frame_from_columns(cols, t, channel_spec("/gnss/quality")))
    return log


def test_gnss_quality_rtk_lost_high_hdop_few_satellites(legs):
    n = len(legs["/gnss/fix"])
    i = np.arange(n)
    q = np.where(i < 0.6 * n, 4, 1)                   # RTK fixed, then autonomous for the last 40 %
    hdop = np.where(i % 4 == 0, 3.5, 0.8)             # 25 % above 2
    sats = np.where(i % 5 == 0, 4, 14)                # 20 % below 6
    res = check_log(_quality_log(legs, q, hdop, sats))
    (lost,) = _bad(res, "sensors.gnss_quality.rtk_lost")
    assert lost.numbers["rtk_share"] == pytest.approx(0.6, abs=0.01)
    assert lost.t0_s == pytest.approx(0.6 * n / 10.0, abs=0.2)
    (h,) = _bad(res, "sensors.gnss_quality.hdop")
    assert h.numbers["hdop_high_share"] == pytest.approx(0.25, abs=0.01)
    (s,) = _bad(res, "sensors.gnss_quality.satellites")
    assert s.numbers["min_satellites"] == 4 and s.numbers["low_share"] == pytest.approx(0.2, abs=0.01)
    info = [f for f in res.by_code("sensors.gnss_quality") if f.severity == "info"]
    assert "RTK fixed 60%" in info[0].evidence and "autonomous 40%" in info[0].evidence


def test_gnss_quality_all_rtk_is_info_only(legs):
    n = len(legs["/gnss/fix"])
    res = check_log(_quality_log(legs, np.full(n, 4), np.full(n, 0.7), np.full(n, 15)))
    assert not _bad(res, "sensors.gnss_quality")


# -----------------------------------------------------------------------------
# heading
# -----------------------------------------------------------------------------

def test_mounting_offset_70_deg(legs):
    log = legs.copy()
    c = log["/compass/heading"]
    _set(log, "/compass/heading", heading_rad=_wrap(c["heading_rad"].to_numpy() + math.radians(70.0)))
    res = check_log(log)
    (f,) = _bad(res, "heading.mounting_offset")
    assert f.severity == "error" and abs(f.numbers["offset_deg"] - 70.0) < 2.0 and f.numbers["courses"] >= 2
    assert "--heading-offset auto" in f.action
    assert res.exit_code == 1


def test_mounting_offset_given_in_the_vessel_is_info(legs):
    log = legs.copy()
    c = log["/compass/heading"]
    _set(log, "/compass/heading", heading_rad=_wrap(c["heading_rad"].to_numpy() + math.radians(70.0)))
    res = check_log(log, replace(log.vessel, heading_offset_deg=70.0))
    (f,) = res.by_code("heading.mounting_offset")
    assert f.severity == "info" and "applies +70.0" in f.evidence


def test_deviation_curve_8_deg(legs):
    log = legs.copy()
    c = log["/compass/heading"]
    psi = _truth_at(log, c.index, "psi_rad")
    _set(log, "/compass/heading", heading_rad=_wrap(c["heading_rad"].to_numpy()
                                                     + math.radians(8.0) * np.sin(psi + 0.5)))
    (f,) = _bad(check_log(log), "heading.deviation")
    assert f.severity == "warning" and f.numbers["p"] < 1e-3
    assert f.numbers["one_cycle_deg"] == pytest.approx(8.0, abs=1.5)
    assert f.numbers["amplitude_deg"] == pytest.approx(8.0, abs=2.0)


def test_heading_disturbance_that_follows_thrust(legs):
    log = legs.copy()
    c = log["/compass/heading"]
    left, right = _thrust_at(log, np.asarray(c.index, np.int64))
    k = 2.0   # deg per N of |left| + |right|: 6 deg over the run's 3-6 N on the straight legs
    _set(log, "/compass/heading", heading_rad=_wrap(c["heading_rad"].to_numpy()
                                                     + math.radians(k) * (np.abs(left) + np.abs(right))))
    (f,) = _bad(check_log(log), "heading.thrust_disturbance")
    assert f.numbers["per_unit_total_deg"] == pytest.approx(k, abs=0.5)
    assert f.numbers["p"] < 1e-3 and "motor current" in f.action


def _yaw_rate_log(legs, scale):
    log = legs.copy()
    tr = log["/truth/state"]
    t = np.asarray(tr.index, np.int64)[::5]                 # 20 Hz
    r = tr["r_radps"].to_numpy(float)[::5] * scale
    r = r + 0.002 * np.random.default_rng(1).standard_normal(len(r))
    log.set("/imu/yaw_rate", frame_from_columns({"stamp_ns": t.copy(), "r_radps": r}, t,
                                                channel_spec("/imu/yaw_rate")))
    return log


@pytest.mark.parametrize("scale,severity", [(1.0, "info"), (-1.0, "error"), (180 / math.pi, "error"),
                                            (0.6, "warning")])
def test_yaw_rate_sign_and_scale(legs, scale, severity):
    (f,) = check_log(_yaw_rate_log(legs, scale)).by_code("heading.yaw_rate")
    assert f.severity == severity
    assert f.numbers["scale"] == pytest.approx(scale, rel=0.1)
    if scale < 0:
        assert "sign" in f.action


# -----------------------------------------------------------------------------
# thrusters
# -----------------------------------------------------------------------------

def test_left_right_swapped(legs):
    log = legs.copy()
    th = log["/thrust/command"]
    _set(log, "/thrust/command", left=th["right"].to_numpy(), right=th["left"].to_numpy(),
         thrust_left_n=th["thrust_right_n"].to_numpy(), thrust_right_n=th["thrust_left_n"].to_numpy())
    res = check_log(log)
    (f,) = _bad(res, "thrusters.swapped")
    assert f.severity == "error" and f.numbers["sign"] == -1 and f.numbers["correlation"] < -0.5
    assert "thrust_left" in f.action and res.exit_code == 1


def test_saturated_and_out_of_range(legs):
    log = legs.copy()
    th = log["/thrust/command"]
    t = (np.asarray(th.index, np.int64) - int(th.index[0])) / 1e9
    left = th["left"].to_numpy(float).copy()
    left[(t >= 100) & (t < 370)] = 20.0              # forward_n: 30 % of the 900 s run at the limit
    left[(t >= 500) & (t < 510)] = 25.0              # beyond it
    _set(log, "/thrust/command", left=left, thrust_left_n=left)
    res = check_log(log)
    (s,) = _bad(res, "thrusters.saturated")
    assert s.numbers["share"] == pytest.approx(0.30, abs=0.01) and s.t0_s == pytest.approx(100.0, abs=0.02)
    (o,) = _bad(res, "thrusters.out_of_range")
    assert o.numbers["count"] == 1000 and o.numbers["max"] == 25.0


def test_deadband_small_commands_that_move_nothing():
    log = legs_log(duration_s=300.0, first_idle_s=40.0)
    th = log["/thrust/command"]
    t = (np.asarray(th.index, np.int64) - int(th.index[0])) / 1e9
    idle = t < 40.0
    small = np.where(idle, 1.5, th["left"].to_numpy(float))   # 7.5 % of 20 N, the boat stays still
    _set(log, "/thrust/command", left=small, right=np.where(idle, 1.5, th["right"].to_numpy(float)))
    (f,) = _bad(check_log(log), "thrusters.deadband")
    assert f.t0_s == pytest.approx(0.0) and f.t1_s == pytest.approx(40.0, abs=1.0)   # the boat starts late
    assert 1.5 <= f.numbers["command_max"] <= 3.0 and f.numbers["speed_mps"] < 0.1   # at most 15 % of 20 N


# -----------------------------------------------------------------------------
# run content
# -----------------------------------------------------------------------------

def test_straight_run_asks_for_a_zigzag_and_turning_circles():
    log = simulate("straight", SimSettings(duration_s=200.0), seed=4)
    res = check_log(log)
    nxt = _bad(res, "content.next_manoeuvre")
    text = " | ".join(f.evidence + " -> " + f.action for f in nxt)
    assert len(nxt) == 2 and "Iz, d33 not determined" in text and "zig-zag" in text
    assert "d22, xg not determined" in text and "turning circles" in text
    info = res.by_code("content.excitation")[0]
    assert "m, d11" in info.evidence and info.numbers["yaw_rate_rms_deg_s"] < 2.0


# -----------------------------------------------------------------------------
# findings: forms and the import's health record
# -----------------------------------------------------------------------------

def test_findings_from_health_record():
    health = {"dead": ["/compass/heading"], "suspect": ["/imu/yaw_rate"],
              "channels": {"/compass/heading": {"status": "dead", "why": "heading moved 0.00 deg in all while the "
                                                "GNSS track turned 270 deg", "written_as": "/raw/compass/heading",
                                                "records": 100},
                           "/imu/yaw_rate": {"status": "suspect", "why": "yaw rate constant at 0 rad/s"},
                           "/gnss/fix": {"status": "ok", "gaps": 3, "longest_gap_s": 4.5, "rate_hz": 5.0,
                                         "time_disorder": 2, "out_of_range": 1, "records": 500},
                           "/thrust/command": {"status": "ok", "out_of_range": 7, "records": 900}},
              "heading_offset": {"decided": True, "offset_deg": 70.2, "std_deg": 0.4, "runs": 6, "courses": 4},
              "thrust": {"unit": "counts", "force_scale": "unknown", "reason": "no vessel"}}
    fs = findings_from_health(health, {"/gnss/fix": 1543})
    codes = {(f.severity, f.code, f.channel) for f in fs}
    assert ("error", "sensors.dead", "/compass/heading") in codes
    assert ("warning", "sensors.dead.suspect", "/imu/yaw_rate") in codes
    assert ("warning", "sensors.gaps", "/gnss/fix") in codes
    assert ("warning", "sensors.time_backwards", "/gnss/fix") in codes
    assert ("warning", "sensors.out_of_range", "/gnss/fix") in codes
    assert ("warning", "thrusters.out_of_range", "/thrust/command") in codes
    assert ("error", "heading.mounting_offset", "/compass/heading") in codes
    assert ("warning", "thrusters.force_scale", "/thrust/command") in codes
    assert ("info", "sensors.held", "/gnss/fix") in codes
    assert fs[0].severity == "error" and fs == sort_findings(fs)
    off = [f for f in fs if f.code == "heading.mounting_offset"][0]
    assert off.numbers["offset_deg"] == 70.2 and "/raw/compass/heading" in fs[0].evidence + fs[1].evidence
    assert findings_from_health(None) == [] and findings_from_health({}) == []


def test_finding_forms_table_json_junit():
    fs = [Finding(severity="info", code="sensors.rate", evidence="rates: /gnss/fix 10 Hz"),
          Finding(severity="error", code="thrusters.swapped", channel="/thrust/command", t0_s=0.0, t1_s=90.5,
                  evidence="left & right <swapped>", action="map them", numbers={"sign": -1}),
          Finding(severity="warning", code="heading.deviation.curve", channel="/compass/heading", t0_s=12.0,
                  evidence="amplitude 8.1 deg", numbers={"amplitude_deg": 8.1, "p": float("nan")})]
    table = format_table(fs)
    lines = table.splitlines()
    assert lines[0].split() == ["SEVERITY", "CHECK", "CHANNEL", "TIME"]
    assert lines[1].startswith("ERROR") and "0.0-90.5 s" in lines[1] and lines[-1] == "1 error(s), 1 warning(s), 1 info"
    d = json.loads(json.dumps([f.to_dict() for f in fs]))
    assert d[2]["numbers"]["p"] is None and d[2]["check"] == "heading.deviation"
    root = ET.fromstring(junit_xml(fs, ["sensors.rate", "thrusters.swapped", "heading.deviation", "sensors.gaps"]))
    cases = root.findall(".//testcase")
    assert len(cases) == 4 and root.get("failures") == "1"
    failed = [c for c in cases if c.find("failure") is not None]
    assert [(c.get("classname"), c.get("name")) for c in failed] == [("thrusters", "swapped")]
    assert "<swapped>" in failed[0].find("failure").get("message")
    dev = [c for c in cases if c.get("name") == "deviation"][0]
    assert dev.find("skipped") is None and "WARNING heading.deviation.curve" in dev.find("system-out").text
    with pytest.raises(ValueError):
        Finding(severity="fatal", code="x.y")
    with pytest.raises(ValueError):
        Finding(severity="info", code="x.y", t0_s=5.0, t1_s=1.0)


def test_an_estimated_log_shows_the_estimates_status_in_the_estimates_words():
    """One implementation: the estimate's status reasons stored in the log are check findings, word for word."""
    from usvlog.check import check_log
    from usvlog.estimate.core import estimate
    from usvlog.estimate.settings import EstimateSettings
    from usvlog.log.status import estimate_status
    from usvlog.sim.simulate import SimSettings, simulate

    log = simulate("turns", SimSettings(duration_s=120.0), seed=3)
    out = estimate(log, EstimateSettings(gps_only=True)).to_log(log)
    st = estimate_status(out)
    assert st is not None and st.status == "degraded" and st.reasons
    found = [f for f in check_log(out).findings if f.code == "estimate.degraded"]
    assert [f.evidence for f in found] == [f"estimate degraded ({st.mode}): {r}" for r in st.reasons]
    assert all(f.severity == "warning" and f.channel == "/estimate/state" for f in found)
    assert not [f for f in check_log(log).findings if f.code.startswith("estimate.")]


def test_sorted_unique_keeps_sorted_arrays_and_sorts_the_others():
    """The arrays themselves when already in time order without repeats; else sorted, the first of
    each time stamp kept."""
    from usvlog.check.common import _sorted_unique

    t, x = np.array([0.0, 1.0, 2.0]), np.array([5.0, 6.0, 7.0])
    a = _sorted_unique(t, x)
    assert a[0] is t and a[1] is x
    b = _sorted_unique(np.array([2.0, 0.0, 1.0, 1.0]), np.array([1.0, 2.0, 3.0, 4.0]))
    assert b[0].tolist() == [0.0, 1.0, 2.0] and b[1].tolist() == [2.0, 3.0, 1.0]


def test_smoothing_made_before_from_the_forces_alone_gives_the_same_findings(legs):
    """check_log with the run smoothed before (usvlog.check.smooth) on a copy whose commands hold
    only their forces (every row records both: all the smoothing reads of them): the same result."""
    from usvlog.check import smooth

    log = legs.copy()
    th = log["/thrust/command"]
    assert np.isfinite(th[["thrust_left_n", "thrust_right_n"]].to_numpy()).all()
    lean = log.copy()
    lean.set("/thrust/command", th[["thrust_left_n", "thrust_right_n"]])
    made = smooth(lean)
    assert made.states is not None and made.tau is not None
    assert check_log(log, smoothed=made).to_dict() == check_log(log).to_dict()
    no_compass = lean.copy()
    no_compass.channels.pop("/compass/heading")
    assert smooth(no_compass).states is None and smooth(no_compass).tau is None   # a channel missing
