"""The real PX4 ULog and ArduSub DataFlash logs in tests/data/real/ imported and catalogued.

Sources (licences beside the files): ``px4_sample_log_small.ulg`` is PX4/pyulog's
``test/sample_log_small.ulg`` (BSD-3-Clause, LICENSE.pyulog.md); ``ardusub_small.BIN`` is
clydemcqueen/ardusub_log_tools' ``testing/small.BIN`` (MIT, LICENSE.ardusub_log_tools.txt).

Every expected count and value is read here independently with pyulog / pymavlink
(and the heading from the quaternion with scipy), never from usvlog.
"""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from usvlog.cli import main
from usvlog.errors import InputError
from usvlog.io.importers import ImportOptions, import_file
from usvlog.io.importers import dataflash as df_reader
from usvlog.io.importers import ulog as ulog_reader
from usvlog.model.frames import ssa

REAL = Path(__file__).resolve().parents[1] / "data" / "real"
ULG = REAL / "px4_sample_log_small.ulg"
BIN = REAL / "ardusub_small.BIN"
SCHEMA = Path(__file__).resolve().parents[2] / "schemas" / "foxglove.LocationFix.json"


# ----------------------------------------------------------------------------- independent truth
@pytest.fixture(scope="module")
def px4():
    from pyulog import ULog

    return ULog(str(ULG))


def _ds(u, name, inst=0):
    return next(d for d in u.data_list if d.name == name and d.multi_id == inst)


@pytest.fixture(scope="module")
def ardu():
    """Every message of the .BIN as pymavlink decodes it, in file order."""
    from pymavlink.DFReader import DFReader_binary

    log = DFReader_binary(str(BIN), zero_time_base=True)
    out = []
    while (m := log.recv_msg()) is not None:
        out.append(m.to_dict())
    return out


@pytest.fixture(scope="module")
def ulog_import():
    return import_file(ULG)


# ----------------------------------------------------------------------------- ULog
def test_ulog_counts_and_values_match_pyulog(px4, ulog_import):
    res = ulog_import
    log = res.log
    gps = _ds(px4, "vehicle_gps_position")
    fixes = gps.data["fix_type"] >= 3
    assert fixes.sum() == 32
    g = log["/gnss/fix"]
    assert len(g) == int(fixes.sum())
    np.testing.assert_allclose(g["lat_deg"], gps.data["lat"][fixes] * 1e-7, atol=1e-9, rtol=0)
    np.testing.assert_allclose(g["lon_deg"], gps.data["lon"][fixes] * 1e-7, atol=1e-9, rtol=0)
    np.testing.assert_allclose(g["alt_m"], gps.data["alt_ellipsoid"][fixes] * 1e-3)
    # UTC: every fix's own receiver time within 20 ms of its log time (one offset for the whole log)
    utc_ns = gps.data["time_utc_usec"][fixes].astype(np.int64) * 1000
    assert np.abs(g.index.to_numpy() - utc_ns).max() < 20_000_000
    # attitude: yaw of the quaternion, by scipy (scalar-last order)
    from scipy.spatial.transform import Rotation

    att = _ds(px4, "vehicle_attitude")
    q = np.column_stack([att.data[f"q[{i}]"] for i in (1, 2, 3, 0)])
    yaw = Rotation.from_quat(q).as_euler("ZYX")[:, 0]
    h = log["/compass/heading"]
    assert len(h) == len(att.data["timestamp"]) == 1298
    np.testing.assert_allclose(ssa(h["heading_rad"].to_numpy() - yaw), 0.0, atol=1e-5)
    # thrust: actuator_outputs instance 0 (the one whose outputs move), output[0]/output[1]
    ao = _ds(px4, "actuator_outputs", 0)
    th = log["/thrust/command"]
    assert len(th) == len(ao.data["timestamp"]) == 65
    np.testing.assert_array_equal(th["left"], ao.data["output[0]"])
    np.testing.assert_array_equal(th["right"], ao.data["output[1]"])
    av = _ds(px4, "vehicle_angular_velocity")
    r = log["/imu/yaw_rate"]
    assert len(r) == len(av.data["timestamp"])
    np.testing.assert_allclose(r["r_radps"], av.data["xyz[2]"], rtol=1e-6)
    v = log["/gnss/velocity"]
    assert len(v) == int((fixes & gps.data["vel_ned_valid"].astype(bool)).sum())
    np.testing.assert_allclose(v["sog_mps"], gps.data["vel_m_s"][fixes], rtol=1e-6)
    assert res.report.skipped == Counter()


def test_ulog_fix_covariance_from_eph_epv_diagonal_known(px4, ulog_import):
    schema = json.loads(SCHEMA.read_text())
    desc = schema["properties"]["position_covariance_type"]["description"]
    diagonal_known = int(desc.split("DIAGONAL_KNOWN")[0].split()[-1])   # "... 2 DIAGONAL_KNOWN ..."
    assert diagonal_known == 2
    gps = _ds(px4, "vehicle_gps_position")
    g = ulog_import.log["/gnss/fix"]
    eph = gps.data["eph"].astype(float)
    epv = gps.data["epv"].astype(float)
    assert 2.5 <= eph.min() and eph.max() <= 3.3
    np.testing.assert_allclose(g["cov_ee_m2"], eph ** 2, rtol=1e-6)
    np.testing.assert_allclose(g["cov_nn_m2"], eph ** 2, rtol=1e-6)
    np.testing.assert_allclose(g["cov_uu_m2"], epv ** 2, rtol=1e-6)
    for c in ("cov_en_m2", "cov_eu_m2", "cov_ne_m2", "cov_nu_m2", "cov_ue_m2", "cov_un_m2"):
        assert (g[c] == 0).all()
    assert set(g["cov_type"]) == {diagonal_known}


def test_ulog_catalog_lists_every_topic_instance_and_field(px4):
    cat = ulog_reader.catalog(ULG, ImportOptions())
    expected = {(d.name, d.multi_id): len(d.data["timestamp"]) for d in px4.data_list}
    assert len(expected) == 70 and len({n for n, _ in expected}) == 55   # 55 topics, 70 instances
    assert len(cat.topics) == len(expected)
    multi = {n for n, i in expected if i > 0}
    for (name, inst), count in expected.items():
        t = cat.topic(f"{name}.{inst}" if name in multi else name)
        assert t is not None and t.count == count and t.type == name
        d = _ds(px4, name, inst)
        leaves = {f.field_name for f in d.field_data}
        listed = set()
        for f in t.fields:
            listed |= {f"{f.path}[{i}]" for i in range(f.length)} if f.length else {f.path}
        assert listed == leaves, name
    q = next(f for f in cat.topic("vehicle_attitude").fields if f.path == "q")
    assert q.length == 4 and q.type == "float"
    assert cat.time_base == "utc"
    assert cat.mapping["thrust_left"] == "actuator_outputs.0.output[0]"
    assert "actuator_outputs.1" in cat.reasons["thrust"]    # both instances weighed, the choice explained


def test_ulog_topic_yaw_rate_honoured(px4):
    sc = _ds(px4, "sensor_combined")
    res = import_file(ULG, topics={"yaw_rate": "sensor_combined.gyro_rad[2]"})
    r = res.log["/imu/yaw_rate"]
    assert len(r) == len(sc.data["timestamp"]) == 1298
    np.testing.assert_allclose(r["r_radps"], sc.data["gyro_rad[2]"], rtol=1e-6)
    assert res.report.mapping["yaw_rate"] == "sensor_combined.gyro_rad[2]"
    assert "topic yaw_rate" not in res.report.guesses
    prov = res.log.provenance[-1]
    assert json.loads(prov["mapping"])["yaw_rate"] == "sensor_combined.gyro_rad[2]"


def test_ulog_topic_honoured_for_other_roles(px4):
    ao1 = _ds(px4, "actuator_outputs", 1)
    res = import_file(ULG, topics={"thrust_left": "actuator_outputs.1.output[1]",
                                   "thrust_right": "actuator_outputs.1.output[2]",
                                   "heading": "vehicle_local_position.heading"})
    th = res.log["/thrust/command"]
    np.testing.assert_array_equal(th["left"], ao1.data["output[1]"])
    np.testing.assert_array_equal(th["right"], ao1.data["output[2]"])
    lp = _ds(px4, "vehicle_local_position")
    h = res.log["/compass/heading"]
    assert len(h) == len(lp.data["timestamp"])
    np.testing.assert_allclose(h["heading_rad"], ssa(lp.data["heading"].astype(float)), atol=1e-6)
    assert res.report.mapping["heading"] == "vehicle_local_position.heading"


@pytest.mark.parametrize(("topics", "match"), [
    ({"yaw_rate": "vehicle_angular_velocity.xyz[7]"}, r"has no field 'xyz\[7\]' \(fields of .*xyz\[2\]"),
    ({"yaw_rate": "vehicle_angular_velocity.xyz"}, None),
    ({"heading": "no_such_topic.yaw"}, r"topic no_such_topic is not in the log \(topics: .*yaw_estimator_status"),
    ({"thrust_left": "actuator_outputs.3.output[0]", "thrust_right": "actuator_outputs.3.output[1]"},
     r"no instance 3 \(instances: 0, 1\)"),
    ({"gnss": "vehicle_attitude"}, r"no lat/lon fields"),
    ({"yaw_rate": "vehicle_gps_position"}, r"name the yaw rate field"),
])
def test_ulog_topic_that_cannot_be_honoured_is_one_line(topics, match):
    if match is None:   # an array with 3 elements: its z component is meant
        res = import_file(ULG, topics=topics)
        assert res.report.mapping["yaw_rate"] == "vehicle_angular_velocity.xyz[2]"
        return
    with pytest.raises(InputError, match=match) as ei:
        import_file(ULG, topics=topics)
    assert "\n" not in str(ei.value) and "px4_sample_log_small.ulg" in str(ei.value)
    if "no_such_topic" in str(topics):   # every one of the 70 topic instances is listed
        assert str(ei.value).count(", ") >= 69 and "in all" not in str(ei.value)


# ----------------------------------------------------------------------------- DataFlash
def test_dataflash_counts_match_pymavlink_and_no_gnss(ardu, tmp_path, capsys):
    counts = Counter(m["mavpackettype"] for m in ardu)
    assert counts["GPS"] == 0 and counts["ATT"] == counts["RCOU"] == 237
    res = import_file(BIN)
    assert "no GNSS in this log (no GPS messages)" in res.report.notes
    assert "gnss" not in res.report.mapping and "speed_mps" not in res.report.mapping
    assert "/gnss/fix" not in res.log.topics
    prov = json.loads(res.log.provenance[-1]["mapping"])
    assert "gnss" not in prov and set(prov) == set(res.report.mapping)
    att = [m for m in ardu if m["mavpackettype"] == "ATT"]
    h = res.log["/compass/heading"]
    assert len(h) == len(att)
    np.testing.assert_allclose(ssa(h["heading_rad"].to_numpy() - np.radians([m["Yaw"] for m in att])), 0, atol=1e-9)
    imu = [m for m in ardu if m["mavpackettype"] == "IMU" and m["I"] == 0]
    r = res.log["/imu/yaw_rate"]
    assert len(r) == len(imu)
    np.testing.assert_allclose(r["r_radps"], [m["GyrZ"] for m in imu], rtol=1e-6)
    # ArduSub motors are SERVOn_FUNCTION 33..38: no thrust unless asked
    assert "/thrust/command" not in res.log.topics
    assert any("SERVO1_FUNCTION=33" in n for n in res.report.notes)
    # the CLI says it too
    rc = main(["import", str(BIN), "--out", str(tmp_path / "o.mcap")])
    out = capsys.readouterr()
    assert rc == 0 and "note      no GNSS in this log" in out.out
    assert "gnss" not in out.err


def test_dataflash_topic_thrust_channels_and_yaw_rate_honoured(ardu):
    res = import_file(BIN, topics={"thrust_left": "RCOU.C1", "thrust_right": "RCOU.C2", "yaw_rate": "RATE.Y"})
    rcou = [m for m in ardu if m["mavpackettype"] == "RCOU"]
    th = res.log["/thrust/command"]
    assert len(th) == len(rcou) == 237
    np.testing.assert_array_equal(th["left"], [m["C1"] for m in rcou])
    np.testing.assert_array_equal(th["right"], [m["C2"] for m in rcou])
    assert set(th["unit"]) == {"pwm_us"}            # RCOU's FMTU unit is us
    np.testing.assert_array_equal(th.index.to_numpy() // 1000, [m["TimeUS"] for m in rcou])
    rate = [m for m in ardu if m["mavpackettype"] == "RATE"]
    r = res.log["/imu/yaw_rate"]
    np.testing.assert_allclose(r["r_radps"], np.radians([m["Y"] for m in rate]), rtol=1e-6)   # deg/s in the log
    assert res.report.mapping == {"heading": "ATT.Yaw", "yaw_rate": "RATE.Y",
                                  "thrust_left": "RCOU.C1", "thrust_right": "RCOU.C2"}
    assert not any(k.startswith("topic thrust") or k == "topic yaw_rate" for k in res.report.guesses)


@pytest.mark.parametrize(("topics", "match"), [
    ({"thrust_left": "RCOU.C99", "thrust_right": "RCOU.C2"}, r"RCOU has no field 'C99' \(fields: TimeUS, C1, .*C14\)"),
    ({"thrust_left": "RCOU.C1"}, "give both"),
    ({"gnss": "GPS"}, r"no GPS messages in the log \(messages: AHR2, .*XKV2\)"),
    ({"heading": "ATT.1.Yaw"}, "ATT has no instance field"),
    ({"yaw_rate": "IMU"}, "name the rate field"),
])
def test_dataflash_topic_that_cannot_be_honoured_is_one_line(topics, match):
    with pytest.raises(InputError, match=match) as ei:
        import_file(BIN, topics=topics)
    assert "\n" not in str(ei.value) and "ardusub_small.BIN" in str(ei.value)


def test_dataflash_catalog_lists_every_message(ardu):
    cat = df_reader.catalog(BIN, ImportOptions())
    counts = Counter(m["mavpackettype"] for m in ardu)
    by_type = Counter()
    for t in cat.topics:
        by_type[t.type] += t.count
    assert by_type == counts
    assert len({t.type for t in cat.topics}) == len(counts) == 39
    baro = [t.name for t in cat.topics if t.type == "BARO"]
    assert baro == ["BARO.0", "BARO.1"]       # two instances, counted apart
    rcou = cat.topic("RCOU")
    assert [f.path for f in rcou.fields] == ["TimeUS"] + [f"C{i}" for i in range(1, 15)]
    assert rcou.fields[1].type == "uint16" and rcou.fields[1].sample == 1500
    assert rcou.rate_hz == pytest.approx(10.0, rel=0.01)
    assert "gnss" not in cat.mapping and cat.reasons["gnss"].startswith("no GNSS in this log")
    assert "no GNSS in this log (no GPS messages)" in cat.notes


def test_start_utc_places_the_first_sample_of_a_log_without_gps_time():
    from pymavlink import mavutil

    start = 1_714_557_600_000_000_000          # 2024-05-01T10:00:00Z
    log = import_file(BIN, start_utc=start).log
    first = min(int(f.index[0]) for f in log.channels.values() if len(f))
    assert first == start
    # the boot-time spacing of the headings (ATT TimeUS, read by pymavlink) is kept
    mlog = mavutil.mavlink_connection(str(BIN))
    t_att = []
    while (m := mlog.recv_match(type="ATT")) is not None:
        t_att.append(m.TimeUS)
    hd = log["/compass/heading"]
    assert hd.index[0] >= start
    np.testing.assert_array_equal(hd.index.to_numpy() - hd.index[0], (np.asarray(t_att) - t_att[0]) * 1000)
