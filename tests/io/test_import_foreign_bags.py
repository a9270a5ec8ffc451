"""Bags from another team's boat: custom message types (definitions embedded), mapped by structure."""

from __future__ import annotations

import json
import shlex

import numpy as np
import pandas as pd
import pytest
from foreign_bags import (
    BAD_DEF,
    DT,
    GPSFIX_PATHS,
    HEADING_DEG,
    LAT,
    LEFT,
    LON,
    MOTOR_PATHS,
    RIGHT,
    SPEED,
    T0,
    N,
    cog_rad,
    write_bad_definition_bag,
    write_bag,
)

from usvlog import api
from usvlog.cli import main
from usvlog.errors import InputError
from usvlog.io.importers import import_file
from usvlog.io.importers.audit import health_of
from usvlog.model.frames import ssa


@pytest.fixture(params=["ros1", "ros2-mcap", "ros2-sqlite3"])
def twin(request, tmp_path):
    name = "twin.bag" if request.param == "ros1" else "twin2"
    return request.param, write_bag(tmp_path / name, request.param)


def test_auto_import_maps_custom_gnss_and_thrust_without_topic(twin):
    kind, path = twin
    res = import_file(path)
    m = res.report.mapping
    assert m["gnss"] == "/gps"
    assert (m["thrust_left"], m["thrust_right"]) == ("/motors/cmd.left", "/motors/cmd.right")
    assert (m["speed_mps"], m["course"]) == ("/gps.speed", "/gps.track")
    log = res.log
    g = log["/gnss/fix"]
    t = T0 + DT * np.arange(N)
    np.testing.assert_array_equal(g.index.to_numpy(), t + 1_000_000)      # record times
    np.testing.assert_array_equal(g["stamp_ns"].to_numpy(), t)             # header stamps
    np.testing.assert_allclose(g["lat_deg"], LAT, atol=1e-9, rtol=0)
    np.testing.assert_allclose(g["lon_deg"], LON, atol=1e-9, rtol=0)
    assert (g["cov_ee_m2"] == 2.25).all() and (g["cov_uu_m2"] == 9.0).all() and (g["cov_type"] == 1).all()
    # whole-number commands up to 255: counts (full scale 255), written as normalized commands
    assert health_of(log)["thrust"]["unit"] == "counts" and health_of(log)["thrust"]["range"] == [-255.0, 255.0]
    th = log["/thrust/command"]
    np.testing.assert_allclose(th["left"].to_numpy(), np.asarray(LEFT) / 255.0, rtol=0, atol=1e-15)
    np.testing.assert_allclose(th["right"].to_numpy(), np.asarray(RIGHT) / 255.0, rtol=0, atol=1e-15)
    v = log["/gnss/velocity"]
    np.testing.assert_allclose(v["sog_mps"], SPEED, atol=1e-12)
    np.testing.assert_allclose(ssa(v["cog_rad"].to_numpy() - cog_rad()), 0.0, atol=1e-9)
    # the compass topic is named capRaw: a scalar message on a topic named like a heading
    assert m["heading"] == "/capRaw.data"
    np.testing.assert_allclose(ssa(log["/compass/heading"]["heading_rad"].to_numpy() - np.radians(HEADING_DEG)),
                               0.0, atol=1e-9)


def test_topic_heading_on_float64_without_data(tmp_path, capsys):
    path = write_bag(tmp_path / "twin.bag")
    res = import_file(path, topics={"heading": "/capRaw"})
    assert res.report.mapping["heading"] == "/capRaw.data"
    h = res.log["/compass/heading"]
    np.testing.assert_allclose(ssa(h["heading_rad"].to_numpy() - np.radians(HEADING_DEG)), 0.0, atol=1e-9)
    out = tmp_path / "o.mcap"
    assert main(["import", str(path), "--out", str(out), "--topic", "heading=/capRaw"]) == 0
    assert out.exists()


def test_topic_thrust_pair_and_indexed_spec(tmp_path):
    path = write_bag(tmp_path / "twin.bag")
    res = import_file(path, topics={"thrust": "/motors/cmd", "gnss": "/gps"})
    assert res.report.mapping["thrust_left"] == "/motors/cmd.left"
    np.testing.assert_allclose(res.log["/thrust/command"]["right"].to_numpy(), np.asarray(RIGHT) / 255.0,
                               rtol=0, atol=1e-15)
    # the covariance array is there but is not a number: the error names the array
    with pytest.raises(InputError, match=r"position_covariance.*not a number"):
        import_file(path, topics={"heading": "/gps.position_covariance"})
    res = import_file(path, topics={"velocity": "/gps"})
    assert (res.report.mapping["speed_mps"], res.report.mapping["course"]) == ("/gps.speed", "/gps.track")
    with pytest.raises(InputError, match="course=/gps.track needs speed_mps from the same message"):
        import_file(path, topics={"course": "/gps.track", "speed_mps": "/capRaw"})
    # a constant "heading" while the track turns is judged dead: kept as data only when asked
    res = import_file(path, topics={"heading": "/gps.position_covariance[4]"}, keep_dead=True)
    assert np.allclose(res.log["/compass/heading"]["heading_rad"], 2.25)


def test_wrong_field_name_lists_the_fields(tmp_path, capsys):
    path = write_bag(tmp_path / "twin.bag")
    with pytest.raises(InputError) as ei:
        import_file(path, topics={"heading": "/gps.headingg"})
    msg = str(ei.value)
    assert "headingg" in msg and "\n" not in msg
    for f in GPSFIX_PATHS:
        assert f in msg
    out = tmp_path / "o.mcap"
    assert main(["import", str(path), "--out", str(out), "--topic", "thrust_left=/motors/cmd.lft"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert "lft" in err[-1] and "left" in err[-1] and "right" in err[-1] and not out.exists()
    # a message with several numbers is not guessed: its numeric fields are listed
    with pytest.raises(InputError, match="numeric fields: .*latitude"):
        import_file(path, topics={"heading": "/gps"})
    with pytest.raises(InputError, match=r"/nope.*topics: /capRaw \[std_msgs/msg/Float64\]"):
        import_file(path, topics={"heading": "/nope.x"})


def _leaf_paths(topic: dict) -> set:
    return {f["path"] for f in topic["fields"]}


def test_inspect_source_lists_every_field_path(twin, capsys):
    kind, path = twin
    assert main(["inspect", str(path), "--json"]) == 0
    cat = json.loads(capsys.readouterr().out)
    topics = {t["name"]: t for t in cat["topics"]}
    assert set(topics) == {"/gps", "/capRaw", "/motors/cmd", "/rosout"}
    seq = {"header.seq"} if kind == "ros1" else set()
    assert _leaf_paths(topics["/gps"]) == set(GPSFIX_PATHS) | seq
    assert _leaf_paths(topics["/motors/cmd"]) == set(MOTOR_PATHS) | seq
    assert _leaf_paths(topics["/capRaw"]) == {"data"}
    gps = topics["/gps"]
    assert gps["type"] == "usv_msgs/msg/GPSFix" and gps["count"] == N
    assert gps["first_ns"] == T0 + 1_000_000 and gps["last_ns"] == T0 + (N - 1) * DT + 1_000_000
    assert gps["rate_hz"] == pytest.approx(1e9 / DT)
    cov = next(f for f in gps["fields"] if f["path"] == "position_covariance")
    assert cov["length"] == 9 and cov["type"] == "float64"
    lat = next(f for f in gps["fields"] if f["path"] == "latitude")
    assert lat["sample"] == pytest.approx(LAT[0]) and lat["type"] == "float64"
    assert topics["/rosout"]["count"] == 4 * (N // 10)
    assert cat["mapping"]["gnss"] == "/gps" and cat["mapping"]["thrust_left"] == "/motors/cmd.left"
    assert cat["time_base"] == "utc"
    assert cat["import_command"].startswith("usvlog import ") and "--topic gnss=/gps" in cat["import_command"]
    # the text form names every path too, and the mapping with its reason
    assert main(["inspect", str(path)]) == 0
    text = capsys.readouterr().out
    for f in GPSFIX_PATHS + MOTOR_PATHS:
        assert f".{f} " in text
    assert "gnss          <- /gps   (fields latitude/longitude" in text
    assert "import with" in text


def test_inspect_command_imports_what_inspect_showed(tmp_path, capsys):
    path = write_bag(tmp_path / "twin.bag")
    cat = api.inspect(path)
    cmd = shlex.split(cat.import_command(str(tmp_path / "x.mcap")))
    assert cmd[:2] == ["usvlog", "import"]
    assert main(cmd[1:]) == 0 and (tmp_path / "x.mcap").exists()
    res = import_file(path, topics={k: v for k, v in cat.mapping.items()})
    assert res.report.mapping == cat.mapping


@pytest.mark.parametrize("kind", ["ros1", "ros2-mcap"])
def test_bad_definition_skips_that_topic_only(tmp_path, capsys, kind):
    path = write_bad_definition_bag(tmp_path / ("bad.bag" if kind == "ros1" else "bad2"), kind=kind)
    res = import_file(path)
    g = res.log["/gnss/fix"]
    np.testing.assert_allclose(g["lat_deg"], LAT, atol=1e-9, rtol=0)
    assert res.report.mapping == {"gnss": "/fix"}
    notes = [n for n in res.report.notes if "/weird" in n]
    assert len(notes) == 1 and "definition" in notes[0] and "\x01" not in notes[0] and "[[" not in notes[0]
    out = tmp_path / "o.mcap"
    assert main(["import", str(path), "--out", str(out)]) == 0
    stdout = capsys.readouterr().out
    assert "note      topic /weird skipped" in stdout and "this line" not in stdout
    assert main(["inspect", str(path)]) == 0
    text = capsys.readouterr().out
    assert "skipped: its message definition" in text and BAD_DEF.splitlines()[1] not in text
    # a mapping onto the unreadable topic is one line, without the definition's text
    with pytest.raises(InputError) as ei:
        import_file(path, topics={"heading": "/weird.x"})
    assert "/weird" in str(ei.value) and "this line" not in str(ei.value) and "\n" not in str(ei.value)


def test_only_unreadable_topic_is_one_line_without_raw_text(tmp_path, capsys):
    path = write_bad_definition_bag(tmp_path / "bad.bag", with_good=False)
    out = tmp_path / "o.mcap"
    assert main(["import", str(path), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no topic maps to a role" in err[0] and "this line" not in err[0]
    assert "\x01" not in err[0] and not out.exists()


def test_rosout_listed_once(tmp_path, capsys):
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    T = store.types
    path = tmp_path / "chatter.bag"
    with Writer(path) as w:
        for k, node in enumerate(("/a", "/b", "/c", "/d")):
            c = w.add_connection("/rosout", "rosgraph_msgs/msg/Log", typestore=store, callerid=node)
            msg = T["rosgraph_msgs/msg/Log"](header=T["std_msgs/msg/Header"](
                seq=0, stamp=T["builtin_interfaces/msg/Time"](sec=1_714_557_600 + k, nanosec=0), frame_id=""),
                level=2, name=node, msg="hi", file="f", function="g", line=1, topics=[])
            w.write(c, T0 + k * 10**9, store.serialize_ros1(msg, "rosgraph_msgs/msg/Log"))
    assert main(["import", str(path), "--out", str(tmp_path / "o.mcap")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].count("/rosout") == 1 and "usvlog inspect" in err[0]
    assert main(["inspect", str(path), "--json"]) == 0
    cat = json.loads(capsys.readouterr().out)
    assert [t["name"] for t in cat["topics"]] == ["/rosout"] and cat["topics"][0]["count"] == 4


def test_inspect_format_without_catalog_says_not_yet(tmp_path, capsys, monkeypatch):
    from usvlog.io.importers import csvlog

    monkeypatch.delattr(csvlog, "catalog", raising=False)
    src = tmp_path / "run.csv"
    src.write_text("time_s,lat_deg,lon_deg\n0,59.1,10.2\n1,59.1001,10.2001\n")
    assert main(["inspect", str(src)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not yet" in err[0] and "run.csv" in err[0]


@pytest.mark.parametrize("seed", range(6))
def test_one_damaged_message_costs_only_itself(tmp_path, seed):
    """Random single-record damage (NaN, overflow, a truncated payload) drops that record's samples only."""
    from foreign_bags import typestore
    from rosbags.rosbag1 import Reader, Writer

    rng = np.random.default_rng(seed)
    clean = write_bag(tmp_path / "clean.bag")
    base = import_file(clean).log
    store = typestore(True)
    i = int(rng.integers(N))
    kind = ("nan", "overflow", "truncate")[seed % 3]
    damaged = tmp_path / "damaged.bag"
    with Reader(clean) as r, Writer(damaged) as w:
        conns = {}
        n_gps = 0
        for c, t, raw in r.messages():
            if c.id not in conns:
                conns[c.id] = w.add_connection(c.topic, c.msgtype, typestore=store, callerid=c.ext.callerid)
            if c.topic == "/gps":
                if n_gps == i:
                    msg = store.deserialize_ros1(raw, c.msgtype)
                    if kind == "nan":
                        msg.latitude = float("nan")
                    elif kind == "overflow":
                        msg.longitude = 1e300
                    raw = store.serialize_ros1(msg, c.msgtype) if kind != "truncate" else raw[:30]
                n_gps += 1
            w.write(conns[c.id], t, raw)
    res = import_file(damaged)
    g, g0 = res.log["/gnss/fix"], base["/gnss/fix"]
    keep = np.arange(N) != i
    np.testing.assert_array_equal(g.index.to_numpy(), g0.index.to_numpy()[keep])
    np.testing.assert_array_equal(g["lat_deg"].to_numpy(), g0["lat_deg"].to_numpy()[keep])
    assert sum(res.report.skipped.values()) >= 1
    for topic in ("/thrust/command", "/compass/heading"):
        pd.testing.assert_frame_equal(res.log[topic], base[topic])
    v, v0 = res.log["/gnss/velocity"], base["/gnss/velocity"]
    if kind == "truncate":   # the whole message is unreadable: its speed goes with it
        np.testing.assert_array_equal(v["sog_mps"].to_numpy(), v0["sog_mps"].to_numpy()[keep])
    else:
        np.testing.assert_array_equal(v["sog_mps"].to_numpy(), v0["sog_mps"].to_numpy())


def test_gnss_batches_carry_the_fix_time_of_a_republished_fix(tmp_path):
    """The reader hands the fix's own time over (the duplicate collapsing downstream needs it)."""
    from usvlog.io.importers import ImportOptions
    from usvlog.io.importers.core import ImportReport
    from usvlog.io.importers.rosbag import read

    path = write_bag(tmp_path / "rep.bag", republish=3)
    batches = list(read(path, ImportOptions(), ImportReport(), fmt="ros1"))
    fix_ns = np.concatenate([b["gnss"]["fix_time_ns"] for b in batches if "gnss" in b])
    want = np.repeat(T0 + DT * np.arange(N) - 3_000_000, 3)
    np.testing.assert_allclose(fix_ns, want, atol=1_000)  # float seconds in the message: within 1 us


def test_inspect_tells_a_ros2_mcap_file_from_a_canonical_log(tmp_path, capsys):
    bagdir = write_bag(tmp_path / "twin2", "ros2-mcap")
    inner = next(bagdir.glob("*.mcap"))
    assert main(["inspect", str(inner), "--json"]) == 0
    cat = json.loads(capsys.readouterr().out)
    assert cat["format"] == "ros2" and cat["mapping"]["gnss"] == "/gps"
    out = tmp_path / "run.mcap"
    assert main(["import", str(bagdir), "--out", str(out)]) == 0
    capsys.readouterr()
    assert main(["inspect", str(out), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert "/gnss/fix" in json.dumps(summary) and "format" not in summary


@pytest.mark.parametrize("kind", ["ros1", "ros2-mcap"])
def test_other_teams_faults_collapsed_flagged_and_skipped(tmp_path, kind):
    """The issue's bag: each fix republished three times (new header stamps, same fix time), a
    compass that reads 0 while the track turns 400 degrees, +-255 commands with one -99360."""
    path = write_bag(tmp_path / ("f.bag" if kind == "ros1" else "f2"), kind, republish=3, dead_compass=True,
                     outlier=True)
    res = import_file(path)
    m, log, skipped = res.report.mapping, res.log, res.report.skipped
    assert m["gnss"] == "/gps" and (m["thrust_left"], m["thrust_right"]) == ("/motors/cmd.left", "/motors/cmd.right")
    # the copies collapsed: one fix per fix time, all N of them, with their values
    assert len(log["/gnss/fix"]) == N and skipped["gnss_republished"] == 2 * N
    np.testing.assert_allclose(log["/gnss/fix"]["lat_deg"], LAT, atol=1e-9, rtol=0)
    # the dead compass: flagged, not written as data, kept under /raw
    h = health_of(log)
    assert h["dead"] == ["/compass/heading"] and "/compass/heading" not in log.topics
    assert len(log["/raw/compass/heading"]) == N and (log["/raw/compass/heading"]["heading_rad"] == 0).all()
    # counts guessed from the bulk, the outlier skipped and counted, the rest scaled by 255
    assert h["thrust"]["unit"] == "counts" and h["thrust"]["range"] == [-255.0, 255.0]
    assert skipped["thrust_out_of_range"] == 1
    th = log["/thrust/command"]
    keep = np.arange(N) != N // 2
    assert len(th) == N - 1
    np.testing.assert_allclose(th["left"].to_numpy(), np.asarray(LEFT)[keep] / 255.0, rtol=0, atol=1e-15)
