"""Make the recorded-run datasets of the regression set (tests/data/*.mcap).

usvlog ships no real boat's logs, so these runs are made with the simulator and, for
the importers, written out in each field format and imported back with `usvlog import`.
Every dataset is one documented command (DATASETS below: the exact argv given to
`usvlog`); the source files of the imported runs are written by the functions here.
Run from the repository root:

    python tests/data/make_datasets.py            # (re)make all
    python tests/data/make_datasets.py NAME ...   # some

Outputs are deterministic (seeded; same version, same bytes). Made with usvlog 0.1.0.
"""

from __future__ import annotations

import datetime as dt
import math
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent.parent))  # run from a checkout without installing
SRC = HERE / "sources"


def _rel(p: Path) -> str:
    return str(p.relative_to(HERE.parent.parent))


# name -> (argv for `usvlog`, description)
DATASETS = {
    "ident-current": (
        ["simulate", "excitation", "--seed", "11", "--duration-s", "300", "--current-mps", "0.2",
         "--current-dir-deg", "60", "--truth-rate-hz", "10"],
        "identification run: multisine surge + 20/20 zig-zag, 0.2 m/s current towards 060 deg"),
    "paper-sine": (
        ["simulate", "paper-sine", "--seed", "3", "--duration-s", "200", "--truth-rate-hz", "10"],
        "path following on the paper's sinusoid with GPS/compass noise, a current and the controller on "
        "the onboard EKF (onboard estimate and controller channels dropped to keep the file small)"),
    "gps-faults": (
        ["simulate", "excitation", "--seed", "5", "--duration-s", "200", "--gps-jump", "40:30",
         "--gps-jump", "95:30", "--gps-jump", "150:30", "--gps-dropout", "110:20", "--truth-rate-hz", "10"],
        "excitation run with three 30 m GPS jumps and a 20 s GPS dropout"),
    "imported-csv": (
        ["import", "SRC/kingfisher-merged.csv", "--format", "csv", "--thrust-unit", "newton"],
        "a merged logger CSV (100 Hz rows, sparse GPS/compass columns) imported"),
    "imported-nmea": (
        ["import", "SRC/kingfisher.nmea", "--format", "nmea"],
        "an NMEA 0183 log (GGA+RMC 10 Hz, HDT 20 Hz, time stamp prefix per line) imported"),
    "imported-ros2": (
        ["import", "SRC/kingfisher-ros2", "--format", "ros2", "--thrust-unit", "newton",
         "--topic", "thrust_left=/thrusters/left.data", "--topic", "thrust_right=/thrusters/right.data"],
        "a ROS 2 bag (mcap storage; NavSatFix 10 Hz, Imu 20 Hz, Float64 thrusters 100 Hz) imported"),
}

DROP = {"paper-sine": ["/control/state", "/estimate/state"]}


def _source_run(seconds: float, seed: int):
    from usvlog.sim.simulate import SimSettings, simulate

    return simulate("excitation", SimSettings(duration_s=seconds, current_mps=0.1, current_dir_deg=200.0),
                    seed=seed)


def make_csv(path: Path) -> None:
    from usvlog.io.mergedcsv import write_merged_csv

    write_merged_csv(_source_run(60.0, 21), path, force=True)


def make_nmea(path: Path) -> None:
    from usvlog.io.nmea import format_deg_min
    from usvlog.io.nmea import with_checksum as _cs

    log = _source_run(90.0, 22)
    lines = []
    gps, hd = log["/gnss/fix"], log["/compass/heading"]
    events = [(int(t), "gps", row) for t, row in zip(gps.index, gps.itertuples())]
    events += [(int(t), "hdg", row) for t, row in zip(hd.index, hd.itertuples())]
    for t, kind, row in sorted(events, key=lambda e: (e[0], e[1])):
        ts = dt.datetime.fromtimestamp(t / 1e9, tz=dt.UTC)
        stamp = ts.isoformat(timespec="milliseconds").replace("+00:00", "Z")
        if kind == "gps":
            hms = ts.strftime("%H%M%S") + f".{ts.microsecond // 10000:02d}"
            la, lh = format_deg_min(row.lat_deg, True, decimals=7)
            lo, oh = format_deg_min(row.lon_deg, False, decimals=7)
            lines.append(f"{stamp} " + _cs(f"GPRMC,{hms},A,{la},{lh},{lo},{oh},0.0,0.0,{ts:%d%m%y},,,A"))
            lines.append(f"{stamp} " + _cs(f"GPGGA,{hms},{la},{lh},{lo},{oh},1,12,0.8,{row.alt_m:.3f},M,0.0,M,,"))
        else:
            lines.append(f"{stamp} " + _cs(f"HEHDT,{math.degrees(row.heading_rad) % 360.0:.4f},T"))
    path.write_text("\n".join(lines) + "\n")


def make_ros2(path: Path) -> None:
    import shutil

    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    log = _source_run(45.0, 23)
    store = get_typestore(Stores.ROS2_HUMBLE)
    T = store.types
    Time, Header = T["builtin_interfaces/msg/Time"], T["std_msgs/msg/Header"]
    V3, Q = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"]
    msgs = []
    for t, row in zip(log["/gnss/fix"].index, log["/gnss/fix"].itertuples()):
        hdr = Header(stamp=Time(sec=int(t) // 10**9, nanosec=int(t) % 10**9), frame_id="gps")
        cov = np.array([row.cov_ee_m2, 0, 0, 0, row.cov_nn_m2, 0, 0, 0, row.cov_uu_m2])
        msgs.append(("/gps/fix", "sensor_msgs/msg/NavSatFix", int(t), T["sensor_msgs/msg/NavSatFix"](
            header=hdr, status=T["sensor_msgs/msg/NavSatStatus"](status=0, service=1), latitude=row.lat_deg,
            longitude=row.lon_deg, altitude=row.alt_m, position_covariance=cov, position_covariance_type=2)))
    truth = log["/truth/state"]
    rng = np.random.default_rng(24)
    for t, row in zip(log["/compass/heading"].index, log["/compass/heading"].itertuples()):
        wz = -float(truth.loc[t, "r_radps"]) + rng.normal(0.0, 0.005)  # gyro: FLU z = -r, 0.005 rad/s noise
        hdr = Header(stamp=Time(sec=int(t) // 10**9, nanosec=int(t) % 10**9), frame_id="imu")
        yaw_enu = math.pi / 2 - row.heading_rad
        q = Q(x=0.0, y=0.0, z=math.sin(yaw_enu / 2), w=math.cos(yaw_enu / 2))
        msgs.append(("/imu/data", "sensor_msgs/msg/Imu", int(t), T["sensor_msgs/msg/Imu"](
            header=hdr, orientation=q, orientation_covariance=np.zeros(9), angular_velocity=V3(x=0.0, y=0.0, z=wz),
            angular_velocity_covariance=np.diag([0.0, 0.0, 0.005**2]).ravel(),
            linear_acceleration=V3(x=0.0, y=0.0, z=9.81),
            linear_acceleration_covariance=np.zeros(9))))
    F64 = T["std_msgs/msg/Float64"]
    th = log["/thrust/command"]
    for t, row in zip(th.index, th.itertuples()):
        msgs.append(("/thrusters/left", "std_msgs/msg/Float64", int(t), F64(data=row.left)))
        msgs.append(("/thrusters/right", "std_msgs/msg/Float64", int(t) + 1000, F64(data=row.right)))
    if path.exists():
        shutil.rmtree(path)
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        conns = {}
        for topic, typ, t, m in sorted(msgs, key=lambda x: x[2]):
            if topic not in conns:
                conns[topic] = w.add_connection(topic, typ, typestore=store)
            w.write(conns[topic], t, store.serialize_cdr(m, typ))


SOURCES = {"imported-csv": ("kingfisher-merged.csv", make_csv), "imported-nmea": ("kingfisher.nmea", make_nmea),
           "imported-ros2": ("kingfisher-ros2", make_ros2)}


def make(name: str) -> Path:
    from usvlog.cli import main
    from usvlog.io.mcap import read_log, write_log

    argv, _ = DATASETS[name]
    out = HERE / f"{name}.mcap"
    if name in SOURCES:
        SRC.mkdir(exist_ok=True)
        fname, fn = SOURCES[name]
        fn(SRC / fname)
    argv = [a.replace("SRC/", str(SRC) + "/") for a in argv] + ["--out", str(out), "--force"]
    rc = main(argv)
    if rc != 0:
        raise SystemExit(f"usvlog {' '.join(argv)} failed ({rc})")
    if name in DROP:
        log = read_log(out)
        for topic in DROP[name]:
            log.channels.pop(topic, None)
            log.schemas.pop(topic, None)
        log.add_provenance(producer="tests/data/make_datasets.py", source=out.name,
                           settings={"dropped_channels": DROP[name]})
        write_log(log, out, force=True)
    return out


if __name__ == "__main__":
    names = sys.argv[1:] or list(DATASETS)
    for n in names:
        p = make(n)
        print(f"{_rel(p)}: {p.stat().st_size / 1e6:.2f} MB  ({DATASETS[n][1]})")
