"""Peak memory of ``usvlog inspect`` on big logs: streamed (now) against loading the whole log.

Makes a 1 h excitation log (``usvlog simulate excitation --duration-s 3600``, ~57 MB)
and a longer one by writing that hour again and again, shifted in time, into one file
(``--hours``, default 8: ~455 MB), then runs ``usvlog inspect`` on each in a fresh
process and reports its peak RSS (``/usr/bin/time``'s maximum resident set size, which
counts the shared libraries: about 230 MB of it is numpy, pandas and numba being loaded)
and wall time; the same for the long log cut short at 90 % (no footer, no summary: what
a killed recorder leaves), which is walked without the summary's help. ``--load`` also
runs the old way, ``summarize(read_log(path))``, and checks that both give the same
summary. The numba kernels are compiled (if the package changed) before measuring.

    python benchmarks/bench_inspect.py --hours 8 --load
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

_LOAD = ("import sys, json; from usvlog.io.mcap import read_log; from usvlog.log.summary import summarize; "
         "print(json.dumps(summarize(read_log(sys.argv[1])).to_dict(), sort_keys=True, default=str))")
_STREAM = ("import sys, json; from usvlog.api import inspect; "
           "print(json.dumps(inspect(sys.argv[1]).to_dict(), sort_keys=True, default=str))")


def _env() -> dict:
    return dict(os.environ, PYTHONPATH=str(ROOT))


def peak(cmd: list[str], ok=(0,)) -> tuple[float, float, str]:
    """(peak RSS MB, wall s, stdout) of a command in a fresh process (exit codes ``ok``)."""
    timer = shutil.which("time") or ("/usr/bin/time" if Path("/usr/bin/time").exists() else None)
    t0 = time.perf_counter()
    if timer is not None:
        r = subprocess.run([timer, "-f", "PEAK_KB=%M", *cmd], capture_output=True, text=True, env=_env(), cwd=ROOT)
        wall = time.perf_counter() - t0
        if r.returncode not in ok:
            raise RuntimeError(r.stderr[-800:])
        kb = int([x for x in r.stderr.splitlines() if x.startswith("PEAK_KB=")][-1].split("=")[1])
        return kb / 1024, wall, r.stdout
    import psutil

    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=_env(), cwd=ROOT)
    ps, top = psutil.Process(p.pid), 0
    while p.poll() is None:
        try:
            top = max(top, ps.memory_info().rss)
        except psutil.Error:
            break
        time.sleep(0.02)
    out, err = p.communicate()
    if p.returncode not in ok:
        raise RuntimeError(err[-800:])
    return top / 2**20, time.perf_counter() - t0, out


def make_hour(path: Path) -> None:
    subprocess.run([sys.executable, "-m", "usvlog", "simulate", "excitation", "--duration-s", "3600", "--seed", "1",
                    "--out", str(path), "--force"], check=True, env=_env(), cwd=ROOT, capture_output=True)


def make_long(hour: Path, path: Path, hours: int) -> None:
    """``hours`` copies of the hour, each shifted 1 h later, streamed into one file (10 min batches)."""
    from usvlog.io.mcap import McapWriter, read_log

    log = read_log(hour)
    hour_ns = 3600 * 10**9
    with open(path, "wb", buffering=1 << 20) as fh:
        w = McapWriter(fh)
        for name in sorted(log.meta):
            w.add_metadata(name, log.meta[name])
        for topic in log.topics:
            w.add_channel(topic, log.schemas.get(topic), log.channels[topic])
        t0 = min(int(f.index[0]) for f in log.channels.values() if len(f))
        for k in range(hours):
            for m in range(6):
                lo, hi = t0 + m * 600 * 10**9, t0 + (m + 1) * 600 * 10**9
                batch = {}
                for topic in log.topics:
                    f = log.channels[topic]
                    f = f[(f.index >= lo) & (f.index < hi)].copy()
                    f.index = f.index + k * hour_ns
                    batch[topic] = f
                w.add_frames(batch, log.schemas)
        w.finish()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=int, default=8, help="length of the long log (h)")
    ap.add_argument("--load", action="store_true", help="also measure loading the whole log, and compare")
    ap.add_argument("--keep", metavar="DIR", help="make / reuse the logs in DIR")
    a = ap.parse_args()
    d = Path(a.keep) if a.keep else Path(tempfile.mkdtemp(prefix="bench_inspect_"))
    d.mkdir(parents=True, exist_ok=True)
    hour, long = d / "excitation_1h.mcap", d / f"excitation_{a.hours}h.mcap"
    if not hour.exists():
        make_hour(hour)
    if not long.exists():
        make_long(hour, long, a.hours)
    cut = d / f"excitation_{a.hours}h_cut.mcap"
    if not cut.exists():
        shutil.copyfile(long, cut)
        os.truncate(cut, int(long.stat().st_size * 0.9))
    subprocess.run([sys.executable, "-m", "usvlog", "inspect", str(hour)], env=_env(), cwd=ROOT,
                   capture_output=True)   # kernels compiled (if the package changed) before measuring
    for f in (hour, long, cut):
        mb, s, out = peak([sys.executable, "-m", "usvlog", "inspect", str(f)], ok=(0, 1))
        line = f"{f.name} ({f.stat().st_size / 1e6:.0f} MB): usvlog inspect peak RSS {mb:.0f} MB, {s:.1f} s"
        if a.load:
            mb2, s2, whole = peak([sys.executable, "-c", _LOAD, str(f)])
            _, _, streamed = peak([sys.executable, "-c", _STREAM, str(f)])
            line += (f"; loading it whole: {mb2:.0f} MB, {s2:.1f} s; summaries "
                     f"{'identical' if whole == streamed else 'DIFFER'}")
        print(line, flush=True)
    if not a.keep:
        shutil.rmtree(d, ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
