"""ROS 1 and ROS 2 bags written with rosbags' own writers, imported back."""

from __future__ import annotations

import math

import numpy as np
import pytest

from usvlog.cli import main
from usvlog.errors import FormatError, InputError
from usvlog.io.importers import detect_format, import_file

T0 = 1_714_557_600_000_000_000  # 2024-05-01T10:00:00Z
N = 20                           # 2 s of 10 Hz fixes
LAT = 59.1 + 1e-5 * np.arange(N) + 1.234567e-8
LON = 10.2 + 2e-5 * np.arange(N) - 3.21e-9
PSI = np.linspace(-3.0, 3.0, N)  # NED heading, rad
WZ = np.linspace(-0.5, 0.5, N)   # FLU yaw rate
STAMP_LAG = 3_000_000            # header stamps 3 ms before the record time

CUSTOM_MSG2 = """std_msgs/msg/Header header
float64 heading_deg
test_msgs/msg/BoatPose pose
"""
BOATPOSE = "float64 lat\nfloat64 lon\n"


def _typestore(ros1: bool):
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    types = {}
    types.update(get_types_from_msg(BOATPOSE, "test_msgs/msg/BoatPose"))
    types.update(get_types_from_msg(CUSTOM_MSG2, "test_msgs/msg/BoatState"))
    store.register(types)
    return store


def _messages(store, nofix_every: int = 0):
    T = store.types
    Time = T["builtin_interfaces/msg/Time"]
    Header = T["std_msgs/msg/Header"]
    out = []  # (topic, msgtype, t_ns, msg)
    for i in range(N):
        t = T0 + i * 100_000_000
        st = t - STAMP_LAG
        hdr = Header(stamp=Time(sec=st // 10**9, nanosec=st % 10**9), frame_id="gps", **(
            {"seq": i} if "seq" in Header.__dataclass_fields__ else {}))
        status = T["sensor_msgs/msg/NavSatStatus"](status=-1 if nofix_every and i % nofix_every == 0 else 0,
                                                    service=1)
        cov = np.array([0.25, 0, 0, 0, 0.25, 0, 0, 0, 1.0])
        out.append(("/gps/fix", "sensor_msgs/msg/NavSatFix", t, T["sensor_msgs/msg/NavSatFix"](
            header=hdr, status=status, latitude=LAT[i], longitude=LON[i], altitude=12.5,
            position_covariance=cov, position_covariance_type=2)))
        yaw_enu = math.pi / 2 - PSI[i]
        q = T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(yaw_enu / 2), w=math.cos(yaw_enu / 2))
        V3 = T["geometry_msgs/msg/Vector3"]
        out.append(("/imu/data", "sensor_msgs/msg/Imu", t + 5_000_000, T["sensor_msgs/msg/Imu"](
            header=hdr, orientation=q, orientation_covariance=np.zeros(9), angular_velocity=V3(x=0.0, y=0.0, z=WZ[i]),
            angular_velocity_covariance=np.zeros(9), linear_acceleration=V3(x=0.0, y=0.0, z=9.81),
            linear_acceleration_covariance=np.zeros(9))))
        F64 = T["std_msgs/msg/Float64"]
        out.append(("/thrust/right_cmd", "std_msgs/msg/Float64", t + 6_000_000, F64(data=0.5 - 0.01 * i)))
        out.append(("/thrust/left_cmd", "std_msgs/msg/Float64", t + 7_000_000, F64(data=0.1 + 0.01 * i)))
        pose = T["test_msgs/msg/BoatPose"](lat=LAT[i], lon=LON[i])
        out.append(("/boat/state", "test_msgs/msg/BoatState", t + 8_000_000, T["test_msgs/msg/BoatState"](
            header=hdr, heading_deg=math.degrees(PSI[i]) % 360.0, pose=pose)))
    return out


def _fill(writer, store, msgs, serialize):
    with writer as w:
        conns = {}
        for topic, typ, t, m in msgs:
            if topic not in conns:
                conns[topic] = w.add_connection(topic, typ, typestore=store)
            w.write(conns[topic], t, serialize(m, typ))


def write_ros1(path, nofix_every=0):
    from rosbags.rosbag1 import Writer

    store = _typestore(True)
    _fill(Writer(path), store, _messages(store, nofix_every), store.serialize_ros1)
    return path


def write_ros2(path, storage: str, nofix_every=0):
    from rosbags.rosbag2 import StoragePlugin, Writer

    store = _typestore(False)
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    _fill(Writer(path, version=9, storage_plugin=plugin), store, _messages(store, nofix_every), store.serialize_cdr)
    return path


@pytest.fixture(params=["ros1", "ros2-sqlite3", "ros2-mcap"])
def bag(request, tmp_path):
    if request.param == "ros1":
        return "ros1", write_ros1(tmp_path / "run.bag")
    return "ros2", write_ros2(tmp_path / "run2", request.param.split("-")[1])


def test_bag_round_trip(bag):
    fmt, path = bag
    assert detect_format(path) == fmt
    res = import_file(path)
    log = res.log
    g = log["/gnss/fix"]
    t = T0 + np.arange(N) * 100_000_000
    np.testing.assert_array_equal(g.index.to_numpy(), t)
    np.testing.assert_array_equal(g["stamp_ns"].to_numpy(), t - STAMP_LAG)  # header stamp kept apart
    np.testing.assert_allclose(g["lat_deg"], LAT, atol=1e-7, rtol=0)
    np.testing.assert_allclose(g["lon_deg"], LON, atol=1e-7, rtol=0)
    assert (g["cov_ee_m2"] == 0.25).all() and (g["cov_type"] == 2).all() and (g["alt_m"] == 12.5).all()
    h = log["/compass/heading"]
    assert len(h) == N
    np.testing.assert_allclose(h["heading_rad"], PSI, atol=1e-6, rtol=0)
    r = log["/imu/yaw_rate"]
    np.testing.assert_allclose(r["r_radps"], -WZ, atol=1e-12)  # FLU -> FRD
    th = log["/thrust/command"]
    np.testing.assert_allclose(th["left"], 0.1 + 0.01 * np.arange(N), atol=1e-12)
    np.testing.assert_allclose(th["right"], 0.5 - 0.01 * np.arange(N), atol=1e-12)
    assert set(th["unit"]) == {"normalized"}
    assert res.report.mapping["gnss"] == "/gps/fix" and res.report.mapping["heading"] == "/imu/data.orientation"
    assert log.datum.lat_deg == pytest.approx(LAT[0], abs=1e-12)


def test_bag_custom_type_field_paths(bag):
    fmt, path = bag
    res = import_file(path, topics={"gnss": "/boat/state.pose", "heading": "/boat/state.heading_deg"})
    log = res.log
    g = log["/gnss/fix"]
    np.testing.assert_allclose(g["lat_deg"], LAT, atol=1e-7, rtol=0)
    np.testing.assert_allclose(g["lon_deg"], LON, atol=1e-7, rtol=0)
    np.testing.assert_array_equal(g.index.to_numpy() - g["stamp_ns"].to_numpy(), STAMP_LAG + 8_000_000)
    from usvlog.model.frames import ssa

    np.testing.assert_allclose(ssa(log["/compass/heading"]["heading_rad"] - PSI), 0.0, atol=1e-6)
    assert res.report.guesses["heading_unit"] == "deg"


def test_bag_no_fix_skipped_and_counted(tmp_path):
    path = write_ros1(tmp_path / "nofix.bag", nofix_every=4)
    res = import_file(path)
    assert len(res.log["/gnss/fix"]) == N - N // 4
    assert res.report.skipped["gnss_no_fix"] == N // 4


def test_bag_missing_topic_one_line_error(tmp_path, capsys):
    path = write_ros2(tmp_path / "b", "sqlite3")
    with pytest.raises(InputError, match="/nope"):
        import_file(path, topics={"gnss": "/nope"})
    out = tmp_path / "o.mcap"
    assert main(["import", str(path), "--out", str(out), "--topic", "heading=/boat/state.no_such"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert "no_such" in err[-1] and not out.exists()


def test_truncated_bag_one_line_error(tmp_path, capsys):
    path = write_ros1(tmp_path / "full.bag")
    cut = tmp_path / "cut.bag"
    cut.write_bytes(path.read_bytes()[:3000])
    out = tmp_path / "o.mcap"
    rc = main(["import", str(cut), "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and "cut.bag" in err[-1] and not out.exists()


def test_wrong_format_forced(tmp_path):
    path = write_ros1(tmp_path / "x.bag")
    with pytest.raises(FormatError, match="x.bag"):
        import_file(path, "ros2")
    with pytest.raises((FormatError, InputError), match="x.bag"):
        import_file(path, "ulog")


@pytest.mark.parametrize("msgtype, wrap", [
    ("geometry_msgs/msg/QuaternionStamped", lambda T, h, q: dict(header=h, quaternion=q)),
    ("geometry_msgs/msg/PoseStamped", lambda T, h, q: dict(header=h, pose=T["geometry_msgs/msg/Pose"](
        position=T["geometry_msgs/msg/Point"](x=0.0, y=0.0, z=0.0), orientation=q))),
])
def test_orientation_messages_guessed_as_heading(tmp_path, msgtype, wrap):
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    T = store.types
    path = tmp_path / "pose_bag"
    with Writer(path, version=9) as w:
        conn = w.add_connection("/boat/pose", msgtype, typestore=store)
        for i in range(N):
            t = T0 + i * 50_000_000
            h = T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=t // 10**9, nanosec=t % 10**9),
                                         frame_id="map")
            yaw_enu = math.pi / 2 - PSI[i]
            q = T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(yaw_enu / 2), w=math.cos(yaw_enu / 2))
            w.write(conn, t, store.serialize_cdr(T[msgtype](**wrap(T, h, q)), msgtype))
    res = import_file(path)
    assert res.report.mapping["heading"].startswith("/boat/pose.")
    np.testing.assert_allclose(res.log["/compass/heading"]["heading_rad"], PSI, atol=1e-6)


def test_ros2_directory_forced_as_ros1(tmp_path):
    path = write_ros2(tmp_path / "b2", "sqlite3")
    with pytest.raises(FormatError, match="b2: not a ROS 1 bag"):
        import_file(path, "ros1")
