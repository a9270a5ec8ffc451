"""Time ``to_rrd`` on a 1-hour log against per-row Rerun logging of the same scalars.

The log: a simulated 3600 s excitation run (GPS 10 Hz, compass 20 Hz, thrust 100 Hz,
truth 100 Hz) plus an ``/estimate/state`` channel and a ``/replay/controller`` channel at
100 Hz built from the truth (the volume the smoother and the replay would write).
``to_rrd`` sends everything with ``rr.send_columns``.

The per-row baseline logs the very same time-series scalars (read back from the .rrd)
one sample at a time, ``rec.set_time(...)`` + ``rec.log(path, rr.Scalars(x))``. It is timed
on a 1/20 slice of every series and scaled by 20 (the cost is linear in the rows), so the
benchmark does not take ten minutes. Run: ``python benchmarks/bench_view.py``.

``--cli LOG`` instead runs ``usvlog view LOG`` and ``usvlog report LOG`` as a user would
(separate processes, ``--repeat`` times each) and prints per run the wall time, the CPU of
the main thread, of the rest of the process (rerun's threads) and of its forked copies (the one
reading a channel while the process imports rerun or matplotlib, the report's figure drawer),
the peak RSS of the process and of the largest copy, and the load average: what the two cores do.

``--figures LOG`` prints the CPU seconds each report figure of LOG takes to draw (best of
``--repeat``) and the page's text, which ``usvlog.view.report.FIGURE_COST`` holds for a 1-hour
log (the report shares the figures between two processes by these), and how it shares them.
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout

from usvlog.log.channels import channel_spec, frame_from_columns
from usvlog.sim.simulate import SimSettings, simulate
from usvlog.view.rrd import to_rrd


def hour_log(duration_s: float):
    log = simulate("excitation", SimSettings(duration_s=duration_s, current_mps=0.2, current_dir_deg=60.0), seed=1)
    tr = log["/truth/state"]
    rng = np.random.default_rng(0)
    est = {"t": (tr.index.to_numpy() - tr.index[0]) / 1e9}
    for c in ("n_m", "e_m", "psi_rad", "u_mps", "v_mps", "r_radps", "current_n_mps", "current_e_mps"):
        est[c] = tr[c].to_numpy() + rng.normal(0, 0.01, len(tr))
        est[c + "_std"] = np.full(len(tr), 0.05)
    log.set("/estimate/state", frame_from_columns(est, tr.index.to_numpy(), channel_spec("/estimate/state")))
    # a replayed controller at 100 Hz (the volume of /replay/controller; values built from the truth)
    n = len(tr)
    z = np.zeros(n)
    ctl = {"theta": np.arange(n) * 0.01, "closest_n_m": tr["n_m"].to_numpy() + 1.0,
           "closest_e_m": tr["e_m"].to_numpy(), "carrot_n_m": tr["n_m"].to_numpy() + 3.0,
           "carrot_e_m": tr["e_m"].to_numpy() + 1.0, "psi_ref_rad": tr["psi_rad"].to_numpy(),
           "psi_d_rad": tr["psi_rad"].to_numpy() + 0.05, "r_d_radps": z, "r_d_dot_radps2": z,
           "u_d_mps": np.where(np.arange(n) < n // 2, 0.4, 0.6), "u_d_dot_mps2": z,
           "u_e_mps": tr["u_mps"].to_numpy() - 0.4, "psi_e_rad": z + 0.05, "cross_track_m": z + 1.0,
           "tau_u_n": tr["tau_u_n"].to_numpy(), "tau_r_nm": tr["tau_r_nm"].to_numpy(), "thrust_left_n": z,
           "thrust_right_n": z, "cmd_left": z, "cmd_right": z, "saturated": np.zeros(n, bool)}
    log.set("/replay/controller", frame_from_columns(ctl, tr.index.to_numpy(), channel_spec("/replay/controller")))
    return log


def series_of(rrd: Path):
    from rerun.chunk import RrdReader

    out: dict[str, tuple[list, list]] = {}
    for c in RrdReader(rrd).stream().to_chunks():
        if c.is_static or "/ts/" not in c.entity_path:
            continue
        rb = c.to_record_batch()
        t = rb.column("time").cast("int64").to_numpy()
        y = np.concatenate(rb.column("Scalars:scalars").to_numpy(zero_copy_only=False))
        ts, ys = out.setdefault(c.entity_path, ([], []))
        ts.append(t)
        ys.append(y)
    return {k: (np.concatenate(v[0]), np.concatenate(v[1])) for k, v in out.items()}


def per_row(series, path: Path, fraction: int) -> tuple[float, int]:
    import rerun as rr

    rec = rr.RecordingStream("usvlog-bench", recording_id="per-row", send_properties=False)
    rec.save(path)
    n = 0
    t0 = time.perf_counter()
    for ent, (t, y) in series.items():
        k = len(t) // fraction
        for tt, yy in zip(t[:k].tolist(), y[:k].tolist()):
            rec.set_time("time", timestamp=np.datetime64(tt, "ns"))
            rec.log(ent, rr.Scalars(yy))
        n += k
    rec.flush()
    rec.disconnect()
    return time.perf_counter() - t0, n


PER_THREAD = """
import os, resource, runpy, sys, time
t0 = time.perf_counter()
sys.argv = ["usvlog", *sys.argv[1:]]
try:
    runpy.run_module("usvlog", run_name="__main__")
except SystemExit:
    pass
s, c = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
main = time.thread_time()
print(f"{time.perf_counter() - t0:.2f} {s.ru_utime + s.ru_stime:.2f} {main:.2f} "
      f"{c.ru_utime + c.ru_stime:.2f} {s.ru_maxrss / 1024:.0f} {c.ru_maxrss / 1024:.0f}", file=sys.stderr)
"""


def cli(log: Path, repeat: int) -> None:
    """``usvlog view`` and ``usvlog report`` of ``log`` in separate processes, CPU per thread."""
    import os
    import subprocess

    root = Path(__file__).resolve().parents[1]
    env = {**os.environ, "PYTHONPATH": str(root) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    with tempfile.TemporaryDirectory() as d:
        verbs = {"view": ["view", str(log), "--out", str(Path(d) / "v.rrd"), "--force"],
                 "report": ["report", str(log), "--out", str(Path(d) / "report"), "--force"]}
        for _ in range(repeat):
            for name, args in verbs.items():
                load = os.getloadavg()[0]
                p = subprocess.run([sys.executable, "-c", PER_THREAD, *args], env=env, capture_output=True,
                                   text=True, check=True)
                wall, cpu, main, kids, rss, kid_rss = p.stderr.strip().splitlines()[-1].split()
                rest = float(cpu) - float(main)
                print(f"{name:6s} {float(wall):5.2f} s wall; CPU {cpu} s in the process (main thread {main}, "
                      f"other threads {rest:.2f}) + {kids} s forked copies (reader, figure drawer); "
                      f"peak RSS {rss} MB (copies {kid_rss} MB); load {load:.2f}", flush=True)


def figure_costs(log_path: Path, repeat: int) -> None:
    """CPU seconds of each report figure of ``log_path`` and of the page's text, best of ``repeat``."""
    from usvlog.io.mcap import read_log
    from usvlog.view import report as rp
    from usvlog.view.source import REPORT_TOPICS, read_drawn

    log = read_drawn(log_path, REPORT_TOPICS, read_log)
    figs = rp.figures(log)
    rp._drawn(figs[0][1], figs[0][2])   # matplotlib's first-figure set-up (fonts) apart
    best: dict[str, float] = {}
    for _ in range(repeat):
        for name, title, make, _needs in figs:
            t = time.process_time()
            drawn = rp._drawn(title, make)
            if drawn is not None:
                best[name] = min(best.get(name, math.inf), time.process_time() - t)
        t = time.process_time()
        rp._page_head(log, None)
        best["(page)"] = min(best.get("(page)", math.inf), time.process_time() - t)
    for name, s in best.items():
        print(f"{name:24s} {s:6.3f} CPU s   (table: {rp.FIGURE_COST.get(name, rp.PAGE_COST):.2f})")
    costs = rp.figure_costs(figs, log)
    theirs = rp.share(costs, rp.PAGE_COST)
    mine = [figs[i][0] for i in range(len(figs)) if costs[i] > 0 and i not in theirs]
    print(f"this process: {mine} + the page; the forked copy: {[figs[i][0] for i in theirs]}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration-s", type=float, default=3600.0)
    ap.add_argument("--fraction", type=int, default=20, help="per-row logging is timed on 1/fraction of the rows")
    ap.add_argument("--cli", type=Path, metavar="LOG",
                    help="time `usvlog view LOG` and `usvlog report LOG` as processes, CPU per thread")
    ap.add_argument("--figures", type=Path, metavar="LOG", help="CPU seconds of each report figure of LOG")
    ap.add_argument("--repeat", type=int, default=3, help="runs of each verb (--cli), of each figure (--figures)")
    args = ap.parse_args()
    if args.cli is not None:
        cli(args.cli, args.repeat)
        return
    if args.figures is not None:
        figure_costs(args.figures, args.repeat)
        return
    t = time.perf_counter()
    log = hour_log(args.duration_s)
    print(f"built a {args.duration_s:.0f} s log in {time.perf_counter() - t:.1f} s: "
          + ", ".join(f"{k} {len(v)}" for k, v in log.channels.items()))
    with tempfile.TemporaryDirectory() as d:
        out = Path(d) / "hour.rrd"
        t = time.perf_counter()
        to_rrd(log, out)
        cols = time.perf_counter() - t
        series = series_of(out)
        n_scalars = sum(len(v[0]) for v in series.values())
        print(f"to_rrd (send_columns): {cols:.2f} s for the whole log "
              f"({n_scalars:,} time-series scalars in {len(series)} series, plus tracks, overlays, events; "
              f"{out.stat().st_size / 1e6:.1f} MB)")
        secs, n = per_row(series, Path(d) / "rows.rrd", args.fraction)
        scaled = secs * n_scalars / max(n, 1)
        print(f"per-row (set_time + log per sample): {secs:.2f} s for {n:,} scalars (1/{args.fraction}), "
              f"scaled to all {n_scalars:,}: {scaled:.1f} s")
        print(f"to_rrd is {scaled / cols:.0f}x faster than per-row logging of the time series alone")


if __name__ == "__main__":
    main()
