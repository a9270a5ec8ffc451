"""Time the estimator on a simulated run (default 1 hour at 100 Hz): the plain per-step
filterpy loop (+ numpy RTS smoother) against the compiled fast path and against the whole
``usvlog.estimate.estimate()`` call a user runs (problem building, outlier handling, result
frames and report included), side by side.

    python benchmarks/bench_estimate.py [--duration-s 3600] [--model kinematic|dynamic|both]
                                        [--reference-s SECONDS] [--[no-]sway-damping]
                                     [--gps-only] [--gps-rate-hz 10]

The compiled kernels are timed as they run (one thread). Default: both models, the CLI default first
(``usvlog estimate``: kinematic, 10 states, sway damping on), then the dynamic model.
``--reference-s`` times the filterpy loop on the
first SECONDS only and scales its time to the whole run (the loop's cost is linear in the
number of steps). ``--gps-only`` drops the compass channel (the GNSS-only path: the kinematic
model over ground, heading = course; ``estimate()`` as a whole includes its course post-processing).

    python benchmarks/bench_estimate.py --verb [--duration-s 3600] [--runs 3]

times the ``usvlog estimate`` verb as a user runs it instead: a simulated excitation log
written to a temporary MCAP file, then ``python -m usvlog estimate raw.mcap --out e.mcap``
in a process of its own ``--runs`` times (wall, CPU and peak RSS of each, with the load
average), and the verb's stages in this process (read, problem, kernels, frames, ``to_log``,
write; the kernels' cache loaded first). Nothing in the verb is changed for the timing.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _proc import timed_run  # noqa: E402

from usvlog.estimate import EstimateSettings, build_problem, estimate  # noqa: E402
from usvlog.estimate.layout import gps_only_settings, head_problem, process_noise  # noqa: E402
from usvlog.estimate.run import run_fast, run_reference_path  # noqa: E402
from usvlog.model.vessel import default_vessel  # noqa: E402
from usvlog.sim.simulate import SensorSettings, SimSettings, simulate  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration-s", type=float, default=3600.0)
    ap.add_argument("--model", default="both", choices=["kinematic", "dynamic", "both"])
    ap.add_argument("--reference-s", type=float, default=None)
    ap.add_argument("--sway-damping", action=argparse.BooleanOptionalAction, default=None,
                    help="kinematic model with sway damping (default: as EstimateSettings, on for kinematic)")
    ap.add_argument("--gps-only", action="store_true", help="no compass channel: the GNSS-only path")
    ap.add_argument("--gps-rate-hz", type=float, default=10.0)
    ap.add_argument("--verb", action="store_true", help="time the usvlog estimate verb (see the module doc)")
    ap.add_argument("--runs", type=int, default=3, help="--verb: runs of the verb")
    args = ap.parse_args()
    if args.verb:
        bench_verb(args.duration_s, args.runs)
        return

    t = time.perf_counter()
    sens = SensorSettings(gps_rate_hz=args.gps_rate_hz)
    log = simulate("excitation", SimSettings(duration_s=args.duration_s, current_mps=0.2, sensors=sens), seed=1)
    print(f"simulated {args.duration_s:.0f} s in {time.perf_counter() - t:.1f} s")
    if args.gps_only:
        del log.channels["/compass/heading"]
    for model in (("kinematic", "dynamic") if args.model == "both" else (args.model,)):
        print()
        bench(log, EstimateSettings(model=model, sway_damping=args.sway_damping if model == "kinematic" else None),
              args.reference_s)


def bench(log, s: EstimateSettings, reference_s: float | None) -> None:
    """Time one model: filterpy reference, compiled kernels, the whole estimate() call."""
    t, c = time.perf_counter(), time.process_time()
    pb = build_problem(log, s, default_vessel())
    t_build, c_build = time.perf_counter() - t, time.process_time() - c
    if pb.mode == "gps-only":
        s = gps_only_settings(s)
    print(f"mode {pb.mode}; build_problem {t_build:.2f} s [{c_build:.2f} s]")
    q = process_noise(s)
    n = len(pb.dts)
    run_fast(head_problem(pb, 1000), q, s.max_consecutive_rejects, True)   # compile / load the cache

    t, c = time.perf_counter(), time.process_time()
    fast = run_fast(pb, q, s.max_consecutive_rejects, True)
    t_fast, c_fast = time.perf_counter() - t, time.process_time() - c

    t, c = time.perf_counter(), time.process_time()
    estimate(log, s)
    t_all, c_all = time.perf_counter() - t, time.process_time() - c

    k = n if reference_s is None else min(n, int(reference_s / s.output_step_s))
    t, c = time.perf_counter(), time.process_time()
    ref = run_reference_path(head_problem(pb, k), q, s.max_consecutive_rejects, True)
    t_ref, c_ref = (time.perf_counter() - t) * n / k, (time.process_time() - c) * n / k

    real = (pb.t_ns[-1] - pb.t_ns[0]) * 1e-9
    sway = f", sway damping {'on' if s.sway_damping else 'off'}" if s.model == "kinematic" else ""
    print(f"model {s.model}{sway}, {pb.nx} states, {n} steps, {len(pb.mstep)} measurements, {real:.0f} s of data")
    print("(wall time; CPU time of this process in brackets: the machine may be shared)")
    print(f"filterpy loop + numpy RTS : {t_ref:8.2f} s [{c_ref:7.2f} s]"
          f"{' (scaled from %d steps)' % k if k < n else ''}"
          f"  ({real / t_ref:6.0f}x [{real / c_ref:6.0f}x] real time)")
    print(f"compiled kernels only     : {t_fast:8.2f} s [{c_fast:7.2f} s]"
          f"  ({real / t_fast:6.0f}x [{real / c_fast:6.0f}x] real time)")
    print(f"whole estimate() call     : {t_all:8.2f} s [{c_all:7.2f} s]"
          f"  ({real / t_all:6.0f}x [{real / c_all:6.0f}x] real time)")
    print(f"speed-up, kernels         : {t_ref / t_fast:8.1f}x [{c_ref / c_fast:6.1f}x]")
    print(f"speed-up, estimate()      : {t_ref / t_all:8.1f}x [{c_ref / c_all:6.1f}x]")
    if k == n:
        d = max(float(np.max(np.abs(fast.XS - ref.XS))), float(np.max(np.abs(fast.X - ref.X))))
    else:  # compare the forward pass on the common head
        d = float(np.max(np.abs(fast.X[:k] - ref.X)))
    print(f"max |fast - filterpy|     : {d:.2e}")
    smoother_parts(pb, q, s)


def smoother_parts(pb, q: np.ndarray, s: EstimateSettings, repeat: int = 3) -> None:
    """The kernels' parts in one thread, best of ``repeat`` (CPU time of the thread, then
    wall): the forward pass, the smoother's block re-runs and its backward steps, each over
    the whole run (a block's buffers refilled, then smoothed), output rows every step."""
    from usvlog.estimate import kernels  # (the kernels module, for its parts)
    from usvlog.estimate.layout import POSITION_STD_LIMIT_M
    from usvlog.estimate.run import reinit_nis

    N, nx, M = len(pb.dts), pb.nx, len(pb.mstep)
    C = -(-N // kernels.SMOOTH_BLOCK)
    args = (pb.x0, pb.P0, pb.dts, pb.taus, pb.qjump, pb.mstep, pb.mkind, pb.mz, pb.mR, pb.prm, pb.model, q,
            pb.gates, s.max_consecutive_rejects, POSITION_STD_LIMIT_M ** 2, reinit_nis(pb))
    run = (np.zeros((M, 4)), np.zeros(M, np.int8), np.zeros(N, np.int8), np.empty((C, nx)),
           np.empty((C, nx, nx)), np.empty((C, kernels.N_IST), np.int64), np.empty((C, kernels.NFS)))
    row = np.arange(N, dtype=np.int64)
    XS, SD, PB, bad = np.empty((N, nx)), np.empty((N, nx)), np.empty((0, 3, 3)), np.full(1, -1, np.int64)
    b = kernels.SmoothBuffers(nx)
    carry = np.zeros(nx), np.zeros((nx, nx)), np.zeros(nx), np.zeros((nx, nx)), np.zeros((nx, nx))

    def forward():
        kernels.forward(*args, np.empty(0, np.int64), XS[:0], SD[:0], PB, *run, bad)

    def rerun(c):
        kernels.smooth_rerun(c, *args, *run, b.BX, b.BP, b.BXp, b.BPp, b.BC)

    def back(c):
        kernels.smooth_back(c, N, run[2], b.BX, b.BP, b.BXp, b.BPp, b.BC, *carry, args[14], row, 0, XS, SD, PB, bad)

    def best(parts):
        cpu, wall = [], []
        for _ in range(repeat):
            tr = tb = 0.0
            w = time.perf_counter()
            for c in range(C - 1, -1, -1):
                for part, f in enumerate(parts):
                    t = time.thread_time()
                    f(c)
                    if part:
                        tb += time.thread_time() - t
                    else:
                        tr += time.thread_time() - t
            cpu.append((tr, tb))
            wall.append(time.perf_counter() - w)
        return min(x[0] for x in cpu), min(x[1] for x in cpu), min(wall)

    forward()
    f_cpu, _, f_wall = best([lambda c: forward() if c == 0 else None])
    r_cpu, b_cpu, rb_wall = best([rerun, back])
    print(f"kernel parts, one thread  : forward {f_cpu:.3f} s, re-runs {r_cpu:.3f} s, backward steps {b_cpu:.3f} s "
          f"of CPU ({C} blocks; wall {f_wall:.3f} s, re-runs + backward {rb_wall:.3f} s; {_load()})")


def _load() -> str:
    return "load average " + " ".join(f"{x:.2f}" for x in os.getloadavg())


def bench_verb(duration_s: float, runs: int) -> None:
    """Time ``usvlog estimate`` on a simulated log: the verb in processes of its own, then its stages here."""
    import resource

    from usvlog import api
    from usvlog.estimate import core
    from usvlog.io.mcap import read_log

    with tempfile.TemporaryDirectory() as tmp:
        raw, out = os.path.join(tmp, "raw.mcap"), os.path.join(tmp, "e.mcap")
        env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1]))
        cmd = [sys.executable, "-m", "usvlog"]
        subprocess.run([*cmd, "simulate", "excitation", "--out", raw, "--duration-s", f"{duration_s:g}"],
                       env=env, check=True, capture_output=True)
        print(f"{duration_s:.0f} s excitation log: {os.path.getsize(raw) / 1e6:.1f} MB")
        print("usvlog estimate raw.mcap --out e.mcap   (wall, CPU = user + sys, peak RSS)")
        for i in range(runs + 1):   # the first run fills the kernels' cache, not counted
            r = timed_run([*cmd, "estimate", raw, "--out", out, "--force"], env)
            if r.returncode:
                raise SystemExit(f"usvlog estimate failed (exit {r.returncode})")
            if i:
                print(f"  run {i}: wall {r.wall_s:6.2f} s  CPU {r.cpu_s:6.2f} s "
                      f"(user {r.user_s:.2f}, sys {r.sys_s:.2f})  peak RSS {r.peak_rss_mb:6.0f} MB  "
                      f"[{_load()}]")
        print(f"output {os.path.getsize(out) / 1e6:.1f} MB")

        marks: list[tuple[str, float, float]] = []

        def mark(name: str) -> None:
            marks.append((name, time.perf_counter(), time.process_time()))

        mark("")
        log = read_log(raw, topics=list(core.INPUT_TOPICS), defer=True)
        mark("read (the inputs, others deferred)")
        vessel = log.vessel or default_vessel()
        s = EstimateSettings()
        pb = build_problem(log, s, vessel)
        mark("build_problem")
        run_fast(head_problem(pb, 1000), process_noise(s), s.max_consecutive_rejects, True)
        mark("kernels' cache loaded")
        core._output_run(pb, process_noise(gps_only_settings(s) if pb.mode == "gps-only" else s), s, smoother=True)
        mark("kernels (forward + smoother)")
        res = estimate(log, s, vessel)
        mark("whole estimate() call")
        out_log = res.to_log(log)
        del log
        out_log.redefer(core.INPUT_TOPICS)
        mark("to_log")
        api.save(out_log, out, force=True)
        mark("write")
        print("stages in this process (wall [CPU] s):")
        for (name, w, c), (_, w0, c0) in zip(marks[1:], marks):
            print(f"  {name:36s} {w - w0:6.2f} [{c - c0:5.2f}]")
        print(f"  peak RSS of this process {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB; "
              f"{_load()}")


if __name__ == "__main__":
    main()
