"""Write speed: usvlog.write_log vs the mcap library Writer (one add_message per message)
on the 1-hour log (468k messages); and the bulk derived channels as JSON vs CDR.

    python benchmarks/bench_write.py
    python benchmarks/bench_write.py --derived r.mcap   # only: the derived channels of r.mcap
    python benchmarks/bench_write.py --verb replay e.mcap    # only: replay's write of r.mcap
    python benchmarks/bench_write.py --verb estimate raw.mcap  # only: estimate's write of e.mcap

``--derived FILE`` (default: the 1-hour simulation's ``/truth/state``) takes the channels of
FILE that are written as CDR (``usvlog.log.channels.BULK_TOPICS``: estimate states, replay,
fit, simulation truth) and writes them twice with ``write_log``: as JSON with their JSON
Schema (as before) and as CDR; CPU time (this process, its threads included) and wall
time of the encoding + compression, best of 3, file sizes, and ``read_log``'s decoding time.

``--verb replay FILE`` / ``--verb estimate FILE`` read FILE as the verb does (its inputs
only, the other channels left in the file and copied as whole chunks), run it (replay: the
paper-sine scenario), then time ``write_log`` of its output: the first write of the process
(the verb's: nothing warmed) and the best of 3 more; wall, CPU of the process (its threads
included) and of the calling thread alone.

Both are timed the same way: one warm-up write each, then best of 3. The library Writer
compresses at zstd level 3, usvlog at level 1 (smaller and faster on these logs), so the
files differ in their chunks' compressed bytes only; written at level 3 ours is the
library's file byte for byte (checked here, and in tests/io).
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

from _log import hour_file


def best_of(fn, n=3):
    best = float("inf")
    for _ in range(n):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def best_cpu(fn, n=3) -> tuple[float, float]:
    """(best wall s, best CPU s of this process, its threads included) of ``fn()``."""
    wall = cpu = float("inf")
    for _ in range(n):
        t, c = time.perf_counter(), time.process_time()
        fn()
        wall, cpu = min(wall, time.perf_counter() - t), min(cpu, time.process_time() - c)
    return wall, cpu


def derived(path: Path | None) -> None:
    """The bulk derived channels written and read as JSON and as CDR."""
    import usvlog.io.mcap.codec as codec_mod
    from usvlog.io.mcap import read_log, write_log
    from usvlog.log.channels import BULK_TOPICS
    from usvlog.log.fieldlog import FieldLog

    if path is None:   # the cached hour log drops the truth: simulated here
        from usvlog.sim.simulate import SimSettings, simulate

        src = simulate("excitation", SimSettings(duration_s=3600.0), seed=1)
    else:
        src = read_log(path, topics=sorted(BULK_TOPICS))
    log = FieldLog()
    for t in src.topics:
        if t in BULK_TOPICS:
            log.channels[t] = src.channels[t]
            log.schemas[t] = src.schemas[t]
    n = sum(len(f) for f in log.channels.values())
    print(f"derived channels of {path or '1 h simulation'}: "
          + ", ".join(f"{t} {len(f)}" for t, f in log.channels.items()))
    rows = []
    with tempfile.TemporaryDirectory() as d:
        for name, bulk in (("JSON + JSON Schema", frozenset()), ("CDR + ros2msg", BULK_TOPICS)):
            out = Path(d) / "d.mcap"
            saved, codec_mod.BULK_TOPICS = codec_mod.BULK_TOPICS, bulk
            try:
                write_log(log, out, force=True)  # warm-up
                w_wall, w_cpu = best_cpu(lambda out=out: write_log(log, out, force=True))
            finally:
                codec_mod.BULK_TOPICS = saved
            read_log(out)  # warm-up
            r_wall, r_cpu = best_cpu(lambda out=out: read_log(out))
            rows.append((name, w_wall, w_cpu, r_wall, r_cpu, out.stat().st_size / 1e6))
    print(f"{n} messages; load average {os.getloadavg()[0]:.2f} (1 min), {os.cpu_count()} CPUs; best of 3")
    print(f"{'encoding':20s} {'write wall':>10s} {'write CPU':>10s} {'read wall':>10s} {'read CPU':>10s} {'size':>9s}")
    for name, ww, wc, rw, rc, mb in rows:
        print(f"{name:20s} {ww:9.2f}s {wc:9.2f}s {rw:9.2f}s {rc:9.2f}s {mb:7.1f}MB")
    (_, ww0, wc0, rw0, rc0, _), (_, ww1, wc1, rw1, rc1, _) = rows
    print(f"CDR vs JSON: write {wc0 / wc1:.1f}x less CPU ({ww0 / ww1:.1f}x wall), "
          f"read {rc0 / rc1:.1f}x less CPU ({rw0 / rw1:.1f}x wall)")


def verb_write(verb: str, path: Path) -> None:
    """A verb's output log written: the first write of the process, then the best of 3."""
    from usvlog import api
    from usvlog.io.mcap import write_log

    if verb == "replay":
        from usvlog.replay import replay_log
        from usvlog.sim.scenario import load_scenario

        log = api._read(str(path), None, topics=api._REPLAY_READS, defer=True)
        out = replay_log(log, load_scenario("paper-sine"), release_inputs=True).log
    else:
        from usvlog.estimate import EstimateSettings, estimate
        from usvlog.estimate.core import INPUT_TOPICS

        log = api._read(str(path), None, topics=list(INPUT_TOPICS), defer=True)
        out = estimate(log, EstimateSettings(), None).to_log(log)
        del log
        out.redefer(INPUT_TOPICS)
    with tempfile.TemporaryDirectory() as d:
        dst = Path(d) / "out.mcap"
        runs = []
        for _ in range(4):
            t, c, m = time.perf_counter(), time.process_time(), time.thread_time()
            write_log(out, dst, force=True)
            runs.append((time.perf_counter() - t, time.process_time() - c, time.thread_time() - m))
        size = dst.stat().st_size / 1e6
    print(f"{verb}'s write of {path} ({size:.0f} MB); load average {os.getloadavg()[0]:.2f} (1 min), "
          f"{os.cpu_count()} CPUs")
    best = min(runs[1:])
    for name, (w, c, m) in (("first write", runs[0]), ("best of 3 more", best)):
        print(f"{name:15s} wall {w:6.2f} s  CPU {c:6.2f} s  calling thread {m:6.2f} s")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--derived", nargs="?", const="", default=None, metavar="FILE",
                    help="only the derived channels (of FILE; default the 1-hour simulation's truth)")
    ap.add_argument("--verb", nargs=2, metavar=("VERB", "FILE"),
                    help="only the output write of VERB (replay or estimate) on FILE")
    args = ap.parse_args()
    if args.derived is not None:
        derived(Path(args.derived) if args.derived else None)
        return
    if args.verb is not None:
        if args.verb[0] not in ("replay", "estimate"):
            ap.error("--verb: replay or estimate")
        verb_write(args.verb[0], Path(args.verb[1]))
        return
    from usvlog.io.mcap import read_log, write_log
    from usvlog.io.mcap.reference import _write_log_reference

    log = read_log(hour_file())
    n = sum(len(f) for f in log.channels.values())
    with tempfile.TemporaryDirectory() as d:
        ours, ref = Path(d) / "ours.mcap", Path(d) / "ref.mcap"
        write_log(log, ours, force=True)  # warm-up
        t_ours = best_of(lambda: write_log(log, ours, force=True))
        size = ours.stat().st_size / 1e6
        _write_log_reference(log, ref, force=True)  # warm-up
        t_ref = best_of(lambda: _write_log_reference(log, ref, force=True))
        ref_size = ref.stat().st_size / 1e6
        t_ours3 = best_of(lambda: write_log(log, ours, force=True, zstd_level=3))
        same = ours.read_bytes() == ref.read_bytes()
    print(f"{n} messages; load average {os.getloadavg()[0]:.2f} (1 min), {os.cpu_count()} CPUs")
    print(f"mcap Writer, add_message per message (zstd 3): {t_ref:7.3f} s  {n / t_ref:12,.0f} msg/s  {ref_size:.1f} MB")
    print(f"usvlog write_log (zstd 1, default):            {t_ours:7.3f} s  {n / t_ours:12,.0f} msg/s  {size:.1f} MB")
    print(f"usvlog write_log (zstd 3):                     {t_ours3:7.3f} s  {n / t_ours3:12,.0f} msg/s")
    print(f"speed-up: {t_ref / t_ours:.1f}x (same level: {t_ref / t_ours3:.1f}x); "
          f"identical bytes at level 3: {same}")


if __name__ == "__main__":
    main()
