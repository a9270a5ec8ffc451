"""First-run compile time: what a verb spends compiling its kernels when the cache is empty.

    python benchmarks/bench_compile.py                          # usvlog demo (every stage)
    python benchmarks/bench_compile.py estimate RUN.mcap --out /tmp/e.mcap --force

The verb (any ``usvlog`` command line; default ``demo --out TMP``) runs once in a fresh
interpreter with a new, empty kernel cache (``NUMBA_CACHE_DIR`` a temporary directory), which is
what a user's first run after an install or an upgrade does. numba's ``numba:compile`` event
(fired only on a cache miss) times each compile: the figure per kernel is its wall time with the
kernels and numba helpers it compiles in counted inside it, and the line says in which kernel it
was compiled (``in forward > _forward_steps``). Printed: the process's wall time, the sum of
the top-level compiles (the first-run cost), and the compiles of at least ``--min-s`` seconds.
Processes the verb forks (view, report) compile in their own process and are not seen.
Wall times: run it on a quiet machine.
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
    from numba.core import event
    done, active = [], []

    class Timer(event.Listener):
        def on_start(self, ev):
            f = ev.data["dispatcher"].py_func
            active.append((time.perf_counter(), f"{f.__module__}.{f.__qualname__}"))

        def on_end(self, ev):
            t0, name = active.pop()
            done.append([time.perf_counter() - t0, name, [a[1].rsplit(".", 1)[-1] for a in active]])

    event.register("numba:compile", Timer())
    from usvlog.cli import main
    t0 = time.perf_counter()
    rc = main(sys.argv[1:])
    print(json.dumps({"rc": rc, "wall_s": time.perf_counter() - t0, "compiles": done}))
""")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--min-s", type=float, default=0.3, help="list the compiles of at least this many seconds")
    ap.add_argument("verb", nargs=argparse.REMAINDER, help="the usvlog command line (default: demo)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        argv = args.verb or ["demo", "--out", str(Path(tmp) / "demo")]
        env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
        env.update(NUMBA_CACHE_DIR=str(Path(tmp) / "cache"),
                   PYTHONPATH=os.pathsep.join([str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])]))
        r = subprocess.run([sys.executable, "-c", CHILD, *argv], env=env, capture_output=True, text=True)
    if r.returncode != 0 or not r.stdout.strip():
        raise SystemExit(r.stderr[-2000:])
    res = json.loads(r.stdout.strip().splitlines()[-1])
    top = [c for c in res["compiles"] if not c[2]]
    print(f"usvlog {' '.join(argv)}: exit {res['rc']}, {res['wall_s']:.1f} s wall with an empty kernel cache "
          f"(load average {os.getloadavg()[0]:.2f}, {os.cpu_count()} CPUs)")
    print(f"  top-level compiles: {len(top)}, {sum(c[0] for c in top):.1f} s; all compiles "
          f"(kernels and numba helpers, nested ones inside their callers): {len(res['compiles'])}")
    for s, name, within in sorted(res["compiles"], key=lambda c: -c[0]):
        if s >= args.min_s:
            print(f"  {s:6.2f} s  {name}" + (f"  in {' > '.join(within)}" if within else ""))


if __name__ == "__main__":
    main()
