"""Start-up time: ``usvlog --help``, ``usvlog VERB --help`` for every verb, ``import usvlog``.

    python benchmarks/bench_startup.py [--runs 7]

Each command runs in a fresh interpreter (a subprocess, as a user's shell runs it); the
figure is the best wall-clock time of ``--runs`` runs (and the best CPU time, which is what
a command costs when other work shares the cores), next to the bare interpreter
(``python -c pass``) for scale. Target on a quiet 2-core machine: each <= 0.3 s. A second
run of each command under ``-X importtime`` lists the heavy modules it imported (numpy, pandas,
scipy, numba, rerun, mcap, matplotlib): there should be none. The checkout's ``usvlog`` is
imported (PYTHONPATH is set to it), installed or not.
"""

from __future__ import annotations

import argparse
import os
import re
import resource
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

HEAVY = ("numpy", "pandas", "scipy", "numba", "rerun", "mcap", "matplotlib")
TARGET_S = 0.3


def _env() -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), *filter(None, [env.get("PYTHONPATH")])])
    env.pop("PYTHONIMPORTTIME", None)
    return env


def best_of(argv: list[str], runs: int) -> tuple[float, float]:
    """Best wall-clock and best CPU (user + system) seconds of ``runs`` runs of ``argv`` (must exit 0).

    The CPU time is what the command costs on a busy machine, where the wall clock also
    counts the time spent waiting for a core.
    """
    env = _env()
    best, best_cpu = float("inf"), float("inf")
    for _ in range(runs):
        r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        t = time.perf_counter()
        r = subprocess.run(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env)
        dt = time.perf_counter() - t
        r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        if r.returncode != 0:
            raise SystemExit(f"{' '.join(argv)} failed ({r.returncode}): {r.stderr.decode()[-500:]}")
        best = min(best, dt)
        best_cpu = min(best_cpu, (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime))
    return best, best_cpu


def heavy_imports(argv: list[str]) -> list[str]:
    """Top-level heavy packages ``argv`` imports, from ``-X importtime`` (PYTHONIMPORTTIME for a script)."""
    env = _env()
    if argv[0] == sys.executable:
        argv = [argv[0], "-X", "importtime", *argv[1:]]
    else:
        env["PYTHONIMPORTTIME"] = "1"
    r = subprocess.run(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=env)
    names = set()
    for line in r.stderr.splitlines():
        m = re.match(r"import time:\s+\d+ \|\s+\d+ \|\s*(\S+)", line)
        if m:
            names.add(m.group(1).split(".")[0])
    return sorted(names & set(HEAVY))


def commands() -> list[tuple[str, list[str]]]:
    from usvlog.cli import VERBS  # light: the verb list, no library import

    py = sys.executable
    cmds = [("python -c pass (interpreter alone)", [py, "-c", "pass"]),
            ("python -c 'import usvlog'", [py, "-c", "import usvlog"]),
            ("usvlog --help", [py, "-m", "usvlog", "--help"])]
    for mod in VERBS:
        verb = mod.rstrip("_")
        cmds.append((f"usvlog {verb} --help", [py, "-m", "usvlog", verb, "--help"]))
    script = shutil.which("usvlog")
    if script:  # the installed console script (it imports this checkout: PYTHONPATH is set)
        cmds.append(("usvlog --help (console script)", [script, "--help"]))
    return cmds


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=7, help="runs per command; the best is reported (default 7)")
    args = ap.parse_args()
    try:
        load = os.getloadavg()
        print(f"load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f} on {os.cpu_count()} cores; "
              f"best of {args.runs} runs; target <= {TARGET_S} s")
    except OSError:
        pass
    print(f"{'command':<40} {'best s':>8} {'cpu s':>7}  {'target':<7} heavy modules imported")
    worst = 0.0
    for name, argv in commands():
        t, cpu = best_of(argv, args.runs)
        heavy = heavy_imports(argv)
        ok = "-" if argv[1:] == ["-c", "pass"] else ("ok" if t <= TARGET_S else "SLOW")
        if ok != "-":
            worst = max(worst, t)
        print(f"{name:<40} {t:8.3f} {cpu:7.3f}  {ok:<7} {', '.join(heavy) or 'none'}", flush=True)
    print(f"slowest: {worst:.3f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
