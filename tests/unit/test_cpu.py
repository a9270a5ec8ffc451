"""usvlog._cpu.spare_cpu: the environment's USVLOG_THREADS decides, else the CPUs this process may use."""

import os
import threading

import pytest

from usvlog._cpu import spare_cpu


@pytest.mark.parametrize(("value", "spare"), [("1", False), ("2", True), ("8", True), ("0", False)])
def test_usvlog_threads_decides(monkeypatch, value, spare):
    monkeypatch.setenv("USVLOG_THREADS", value)
    assert spare_cpu() is spare


def test_without_it_the_affinity_mask_decides(monkeypatch):
    monkeypatch.delenv("USVLOG_THREADS", raising=False)
    assert spare_cpu() is (len(os.sched_getaffinity(0)) > 1)
    monkeypatch.setenv("USVLOG_THREADS", "many")   # not a number: ignored
    assert spare_cpu() is (len(os.sched_getaffinity(0)) > 1)


def test_run_ahead_gives_the_value_or_the_error_where_it_is_taken(monkeypatch):
    from usvlog._cpu import run_ahead

    monkeypatch.setenv("USVLOG_THREADS", "2")
    calls = []
    result = run_ahead(lambda: calls.append(threading.current_thread()) or 42)
    assert result() == 42
    assert calls and calls[0] is not threading.current_thread()   # on a second thread
    err = ValueError("bad file")

    def fails():
        raise err

    result = run_ahead(fails)
    with pytest.raises(ValueError) as got:
        result()
    assert got.value is err


def test_run_ahead_without_a_spare_cpu_runs_when_taken(monkeypatch):
    from usvlog._cpu import run_ahead

    monkeypatch.setenv("USVLOG_THREADS", "1")
    calls = []
    result = run_ahead(lambda: calls.append(threading.current_thread()) or 7)
    assert calls == []   # nothing started
    assert result() == 7 and calls == [threading.current_thread()]
