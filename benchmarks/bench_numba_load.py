"""numba load time per verb: what loading the compiled kernels costs each command, cache warm.

    python benchmarks/bench_numba_load.py [--duration-s 600]

Each verb runs in a fresh interpreter (``usvlog.cli.main``) with numba's dispatcher
instrumented: the figure per kernel is the CPU time of its first call (numba types the
arguments and loads the machine code from usvlog's cache; nothing is compiled when the cache
is warm, which a first untimed run of every verb ensures). Also printed: ``import numba``
(paid by every verb that imports the numeric stack) and the first kernel's extra cost (numba
builds its CPU target: ~180 modules and the typing/lowering registries), which every verb
that calls a kernel pays once whatever it calls. CPU times: the machine may be shared.
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
    import json, sys, time
    C = time.process_time
    t0 = C()
    import numba
    t_numba = C() - t0
    from numba.core import dispatcher
    calls = []
    orig = dispatcher.Dispatcher._compile_for_args
    def timed(self, *a, **k):
        c = C()
        try:
            return orig(self, *a, **k)
        finally:
            calls.append((self.py_func.__module__ + "." + self.py_func.__qualname__, C() - c))
    dispatcher.Dispatcher._compile_for_args = timed
    from usvlog.cli import main
    try:
        main(sys.argv[1:])
    except SystemExit:
        pass
    print("@@" + json.dumps({"import_numba": t_numba, "calls": calls, "total": C() - t0}))
""")


def run(argv: list[str]) -> dict:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])]))
    r = subprocess.run([sys.executable, "-c", CHILD, *argv], capture_output=True, text=True, env=env)
    line = [x for x in r.stdout.splitlines() if x.startswith("@@")]
    if not line:
        raise SystemExit(f"{' '.join(argv)}: {r.stderr[-2000:]}")
    return json.loads(line[-1][2:])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration-s", type=float, default=600.0, help="length of the simulated log")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="usvlog-numba-") as d:
        log, est, nmea = f"{d}/e.mcap", f"{d}/est.mcap", str(ROOT / "tests/data/sources/kingfisher.nmea")
        verbs = {
            "simulate excitation": ["simulate", "excitation", "--duration-s", str(args.duration_s), "--out", log,
                                    "--force"],
            "import (nmea)": ["import", nmea, "--out", f"{d}/n.mcap", "--force"],
            "inspect": ["inspect", log],
            "estimate": ["estimate", log, "--out", est, "--force"],
            "identify": ["identify", log, "--json"],
            "replay": ["replay", log, "--scenario", "paper-sine", "--out", f"{d}/r.mcap", "--force"],
        }
        for argv in verbs.values():   # warm the cache (and make the inputs)
            run(argv)
        print(f"{'verb':<22} {'import numba':>12} {'1st kernel':>10} {'kernels':>7} {'all loads':>9}  "
              "CPU s; per kernel (first call)")
        for name, argv in verbs.items():
            m = run(argv)
            calls = m["calls"]
            loads = sum(c for _, c in calls)
            first = calls[0][1] if calls else 0.0
            per = ", ".join(f"{k.split('.')[-1]} {c:.3f}" for k, c in calls)
            print(f"{name:<22} {m['import_numba']:>12.3f} {first:>10.3f} {len(calls):>7d} {loads:>9.3f}  {per}")


if __name__ == "__main__":
    main()
