"""``view --spawn`` and ``view --serve``: loopback only, no display refused, nothing left running.

No test opens a viewer window: the spawn tests check the command and the refusals only.
"""

from __future__ import annotations

import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import psutil
import pytest

from usvlog.cli import main
from usvlog.errors import ConfigError
from usvlog.view import rrd as viz

DATA = Path(__file__).resolve().parents[1] / "data"


def test_spawn_command_binds_loopback():
    cmd = viz.viewer_command("x.rrd")
    assert cmd[cmd.index("--bind") + 1] == "127.0.0.1"
    assert "--serve-web" not in cmd and cmd[-1] == "x.rrd"
    cmd = viz.viewer_command("x.rrd", grpc_port=9877)
    assert cmd[cmd.index("--port") + 1] == "9877"
    # the binary shipped with rerun-sdk, run directly (its pid is the viewer's)
    exe = viz.rerun_executable()
    assert len(exe) == 1 and Path(exe[0]).name.lower().startswith("rerun") and Path(exe[0]).is_file()


def test_display_detection():
    assert viz.display_missing({}, "linux")
    assert viz.display_missing({"DISPLAY": ""}, "linux")
    assert not viz.display_missing({"DISPLAY": ":0"}, "linux")
    assert not viz.display_missing({"WAYLAND_DISPLAY": "wayland-0"}, "linux")
    assert not viz.display_missing({}, "darwin") and not viz.display_missing({}, "win32")


def test_spawn_without_display_is_one_line_and_starts_nothing(tmp_path, monkeypatch, capsys):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr(sys, "platform", "linux")

    def no_process(*a, **k):
        raise AssertionError("a process was started")

    monkeypatch.setattr(subprocess, "Popen", no_process)
    out = tmp_path / "run.rrd"
    assert main(["view", str(DATA / "imported-nmea.mcap"), "--out", str(out), "--spawn"]) == 2
    cap = capsys.readouterr()
    err = cap.err.strip().splitlines()
    assert [x for x in err if "error" in x] == err[-1:]
    assert "no display" in err[-1] and f"`rerun {out}`" in err[-1]
    assert cap.out.strip() == str(out) and out.stat().st_size > 1000  # the recording is there to open elsewhere


def test_spawn_reports_a_viewer_that_fails_at_once(tmp_path, monkeypatch):
    monkeypatch.setenv("DISPLAY", ":99")
    monkeypatch.setattr(viz, "viewer_command", lambda *a, **k: [sys.executable, "-c", "import sys; sys.exit(4)"])
    with pytest.raises(ConfigError, match="exit code 4") as info:
        viz.spawn_viewer(tmp_path / "x.rrd", check_s=30)
    assert "rerun " in str(info.value) and "\n" not in str(info.value)


def _free_ports(n: int) -> list[int]:
    socks = []
    for _ in range(n):
        s = socket.socket()
        s.bind(("127.0.0.1", 0))
        socks.append(s)
    ports = [s.getsockname()[1] for s in socks]
    for s in socks:
        s.close()
    return ports


def _listening(ports) -> set[int]:
    return {c.laddr.port for c in psutil.net_connections(kind="tcp")
            if c.status == psutil.CONN_LISTEN and c.laddr.port in ports}


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP])
def test_serve_stopped_by_signal_leaves_nothing_running(tmp_path, sig):
    web, grpc = ports = _free_ports(2)
    proc = subprocess.Popen([sys.executable, "-m", "usvlog", "view", str(DATA / "imported-nmea.mcap"),
                             "--out", str(tmp_path / "a.rrd"), "--serve", "--host", "127.0.0.1",
                             "--port", str(web), "--grpc-port", str(grpc)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    kids: list[psutil.Process] = []
    try:
        deadline = time.monotonic() + 120
        while _listening(ports) != set(ports):
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline, "the server did not start listening within 120 s"
            time.sleep(0.2)
        kids = psutil.Process(proc.pid).children(recursive=True)
        assert kids  # the server is a child process
        for c in psutil.net_connections(kind="tcp"):  # loopback only
            if c.status == psutil.CONN_LISTEN and c.laddr.port in ports:
                assert c.laddr.ip == "127.0.0.1"
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=60)
        assert proc.returncode == 128 + sig
        assert err.strip().splitlines()[-1] == f"usvlog view: terminated ({signal.Signals(sig).name})"
        assert _listening(ports) == set()
        alive = [k for k in kids if k.is_running() and k.status() != psutil.STATUS_ZOMBIE]
        assert alive == []
    finally:
        for k in kids:
            if k.is_running():
                k.kill()
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=10)
