"""ROS bags without message definitions read with ``--msg-dir``; a rudder boat imported but refused by identify/replay.

The bags are written with rosbags' own writers, then their definitions removed as an older
recorder leaves them: a ROS 2 sqlite3 bag of the Humble era (schema 3: no
``message_definitions`` table, metadata version 5 without type hashes) and a ROS 1 bag whose
connection header has an empty ``message_definition``. The ``.msg`` files are written into a
workspace-like directory (``ws/src/my_usv_msgs/msg/*.msg``). Every value compared is one the
test wrote.
"""

from __future__ import annotations

import json
import math
import sqlite3

import numpy as np
import pytest
import yaml

from usvlog import api, load
from usvlog.cli import main
from usvlog.errors import ConfigError, UnusableResultError
from usvlog.io.importers import catalog_file, import_file

T0 = 1_714_557_600_000_000_000   # 2024-05-01T10:00:00Z
DT = 200_000_000                 # 5 Hz
N = 150                          # 30 s
SPEED = 1.5                      # m/s on a circle of radius R
R = 20.0
TURN = SPEED / R * DT * 1e-9 * np.arange(N)          # rad travelled; the course is TURN (clockwise from north)
NORTH, EAST = R * np.sin(TURN), R * (1.0 - np.cos(TURN))
LAT0, LON0 = 59.91, 10.75
LAT = LAT0 + NORTH / 111_320.0
LON = LON0 + EAST / (111_320.0 * math.cos(math.radians(LAT0)))
HEADING_DEG = np.degrees(TURN) % 360.0
POSE = np.stack([NORTH, EAST, np.full(N, 0.1), np.full(N, 0.01), np.full(N, -0.02), TURN], axis=1)
RPM = 900.0 + 10.0 * np.arange(N) % 300
RUDDER = 0.2 * np.sin(np.arange(N) / 7.0)          # rad

MSGS = {
    "MocapPose": "std_msgs/Header header\nfloat32[] pose   # x, y, z, roll, pitch, yaw\n",
    "Propulsion": "Header header\nfloat32 rpm\nfloat32 rudder_angle\n",
    "Status": "MocapPose pose_in\nuint8 mode\n",     # a nested custom type of the same package
}
PKG = "my_usv_msgs"


def write_msg_dir(root, msgs=None):
    """``root/src/my_usv_msgs/msg/<Name>.msg`` for every definition; returns ``root``."""
    d = root / "src" / PKG / "msg"
    d.mkdir(parents=True)
    for name, text in (msgs or MSGS).items():
        (d / f"{name}.msg").write_text(text)
    (root / "src" / PKG / "package.xml").write_text("<package/>\n")
    return root


def _store(ros1: bool):
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    types = {}
    for name, text in MSGS.items():
        types.update(get_types_from_msg(text, f"{PKG}/msg/{name}"))
    store.register(types)
    return store


def _messages(store, ros1: bool, with_fix: bool):
    """(topic, type, record time ns, message) in time order."""
    T = store.types
    out = []
    for i in range(N):
        t = T0 + i * DT
        kw = {"seq": i} if ros1 else {}
        hdr = T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=t // 10**9, nanosec=t % 10**9),
                                       frame_id="base", **kw)
        pose = T[f"{PKG}/msg/MocapPose"](header=hdr, pose=POSE[i].astype(np.float32))
        out.append(("/mocap", f"{PKG}/msg/MocapPose", t + 1_000_000, pose))
        out.append(("/propulsion", f"{PKG}/msg/Propulsion", t + 2_000_000,
                    T[f"{PKG}/msg/Propulsion"](header=hdr, rpm=RPM[i], rudder_angle=RUDDER[i])))
        if i % 5 == 0:
            out.append(("/state", f"{PKG}/msg/Status", t + 3_000_000, T[f"{PKG}/msg/Status"](pose_in=pose, mode=2)))
        if with_fix:
            fix = T["sensor_msgs/msg/NavSatFix"](
                header=hdr, status=T["sensor_msgs/msg/NavSatStatus"](status=0, service=1), latitude=LAT[i],
                longitude=LON[i], altitude=12.0, position_covariance=np.zeros(9), position_covariance_type=0)
            out.append(("/fix", "sensor_msgs/msg/NavSatFix", t + 4_000_000, fix))
            out.append(("/heading", "std_msgs/msg/Float64", t + 5_000_000,
                        T["std_msgs/msg/Float64"](data=HEADING_DEG[i])))
    return out


def write_ros2_db3_without_definitions(path, with_fix: bool = False):
    """A ROS 2 sqlite3 bag directory as Humble wrote them: no message definitions stored."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    store = _store(False)
    with Writer(path, version=9, storage_plugin=StoragePlugin.SQLITE3) as w:
        conns = {}
        for topic, typ, t, m in _messages(store, False, with_fix):
            if topic not in conns:
                conns[topic] = w.add_connection(topic, typ, typestore=store)
            w.write(conns[topic], t, store.serialize_cdr(m, typ))
    db = next(path.glob("*.db3"))
    with sqlite3.connect(db) as con:
        con.execute("DROP TABLE message_definitions")
        con.execute("UPDATE schema SET schema_version = 3")
    meta = yaml.safe_load((path / "metadata.yaml").read_text())
    info = meta["rosbag2_bagfile_information"]
    info["version"] = 5
    for x in info["topics_with_message_count"]:
        x["topic_metadata"].pop("type_description_hash", None)
    (path / "metadata.yaml").write_text(yaml.safe_dump(meta))
    return path


def write_ros1_with_empty_definition(path):
    """A ROS 1 bag: /fix and /heading with their definitions, /propulsion with an empty one."""
    from rosbags.rosbag1 import Writer

    store = _store(True)
    with Writer(path) as w:
        conns = {}
        for topic, typ, t, m in _messages(store, True, True):
            if topic in ("/mocap", "/state"):
                continue
            if topic not in conns:
                if topic == "/propulsion":   # the md5 of the real type, the text left out
                    conns[topic] = w.add_connection(topic, typ, msgdef="", md5sum=store.generate_msgdef(typ)[1])
                else:
                    conns[topic] = w.add_connection(topic, typ, typestore=store)
            w.write(conns[topic], t, store.serialize_ros1(m, typ))
    return path


@pytest.fixture
def ws(tmp_path):
    return write_msg_dir(tmp_path / "ws")


def _topic(cat, name):
    return next(t for t in cat.topics if t.name == name)


def _sample(topic, path):
    return next(f for f in topic.fields if f.path == path).sample


def test_db3_without_definitions_is_skipped_with_the_reason_then_read_with_msg_dir(tmp_path, ws, capsys):
    bag = write_ros2_db3_without_definitions(tmp_path / "mocap_bag")
    cat = catalog_file(bag)
    for name in ("/mocap", "/propulsion", "/state"):
        t = _topic(cat, name)
        assert "its message definition cannot be read" in t.note and "--msg-dir" in t.note and not t.fields
    assert main(["inspect", str(bag)]) == 0
    assert "skipped: its message definition cannot be read (my_usv_msgs/msg/MocapPose" in capsys.readouterr().out

    cat = catalog_file(bag, msg_dirs=[ws])
    mocap, prop, state = _topic(cat, "/mocap"), _topic(cat, "/propulsion"), _topic(cat, "/state")
    assert not (mocap.note or prop.note or state.note)
    assert [f.path for f in prop.fields] == ["header.stamp.sec", "header.stamp.nanosec", "header.frame_id",
                                             "rpm", "rudder_angle"]
    pose = next(f for f in mocap.fields if f.path == "pose")
    assert (pose.type, pose.length) == ("float32[]", 6)
    np.testing.assert_array_equal(pose.sample, POSE[0, :4].astype(np.float32))
    assert _sample(prop, "rpm") == np.float32(RPM[0]) and _sample(prop, "rudder_angle") == np.float32(RUDDER[0])
    assert _sample(prop, "header.stamp.sec") == T0 // 10**9
    # a nested custom type (MocapPose inside Status) and a standard one (Header) inside it
    np.testing.assert_array_equal(_sample(state, "pose_in.pose"), POSE[0, :4].astype(np.float32))
    assert _sample(state, "mode") == 2 and _sample(state, "pose_in.header.stamp.sec") == T0 // 10**9
    assert (mocap.count, prop.count, state.count) == (N, N, N // 5)
    types = [f"{PKG}/msg/{n}" for n in sorted(MSGS)]
    assert any(n.startswith(f"--msg-dir {ws}: 3 message types registered ({', '.join(types)})") for n in cat.notes)
    assert cat.propulsion["kind"] == "propeller and rudder"
    assert cat.propulsion["commands"] == ["/propulsion.rpm", "/propulsion.rudder_angle"]

    assert main(["inspect", str(bag), "--msg-dir", str(ws), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["msg_dirs"] == [str(ws)] and f"--msg-dir {ws}" in d["import_command"]
    assert d["propulsion"]["commands"] == ["/propulsion.rpm", "/propulsion.rudder_angle"]
    assert any("does not apply to this vessel's propulsion" in n for n in d["notes"])


def test_msg_dir_errors_are_one_line(tmp_path, ws, capsys):
    bag = write_ros2_db3_without_definitions(tmp_path / "b")
    empty = tmp_path / "empty"
    empty.mkdir()
    bad = write_msg_dir(tmp_path / "bad", {"Broken": "float32 x\nuint8[ broken\n"})
    for d, want in ((tmp_path / "nope", "not a directory"), (empty, "no .msg file"),
                    (bad, "Broken.msg does not parse")):
        for verb in (["inspect", str(bag)], ["import", str(bag), "--out", str(tmp_path / "x.mcap")]):
            assert main(verb + ["--msg-dir", str(d)]) == 2
            err = capsys.readouterr().err.strip().splitlines()
            assert len(err) == 1 and want in err[0] and str(d) in err[0]
    with pytest.raises(ConfigError, match="not a directory"):
        import_file(bag, msg_dirs=[tmp_path / "nope"])
    assert not (tmp_path / "x.mcap").exists()


def test_rudder_boat_imports_positions_keeps_commands_and_identify_replay_refuse(tmp_path, ws, capsys):
    bag = write_ros2_db3_without_definitions(tmp_path / "rudder_boat", with_fix=True)
    out = tmp_path / "rudder.mcap"
    assert main(["import", str(bag), "--out", str(out), "--msg-dir", str(ws)]) == 0
    text = capsys.readouterr().out
    assert ("note      propulsion: the paper's twin-thruster model (differential thrust) does not apply to this "
            "vessel's propulsion: propeller and rudder (/propulsion.rpm, /propulsion.rudder_angle)") in text
    log = load(out)
    g, h, raw = log["/gnss/fix"], log["/compass/heading"], log["/raw/propulsion"]
    t = T0 + DT * np.arange(N)
    np.testing.assert_allclose(g["lat_deg"], LAT, atol=1e-9, rtol=0)
    np.testing.assert_allclose(g["lon_deg"], LON, atol=1e-9, rtol=0)
    err = (np.radians(HEADING_DEG) - h["heading_rad"].to_numpy() + math.pi) % (2 * math.pi) - math.pi
    assert np.abs(err).max() < 1e-9
    np.testing.assert_array_equal(raw.index.to_numpy(), t + 2_000_000)
    np.testing.assert_array_equal(raw["stamp_ns"].to_numpy(), t)
    np.testing.assert_array_equal(raw["rpm"].to_numpy(), RPM.astype(np.float32))
    np.testing.assert_array_equal(raw["rudder_angle"].to_numpy(), RUDDER.astype(np.float32))
    assert "/thrust/command" not in log.topics
    prov = json.loads(log.provenance[-1]["propulsion"])
    assert prov["kind"] == "propeller and rudder" and prov["topics"] == ["/propulsion"]

    st = api.estimate(log).state     # positions and heading are enough for the estimate
    at = np.interp(st.index.to_numpy(), g.index.to_numpy(), np.arange(N))
    assert np.abs(st["n_m"].to_numpy() - np.interp(at, np.arange(N), NORTH)).max() < 0.5
    assert np.abs(st["e_m"].to_numpy() - np.interp(at, np.arange(N), EAST)).max() < 0.5

    assert main(["identify", str(out), "--out", str(tmp_path / "v.toml")]) == 1
    err_id = capsys.readouterr().err
    assert "identification refused: the paper's twin-thruster model (differential thrust) does not apply" in err_id
    assert "/propulsion.rudder_angle" in err_id and "/thrust/command" not in err_id
    assert not (tmp_path / "v.toml").exists()
    assert main(["replay", str(out), "--scenario", "paper-circle", "--out", str(tmp_path / "r.mcap")]) == 1
    err_rp = capsys.readouterr().err.strip().splitlines()
    assert "replay refused: the paper's twin-thruster model" in err_rp[-1] and "rudder" in err_rp[-1]
    assert not (tmp_path / "r.mcap").exists()
    with pytest.raises(UnusableResultError, match="propeller and rudder"):
        api.identify(log)


def test_ros1_empty_definition_read_with_msg_dir(tmp_path, ws):
    bag = write_ros1_with_empty_definition(tmp_path / "rudder.bag")
    assert "cannot be read" in _topic(catalog_file(bag), "/propulsion").note
    res = import_file(bag, msg_dirs=[ws])
    raw = res.log["/raw/propulsion"]
    np.testing.assert_array_equal(raw["rpm"].to_numpy(), RPM.astype(np.float32))
    np.testing.assert_array_equal(raw["rudder_angle"].to_numpy(), RUDDER.astype(np.float32))
    np.testing.assert_allclose(res.log["/gnss/fix"]["lat_deg"], LAT, atol=1e-9, rtol=0)
    assert res.report.propulsion["kind"] == "propeller and rudder"
    assert res.report.mapping["heading"] == "/heading.data"
    # a .msg that is not the one recorded (float64 rpm): its checksum differs, the topic is skipped
    other = write_msg_dir(tmp_path / "other", {**MSGS, "Propulsion": MSGS["Propulsion"].replace("float32 rpm",
                                                                                                 "float64 rpm")})
    note = _topic(catalog_file(bag, msg_dirs=[other]), "/propulsion").note
    assert "does not match its checksum (the --msg-dir file differs" in note
