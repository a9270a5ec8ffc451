"""Bags like other teams' boats record them, written with rosbags' own writers.

A twin-motor boat: a custom GPSFix-like message (``usv_msgs/GPSFix``: latitude, longitude,
altitude, speed, track, time, ... with a nested status), a custom motor command
(``usv_msgs/MotorCmd``: integer ``left``/``right``), a compass heading on ``/capRaw``
(``std_msgs/Float64``, degrees) and ``/rosout`` from several publishers. The message
definitions are embedded in the bag (ROS 1 connection headers, ROS 2 MCAP schemas), so no
ROS install knows these types.

Optional field faults (for the sensor health audit): each fix republished ``republish``
times with new header stamps but the same fix ``time``; a compass that reads exactly 0;
one motor command at -99360.
"""

from __future__ import annotations

import math

import numpy as np

T0 = 1_714_557_600_000_000_000   # 2024-05-01T10:00:00Z
N = 40                            # fixes, 5 Hz
DT = 200_000_000
_TURN = np.radians(400.0) * np.arange(N) / (N - 1)   # the track turns through 400 degrees
LAT = 63.43 + 15.0 * np.sin(_TURN) / 111_320.0         # a 15 m circle
LON = 10.39 + 15.0 * (1.0 - np.cos(_TURN)) / (111_320.0 * math.cos(math.radians(63.43)))
ALT = 41.0 - 0.01 * np.arange(N)
SPEED = 1.0 + 0.02 * np.arange(N)             # m/s
TRACK = (30.0 + 10.0 * np.arange(N)) % 360.0   # degrees, turning
HEADING_DEG = (25.0 + 9.5 * np.arange(N)) % 360.0
LEFT = np.round(255 * np.sin(np.arange(N) / 5.0)).astype(int)
RIGHT = np.round(200 * np.cos(np.arange(N) / 5.0)).astype(int)

GPS_STATUS = "int16 status\nuint16 satellites_used\n"
GPSFIX = """std_msgs/Header header
usv_msgs/GPSStatus status
float64 latitude
float64 longitude
float64 altitude
float64 track
float64 speed
float64 climb
float64 time
float64 err_horz
float64[9] position_covariance
uint8 position_covariance_type
"""
MOTOR = "std_msgs/Header header\nint32 left\nint32 right\n"

# every leaf field path, written out by hand (the independent truth for `inspect`)
GPSFIX_PATHS = ["header.stamp.sec", "header.stamp.nanosec", "header.frame_id", "status.status",
                "status.satellites_used", "latitude", "longitude", "altitude", "track", "speed", "climb", "time",
                "err_horz", "position_covariance", "position_covariance_type"]
MOTOR_PATHS = ["header.stamp.sec", "header.stamp.nanosec", "header.frame_id", "left", "right"]


def typestore(ros1: bool):
    """The store with the custom types registered (as the boat's own ROS workspace had them)."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    types = {}
    types.update(get_types_from_msg(GPS_STATUS, "usv_msgs/msg/GPSStatus"))
    types.update(get_types_from_msg(GPSFIX.replace("usv_msgs/GPSStatus", "usv_msgs/msg/GPSStatus"),
                                    "usv_msgs/msg/GPSFix"))
    types.update(get_types_from_msg(MOTOR, "usv_msgs/msg/MotorCmd"))
    store.register(types)
    return store


def _header(T, t, frame, ros1):
    kw = {"seq": 0} if ros1 else {}
    return T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=t // 10**9, nanosec=t % 10**9),
                                    frame_id=frame, **kw)


def messages(store, ros1: bool, *, republish: int = 1, dead_compass: bool = False, outlier: bool = False):
    """(topic, msgtype, record time ns, message, callerid) in time order."""
    T = store.types
    out = []
    for i in range(N):
        t = T0 + i * DT
        for k in range(republish):        # the same fix again, new header stamp, same fix time
            tk = t + k * 20_000_000
            fix = T["usv_msgs/msg/GPSFix"](
                header=_header(T, tk, "gps", ros1), status=T["usv_msgs/msg/GPSStatus"](status=0, satellites_used=9),
                latitude=LAT[i], longitude=LON[i], altitude=ALT[i], track=TRACK[i], speed=SPEED[i], climb=0.0,
                time=(t - 3_000_000) / 1e9, err_horz=1.5,
                position_covariance=np.array([2.25, 0, 0, 0, 2.25, 0, 0, 0, 9.0]), position_covariance_type=1)
            out.append(("/gps", "usv_msgs/msg/GPSFix", tk + 1_000_000, fix, "/gps_driver"))
        heading = 0.0 if dead_compass else HEADING_DEG[i]
        out.append(("/capRaw", "std_msgs/msg/Float64", t + 5_000_000, T["std_msgs/msg/Float64"](data=heading),
                    "/compass"))
        left = -99360 if outlier and i == N // 2 else int(LEFT[i])
        out.append(("/motors/cmd", "usv_msgs/msg/MotorCmd", t + 7_000_000, T["usv_msgs/msg/MotorCmd"](
            header=_header(T, t + 7_000_000, "base_link", ros1), left=left, right=int(RIGHT[i])), "/pilot"))
        if i % 10 == 0:
            for node in ("/gps_driver", "/compass", "/pilot", "/recorder"):   # /rosout from four publishers
                log = _rosout(T, t + 9_000_000, node, ros1)
                out.append(("/rosout", log[0], t + 9_000_000, log[1], node))
    out.sort(key=lambda m: m[2])
    return out


def _rosout(T, t, node, ros1):
    if ros1:
        typ = "rosgraph_msgs/msg/Log"
        return typ, T[typ](header=_header(T, t, "", True), level=2, name=node, msg="running", file="x.py",
                           function="main", line=1, topics=[])
    typ = "rcl_interfaces/msg/Log"
    return typ, T[typ](stamp=T["builtin_interfaces/msg/Time"](sec=t // 10**9, nanosec=t % 10**9), level=20,
                       name=node, msg="running", file="x.py", function="main", line=1)


def write_bag(path, kind: str = "ros1", **faults):
    """Write the twin-motor bag: ``kind`` ``ros1`` (.bag file) or ``ros2-mcap``/``ros2-sqlite3`` (directory)."""
    ros1 = kind == "ros1"
    store = typestore(ros1)
    msgs = messages(store, ros1, **faults)
    if ros1:
        from rosbags.rosbag1 import Writer

        writer, ser = Writer(path), store.serialize_ros1
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        plugin = StoragePlugin.MCAP if kind.endswith("mcap") else StoragePlugin.SQLITE3
        writer, ser = Writer(path, version=9, storage_plugin=plugin), store.serialize_cdr
    with writer as w:
        conns = {}
        for topic, typ, t, m, caller in msgs:
            key = (topic, caller if ros1 else "")
            if key not in conns:
                conns[key] = (w.add_connection(topic, typ, typestore=store, callerid=caller) if ros1
                              else w.add_connection(topic, typ, typestore=store))
            w.write(conns[key], t, ser(m, typ))
    return path


BAD_DEF = "float64 x\nthis line \x01\x02 is not [[ a field\n"


def write_bad_definition_bag(path, *, with_good: bool = True, kind: str = "ros1"):
    """A good NavSatFix topic ``/fix`` and ``/weird`` whose embedded definition cannot be parsed.

    ``kind``: ``ros1`` (a .bag file) or ``ros2-mcap`` (a directory).
    """
    from rosbags.typesys import Stores, get_typestore

    ros1 = kind == "ros1"
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    T = store.types
    if ros1:
        from rosbags.rosbag1 import Writer

        writer, ser = Writer(path), store.serialize_ros1
    else:
        from rosbags.rosbag2 import StoragePlugin
        from rosbags.rosbag2 import Writer as Writer2

        writer, ser = Writer2(path, version=9, storage_plugin=StoragePlugin.MCAP), store.serialize_cdr
    with writer as w:
        if ros1:
            weird = w.add_connection("/weird", "acme_msgs/msg/Weird", msgdef=BAD_DEF, md5sum="0" * 32,
                                     callerid="/acme")
        else:
            weird = w.add_connection("/weird", "acme_msgs/msg/Weird", msgdef=BAD_DEF, rihs01="RIHS01_" + "0" * 64)
        fix = w.add_connection("/fix", "sensor_msgs/msg/NavSatFix", typestore=store) if with_good else None
        for i in range(N):
            t = T0 + i * DT
            w.write(weird, t, b"\x00\x01\x02\x03\xff\xfe" * 3)
            if fix is not None:
                msg = T["sensor_msgs/msg/NavSatFix"](
                    header=_header(T, t, "gps", ros1), status=T["sensor_msgs/msg/NavSatStatus"](status=0, service=1),
                    latitude=LAT[i], longitude=LON[i], altitude=ALT[i], position_covariance=np.zeros(9),
                    position_covariance_type=0)
                w.write(fix, t + 1, ser(msg, "sensor_msgs/msg/NavSatFix"))
    return path


def cog_rad():
    """The course over ground the import should write (rad, wrapped to [-pi, pi))."""
    return (np.radians(TRACK) + math.pi) % (2 * math.pi) - math.pi
