"""Sustained load on the live recorder: N messages/s over loopback UDP for S seconds.

Runs ``usvlog record`` as a subprocess (GNSS + compass NMEA on one UDP port, thrust
JSON lines on another), streams a stand-in boat at the given total rate, samples
the recorder's CPU % and RSS every second, stops it with SIGINT and compares
what was sent with what the file holds. Socket drops (kernel receive buffer
overflow, from /proc/net/udp) are reported apart from losses inside the recorder.

    python benchmarks/bench_record.py --rate 2000 --duration-s 30
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import psutil

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from usvlog.io.mcap import read_log  # noqa: E402
from usvlog.io.record.loopback import LoopbackBoat, free_udp_port, udp_target  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rate", type=float, default=2000.0, help="total messages (datagrams) per second")
    ap.add_argument("--duration-s", type=float, default=30.0)
    a = ap.parse_args()
    # 10% GNSS epochs (GGA + RMC = 2 datagrams each), 10% compass, 80% thrust
    gnss_hz, compass_hz = a.rate * 0.05, a.rate * 0.10
    thrust_hz = a.rate - 2 * gnss_hz - compass_hz
    tmp = Path(tempfile.mkdtemp(prefix="bench_record_"))
    out = tmp / "bench.mcap"
    p_nmea, p_json = free_udp_port(), free_udp_port()
    cmd = [sys.executable, "-m", "usvlog", "record", "--out", str(out), "--gnss", f"udp://127.0.0.1:{p_nmea}",
           "--compass", f"udp://127.0.0.1:{p_nmea}", "--thrust", f"udp://127.0.0.1:{p_json}", "--json"]
    proc = subprocess.Popen(cmd, cwd=ROOT, env=dict(os.environ, PYTHONPATH=str(ROOT)),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    while not out.exists():
        if proc.poll() is not None:
            print(proc.stderr.read())
            return 1
        time.sleep(0.05)
    ps = psutil.Process(proc.pid)
    ps.cpu_percent(None)
    samples = []
    stop = threading.Event()

    def sample():
        t0 = time.monotonic()
        while not stop.wait(1.0):
            try:
                samples.append((time.monotonic() - t0, ps.cpu_percent(None), ps.memory_info().rss / 2**20,
                                out.stat().st_size / 2**20))
            except (psutil.Error, OSError):
                return

    th = threading.Thread(target=sample, daemon=True)
    th.start()
    boat = LoopbackBoat(gnss=udp_target(("127.0.0.1", p_nmea)), compass=udp_target(("127.0.0.1", p_nmea)),
                        thrust=udp_target(("127.0.0.1", p_json)), gnss_hz=gnss_hz, compass_hz=compass_hz,
                        thrust_hz=thrust_hz)
    t0 = time.monotonic()
    sent = boat.run(a.duration_s)
    send_s = time.monotonic() - t0
    time.sleep(1.5)
    stop.set()
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=60)
    summary = json.loads(stdout)
    log = read_log(out)
    n_sent = {"gnss (GGA+RMC)": 2 * len(sent.fixes), "compass (HDT)": len(sent.headings),
              "thrust (JSON)": len(sent.thrust)}
    raw = log["/raw/nmea"]
    n_rec = {"gnss (GGA+RMC)": int(raw.kind.isin(["GGA", "RMC"]).sum()),
             "compass (HDT)": int((raw.kind == "HDT").sum()),
             "thrust (JSON)": len(log["/thrust/command"])}
    drops = {s["name"]: s["dropped"] for s in summary["status"]["sources"]}
    total_sent = sum(n_sent.values())
    print(f"recorder: {' '.join(cmd[1:4])} ... ; sender: {total_sent} datagrams in {send_s:.1f} s "
          f"= {total_sent / send_s:.0f} msg/s (target {a.rate:.0f})")
    print(f"{'stream':16s} {'sent':>8s} {'recorded':>9s} {'lost':>6s}")
    for k in n_sent:
        print(f"{k:16s} {n_sent[k]:8d} {n_rec[k]:9d} {n_sent[k] - n_rec[k]:6d}")
    print(f"socket drops (kernel, /proc/net/udp): {drops}")
    print(f"/gnss/fix {len(log['/gnss/fix'])} (one per GGA+RMC epoch), /compass/heading {len(log['/compass/heading'])}")
    print(f"file: {out.stat().st_size / 2**20:.2f} MiB, complete={log.recovery is None}")
    print(f"{'t s':>5s} {'CPU %':>6s} {'RSS MiB':>8s} {'file MiB':>9s}")
    for t, cpu, rss, size in samples:
        print(f"{t:5.0f} {cpu:6.1f} {rss:8.1f} {size:9.2f}")
    if samples:
        cpu = [s[1] for s in samples[1:-1]] or [s[1] for s in samples]
        rss = [s[2] for s in samples]
        print(f"CPU % mean {sum(cpu) / len(cpu):.1f} (min {min(cpu):.1f}, max {max(cpu):.1f}); "
              f"RSS first {rss[0]:.1f} MiB, last {rss[-1]:.1f} MiB, max {max(rss):.1f} MiB")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
