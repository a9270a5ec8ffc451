"""Campaign throughput: N simulated runs sequentially in one process vs on a local Dask cluster.

    python benchmarks/bench_campaign.py [--runs 40] [--duration-s 600] [--workers 2] [--stages import,estimate,identify]

The runs (two boats over a season, tests/campaign/season.py, no corrupt or straight run)
are simulated once into benchmarks/out/campaign_<runs>x<duration>/. Both passes start from
an empty campaign directory and write no report (the report is drawn once, not per run).
Printed:

* wall time of each pass and the speed-up;
* per-run cost: the mean time each task spent in the stages (measured inside the task);
* scheduling overhead per run: ``(workers * (wall - cluster start) - sum of task times) / runs``,
  i.e. what the cluster adds per run beyond the stage work (idle workers at the tail included);
* peak resident memory of one worker process (``ru_maxrss`` of the children) and of the
  sequential process;
* the client's own part, from a third pass with every run reused and the report drawn:
  hashing each source, reading the rows, the drift statistics, the HTML, PNGs and the map;
* the load average (the machine may be shared: say so with the figures).

Both passes run BLAS in one thread per process, as every usvlog verb does and as Dask starts its
workers: with OpenBLAS's own second thread the sequential pass would borrow the other core
(~15 % more CPU than wall time) and the comparison would not be one process against two.
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests" / "campaign"))

from usvlog.cli.common import one_blas_thread  # noqa: E402  (standard library only)

one_blas_thread()   # before numpy loads: one BLAS thread, as `usvlog campaign` runs and as Dask's workers do

from season import ALPHA_DATES, BRAVO_DATES, M_KG, write_season  # noqa: E402

import usvlog  # noqa: E402


def season_dates(n: int) -> tuple[list[str], list[str]]:
    """n run dates over May-August 2026, alternately alpha and bravo."""
    import datetime as dt

    days = [(dt.date(2026, 5, 1) + dt.timedelta(days=int(i * 120 / max(n, 1)))).isoformat() for i in range(n)]
    return days[0::2], days[1::2]


def build(n: int, duration_s: float) -> dict:
    out = ROOT / "benchmarks" / "out" / f"campaign_{n}x{duration_s:.0f}"
    a, b = season_dates(n) if n != len(ALPHA_DATES) + len(BRAVO_DATES) else (ALPHA_DATES, BRAVO_DATES)
    if not (out / "vessels.toml").exists():
        t = time.perf_counter()
        print(f"simulating {n} runs of {duration_s:.0f} s into {out} ...", flush=True)
        s = write_season(out, duration_s=duration_s, alpha_dates=a, bravo_dates=b, straight=False, corrupt=False)
        print(f"  {time.perf_counter() - t:.0f} s", flush=True)
        return s
    return {"runs": out / "runs", "map": out / "vessels.toml"}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=40)
    ap.add_argument("--duration-s", type=float, default=600.0)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--stages", default="import,estimate,identify")
    ap.add_argument("--skip-sequential", action="store_true")
    args = ap.parse_args()
    s = build(args.runs, args.duration_s)
    work = ROOT / "benchmarks" / "out" / "campaign_work"
    opts = dict(vessel_map=s["map"], fix={"m": M_KG}, current=False, stages=args.stages.split(","), report=False)
    print(f"load average before: {' '.join(f'{x:.2f}' for x in os.getloadavg())}", flush=True)

    seq = None
    if not args.skip_sequential:
        shutil.rmtree(work, ignore_errors=True)
        t = time.perf_counter()
        r = usvlog.campaign([s["runs"]], work / "seq", sequential=True, **opts)
        seq = time.perf_counter() - t
        cpu_seq = resource.getrusage(resource.RUSAGE_SELF)
        per = r.table["seconds"].to_numpy()
        rss_seq = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        print(f"sequential: {seq:.1f} s for {len(per)} runs ({r.failed} failed); per run {per.mean():.2f} s "
              f"(min {per.min():.2f}, max {per.max():.2f}); CPU {cpu_seq.ru_utime + cpu_seq.ru_stime:.1f} s; "
              f"peak RSS {rss_seq:.0f} MB", flush=True)

    started = {}
    shutil.rmtree(work / "dask", ignore_errors=True)   # from an empty campaign, also with --skip-sequential
    t, c_main = time.perf_counter(), time.process_time()
    r = usvlog.campaign([s["runs"]], work / "dask", workers=args.workers,
                        progress=lambda m: started.setdefault("t", time.perf_counter()), **opts)
    wall = time.perf_counter() - t
    c_main = time.process_time() - c_main
    start = started.get("t", t) - t
    per = r.table["seconds"].to_numpy()
    rss = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    over = (args.workers * (wall - start) - per.sum()) / len(per)
    print(f"dask {args.workers} workers: {wall:.1f} s ({start:.1f} s to plan and start the cluster); per run "
          f"{per.mean():.2f} s in the task; scheduling overhead {over:.3f} s per run; peak RSS of a worker "
          f"{rss:.0f} MB", flush=True)
    print(f"  this process (scheduler, nannies, client) used {c_main:.1f} s CPU meanwhile: "
          f"{100 * c_main / (wall * (os.cpu_count() or 1)):.1f} % of the machine's cores", flush=True)
    if seq:
        print(f"speed-up {seq / wall:.2f}x (ideal {args.workers}x)")
    # the client's own part: the same campaign again (every run reused: planning with each
    # source's sha256, the table, the drift statistics) and its report (HTML, PNGs, the map)
    t, c = time.perf_counter(), time.process_time()
    r = usvlog.campaign([s["runs"]], work / "dask", workers=args.workers, **{**opts, "report": True})
    print(f"client, every run reused, with the report: {time.perf_counter() - t:.1f} s wall, "
          f"{time.process_time() - c:.1f} s CPU for {len(r.table)} runs ({r.reused} reused)", flush=True)
    print(f"load average after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    main()
