"""The sensor health audit and thrust units, through the real CSV importer (and the CLI).

Each case is a CSV written here with a known truth: a fix republished three times, a
compass that reads 0 while the track turns 400 deg, +-255 commands with a -99360
outlier, 0..200 commands with a direction flag, impossible headings and thrusts.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from usvlog import api
from usvlog.cli import main
from usvlog.errors import ConfigError
from usvlog.io.importers import ImportOptions, import_file, parse_thrust_range
from usvlog.io.importers.audit import health_of
from usvlog.log.summary import format_summary

T0 = 1_714_557_600.0          # 2024-05-01T10:00:00Z, s
LAT0, LON0 = 59.0, 10.0
N_FIX = 120                   # fixes, 1 Hz
TURN_DEG = 400.0              # the track turns through this much
R_M = 30.0


def _track(k):
    """Position (deg) of fix k on a circle of R_M, turning TURN_DEG over the run."""
    ang = math.radians(TURN_DEG * k / (N_FIX - 1))
    n, e = R_M * math.sin(ang), R_M * (1 - math.cos(ang))
    return LAT0 + n / 111_320.0, LON0 + e / (111_320.0 * math.cos(math.radians(LAT0)))


def _commands(k):
    """Integer +-255 commands of row k (left, right)."""
    return (255 if k % 3 == 0 else -255 if k % 3 == 1 else (k * 7) % 511 - 255), 128


def foreign_csv(path, *, outlier=True):
    """Fixes at 1 Hz each written 3 times (0.1 s apart), a compass stuck at 0 at 5 Hz,
    +-255 commands at 1 Hz (and one -99360 outlier row)."""
    rows = ["time_s,lat,lon,heading_deg,thrust_left,thrust_right"]
    for k in range(N_FIX):
        lat, lon = _track(k)
        for c in range(3):
            rows.append(f"{T0 + k + 0.1 * c:.3f},{lat:.9f},{lon:.9f},,,")
        for j in range(5):
            rows.append(f"{T0 + k + 0.05 + 0.2 * j:.3f},,,0,,")
        left, right = _commands(k)
        rows.append(f"{T0 + k + 0.07:.3f},,,,{left},{right}")
        if outlier and k == 50:
            rows.append(f"{T0 + k + 0.08:.3f},,,,-99360,{right}")
    path.write_text("\n".join(rows) + "\n")
    return path


def test_foreign_csv_audit_end_to_end(tmp_path):
    src = foreign_csv(tmp_path / "boat.csv")
    res = import_file(src)
    log, rep = res.log, res.report
    # republished fixes: 3 records each; copies of the very first fix are kept (no move seen before it)
    assert len(log["/gnss/fix"]) == N_FIX + 2
    assert rep.skipped["gnss_republished"] == 2 * N_FIX - 2
    lat = np.array([_track(k)[0] for k in range(N_FIX)])
    got = log["/gnss/fix"]["lat_deg"].to_numpy()
    np.testing.assert_allclose(got[:3], lat[0], atol=1e-9)
    np.testing.assert_allclose(got[3:], lat[1:], atol=1e-9)
    # dead compass: not data, kept under /raw, flagged
    assert "/compass/heading" not in log
    raw = log["/raw/compass/heading"]
    assert len(raw) == 5 * N_FIX and (raw["heading_rad"] == 0).all()
    h = health_of(log)
    assert h["dead"] == ["/compass/heading"]
    ch = h["channels"]["/compass/heading"]
    assert ch["status"] == "dead" and ch["written_as"] == "/raw/compass/heading"
    assert ch["stuck_longest_s"] == pytest.approx(N_FIX - 1 + 0.8)
    assert h["track_turn_deg"] > 300
    assert h["channels"]["/gnss/fix"]["republished"] == 2 * N_FIX - 2
    # thrust: counts guessed, the outlier skipped and counted, written normalized
    assert rep.guesses["thrust_unit"] == "counts" and rep.guesses["thrust_range"] == "-255:255"
    assert rep.skipped["thrust_out_of_range"] == 1
    thr = log["/thrust/command"]
    want = np.array([_commands(k)[0] for k in range(N_FIX)]) / 255.0
    np.testing.assert_allclose(thr["left"].to_numpy(), want)
    assert set(thr["unit"]) == {"normalized"}
    assert h["thrust"]["unit"] == "counts" and h["thrust"]["range"] == [-255.0, 255.0]
    assert h["thrust"]["force_scale"] == "unknown"
    assert log.provenance[-1]["force_scale"] == "unknown"
    assert h["channels"]["/thrust/command"]["out_of_range"] == 1
    assert any("counts" in n for n in rep.notes)


def test_keep_dead_writes_the_dead_channel_as_data(tmp_path):
    res = import_file(foreign_csv(tmp_path / "boat.csv"), keep_dead=True)
    log = res.log
    assert len(log["/compass/heading"]) == 5 * N_FIX and "/raw/compass/heading" not in log
    h = health_of(log)
    assert h["dead"] == ["/compass/heading"] and h["keep_dead"]
    assert h["channels"]["/compass/heading"]["written_as"] == "/compass/heading"


def test_audit_does_not_depend_on_chunking(tmp_path):
    src = foreign_csv(tmp_path / "boat.csv")
    a = import_file(src)
    b = import_file(src, chunk_rows=7)
    assert a.report.skipped == b.report.skipped
    assert json.dumps(health_of(a.log), sort_keys=True) == json.dumps(health_of(b.log), sort_keys=True)
    for t in a.log.topics:
        assert a.log[t].equals(b.log[t]), t


def test_inspect_of_the_mcap_shows_the_audit(tmp_path):
    out = tmp_path / "boat.mcap"
    import_file(foreign_csv(tmp_path / "boat.csv"), out=out)
    s = api.inspect(out)
    assert s.health["dead"] == ["/compass/heading"]
    assert s.to_dict()["health"]["channels"]["/gnss/fix"]["republished"] == 2 * N_FIX - 2
    text = format_summary(s)
    assert "DEAD /compass/heading" in text and "written as /raw/compass/heading" in text
    assert "thrust unit counts range -255:255" in text and "force scale unknown" in text
    assert api.inspect(api.load(out)).health == s.health


def test_direction_flag_with_0_to_200_commands(tmp_path):
    rng = np.random.default_rng(3)
    mag = rng.integers(0, 201, 300)
    mag[0] = 200
    flag = rng.integers(0, 2, 300)
    rows = ["time_s,lat,lon,cmd_left,cmd_right,left_dir,right_dir"]
    for k in range(300):
        lat, lon = _track(k % N_FIX)
        rows.append(f"{T0 + k * 0.5:.3f},{lat:.9f},{lon:.9f},{mag[k]},{mag[::-1][k]},{flag[k]},0")
    src = tmp_path / "dir.csv"
    src.write_text("\n".join(rows) + "\n")
    res = import_file(src)
    thr = res.log["/thrust/command"]
    np.testing.assert_allclose(thr["left"].to_numpy(), np.where(flag == 1, -mag, mag) / 200.0)
    np.testing.assert_allclose(thr["right"].to_numpy(), mag[::-1] / 200.0)
    assert res.report.guesses["thrust_unit"] == "counts" and res.report.guesses["thrust_range"] == "-200:200"
    assert res.report.guesses["thrust_direction_flag"].startswith("0 forward")
    assert health_of(res.log)["thrust"]["direction_flag"] == "0/1"


def test_thrust_range_given_skips_outside_and_implies_counts(tmp_path):
    rows = ["time_s,lat,lon,thrust_left,thrust_right"]
    vals = [0, 50, 100, 101, -1, 100, 30]
    for k, v in enumerate(vals):
        lat, lon = _track(k)
        rows.append(f"{T0 + k:.3f},{lat:.9f},{lon:.9f},{v},{v}")
    src = tmp_path / "r.csv"
    src.write_text("\n".join(rows) + "\n")
    res = import_file(src, thrust_range="0:100")
    keep = [v for v in vals if 0 <= v <= 100]
    np.testing.assert_allclose(res.log["/thrust/command"]["left"].to_numpy(), np.array(keep) / 100.0)
    assert res.report.skipped["thrust_out_of_range"] == 2
    assert health_of(res.log)["thrust"]["reason"] == "--thrust-range"


def test_impossible_heading_and_thrust_skipped_and_counted(tmp_path):
    rows = ["time_s,lat,lon,heading_deg,thrust_left,thrust_right"]
    heads = [10.0, 1e300, 359.0, -359.5, 400.0, -1e300, 20.0]
    thrusts = [(1.5, 2.5), (1e300, 2.0), (-1e300, 1.0), (3.25, -1e300), (4.5, 4.5), (-2.5, 0.5), (0.0, 1.5)]
    for k in range(len(heads)):
        lat, lon = _track(k)
        rows.append(f"{T0 + k:.3f},{lat:.9f},{lon:.9f},{heads[k]!r},{thrusts[k][0]!r},{thrusts[k][1]!r}")
    src = tmp_path / "bad.csv"
    src.write_text("\n".join(rows) + "\n")
    res = import_file(src)
    rep = res.report
    assert rep.skipped["heading_out_of_range"] == 3
    assert rep.skipped["thrust_out_of_range"] == 3
    good_h = [h for h in heads if abs(h) <= 360]
    got = np.degrees(res.log["/compass/heading"]["heading_rad"].to_numpy())
    np.testing.assert_allclose(np.mod(got, 360), np.mod(good_h, 360), atol=1e-9)
    assert rep.guesses["thrust_unit"] == "newton"
    good_t = [t for t in thrusts if max(abs(t[0]), abs(t[1])) < 1e5]
    np.testing.assert_allclose(res.log["/thrust/command"]["left"].to_numpy(), [t[0] for t in good_t])
    h = health_of(res.log)
    assert h["channels"]["/compass/heading"]["out_of_range"] == 3
    assert h["thrust"]["force_scale"] == "known"


def test_cli_thrust_range_keep_dead_and_inspect(tmp_path, capsys):
    src = foreign_csv(tmp_path / "boat.csv", outlier=False)
    out = tmp_path / "o.mcap"
    assert main(["import", str(src), "--out", str(out), "--thrust-range=-255:255", "--keep-dead", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["health"]["thrust"]["reason"] == "--thrust-range"
    assert d["channels"]["/compass/heading"] == 5 * N_FIX
    assert main(["inspect", str(out), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["health"]["dead"] == ["/compass/heading"]
    assert main(["import", str(src), "--out", str(tmp_path / "x.mcap"), "--thrust-range", "5:1"]) == 2


def test_thrust_range_validation():
    assert parse_thrust_range("-255:255") == (-255.0, 255.0)
    for bad in ("255", "a:b", "5:1", "nan:1", "0:inf"):
        with pytest.raises(ConfigError):
            parse_thrust_range(bad)
    with pytest.raises(ConfigError):
        ImportOptions(thrust_unit="pwm_us", thrust_range=(0.0, 200.0))


def test_health_of_a_simulated_log_is_empty():
    from usvlog.log.fieldlog import FieldLog
    assert health_of(FieldLog()) == {}


def _clean_rows(n=200):
    rows = []
    for k in range(n):
        ang = math.radians(400.0 * k / (n - 1))
        lat = LAT0 + R_M * math.sin(ang) / 111_320.0
        lon = LON0 + R_M * (1 - math.cos(ang)) / (111_320.0 * math.cos(math.radians(LAT0)))
        rows.append([f"{T0 + 0.1 * k:.3f}", f"{lat:.9f}", f"{lon:.9f}", f"{(400.0 * k / (n - 1)) % 360:.3f}",
                     str((k * 37) % 511 - 255), str((k * 11) % 511 - 255)])
    return rows


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(row=st.integers(0, 199), col=st.sampled_from([1, 3, 4]),
       damage=st.sampled_from(["1e300", "-1e300", "nan", "", "-99360", "abc", "1e400"]))
def test_one_damaged_record_changes_only_its_own_sample(tmp_path, row, col, damage):
    header = "time_s,lat,lon,heading_deg,thrust_left,thrust_right"
    rows = _clean_rows()
    clean = tmp_path / "clean.csv"
    clean.write_text(header + "\n" + "\n".join(",".join(r) for r in rows) + "\n")
    rows[row][col] = damage
    bad = tmp_path / "bad.csv"
    bad.write_text(header + "\n" + "\n".join(",".join(r) for r in rows) + "\n")
    a, b = import_file(clean).log, import_file(bad).log
    hit = {1: "/gnss/fix", 3: "/compass/heading", 4: "/thrust/command"}[col]
    t_row = a[hit].index[row]
    assert sorted(a.topics) == sorted(b.topics)
    for topic in a.topics:
        want = a[topic].drop(index=t_row) if topic == hit else a[topic]
        assert want.equals(b[topic]), (topic, damage)


def test_ros2_bag_fix_republished_with_the_same_header_stamp(tmp_path):
    """Through the real ROS 2 reader: each NavSatFix sent 3 times (record times 0.2, 0.25, 0.3 s
    after its header stamp), an Imu whose orientation never moves while the track turns 400 deg,
    +-255 thruster commands with a -99360 outlier."""
    rosbag2 = pytest.importorskip("rosbags.rosbag2")
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    T = store.types
    Time, Header = T["builtin_interfaces/msg/Time"], T["std_msgs/msg/Header"]
    V3, Q = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"]
    t0 = int(T0) * 1_000_000_000
    s = 1_000_000_000
    msgs = []
    for k in range(N_FIX):
        lat, lon = _track(k)
        st = t0 + k * s
        hdr = Header(stamp=Time(sec=st // s, nanosec=st % s), frame_id="gps")
        fix = T["sensor_msgs/msg/NavSatFix"](
            header=hdr, status=T["sensor_msgs/msg/NavSatStatus"](status=0, service=1), latitude=lat, longitude=lon,
            altitude=1.0, position_covariance=np.zeros(9), position_covariance_type=0)
        for c in range(3):
            msgs.append(("/gps/fix", "sensor_msgs/msg/NavSatFix", st + 200_000_000 + c * 50_000_000, fix))
        for j in range(5):
            ti = st + j * 200_000_000 + 10_000_000
            hdr = Header(stamp=Time(sec=ti // s, nanosec=ti % s), frame_id="imu")
            msgs.append(("/imu/data", "sensor_msgs/msg/Imu", ti, T["sensor_msgs/msg/Imu"](
                header=hdr, orientation=Q(x=0.0, y=0.0, z=0.0, w=1.0), orientation_covariance=np.zeros(9),
                angular_velocity=V3(x=0.0, y=0.0, z=0.01 * ((k + j) % 7)), angular_velocity_covariance=np.zeros(9),
                linear_acceleration=V3(x=0.0, y=0.0, z=9.81), linear_acceleration_covariance=np.zeros(9))))
        left = -99360.0 if k == 50 else float(_commands(k)[0])
        msgs.append(("/thrusters/left", "std_msgs/msg/Float64", st + 30_000_000, T["std_msgs/msg/Float64"](data=left)))
        msgs.append(("/thrusters/right", "std_msgs/msg/Float64", st + 30_001_000,
                     T["std_msgs/msg/Float64"](data=float(_commands(k)[1]))))
    bag = tmp_path / "bag"
    with rosbag2.Writer(bag, version=9, storage_plugin=rosbag2.StoragePlugin.MCAP) as w:
        conns = {}
        for topic, typ, t, m in sorted(msgs, key=lambda x: x[2]):
            if topic not in conns:
                conns[topic] = w.add_connection(topic, typ, typestore=store)
            w.write(conns[topic], t, store.serialize_cdr(m, typ))
    res = import_file(bag, topics={"thrust_left": "/thrusters/left.data", "thrust_right": "/thrusters/right.data"})
    log, rep = res.log, res.report
    h = health_of(log)
    # the same-stamp rule needs no move: every copy goes, the very first fix's too
    assert len(log["/gnss/fix"]) == N_FIX and rep.skipped["gnss_republished"] == 2 * N_FIX
    assert h["channels"]["/gnss/fix"]["republished_same_stamp"] == 2 * N_FIX
    assert h["channels"]["/gnss/fix"]["stamp_offset_s"]["median"] == pytest.approx(-0.2)
    assert h["channels"]["/gnss/fix"]["rate_hz"] == pytest.approx(1.0) and h["channels"]["/gnss/fix"]["gaps"] == 0
    assert h["dead"] == ["/compass/heading"] and "/compass/heading" not in log
    assert len(log["/raw/compass/heading"]) == 5 * N_FIX
    assert h["channels"]["/imu/yaw_rate"]["status"] == "ok" and len(log["/imu/yaw_rate"]) == 5 * N_FIX
    assert rep.guesses["thrust_unit"] == "counts" and rep.skipped["thrust_out_of_range"] == 1
    # the reader pairs each left command with the last right one: the first left has none yet
    assert rep.skipped["thrust_incomplete"] == 1
    assert len(log["/thrust/command"]) == N_FIX - 2


def test_a_wrong_thrust_unit_is_pointed_out(tmp_path):
    src = foreign_csv(tmp_path / "boat.csv", outlier=False)
    res = import_file(src, thrust_unit="pwm_us")
    assert res.report.skipped["thrust_out_of_range"] == N_FIX
    assert "/thrust/command" not in res.log
    assert any("is the unit right" in n for n in res.report.notes)
