"""Role mapping by structure on hand-made catalogs (no file: the same rules for every format)."""

from __future__ import annotations

import pytest

from usvlog.errors import InputError
from usvlog.io.importers.catalog import Catalog, FieldInfo, TopicInfo
from usvlog.io.importers.mapping import map_roles, resolve_spec, split_path


def _t(name, typ, fields, count=100, span_s=10.0):
    return TopicInfo(name=name, type=typ, count=count, first_ns=0, last_ns=int(span_s * 1e9),
                     fields=tuple(FieldInfo(*f) for f in fields))


def test_ulog_like_names_and_scaled_integers():
    cat = Catalog("x.ulg", "ulog", [
        _t("vehicle_gps_position", "vehicle_gps_position",
           [("timestamp", "uint64", None, 1), ("lat", "int32", None, 473977418), ("lon", "int32", None, 85455939),
            ("alt", "int32", None, 488000), ("vel_m_s", "float", None, 0.1), ("cog_rad", "float", None, 0.5)],
           count=32),
        _t("vehicle_angular_velocity", "vehicle_angular_velocity",
           [("timestamp", "uint64", None, 1), ("xyz", "float", 3, [0.0, 0.0, 0.1])]),
        _t("actuator_outputs.1", "actuator_outputs", [("output", "float", 2, [1500.0, 1500.0])]),
    ])
    mapping, reasons, notes = map_roles(cat)
    assert mapping["gnss"] == "vehicle_gps_position"
    assert mapping["speed_mps"] == "vehicle_gps_position.vel_m_s"
    assert mapping["course"] == "vehicle_gps_position.cog_rad"
    assert (mapping["thrust_left"], mapping["thrust_right"]) == ("actuator_outputs.1.output[0]",
                                                                 "actuator_outputs.1.output[1]")
    assert "2-element array" in reasons["thrust_left"]
    # an instance-numbered topic and an indexed field, as --topic gives them
    assert resolve_spec(cat, "yaw_rate", "vehicle_angular_velocity.xyz[2]") == ("vehicle_angular_velocity", "xyz[2]")
    with pytest.raises(InputError, match=r"index|xyz\[3\]"):
        resolve_spec(cat, "yaw_rate", "vehicle_angular_velocity.xyz[7]")


def test_implausible_position_not_taken_and_said_why():
    cat = Catalog("a.bag", "ros1", [_t("/odom_xy", "x/Pos", [("lat", "float64", None, 4512.3),
                                                             ("lon", "float64", None, -9000.0)])])
    mapping, reasons, _ = map_roles(cat)
    assert "gnss" not in mapping and "not a position" in reasons["gnss"]


def test_candidates_picked_by_kind_then_rate_and_ties_listed():
    fast = _t("/gps_a", "custom/Fix", [("latitude", "float64", None, 59.0), ("longitude", "float64", None, 10.0)],
              count=101)
    slow = _t("/gps_b", "custom/Fix", [("latitude", "float64", None, 59.0), ("longitude", "float64", None, 10.0)],
              count=11)
    mapping, reasons, notes = map_roles(Catalog("a.bag", "ros1", [slow, fast]))
    assert mapping["gnss"] == "/gps_a" and "10 Hz" in reasons["gnss"] and "/gps_b" in reasons["gnss"]
    assert not notes
    twin = _t("/gps_c", "custom/Fix", [("latitude", "float64", None, 59.0), ("longitude", "float64", None, 10.0)],
              count=101)
    mapping, reasons, notes = map_roles(Catalog("a.bag", "ros1", [fast, twin]))
    assert len(notes) == 1 and "/gps_a" in notes[0] and "/gps_c" in notes[0] and "\n" not in notes[0]
    std = _t("/fix", "sensor_msgs/msg/NavSatFix", [("latitude", "float64", None, 59.0),
                                                   ("longitude", "float64", None, 10.0)], count=5)
    mapping, reasons, _ = map_roles(Catalog("a.bag", "ros1", [fast, std]))
    assert mapping["gnss"] == "/fix"   # a standard fix message beats a faster custom one


def test_course_is_listed_not_taken_as_heading():
    cat = Catalog("a.bag", "ros1", [_t("/gps", "c/Fix", [("latitude", "float64", None, 59.0),
                                                        ("longitude", "float64", None, 10.0),
                                                        ("track", "float64", None, 80.0)])])
    mapping, reasons, _ = map_roles(cat)
    assert "heading" not in mapping and "/gps.track" in reasons["heading"]
    mapping, _, _ = map_roles(cat, {"heading": "/gps.track"})
    assert mapping["heading"] == "/gps.track"


def test_requested_errors_list_what_exists():
    cat = Catalog("a.bag", "ros1", [_t("/m", "c/Pair", [("port", "int16", None, 1), ("stbd", "int16", None, 2)]),
                                    _t("/battery/capacity", "std_msgs/msg/Float32", [("data", "float32", None, 3.0)])])
    mapping, _, _ = map_roles(cat)
    assert "thrust_left" not in mapping                # /m is not named like a command topic
    assert "heading" not in mapping                    # "capacity" is not the word "cap"
    mapping, _, _ = map_roles(cat, {"thrust": "/m"})
    assert (mapping["thrust_left"], mapping["thrust_right"]) == ("/m.port", "/m.stbd")
    with pytest.raises(InputError, match=r"no field 'prt'.*fields: port, stbd"):
        map_roles(cat, {"thrust_left": "/m.prt"})
    with pytest.raises(InputError, match="no latitude/longitude"):
        map_roles(cat, {"gnss": "/m"})
    with pytest.raises(InputError, match="unknown role"):
        map_roles(cat, {"rudder": "/m"})


def test_split_path():
    assert split_path("pose.position[2].x") == ["pose", "position", 2, "x"]
    assert split_path("a.0.b") == ["a", 0, "b"]


def test_speed_only_from_navigation_messages_and_driver_topics_not_commands():
    motor = _t("/port_motor/status", "c/Motor", [("speed", "float64", None, 12.0)])
    gps = _t("/gps_driver/vel", "c/Vel", [("speed", "float64", None, 1.2)])
    mapping, _, _ = map_roles(Catalog("a.bag", "ros1", [motor]))
    assert "speed_mps" not in mapping                  # a motor's speed is not speed over ground
    mapping, _, _ = map_roles(Catalog("a.bag", "ros1", [motor, gps]))
    assert mapping["speed_mps"] == "/gps_driver/vel.speed"
    setpoint = _t("/heading_setpoint", "std_msgs/msg/Float64", [("data", "float64", None, 90.0)])
    mapping, _, _ = map_roles(Catalog("a.bag", "ros1", [setpoint]))
    assert "heading" not in mapping                    # a setpoint is not a measurement
