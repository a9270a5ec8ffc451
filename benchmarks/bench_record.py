"""Sustained load on the live recorder: N messages/s over loopback UDP for S seconds.

Runs ``usvlog record`` as a subprocess (GNSS + compass NMEA on one UDP port, thrust
JSON lines on another), streams a stand-in boat at the given total rate, samples
the recorder's CPU % and RSS every second, stops it with SIGINT and compares
what was sent with what the file holds. Socket drops (kernel receive buffer
overflow, from /proc/net/udp) are reported apart from losses inside the recorder.

    python benchmarks/bench_record.py --rate 2000 --duration-s 30
    python benchmarks/bench_record.py --rate 2000 --duration-s 30 --view      # + live view to a Rerun server
    python benchmarks/bench_record.py --rate 2000 --duration-s 20 --compare 2 # without/with --view, alternating

With ``--view`` a Rerun gRPC server (the ``rerun`` binary, bound to 127.0.0.1) receives the
live stream (``usvlog record --view 127.0.0.1:PORT``); the recorder's CPU counts every
thread of its process (the view's thread and the Rerun SDK's own threads too) and its
children, the server's CPU is printed apart. Each run prints:

- the steady-state CPU % of one core: from the 5th second of sending (with ``--view``: and
  two seconds after the view connected) to the end of sending, from the process's CPU time;
- the start-up: the process's CPU-s up to that window beyond what the steady rate explains
  (interpreter, imports, with ``--view`` the SDK, the online filter and the connection);
- the steady-state CPU % by thread name (``/proc/PID/task``; Python's threads are all
  ``python``, the SDK's carry their names);
- with ``--view``: messages that reached the view's thread, dropped (its queue full), rows
  sent to the viewer, the view thread's own CPU.

``--compare N`` prints the means: CPU added by ``--view`` in points and in % of the
recorder's CPU without it (the target: <= 10 % at 2,000 msg/s), and the start-up CPU-s.
On a shared machine one run's figure moves by a few points: compare several.
``--together N`` runs the two recorders at the same time, each receiving every datagram the
stand-in boat sends, so the machine's load and its swings weigh on both alike; it prints each
run's difference and their mean.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import socket
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
from usvlog.view.rrd import rerun_executable  # noqa: E402

STEADY_FROM_S = 5   # the steady-state window starts at this second of sending


def _free_tcp_port() -> int:
    with socket.socket() as sk:
        sk.bind(("127.0.0.1", 0))
        return sk.getsockname()[1]


def start_viewer():
    """A Rerun gRPC server on 127.0.0.1 (what ``--view ADDRESS`` connects to): (process, port)."""
    port = _free_tcp_port()
    proc = subprocess.Popen([*rerun_executable(), "--serve-grpc", "--bind", "127.0.0.1", "--port", str(port)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        with socket.socket() as sk:
            if sk.connect_ex(("127.0.0.1", port)) == 0:
                return proc, port
        time.sleep(0.1)
    proc.kill()
    raise SystemExit("the rerun server did not start")


def thread_cpu(pid: int) -> dict[str, float]:
    """CPU-s so far of each thread of ``pid``, summed by thread name (``/proc/PID/task``; Linux only)."""
    out: dict[str, float] = {}
    tick = os.sysconf("SC_CLK_TCK")
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            name = (task / "comm").read_text().strip()
            fields = (task / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue   # the thread ended
        out[name] = out.get(name, 0.0) + (int(fields[11]) + int(fields[12])) / tick   # utime + stime
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rate", type=float, default=2000.0, help="total messages (datagrams) per second")
    ap.add_argument("--duration-s", type=float, default=30.0)
    ap.add_argument("--view", action="store_true", help="record with --view to a Rerun server on 127.0.0.1")
    ap.add_argument("--compare", type=int, default=0, metavar="N",
                    help="N pairs of runs without and with --view, alternating; prints the CPU added by --view")
    ap.add_argument("--together", type=int, default=0, metavar="N",
                    help="N runs of two recorders at once, one with --view, fed the same datagrams at the same "
                         "time (the machine's load weighs on both alike); prints the CPU added by --view")
    a = ap.parse_args()
    if a.together:
        return together(a.rate, a.duration_s, a.together)
    if not a.compare:
        return 0 if run(a.rate, a.duration_s, a.view) is not None else 1
    res: dict[bool, list[dict]] = {False: [], True: []}
    for _ in range(a.compare):
        for view in (False, True):
            r = run(a.rate, a.duration_s, view, verbose=False)
            if r is None:
                return 1
            res[view].append(r)
            print()

    def mean(view, key):
        return sum(r[key] for r in res[view]) / len(res[view])

    off, on = mean(False, "cpu"), mean(True, "cpu")
    print(f"recorder CPU % of one core, steady state (mean of {a.compare} runs each): without --view {off:.1f} "
          f"{[r['cpu'] for r in res[False]]}, with --view {on:.1f} {[r['cpu'] for r in res[True]]}")
    print(f"--view adds {on - off:+.1f} percentage points = {100 * (on - off) / off:+.1f} % of the recorder's "
          f"CPU at {a.rate:.0f} msg/s (target <= +10 %)")
    own = mean(True, "view_thread") + mean(True, "sdk")
    print(f"of which measured per thread: the view's thread {mean(True, 'view_thread'):.2f} % + the SDK's threads "
          f"{mean(True, 'sdk'):.2f} % = {own:.2f} points = {100 * own / off:.1f} % of the recorder's CPU (the rest: "
          f"the hand-off on the recorder's threads, and the machine's noise)")
    s_off, s_on = mean(False, "start_cpu_s"), mean(True, "start_cpu_s")
    print(f"start-up CPU-s: without --view {s_off:.2f}, with --view {s_on:.2f} ({s_on - s_off:+.2f} CPU-s, once)")
    views = [r["view"] for r in res[True]]
    print(f"live view: messages reaching its thread {[v['received'] for v in views]}, dropped "
          f"{[v['dropped'] for v in views]}, errors {[v['error'] for v in views]}")
    print(f"load average {os.getloadavg()}")
    return 0


def _together_once(k: int, hz: tuple[float, float, float], duration_s: float) -> tuple[float, float] | None:
    """One run of the two recorders fed at once: (CPU % without, with --view) in the steady state."""
    gnss_hz, compass_hz, thrust_hz = hz
    tmp = Path(tempfile.mkdtemp(prefix="bench_record_"))
    viewer, port = start_viewer()
    procs, outs, ports = [], [], []
    for view in (False, True):
        out = tmp / f"{'view' if view else 'plain'}.mcap"
        p_nmea, p_json = free_udp_port(), free_udp_port()
        cmd = [sys.executable, "-m", "usvlog", "record", "--out", str(out), "--gnss", f"udp://127.0.0.1:{p_nmea}",
               "--compass", f"udp://127.0.0.1:{p_nmea}", "--thrust", f"udp://127.0.0.1:{p_json}", "--json"]
        if view:
            cmd += ["--view", f"127.0.0.1:{port}"]
        procs.append(subprocess.Popen(cmd, cwd=ROOT, env=dict(os.environ, PYTHONPATH=str(ROOT)),
                                      stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True))
        outs.append(out)
        ports.append((p_nmea, p_json))
    while not all(o.exists() for o in outs):
        if any(p.poll() is not None for p in procs):
            print(*(p.stderr.read() for p in procs if p.poll() is not None))
            return None
        time.sleep(0.05)
    ps = [psutil.Process(p.pid) for p in procs]

    def cpu_s(q):
        c = q.cpu_times()
        return c.user + c.system + c.children_user + c.children_system

    def connected() -> bool:
        try:
            return any(c.status == psutil.CONN_ESTABLISHED and c.raddr and c.raddr.port == port
                       for c in ps[1].net_connections("tcp"))
        except (psutil.Error, OSError):
            return False

    marks: list[tuple[float, float, float]] = []   # (t, CPU-s plain, CPU-s view), from 2 s after connecting
    stop = threading.Event()

    def sample():
        t0 = time.monotonic()
        since = None
        while not stop.wait(0.5):
            now = time.monotonic() - t0
            if since is None and connected():
                since = now
            if since is not None and now >= max(STEADY_FROM_S, since + 2.0):
                marks.append((now, cpu_s(ps[0]), cpu_s(ps[1])))

    def both(*sends):
        return lambda data: [f(data) for f in sends]

    sends = [(udp_target(("127.0.0.1", a)), udp_target(("127.0.0.1", b))) for a, b in ports]
    boat = LoopbackBoat(gnss=both(sends[0][0], sends[1][0]), compass=both(sends[0][0], sends[1][0]),
                        thrust=both(sends[0][1], sends[1][1]), gnss_hz=gnss_hz, compass_hz=compass_hz,
                        thrust_hz=thrust_hz)
    th = threading.Thread(target=sample, daemon=True)
    th.start()
    sent = boat.run(duration_s)
    stop.set()
    th.join()
    time.sleep(1.0)
    summaries = []
    for p in procs:
        p.send_signal(signal.SIGINT)
        stdout, _ = p.communicate(timeout=60)
        summaries.append(json.loads(stdout))
    viewer.kill()
    viewer.wait()
    n_sent = 2 * len(sent.fixes) + len(sent.headings) + len(sent.thrust)
    n_rec = [len(read_log(o)["/raw/nmea"]) + len(read_log(o)["/thrust/command"]) for o in outs]
    if len(marks) < 2 or marks[-1][0] - marks[0][0] < 5:
        print(f"run {k + 1}: no steady window ({len(marks)} samples); give a longer --duration-s")
        return None
    (ta, a0, b0), (tb, a1, b1) = marks[0], marks[-1]
    off, on = 100 * (a1 - a0) / (tb - ta), 100 * (b1 - b0) / (tb - ta)
    v = summaries[1]["view"]
    print(f"run {k + 1}: same {n_sent} datagrams to both ({n_rec[0]} and {n_rec[1]} recorded); steady state "
          f"s {ta:.0f}-{tb:.0f}: recorder CPU {off:.1f} % without --view, {on:.1f} % with it ({on - off:+.1f} "
          f"points); view: {v['received']} messages, {v['dropped']} dropped, error {v['error']}; load "
          f"{os.getloadavg()[0]:.2f}")
    return off, on


def together(rate: float, duration_s: float, n: int) -> int:
    """``n`` runs of a plain recorder and a ``--view`` one receiving the same stream at once."""
    gnss_hz, compass_hz = rate * 0.05, rate * 0.10
    thrust_hz = rate - 2 * gnss_hz - compass_hz
    diffs, offs = [], []
    for k in range(n):
        r = _together_once(k, (gnss_hz, compass_hz, thrust_hz), duration_s)
        if r is None:
            return 1
        off, on = r
        diffs.append(on - off)
        offs.append(off)
    d, o = sum(diffs) / n, sum(offs) / n
    print(f"--view adds {d:+.2f} percentage points (runs {[round(x, 2) for x in diffs]}) on {o:.1f} % = "
          f"{100 * d / o:+.1f} % of the recorder's CPU at {rate:.0f} msg/s (target <= +10 %), both recorders "
          f"fed at once")
    return 0


def run(rate: float, duration_s: float, view: bool, verbose: bool = True) -> dict | None:
    """One recording at ``rate`` msg/s for ``duration_s``; prints its table, returns the CPU figures."""
    # 10% GNSS epochs (GGA + RMC = 2 datagrams each), 10% compass, 80% thrust
    gnss_hz, compass_hz = rate * 0.05, rate * 0.10
    thrust_hz = rate - 2 * gnss_hz - compass_hz
    tmp = Path(tempfile.mkdtemp(prefix="bench_record_"))
    out = tmp / "bench.mcap"
    p_nmea, p_json = free_udp_port(), free_udp_port()
    cmd = [sys.executable, "-m", "usvlog", "record", "--out", str(out), "--gnss", f"udp://127.0.0.1:{p_nmea}",
           "--compass", f"udp://127.0.0.1:{p_nmea}", "--thrust", f"udp://127.0.0.1:{p_json}", "--json"]
    viewer, port = None, -1
    if view:
        viewer, port = start_viewer()
        cmd += ["--view", f"127.0.0.1:{port}"]
    proc = subprocess.Popen(cmd, cwd=ROOT, env=dict(os.environ, PYTHONPATH=str(ROOT)),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    while not out.exists():
        if proc.poll() is not None:
            print(proc.stderr.read())
            return None
        time.sleep(0.05)
    ps = psutil.Process(proc.pid)
    ps.cpu_percent(None)
    vs = psutil.Process(viewer.pid) if viewer is not None else None
    if vs is not None:
        vs.cpu_percent(None)
    samples = []
    threads: list[dict[str, float]] = []   # per-thread CPU-s at the start and the end of the steady window
    window = [STEADY_FROM_S - 1, int(duration_s) - 1]   # samples opening and closing the steady state
    stop = threading.Event()
    go = threading.Event()

    def connected() -> bool:   # the view's start (SDK import, filter, connection) is over
        try:   # a socket closing while its fd is read (the view's probe) fails the call: try again
            return any(c.status == psutil.CONN_ESTABLISHED and c.raddr and c.raddr.port == port
                       for c in ps.net_connections("tcp"))
        except (psutil.Error, OSError):
            return False

    def sample():
        go.wait()
        t0 = time.monotonic()
        started = not view
        while not stop.wait(1.0):
            try:
                c = ps.cpu_times()
                samples.append((time.monotonic() - t0, ps.cpu_percent(None), ps.memory_info().rss / 2**20,
                                out.stat().st_size / 2**20, c.user + c.system + c.children_user + c.children_system))
                if not started and connected():
                    started = True
                    window[0] = max(window[0], len(samples) + 1)   # and one more second
                if started and len(samples) - 1 in window:
                    threads.append(thread_cpu(proc.pid))
            except (psutil.Error, OSError):
                return

    th = threading.Thread(target=sample, daemon=True)
    th.start()
    boat = LoopbackBoat(gnss=udp_target(("127.0.0.1", p_nmea)), compass=udp_target(("127.0.0.1", p_nmea)),
                        thrust=udp_target(("127.0.0.1", p_json)), gnss_hz=gnss_hz, compass_hz=compass_hz,
                        thrust_hz=thrust_hz)
    go.set()
    t0 = time.monotonic()
    sent = boat.run(duration_s)
    send_s = time.monotonic() - t0
    time.sleep(1.5)
    stop.set()
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=60)
    summary = json.loads(stdout)
    viewer_cpu = None
    if viewer is not None:
        viewer_cpu = vs.cpu_percent(None)   # mean over the run
        viewer.kill()
        viewer.wait()
    log = read_log(out)
    n_sent = {"gnss (GGA+RMC)": 2 * len(sent.fixes), "compass (HDT)": len(sent.headings),
              "thrust (JSON)": len(sent.thrust)}
    raw = log["/raw/nmea"]
    n_rec = {"gnss (GGA+RMC)": int(raw.kind.isin(["GGA", "RMC"]).sum()),
             "compass (HDT)": int((raw.kind == "HDT").sum()),
             "thrust (JSON)": len(log["/thrust/command"])}
    drops = {s["name"]: s["dropped"] for s in summary["status"]["sources"]}
    total_sent = sum(n_sent.values())
    print(f"recorder: {' '.join(cmd[1:4])} ...{' --view' if view else ''}; sender: {total_sent} datagrams in "
          f"{send_s:.1f} s "
          f"= {total_sent / send_s:.0f} msg/s (target {rate:.0f})")
    print(f"{'stream':16s} {'sent':>8s} {'recorded':>9s} {'lost':>6s}")
    for k in n_sent:
        print(f"{k:16s} {n_sent[k]:8d} {n_rec[k]:9d} {n_sent[k] - n_rec[k]:6d}")
    print(f"socket drops (kernel, /proc/net/udp): {drops}")
    print(f"/gnss/fix {len(log['/gnss/fix'])} (one per GGA+RMC epoch), /compass/heading {len(log['/compass/heading'])}")
    print(f"file: {out.stat().st_size / 2**20:.2f} MiB, complete={log.recovery is None}")
    if verbose:
        print(f"{'t s':>5s} {'CPU %':>6s} {'RSS MiB':>8s} {'file MiB':>9s}")
        for t, c, r, size, _ in samples:
            print(f"{t:5.0f} {c:6.1f} {r:8.1f} {size:9.2f}")
    k0, k1 = window
    if len(threads) < 2 or k1 - k0 < 5:
        print(f"no steady-state figure: samples {len(samples)}, window {window}, view connected "
              f"{len(threads) > 0} (give a longer --duration-s)")
        return None
    # steady state: from the STEADY_FROM_S-th second, and two after the view connected, to the end of sending
    (ta, *_, ca), (tb, *_, cb) = samples[k0], samples[k1]
    cpu = 100 * (cb - ca) / (tb - ta)
    start_cpu_s = ca - cpu / 100 * ta     # CPU-s of the process up to the window beyond the steady rate
    per = [s[1] for s in samples[k0 + 1:k1 + 1]]
    rss = [s[2] for s in samples]
    print(f"recorder CPU {cpu:.1f} % of one core in the steady state (s {ta:.0f}-{tb:.0f}; 1-s samples min "
          f"{min(per):.1f}, max {max(per):.1f}); start-up {start_cpu_s:.2f} CPU-s beyond that rate; "
          f"RSS first {rss[0]:.1f} MiB, last {rss[-1]:.1f} MiB, max {max(rss):.1f} MiB; load average "
          f"{os.getloadavg()}")
    by_thread = {k: 100 * (v - threads[0].get(k, 0.0)) / (tb - ta) for k, v in threads[1].items()}
    print("  by thread (CPU %, steady state): " + ", ".join(
        f"{k} {v:.1f}" for k, v in sorted(by_thread.items(), key=lambda kv: -kv[1]) if v >= 0.05))
    v = summary.get("view")
    if v is not None:
        print(f"live view: {v['received']} messages reached its thread, {v['dropped']} dropped (queue full), "
              f"rows sent to the viewer {sum(v['sent'].values())} over {len(v['sent'])} entities, error "
              f"{v['error']}; its thread {v['start_cpu_s']:.2f} CPU-s to start, then "
              f"{100 * (v['thread_cpu_s'] - v['start_cpu_s']) / duration_s:.1f} % CPU; "
              f"rerun server CPU % mean {viewer_cpu:.1f}")
    own = {"sdk": sum(x for k, x in by_thread.items() if k != "python"),   # the SDK's threads are named
           "view_thread": 100 * (v["thread_cpu_s"] - v["start_cpu_s"]) / duration_s if v else 0.0}
    return {"cpu": round(cpu, 2), "start_cpu_s": round(start_cpu_s, 3), "view": v, **own}

if __name__ == "__main__":
    raise SystemExit(main())
