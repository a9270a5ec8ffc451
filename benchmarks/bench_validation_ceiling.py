"""What a perfect model scores: the true motion of the shared Otter runs, scored as identify validates.

``usvlog identify`` judges a model by its free run over the held-out part, compared like with like
(:mod:`usvlog.identify.seen`): the free run is sampled at the log's GNSS and compass stamps and
smoothed exactly as the measurements were, and fit % of u, v and r is taken between the two
smoothed series after the initial-state window. A perfect model's free run is the true motion, so
scoring the true motion (``*_truth10hz.csv.gz``: positions, heading, water-relative u and v, r; the
current from the true ground and water-relative velocities) the same way gives the fit % of a
perfect model on that part: what keeps it under 100 is the GNSS and compass noise the smoother lets
through. A model's fit % above it would be luck (its errors matching that noise), not skill.

    python benchmarks/bench_validation_ceiling.py [--trainlogs ../shared/trainlogs] [--holdout 0.4]

Each run is imported from its CSV as its README says (``usvlog import`` with the column mapping),
into a temporary MCAP file, and smoothed with identify's own settings (process noise tuned to the
run). Printed per run: the truth's like-with-like fit % of u, v and r (the ceiling), and, for
comparison, the truth against the smoothed measurements directly (what the smoother's own error
costs without the like-with-like comparison).
"""

from __future__ import annotations

import argparse
import importlib
import json
import sys
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # run from a checkout

from usvlog.api import import_log  # noqa: E402
from usvlog.identify.data import run_data  # noqa: E402
from usvlog.io.mcap import read_log  # noqa: E402
from usvlog.model.stats import fit_percent  # noqa: E402
from usvlog.model.vessel import Thrusters, Vessel  # noqa: E402

smooth = importlib.import_module("usvlog.identify.smooth")   # the module, not the verb function

COLUMNS = {"time_s": "t", "lat_deg": "lat_deg", "lon_deg": "lon_deg", "heading_deg": "heading_deg",
           "thrust_left": "thrust_cmd_left_N", "thrust_right": "thrust_cmd_right_N"}
START_UTC = "2026-06-01T12:00:00Z"
INIT_WINDOW_S = 60.0   # identify's validation: the initial state is fitted on the part's first 60 s (at most half)


def ceiling(sensor_csv: Path, truth_csv: Path, holdout: float, work: Path) -> dict:
    """{"like with like": fit % of u, v, r, "directly": ..., "current_ne_mps"} of the true motion over the
    last ``holdout`` of a run."""
    boat = Vessel(name="otter", thrusters=Thrusters(arm_m=0.395, forward_n=120.0, reverse_n=67.0))
    out = work / (sensor_csv.name.split(".")[0] + ".mcap")
    import_log(sensor_csv, out, fmt="csv", columns=COLUMNS, thrust_unit="newton", start_utc=START_UTC,
               vessel=boat, force=True)
    log = read_log(out)
    run = run_data(log, boat)
    ks = smooth.kinematic_states(log, run, boat, tune=True)
    tr = pd.read_csv(truth_csv)
    cut = run.t_thrust[0] + (1 - holdout) * run.duration_s
    # the truth's times are s from the CSV's first row (START_UTC), the run's from its first thrust sample
    t_all = tr["t"].to_numpy(float) - (run.t0_ns - pd.Timestamp(START_UTC).value) / 1e9
    keep = (t_all >= cut) & (t_all <= run.t_thrust[-1])
    t = t_all[keep]
    sim = np.column_stack([tr[c].to_numpy(float)[keep] for c in
                           ("x_north_m", "y_east_m", "psi_unwrapped_rad", "u_rel_mps", "v_rel_mps", "r_radps")])
    c, s = np.cos(sim[:, 2]), np.sin(sim[:, 2])
    du, dv = tr["u_mps"].to_numpy(float)[keep] - sim[:, 3], tr["v_mps"].to_numpy(float)[keep] - sim[:, 4]
    current = (float(np.mean(c * du - s * dv)), float(np.mean(s * du + c * dv)))
    seen = ks.seen(t, sim, current)
    meas = ks.at(t, current)
    after = t > t[0] + min(INIT_WINDOW_S, 0.5 * (t[-1] - t[0]))
    names = (("u", 3), ("v", 4), ("r", 5))
    return {"current_ne_mps": [round(x, 3) for x in current],
            "like with like": {n: round(fit_percent(meas[after, i], seen[after, i]), 1) for n, i in names},
            "directly": {n: round(fit_percent(meas[after, i], sim[after, i]), 1) for n, i in names}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trainlogs", type=Path, default=ROOT.parent / "shared" / "trainlogs")
    ap.add_argument("--holdout", type=float, default=0.4, help="the last share of each run scored (0.4: the issue's)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        for sensor in sorted(args.trainlogs.glob("*_sensor.csv.gz")):
            truth = sensor.with_name(sensor.name.replace("_sensor.csv.gz", "_truth10hz.csv.gz"))
            res = ceiling(sensor, truth, args.holdout, Path(tmp))
            print(f"{sensor.name}: the truth scored like with like {json.dumps(res['like with like'])}; "
                  f"against the smoothed measurements directly {json.dumps(res['directly'])}; "
                  f"current {res['current_ne_mps']} m/s", flush=True)


if __name__ == "__main__":
    main()
