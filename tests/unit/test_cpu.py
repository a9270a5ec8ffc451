"""usvlog._cpu.spare_cpu: the environment's USVLOG_THREADS decides, else the CPUs this process may use."""

import os

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
