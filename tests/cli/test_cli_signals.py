"""SIGTERM/SIGHUP end a verb cleanly: exit 128 + N, one line, no temporary file left behind."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from usvlog.cli import Terminated, main
from usvlog.errors import OutputExistsError
from usvlog.io.atomic import atomic_dir, atomic_path

DATA = Path(__file__).resolve().parents[1] / "data"

# `usvlog export` whose CSV writer stops half-way through a file (its temporary file exists and
# holds data) until the test signals it
SLOW_EXPORT = textwrap.dedent("""
    import os, sys, time
    import pyarrow.csv
    from usvlog.cli import main

    real = pyarrow.csv.write_csv

    def slow(table, out, *a, **k):
        real(table, out, *a, **k)
        out.flush()
        open(os.environ["READY"], "w").close()
        time.sleep(60)

    pyarrow.csv.write_csv = slow
    sys.exit(main(sys.argv[1:]))
""")


def _wait_for(cond, timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not cond():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")
        time.sleep(0.05)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP])
def test_signal_mid_write_leaves_no_temporary_file(tmp_path, sig):
    out = tmp_path / "csv"
    ready = tmp_path / "ready"
    proc = subprocess.Popen([sys.executable, "-c", SLOW_EXPORT, "export", str(DATA / "imported-nmea.mcap"),
                             "--out", str(out)], env={**os.environ, "READY": str(ready)},
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        _wait_for(ready.exists, 120, "the first CSV to be half-written")
        tmps = [p for p in out.iterdir() if p.name.endswith(".tmp")]
        assert len(tmps) == 1 and tmps[0].name.startswith(".") and tmps[0].stat().st_size > 1000  # mid-write
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=10)
    assert proc.returncode == 128 + sig
    assert err.strip().splitlines() == [f"usvlog export: terminated ({signal.Signals(sig).name})"]
    assert list(out.iterdir()) == []  # neither the temporary file nor a partial output


def test_handlers_installed_only_while_a_verb_runs(tmp_path, monkeypatch):
    before = signal.getsignal(signal.SIGTERM)
    seen = {}

    def fake_export(log, out, fmt, force, progress=None):
        seen["handler"] = signal.getsignal(signal.SIGTERM)
        os.kill(os.getpid(), signal.SIGTERM)  # delivered to this (main) thread: raised here
        time.sleep(5)
        raise AssertionError("not interrupted")

    from usvlog import api

    monkeypatch.setattr(api, "export", fake_export)
    assert main(["export", "x.mcap", "--out", str(tmp_path / "d")]) == 143
    assert seen["handler"] is not before and signal.getsignal(signal.SIGTERM) is before


def test_ignored_sighup_stays_ignored(monkeypatch):
    """Under nohup SIGHUP is ignored: the CLI does not turn it back on."""
    from usvlog.cli import _install_signal_handlers, _restore_signal_handlers

    old = signal.signal(signal.SIGHUP, signal.SIG_IGN)
    try:
        installed = _install_signal_handlers()
        assert signal.SIGHUP not in installed and signal.getsignal(signal.SIGHUP) is signal.SIG_IGN
        _restore_signal_handlers(installed)
    finally:
        signal.signal(signal.SIGHUP, old)


@pytest.mark.parametrize("exc", [KeyboardInterrupt, SystemExit, Terminated(signal.SIGTERM), RuntimeError])
def test_atomic_file_cleaned_on_any_exit(tmp_path, exc):
    target = tmp_path / "out.bin"
    with pytest.raises(BaseException) as info:  # noqa: PT011 - the exception is the parameter
        with atomic_path(target) as tmp:
            tmp.write_bytes(b"x" * 100_000)
            raise exc
    assert info.type is (exc if isinstance(exc, type) else type(exc))
    assert list(tmp_path.iterdir()) == []


def test_atomic_dir_complete_or_absent(tmp_path):
    target = tmp_path / "rep"
    with pytest.raises(KeyboardInterrupt), atomic_dir(target) as tmp:
        (tmp / "a.png").write_bytes(b"1")
        raise KeyboardInterrupt
    assert list(tmp_path.iterdir()) == []
    with atomic_dir(target) as tmp:
        (tmp / "a.png").write_bytes(b"1")
    assert [p.name for p in target.iterdir()] == ["a.png"]
    with pytest.raises(OutputExistsError), atomic_dir(target):
        pass
    with pytest.raises(RuntimeError), atomic_dir(target, force=True) as tmp:  # a failed replacement keeps the old
        (tmp / "b.png").write_bytes(b"2")
        raise RuntimeError
    assert [p.name for p in tmp_path.iterdir()] == ["rep"] and [p.name for p in target.iterdir()] == ["a.png"]
    with atomic_dir(target, force=True) as tmp:
        (tmp / "b.png").write_bytes(b"2")
    assert [p.name for p in tmp_path.iterdir()] == ["rep"] and [p.name for p in target.iterdir()] == ["b.png"]
