"""The loopback recipe of docs/recording.md for ``usvlog record``, timed from a cold start.

Starts ``usvlog record`` and, at once, without waiting for it to be ready, the
stand-in boat (``python -m usvlog.io.record.loopback``), exactly as docs/recording.md
"Recording live" does with ``&``. Reports the fixes stored against the fixes sent,
and how late the receive time of the first thrust messages is (receive time minus
the sender's own ``t``) against the steady state: datagrams that arrive while the
recorder is still importing must neither be lost nor stamped late.

    python benchmarks/bench_record_startup.py --duration-s 30 --repeat 3
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from usvlog.io.mcap import read_log  # noqa: E402
from usvlog.io.record.loopback import free_udp_port  # noqa: E402


def run_recipe(tmp: Path, duration_s: float) -> dict:
    """One run of the recipe; the counts and receive-time lateness (ms)."""
    out = tmp / "run.mcap"
    p_nmea, p_json = free_udp_port(), free_udp_port()
    gnss, thrust = f"udp://127.0.0.1:{p_nmea}", f"udp://127.0.0.1:{p_json}"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    rec = subprocess.Popen([sys.executable, "-m", "usvlog", "record", "--out", str(out), "--gnss", gnss,
                            "--compass", gnss, "--thrust", thrust, "--duration-s", str(duration_s + 5)],
                           cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    boat = subprocess.run([sys.executable, "-m", "usvlog.io.record.loopback", "--gnss", gnss, "--compass", gnss,
                           "--thrust", thrust, "--duration-s", str(duration_s)],
                          cwd=ROOT, env=env, capture_output=True, text=True, timeout=duration_s + 60)
    try:
        _, err = rec.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        rec.kill()
        raise
    if rec.returncode != 0:
        raise RuntimeError(f"usvlog record exited {rec.returncode}: {err.strip()[-500:]}")
    m = re.search(r"sent (\d+) fixes \(GGA\+RMC\), (\d+) headings, (\d+) thrust", boat.stdout)
    if m is None:
        raise RuntimeError(f"loopback: {boat.stdout!r} {boat.stderr[-500:]!r}")
    sent = [int(x) for x in m.groups()]
    log = read_log(out)
    th = log["/thrust/command"]
    late_ms = (th.index.to_numpy() - th.stamp_ns.to_numpy()) / 1e6   # receive minus send time
    first = late_ms[:50]                                              # the first 0.5 s of thrust
    return {"fixes": len(log["/gnss/fix"]), "fixes_sent": sent[0], "headings": len(log["/compass/heading"]),
            "headings_sent": sent[1], "thrust": len(th), "thrust_sent": sent[2],
            "first_late_ms_max": float(first.max()) if len(first) else float("nan"),
            "late_ms_median": float(np.median(late_ms)) if len(late_ms) else float("nan")}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration-s", type=float, default=30.0, help="the boat's run (the docs: 30 s, 300 fixes)")
    ap.add_argument("--repeat", type=int, default=1)
    a = ap.parse_args()
    for i in range(a.repeat):
        with tempfile.TemporaryDirectory(prefix="bench_record_startup_") as d:
            r = run_recipe(Path(d), a.duration_s)
        print(f"run {i + 1}: fixes stored {r['fixes']} of {r['fixes_sent']}, headings {r['headings']} of "
              f"{r['headings_sent']}, thrust {r['thrust']} of {r['thrust_sent']}; receive time minus send time: "
              f"first 0.5 s max {r['first_late_ms_max']:.1f} ms, median {r['late_ms_median']:.2f} ms", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
