"""ROS bag import: the listing pass (catalog) and the whole import, messages/s and peak RSS.

The bag is listed first (every record read once for counts and spans, the first message of
each topic decoded), then the mapped topics are read. This prints what the listing costs
next to the whole import, for a ROS 1 bag of NavSatFix at 10 Hz and Imu at 100 Hz.

Each measurement runs in its own Python process (peak RSS = its ru_maxrss); rates are given
per wall-clock second and per CPU second (the fairer figure on a shared machine).

Run:  python benchmarks/bench_import_bag.py [--imu 100000]
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
T0 = 1_714_557_600_000_000_000

CHILD = r"""
import json, resource, sys, time
from pathlib import Path
what, path = sys.argv[1], Path(sys.argv[2])
t0, c0 = time.perf_counter(), time.process_time()
if what == "catalog":
    from usvlog.io.importers.rosbag import catalog
    n = sum(t.count for t in catalog(path).topics)
else:
    from usvlog.io.importers import import_file
    n = import_file(path).report.records
print(json.dumps({"n": n, "wall": time.perf_counter() - t0, "cpu": time.process_time() - c0,
                  "rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def write_bag(path: Path, n_imu: int) -> None:
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    T = store.types
    V3 = T["geometry_msgs/msg/Vector3"]
    with Writer(path) as w:
        cf = w.add_connection("/gps/fix", "sensor_msgs/msg/NavSatFix", typestore=store)
        ci = w.add_connection("/imu/data", "sensor_msgs/msg/Imu", typestore=store)
        for i in range(n_imu):
            t = T0 + i * 10_000_000
            h = T["std_msgs/msg/Header"](seq=i, stamp=T["builtin_interfaces/msg/Time"](sec=t // 10**9,
                                                                                        nanosec=t % 10**9),
                                         frame_id="x")
            if i % 10 == 0:
                fix = T["sensor_msgs/msg/NavSatFix"](
                    header=h, status=T["sensor_msgs/msg/NavSatStatus"](status=0, service=1), latitude=59 + i * 1e-7,
                    longitude=10.0, altitude=1.0, position_covariance=np.zeros(9), position_covariance_type=0)
                w.write(cf, t, store.serialize_ros1(fix, "sensor_msgs/msg/NavSatFix"))
            q = T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(i / 1e4), w=math.cos(i / 1e4))
            imu = T["sensor_msgs/msg/Imu"](
                header=h, orientation=q, orientation_covariance=np.zeros(9), angular_velocity=V3(x=0.0, y=0.0, z=0.1),
                angular_velocity_covariance=np.zeros(9), linear_acceleration=V3(x=0.0, y=0.0, z=9.8),
                linear_acceleration_covariance=np.zeros(9))
            w.write(ci, t, store.serialize_ros1(imu, "sensor_msgs/msg/Imu"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--imu", type=int, default=100_000, help="Imu messages (NavSatFix: a tenth of that)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        bag = Path(d) / "bench.bag"
        write_bag(bag, args.imu)
        mb = bag.stat().st_size / 1e6
        print(f"bag: {mb:.1f} MB, {args.imu + args.imu // 10} messages")
        for what in ("catalog", "import"):
            r = json.loads(subprocess.run([sys.executable, "-c", CHILD, what, str(bag)], check=True,
                                          capture_output=True, text=True, cwd=ROOT).stdout)
            print(f"{what:<8} {r['n']:>8} msgs  wall {r['wall']:6.2f} s ({r['n'] / r['wall']:>9,.0f}/s)  "
                  f"cpu {r['cpu']:6.2f} s ({r['n'] / r['cpu']:>9,.0f}/s)  peak RSS {r['rss_mb']:.0f} MB")


if __name__ == "__main__":
    main()
