"""Time the open-loop replay of 1 hour of 100 Hz controller ticks (target <= 3 s).

Builds a 1-hour closed-loop run of the paper-sine scenario on the true state (the path
repeats: a long sinusoid), then times ``replay_log`` without and with the what-if
simulation, and the compiled controller kernel alone. Prints the figures.

    python benchmarks/bench_replay.py [--hours 1.0]
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # run from a checkout

from usvlog.control.law import Controller, speed_at
from usvlog.replay import replay_log
from usvlog.sim.closed_loop import simulate_scenario
from usvlog.sim.scenario import load_scenario


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--hours", type=float, default=1.0)
    args = ap.parse_args()
    dur = 3600.0 * args.hours
    scen = load_scenario("paper-sine")
    scen = replace(scen, controller_input="truth", path_spec=dict(scen.path_spec, length_m=2000.0),
                   sim=replace(scen.sim, duration_s=dur))
    t0 = time.perf_counter()
    log = simulate_scenario(scen)
    t_sim = time.perf_counter() - t0
    n = len(log["/thrust/command"])
    print(f"closed-loop simulation of {dur:.0f} s ({n} controller ticks, plant_step + sensors): {t_sim:.2f} s")

    replay_log(replace(log, channels=dict(log.channels)), replace(scen, sim=replace(scen.sim, duration_s=10.0)),
               whatif=False)  # warm-up: numba compilation / cache load
    t0 = time.perf_counter()
    res = replay_log(log, scen, whatif=False)
    t_rep = time.perf_counter() - t0
    print(f"open-loop replay of {n} ticks ({dur / 3600:.2f} h at 100 Hz): {t_rep:.2f} s "
          f"(target <= 3 s per hour); decisions max |diff| {res.metrics.decisions_max_abs:.2e}")

    tr = log["/truth/state"]
    X = tr[["n_m", "e_m", "psi_rad", "u_mps", "v_mps", "r_radps"]].to_numpy(dtype=float)
    c = Controller(scen.path(), scen.sim.vessel, scen.gains, scen.guidance)
    c.reset(X[0])
    t_rel = np.arange(len(X)) * 0.01
    u = speed_at(scen.schedule, t_rel)
    dth = speed_at(scen.schedule, t_rel, 2)
    t0 = time.perf_counter()
    c.run(X, u, np.full(len(X), 0.01), dth)
    t_k = time.perf_counter() - t0
    print(f"controller kernel alone (guidance {scen.guidance.iterations} iterations + prefilters + law): "
          f"{t_k:.3f} s = {t_k / len(X) * 1e6:.2f} us per tick")

    t0 = time.perf_counter()
    replay_log(log, scen, whatif=True)
    t_w = time.perf_counter() - t0
    print(f"open-loop replay + what-if closed-loop simulation: {t_w:.2f} s")


if __name__ == "__main__":
    main()
