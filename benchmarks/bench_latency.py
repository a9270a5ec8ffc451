"""Time the estimate with and without the latency search on a simulated run (default 1 hour,
GNSS stamped 0.2 s late): the compiled path end to end (build, search, filter, smoother).

    python benchmarks/bench_latency.py [--duration-s 3600] [--model dynamic|kinematic]
                                       [--delays gnss|gnss,compass] [--gps-noise-m 1.5]

The search evaluates the forward filter's likelihood on a window of
``usvlog.estimate.latency.WINDOW_S`` seconds per sensor, so its cost does not grow with the log.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from usvlog.estimate import EstimateSettings, estimate  # noqa: E402
from usvlog.sim.simulate import SensorSettings, SimSettings, simulate  # noqa: E402


def _timed(log, settings):
    t, c = time.perf_counter(), time.process_time()
    res = estimate(log, settings)
    return res, time.perf_counter() - t, time.process_time() - c


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration-s", type=float, default=3600.0)
    ap.add_argument("--model", default="dynamic", choices=["kinematic", "dynamic"])
    ap.add_argument("--delays", default="gnss", help="sensors whose delay is searched, comma-separated")
    ap.add_argument("--gps-noise-m", type=float, default=1.5)
    args = ap.parse_args()

    t = time.perf_counter()
    sens = SensorSettings(gps_delay_s=0.2, gps_noise_m=args.gps_noise_m)
    log = simulate("excitation", SimSettings(duration_s=args.duration_s, sensors=sens), seed=1)
    log.channels.pop("/truth/state", None)
    print(f"simulated {args.duration_s:.0f} s in {time.perf_counter() - t:.1f} s (GNSS 0.2 s late, "
          f"{args.gps_noise_m} m)")
    delays = tuple(x for x in args.delays.split(",") if x)
    plain = EstimateSettings(model=args.model)
    search = EstimateSettings(model=args.model, estimate_delays=delays)
    estimate(simulate("excitation", SimSettings(duration_s=60.0), seed=2), search)   # compile / load the cache

    real = args.duration_s
    print("(wall time; CPU time of this process in brackets: the machine may be shared)")
    _, w0, c0 = _timed(log, plain)
    print(f"estimate, delays given         : {w0:7.2f} s [{c0:6.2f} s]  ({real / w0:6.0f}x [{real / c0:6.0f}x] "
          "real time)")
    res, w1, c1 = _timed(log, search)
    print(f"estimate, delays {'+'.join(delays):14s}: {w1:7.2f} s [{c1:6.2f} s]  ({real / w1:6.0f}x [{real / c1:6.0f}x] "
          f"real time)")
    print(f"latency search alone           : {w1 - w0:7.2f} s [{c1 - c0:6.2f} s]")
    for d in res.report.latency:
        print(f"  {d.format()}  ({d.evaluations} likelihood evaluations)")


if __name__ == "__main__":
    main()
