"""``usvlog record --view``: a real Rerun server on 127.0.0.1 receives the live stream; killed mid-run,
the recording loses nothing and the loss is reported once.

The viewer side is the ``rerun`` binary of rerun-sdk in server mode (``--serve-grpc --bind
127.0.0.1 --port P --save view.rrd``): what reached it is read back from its .rrd.
"""

from __future__ import annotations

import json
import math
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from usvlog.errors import ConfigError
from usvlog.io.mcap import read_log
from usvlog.io.record import Recorder
from usvlog.io.record.loopback import LoopbackBoat, free_udp_port, udp_target
from usvlog.view.live import TOPICS, LiveView, viewer_url
from usvlog.view.rrd import rerun_executable

from .test_viz import read_rrd

ROOT = Path(__file__).resolve().parents[2]


def _free_tcp_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait(cond, timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not cond():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.05)


def _accepts(port: int) -> bool:
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=0.2):
            return True
    except OSError:
        return False


def _viewer(tmp_path: Path) -> tuple[subprocess.Popen, int, Path]:
    """A Rerun gRPC server on 127.0.0.1 saving what it receives."""
    port, saved = _free_tcp_port(), tmp_path / "view.rrd"
    proc = subprocess.Popen([*rerun_executable(), "--serve-grpc", "--bind", "127.0.0.1", "--port", str(port),
                             "--save", str(saved)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    try:
        _wait(lambda: _accepts(port) or proc.poll() is not None, 30, "the viewer's port")
    except AssertionError:
        proc.kill()
        raise
    assert proc.poll() is None, "the rerun server did not start"
    return proc, port, saved


@pytest.mark.filterwarnings("ignore:RRD file has no footer")   # the killed viewer's file has none
def test_record_view_survives_a_killed_viewer(tmp_path):
    viewer, port, saved = _viewer(tmp_path)
    out = tmp_path / "run.mcap"
    p_nmea, p_json = free_udp_port(), free_udp_port()
    cmd = [sys.executable, "-m", "usvlog", "record", "--out", str(out), "--gnss", f"udp://127.0.0.1:{p_nmea}",
           "--compass", f"udp://127.0.0.1:{p_nmea}", "--thrust", f"udp://127.0.0.1:{p_json}", "--json",
           "--view", f"127.0.0.1:{port}"]
    proc = subprocess.Popen(cmd, cwd=ROOT, env=dict(os.environ, PYTHONPATH=str(ROOT)), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        _wait(lambda: out.exists() or proc.poll() is not None, 60, "the recorder to start")
        boat = LoopbackBoat(gnss=udp_target(("127.0.0.1", p_nmea)), compass=udp_target(("127.0.0.1", p_nmea)),
                            thrust=udp_target(("127.0.0.1", p_json)), garbage_every=10)
        blueprint_only = saved.stat().st_size if saved.exists() else 0
        stop = threading.Event()
        sender = threading.Thread(target=boat.run, args=(120.0, stop))
        sender.start()
        _wait(lambda: saved.stat().st_size > blueprint_only + 20_000, 30, "data at the viewer")
        time.sleep(3.0)                          # the map is re-sent once a second: several snapshots
        viewer.send_signal(signal.SIGKILL)       # the viewer dies mid-run
        viewer.wait(10)
        time.sleep(3.0)                          # the boat keeps sending
        stop.set()
        sender.join(10)
        sent = boat.sent
        time.sleep(0.5)
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
        if viewer.poll() is None:
            viewer.kill()
    assert proc.returncode == 0, stderr
    summary = json.loads(stdout)
    # the recording: complete, every message sent is in it (what a run without --view holds)
    log = read_log(out, strict=True)
    assert log.provenance[0]["closed"] == "true"
    assert len(log["/gnss/fix"]) == len(sent.fixes)
    assert len(log["/compass/heading"]) == len(sent.headings)
    assert log["/thrust/command"].left.tolist() == [x[1] for x in sent.thrust]
    raw = log["/raw/nmea"]
    assert sorted(raw.text[~raw.valid].tolist()) == sorted(sent.garbage)
    counts = {s["name"]: s for s in summary["status"]["sources"]}
    assert counts["gnss+compass"]["messages"] == 2 * len(sent.fixes) + len(sent.headings) + len(sent.garbage)
    assert counts["gnss+compass"]["garbage"] == len(sent.garbage)
    assert counts["thrust"]["messages"] == len(sent.thrust)
    # the viewer's loss: reported once, in the summary and on stderr
    view = summary["view"]
    assert view["url"] == f"rerun+http://127.0.0.1:{port}/proxy"
    assert view["error"] and "does not answer" in view["error"]
    assert stderr.count("live view stopped") == 1, stderr
    assert view["received"] > 0 and view["dropped"] == 0
    # what reached the viewer before it died: every entity, finite values, right ranges
    ents, _ = read_rrd(saved)
    for path in ("/heading/compass", "/heading/ekf", "/speed/ekf", "/thrust/left", "/thrust/right",
                 "/status/gnss_compass/rate_hz", "/status/gnss_compass/bad_lines", "/status/thrust/rate_hz",
                 "/status/view/dropped"):
        vals = np.array([v for row in ents[path]["rows"]["Scalars:scalars"] for v in row], float)
        assert len(vals) > 0 and np.isfinite(vals).all(), path
    thrust_left = np.array([v for row in ents["/thrust/left"]["rows"]["Scalars:scalars"] for v in row])
    assert set(thrust_left) <= {x[1] for x in sent.thrust}
    heading = np.array([v for row in ents["/heading/compass"]["rows"]["Scalars:scalars"] for v in row])
    assert ((heading >= 0) & (heading < 360)).all()
    assert np.isin(np.round(heading, 3), np.round([h[1] for h in sent.headings], 3)).all()
    fixes = np.array(ents["/map/fixes"]["static"]["GeoPoints:positions"][-1], float)
    sent_ll = np.array([f[2:4] for f in sent.fixes])
    assert len(fixes) >= 10
    assert np.abs(fixes[:, None, :] - sent_ll[None, :, :]).max(-1).min(1).max() < 1e-7  # each one was sent
    # the online EKF track follows the circle the boat drove (radius 50 m)
    track = np.array(ents["/map/track"]["static"]["GeoPoints:positions"][-1], float)
    assert np.isfinite(track).all() and len(track) > 10
    n_m = (track[:, 0] - boat.lat0) * 111_320.0
    e_m = (track[:, 1] - boat.lon0) * 111_320.0 * math.cos(math.radians(boat.lat0)) - boat.radius
    assert np.abs(np.hypot(n_m, e_m) - boat.radius).max() < 3.0     # on the circle about (0, 50 m)
    speed = np.array([v for row in ents["/speed/ekf"]["rows"]["Scalars:scalars"] for v in row])
    assert abs(np.median(speed) - 2 * math.pi * 50.0 / 60.0) < 0.5  # 5.24 m/s on the circle


def test_view_that_cannot_connect_is_reported_once_and_recording_goes_on(tmp_path):
    port = _free_tcp_port()                      # nothing listens here
    errors = []
    view = LiveView(f"127.0.0.1:{port}", on_error=errors.append)
    with Recorder(tmp_path / "r.mcap") as rec:
        rec.subscribe(view, TOPICS)
        view.start()
        for k in range(200):
            rec.thrust(float(k), 0.0)
            rec.heading(0.1)
        _wait(lambda: view.error is not None, 10, "the view to give up")
        for k in range(200):
            rec.thrust(float(k), 1.0)
        view.close()
    log = read_log(tmp_path / "r.mcap", strict=True)
    assert len(log["/thrust/command"]) == 400 and len(log["/compass/heading"]) == 200
    assert len(errors) == 1 and f"127.0.0.1:{port}" in errors[0]


def test_spawn_without_a_display_is_reported_once_and_starts_nothing(monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    errors = []
    view = LiveView("spawn", on_error=errors.append).start()
    _wait(lambda: view.error is not None, 30, "the view to give up")
    view.close()
    assert len(errors) == 1 and "no display" in errors[0] and view._proc is None


def test_a_subscriber_that_raises_is_dropped_and_the_recording_goes_on(tmp_path):
    seen = []

    def bad(topic, row, t_ns):
        seen.append(topic)
        raise RuntimeError("broken view")

    with Recorder(tmp_path / "r.mcap") as rec:
        rec.subscribe(bad, {"/thrust/command"})
        for k in range(5):
            rec.heading(0.2)
            rec.thrust(float(k), 0.0)
    assert seen == ["/thrust/command"]                # only its topic, and once: then unsubscribed
    assert rec.subscriber_errors == ["bad: broken view"]
    assert len(read_log(tmp_path / "r.mcap", strict=True)["/thrust/command"]) == 5


def test_a_full_queue_drops_and_counts_without_waiting(tmp_path):
    view = LiveView("127.0.0.1:9", queue_size=10)    # never started: nothing drains the queue
    t0 = time.perf_counter()
    for k in range(1000):                             # 10 Hz: none thinned
        view("/gnss/fix", {"lat_deg": 59.9, "lon_deg": 10.7}, k * 100_000_000)
    assert time.perf_counter() - t0 < 1.0            # bounded queue, never blocks
    assert view.dropped == 990 and len(view._q) == 10


def test_each_topic_is_thinned_to_max_hz_before_the_queue():
    view = LiveView("127.0.0.1:9", max_hz=50.0)
    for k in range(1000):                             # 1 s at 1 kHz each
        view("/thrust/command", {"left": 1.0, "right": 2.0}, k * 1_000_000)
        view("/compass/heading", {"heading_rad": 0.1}, k * 1_000_000)
        view("/gnss/fix", {"lat_deg": 59.9, "lon_deg": 10.7}, k * 1_000_000)
        if k % 100 == 0:                              # 10 Hz: every one
            view("/recorder/status", {"source": "gnss"}, k * 1_000_000)
    for topic in ("/thrust/command", "/compass/heading", "/gnss/fix"):
        times = [m[2] for m in view._q if m[0] == topic]
        assert len(times) == 50 and set(np.diff(times)) == {20_000_000}, topic
    assert sum(m[0] == "/recorder/status" for m in view._q) == 10 and view.dropped == 0


@pytest.mark.parametrize("target, url", [
    ("9876", "rerun+http://127.0.0.1:9876/proxy"),
    ("10.0.0.2:9000", "rerun+http://10.0.0.2:9000/proxy"),
    ("rerun+http://boat.local:9877/proxy", "rerun+http://boat.local:9877/proxy"),
])
def test_viewer_address_forms(target, url):
    assert viewer_url(target)[0] == url


@pytest.mark.parametrize("bad", ["http://x:1/proxy", "nohost", "rerun+http://h:1/other", "h:port"])
def test_bad_viewer_address_is_a_config_error(bad):
    with pytest.raises(ConfigError, match="--view"):
        viewer_url(bad)
