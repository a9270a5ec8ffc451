"""Positions in metres from bags written with rosbags: odometry in ROS ENU, a Pose2D not named NED,
and a motion-capture array mapped by hand (``--topic local_n=/mocap.data[0]``).

Truth: the trajectory written (a 20 m circle driven at 1 m/s, heading along the track).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from usvlog.cli import main
from usvlog.io.importers import import_file
from usvlog.model.frames import ssa

T0 = 1_714_557_600_000_000_000
N = 300                      # 10 Hz, 30 s
DT = 100_000_000
R = 10.0
_A = np.arange(N) * (1.0 / R) * 0.1        # angle on the circle (1 m/s)
NORTH = R * np.sin(_A)                     # starts heading north, turns to starboard (east)
EAST = R * (1.0 - np.cos(_A))
PSI = ssa(_A)                              # clockwise from north, along the track
TIMES = T0 + DT * np.arange(N)


def _store(ros1: bool):
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)


def _write(path, msgs, ros1: bool):
    store = _store(ros1)
    if ros1:
        from rosbags.rosbag1 import Writer

        writer, ser = Writer(path), store.serialize_ros1
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        writer, ser = Writer(path, version=9, storage_plugin=StoragePlugin.SQLITE3), store.serialize_cdr
    with writer as w:
        conns = {}
        for topic, typ, t, make in msgs:
            if topic not in conns:
                conns[topic] = w.add_connection(topic, typ, typestore=store)
            w.write(conns[topic], t, ser(make(store.types), typ))
    return path


def _header(T, t, ros1):
    kw = {"seq": 0} if ros1 else {}
    return T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=t // 10**9, nanosec=t % 10**9),
                                    frame_id="odom", **kw)


def _odometry(T, i, ros1):
    yaw_enu = math.pi / 2 - PSI[i]   # REP-103: counter-clockwise from east
    q = T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(yaw_enu / 2), w=math.cos(yaw_enu / 2))
    p = T["geometry_msgs/msg/Point"](x=EAST[i], y=NORTH[i], z=0.0)
    pose = T["geometry_msgs/msg/PoseWithCovariance"](pose=T["geometry_msgs/msg/Pose"](position=p, orientation=q),
                                                      covariance=np.zeros(36))
    v3 = T["geometry_msgs/msg/Vector3"]
    tw = T["geometry_msgs/msg/TwistWithCovariance"](
        twist=T["geometry_msgs/msg/Twist"](linear=v3(x=1.0, y=0.0, z=0.0), angular=v3(x=0.0, y=0.0, z=0.0)),
        covariance=np.zeros(36))
    return T["nav_msgs/msg/Odometry"](header=_header(T, int(TIMES[i]), ros1), child_frame_id="base_link", pose=pose,
                                      twist=tw)


def _float(value):
    return lambda T: T["std_msgs/msg/Float64"](data=float(value))


def _thrust(i):
    return [("/motors/left_cmd", "std_msgs/msg/Float64", int(TIMES[i]) + 1, _float(12.0)),
            ("/motors/right_cmd", "std_msgs/msg/Float64", int(TIMES[i]) + 2, _float(8.0))]


def test_odometry_in_enu_gives_north_east_and_the_heading(tmp_path):
    """nav_msgs/Odometry (ENU): x east, y north; its orientation is the heading; a controller's
    heading error (a continuous angle-like signal) does not take the heading's place."""
    ros1 = False
    msgs = []
    for i in range(N):
        msgs.append(("/odom", "nav_msgs/msg/Odometry", int(TIMES[i]), lambda T, i=i: _odometry(T, i, ros1)))
        msgs.append(("/controller/heading_error", "std_msgs/msg/Float64", int(TIMES[i]) + 3,
                     _float(0.1 * math.sin(i / 10.0))))
        msgs += _thrust(i)
    bag = _write(tmp_path / "odom", msgs, ros1)
    res = import_file(bag)
    m = res.report.mapping
    assert (m["local_n"], m["local_e"]) == ("/odom.pose.pose.position.y", "/odom.pose.pose.position.x")
    assert m["heading"] == "/odom.pose.pose.orientation"
    assert res.report.guesses["local_frame"] == "enu"
    lp = res.log["/local/position"]
    np.testing.assert_allclose(lp["n_m"], NORTH, atol=1e-9)
    np.testing.assert_allclose(lp["e_m"], EAST, atol=1e-9)
    h = res.log["/compass/heading"]["heading_rad"].to_numpy()
    np.testing.assert_allclose(ssa(h - PSI), 0.0, atol=1e-6)


def test_pose2d_not_named_ned_is_read_as_ros_enu(tmp_path):
    ros1 = True
    msgs = []
    for i in range(N):
        theta = math.pi / 2 - PSI[i]
        msgs.append(("/ins/pose", "geometry_msgs/msg/Pose2D", int(TIMES[i]),
                     lambda T, i=i, th=theta: T["geometry_msgs/msg/Pose2D"](x=EAST[i], y=NORTH[i], theta=th)))
        msgs += _thrust(i)
    res = import_file(_write(tmp_path / "p.bag", msgs, ros1))
    assert res.report.guesses["local_frame"] == "enu" and res.report.guesses["heading_frame"] == "enu"
    lp = res.log["/local/position"]
    np.testing.assert_allclose(lp["n_m"], NORTH, atol=1e-9)
    np.testing.assert_allclose(lp["e_m"], EAST, atol=1e-9)
    np.testing.assert_allclose(ssa(res.log["/compass/heading"]["heading_rad"].to_numpy() - PSI), 0.0, atol=1e-9)


@pytest.fixture
def mocap_bag(tmp_path):
    """A motion-capture array (x north, y east, z, roll, pitch, yaw in deg) nothing names as a pose."""
    msgs = []
    for i in range(N):
        arr = [NORTH[i], EAST[i], 0.0, 0.0, 0.0, math.degrees(PSI[i]) % 360.0]
        msgs.append(("/sensor", "std_msgs/msg/Float32MultiArray", int(TIMES[i]),
                     lambda T, a=arr: T["std_msgs/msg/Float32MultiArray"](
                         layout=T["std_msgs/msg/MultiArrayLayout"](dim=[], data_offset=0),
                         data=np.asarray(a, np.float32))))
        msgs += _thrust(i)
    return _write(tmp_path / "mocap.bag", msgs, True)


def test_motion_capture_array_mapped_by_hand(mocap_bag, tmp_path):
    out = tmp_path / "run.mcap"
    assert main(["import", str(mocap_bag), "--out", str(out), "--topic", "local_n=/sensor.data[0]",
                 "--topic", "local_e=/sensor.data[1]", "--topic", "heading=/sensor.data[5]",
                 "--datum", "59.91,10.75"]) == 0
    import usvlog

    log = usvlog.load(out)
    lp = log["/local/position"]
    np.testing.assert_allclose(lp["n_m"], NORTH, atol=1e-5)    # float32 in the message
    np.testing.assert_allclose(lp["e_m"], EAST, atol=1e-5)
    assert lp["geo"].all() and log.datum.lat_deg == pytest.approx(59.91)
    np.testing.assert_allclose(ssa(log["/compass/heading"]["heading_rad"].to_numpy() - PSI), 0.0, atol=1e-5)
    # every verb reads it: the estimate follows the circle
    est = tmp_path / "est.mcap"
    assert main(["estimate", str(out), "--out", str(est)]) == 0
    st = usvlog.load(est)["/estimate/state"]
    t = np.asarray(st.index, np.int64)
    n = np.interp(TIMES, t, st["n_m"].to_numpy())
    e = np.interp(TIMES, t, st["e_m"].to_numpy())
    assert float(np.sqrt(np.mean((n - NORTH) ** 2 + (e - EAST) ** 2))) < 0.1


def test_only_one_of_local_n_local_e_is_an_error(mocap_bag, tmp_path, capsys):
    assert main(["import", str(mocap_bag), "--out", str(tmp_path / "x.mcap"),
                 "--topic", "local_n=/sensor.data[0]"]) == 2
    assert "local_n and local_e" in capsys.readouterr().err


def test_bad_datum_is_a_config_error(mocap_bag, tmp_path, capsys):
    assert main(["import", str(mocap_bag), "--out", str(tmp_path / "x.mcap"), "--datum", "95,10"]) == 2
    assert "--datum" in capsys.readouterr().err


def test_inspect_decides_from_the_values_and_prints_a_command_that_reproduces_the_import(tmp_path, capsys):
    """A Pose2D in ENU: inspect names the frame, and its command (--topic local=...) imports the same."""
    import json

    msgs = []
    for i in range(N):
        theta = math.pi / 2 - PSI[i]
        msgs.append(("/ins/pose", "geometry_msgs/msg/Pose2D", int(TIMES[i]),
                     lambda T, i=i, th=theta: T["geometry_msgs/msg/Pose2D"](x=EAST[i], y=NORTH[i], theta=th)))
        msgs.append(("/heading_gain", "std_msgs/msg/Float64", int(TIMES[i]) + 3, _float(2.0 + (i % 7))))
        msgs += _thrust(i)
    bag = _write(tmp_path / "p.bag", msgs, True)
    assert main(["inspect", str(bag), "--json"]) == 0
    cat = json.loads(capsys.readouterr().out)
    assert cat["mapping"]["heading"] == "/ins/pose.theta" and cat["reasons"]["local_frame"] == "enu"
    cmd = cat["import_command"].split()
    assert "local=/ins/pose" in cmd
    out = tmp_path / "again.mcap"
    assert main(cmd[1:3] + ["--out", str(out)] + cmd[5:]) == 0
    import usvlog

    log = usvlog.load(out)
    np.testing.assert_allclose(log["/local/position"]["n_m"], NORTH, atol=1e-9)
    np.testing.assert_allclose(ssa(log["/compass/heading"]["heading_rad"].to_numpy() - PSI), 0.0, atol=1e-9)


def _csv(path, cols: dict):
    import pandas as pd

    pd.DataFrame({"time_s": (TIMES - T0) / 1e9, **cols, "left": 12.0, "right": 8.0}).to_csv(path, index=False)
    return path


@pytest.mark.parametrize("north_is_x", [True, False])
def test_csv_x_y_columns_decided_from_the_heading(tmp_path, north_is_x):
    """x/y in metres: which is north is decided by the heading's agreement with the course."""
    x, y = (NORTH, EAST) if north_is_x else (EAST, NORTH)
    src = _csv(tmp_path / "xy.csv", {"x": x, "y": y, "heading_deg": np.degrees(PSI) % 360})
    res = import_file(src, start_utc="2024-05-01T10:00:00Z")
    assert (res.report.mapping["local_n"], res.report.mapping["local_e"]) == (("x", "y") if north_is_x else ("y", "x"))
    assert ("x north, y east" if north_is_x else "x east, y north") in res.report.guesses["local_frame"]
    lp = res.log["/local/position"]
    np.testing.assert_allclose(lp["n_m"], NORTH, atol=1e-6)
    np.testing.assert_allclose(lp["e_m"], EAST, atol=1e-6)


def test_csv_north_east_columns_given(tmp_path):
    src = _csv(tmp_path / "ne.csv", {"pn": NORTH, "pe": EAST})
    res = import_file(src, columns={"local_n": "pn", "local_e": "pe"}, start_utc="2024-05-01T10:00:00Z")
    np.testing.assert_allclose(res.log["/local/position"]["n_m"], NORTH, atol=1e-6)
    np.testing.assert_allclose(res.log["/local/position"]["e_m"], EAST, atol=1e-6)
    assert "/gnss/fix" not in res.log.topics and "/compass/heading" not in res.log.topics
