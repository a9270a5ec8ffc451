"""numba load time per verb: what loading the compiled kernels costs each command, cache warm.

    python benchmarks/bench_numba_load.py [--duration-s 600] [--runs 3]

Each verb runs in a fresh interpreter (``usvlog.cli.main``) with numba's dispatcher
instrumented: the figure per kernel is the CPU time of its first call (of the thread calling it) (numba types the
arguments and loads the machine code from usvlog's cache; nothing is compiled when the cache
is warm, which a first untimed run of every verb ensures). Also printed: ``import numba``
(paid by every verb that imports the numeric stack) and the first kernel's extra cost (numba
builds its CPU target: ~180 modules and the typing/lowering registries), which every verb
that calls a kernel pays once whatever it calls. CPU times: the machine may be shared.

Each verb also runs with numba's own cache load (``numba's load``: numba sets its whole
compiler up, every typing/lowering registry and ``scipy.linalg``, before loading cached
code) next to usvlog's (``usvlog's load``: the runtime and the symbols only, see
:mod:`usvlog._jit`), same cache, same process layout; ``verb CPU`` is the process's CPU
from the start of ``import numba`` to the verb's end (best of ``--runs``), so the difference
of the two rows is what the lighter load saves each verb.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

CHILD = textwrap.dedent("""
    import json, os, sys, time
    C = time.process_time
    T = time.thread_time   # a kernel's first call: the calling thread's CPU (a verb may read on a second thread)
    if os.environ.get("BENCH_NUMBA_OWN_LOAD"):
        import usvlog._jit
        usvlog._jit._light_loads = lambda d: d   # numba's own Cache.load_overload
    t0 = C()
    import numba
    t_numba = C() - t0
    from numba.core import dispatcher
    calls = []
    orig = dispatcher.Dispatcher._compile_for_args
    def timed(self, *a, **k):
        c = T()
        try:
            return orig(self, *a, **k)
        finally:
            calls.append((self.py_func.__module__ + "." + self.py_func.__qualname__, T() - c))
    dispatcher.Dispatcher._compile_for_args = timed
    from usvlog.cli import main
    try:
        main(sys.argv[1:])
    except SystemExit:
        pass
    print("@@" + json.dumps({"import_numba": t_numba, "calls": calls, "total": C() - t0}))
""")


def run(argv: list[str], own_load: bool = False) -> dict:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])]))
    env.pop("BENCH_NUMBA_OWN_LOAD", None)
    if own_load:
        env["BENCH_NUMBA_OWN_LOAD"] = "1"
    r = subprocess.run([sys.executable, "-c", CHILD, *argv], capture_output=True, text=True, env=env)
    line = [x for x in r.stdout.splitlines() if x.startswith("@@")]
    if not line:
        raise SystemExit(f"{' '.join(argv)}: {r.stderr[-2000:]}")
    return json.loads(line[-1][2:])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration-s", type=float, default=600.0, help="length of the simulated log")
    ap.add_argument("--runs", type=int, default=3, help="runs per verb and load; the best CPU is shown")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="usvlog-numba-") as d:
        log, est, nmea = f"{d}/e.mcap", f"{d}/est.mcap", str(ROOT / "tests/data/sources/kingfisher.nmea")
        verbs = {
            "simulate excitation": ["simulate", "excitation", "--duration-s", str(args.duration_s), "--out", log,
                                    "--force"],
            "import (nmea)": ["import", nmea, "--out", f"{d}/n.mcap", "--force"],
            "inspect": ["inspect", log],
            "estimate": ["estimate", log, "--out", est, "--force"],
            "identify": ["identify", log, "--out", f"{d}/fit.json", "--force"],
            "replay": ["replay", log, "--scenario", "paper-sine", "--out", f"{d}/r.mcap", "--force"],
            "view": ["view", log, "--out", f"{d}/e.rrd", "--force"],
            "report": ["report", log, "--out", f"{d}/e.html", "--force"],
        }
        for argv in verbs.values():   # warm the cache (and make the inputs)
            run(argv)
        try:
            load = " ".join(f"{x:.2f}" for x in os.getloadavg())
            print(f"load average {load}; best of {args.runs} runs")
        except OSError:
            pass
        print(f"{'verb':<22} {'load':<15} {'import numba':>12} {'1st kernel':>10} {'kernels':>7} {'all loads':>9} "
              f"{'verb CPU':>8}  CPU s; per kernel (first call)")
        for name, argv in verbs.items():
            for own in (True, False):
                ms = [run(argv, own) for _ in range(max(1, args.runs))]
                m = min(ms, key=lambda x: x["total"])
                calls = m["calls"]
                loads = sum(c for _, c in calls)
                first = calls[0][1] if calls else 0.0
                per = ", ".join(f"{k.split('.')[-1]} {c:.3f}" for k, c in calls)
                label = "numba's load" if own else "usvlog's load"
                print(f"{name:<22} {label:<15} {m['import_numba']:>12.3f} "
                      f"{first:>10.3f} {len(calls):>7d} {loads:>9.3f} {m['total']:>8.3f}  {per}", flush=True)


if __name__ == "__main__":
    main()
