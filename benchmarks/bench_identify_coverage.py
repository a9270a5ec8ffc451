"""Honesty of the reported uncertainty: coverage of the 95% intervals over seeds.

10-minute excitation runs (GPS 1.5 m at 10 Hz, compass 2 deg at 20 Hz), with and without
a 0.2 m/s current; prints per-parameter errors of output error and equation error, and how
often each output-error 95% interval contains the truth.

    python benchmarks/bench_identify_coverage.py [--seeds 10] [--current 0.2]
"""

from __future__ import annotations

import argparse
import sys  # noqa: E402
import time
from pathlib import Path  # noqa: E402

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout

from usvlog.identify import Identifier
from usvlog.model.vessel import PARAM_NAMES, VesselParams
from usvlog.sim.simulate import SimSettings, simulate


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--current", type=float, default=0.2)
    ap.add_argument("--duration-s", type=float, default=600.0)
    args = ap.parse_args()
    true = VesselParams().as_array()
    cur_true = args.current * np.array([np.cos(np.radians(60.0)), np.sin(np.radians(60.0))])
    hits = np.zeros(6 + 2)
    oe_err, ee_err, cur_err = [], [], []
    for seed in range(args.seeds):
        log = simulate("excitation", SimSettings(duration_s=args.duration_s, current_mps=args.current,
                                                 current_dir_deg=60.0), seed=1000 + seed)
        t = time.perf_counter()
        idf = Identifier("output-error").fit([log])
        dt = time.perf_counter() - t
        th = idf.theta_
        se = np.array([idf.stderr_[k] for k in PARAM_NAMES])
        hits[:6] += np.abs(th - true) <= 1.959964 * se
        c, cse = np.array(idf.current_[0]), np.array(idf.current_stderr_[0])
        hits[6:] += np.abs(c - cur_true) <= 1.959964 * cse
        oe_err.append(100 * (th / true - 1))
        ee_err.append(100 * (idf.equation_error_.theta / true - 1))
        cur_err.append(np.abs(c - cur_true).max())
        print(f"seed {seed}: {dt:5.1f} s  OE err % " + " ".join(f"{e:+6.2f}" for e in oe_err[-1])
              + f"  current err {cur_err[-1]:.4f} m/s  | EE err % " + " ".join(f"{e:+6.1f}" for e in ee_err[-1]),
              flush=True)
    n = args.seeds
    names = list(PARAM_NAMES) + ["current_n", "current_e"]
    print(f"\ncurrent {args.current} m/s, {n} seeds")
    print("coverage of 95% intervals: " + ", ".join(f"{k} {h / n:.0%}" for k, h in zip(names, hits)))
    oe, ee = np.abs(np.array(oe_err)), np.abs(np.array(ee_err))
    print("output error   |err| % mean (max): " + ", ".join(f"{k} {a:.2f} ({b:.2f})" for k, a, b in
                                                       zip(PARAM_NAMES, oe.mean(0), oe.max(0))))
    print("equation error |err| % mean (max): " + ", ".join(f"{k} {a:.1f} ({b:.1f})" for k, a, b in
                                                       zip(PARAM_NAMES, ee.mean(0), ee.max(0))))
    print(f"current |err| max {max(cur_err):.4f} m/s")


if __name__ == "__main__":
    main()
