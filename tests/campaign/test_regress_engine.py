"""``usvlog regress --workers`` runs the scenarios as Dask tasks (the campaign engine): same numbers.

The engine is the only parallel path (``--jobs`` is a deprecated name of ``--workers``), and
the local cluster's dashboard address serves the Dask status page.
"""

from __future__ import annotations

import re
import urllib.request

import pytest

import usvlog
from usvlog.cli import main


def _page(url: str) -> str:
    with urllib.request.urlopen(url, timeout=60) as resp:   # the cluster's own address on 127.0.0.1
        assert resp.status == 200
        return resp.read().decode()


def test_regress_on_a_local_cluster_gives_the_in_process_metrics(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    for seed in (1, 2):
        usvlog.simulate("turns", f"run{seed}.mcap", seed=seed, duration_s=40)
        (tmp_path / f"est{seed}.toml").write_text(f'[dataset]\nlog = "run{seed}.mcap"\n[stages]\nrun = ["estimate"]\n')
    scns = ["est1.toml", "est2.toml"]
    usvlog.regress(scns, update=True)
    here = usvlog.regress(scns)
    seen, pages = [], []

    def note(line: str) -> None:   # called while the cluster is up: its dashboard answers
        seen.append(line)
        m = re.search(r"dashboard (http://127\.0\.0\.1:\d+/status)$", line)
        if m:
            pages.append(_page(m.group(1)))

    there = usvlog.regress(scns, workers=2, progress=note, on_outcome=lambda o: seen.append(o.name))
    assert [o.name for o in there] == [o.name for o in here] == ["est1", "est2"]
    assert [o.metrics for o in there] == [o.metrics for o in here] and not any(o.failed for o in there)
    assert seen[0].startswith("dask: tcp://") and sorted(seen[1:]) == ["est1", "est2"]
    assert len(pages) == 1 and "<title>Dask Diagnostic UI</title>" in pages[0]
    capsys.readouterr()
    assert main(["regress", *scns, "--jobs", "1"]) == 0   # the old option: the same engine, and a warning
    out, err = capsys.readouterr()
    assert "2 scenarios" in out and "--jobs is deprecated, use --workers" in err and "dask: tcp://" in err


def test_jobs_and_workers_that_disagree_are_refused_before_any_run(tmp_path, capsys):
    assert main(["regress", str(tmp_path / "none.toml"), "--jobs", "2", "--workers", "1"]) == 2
    assert "--jobs 2 and --workers 1 differ" in capsys.readouterr().err
    with pytest.deprecated_call(), pytest.raises(usvlog.UsvlogError, match="--workers 0 must be >= 1"):
        usvlog.regress([tmp_path / "none.toml"], jobs=0)


def test_local_workers_keep_glibcs_own_trim_threshold_and_do_not_profile(monkeypatch):
    """Dask would start the workers with MALLOC_TRIM_THRESHOLD_=65536 (every freed block over
    64 KB back to the system: a run's arrays come back as fresh pages, ~1 s of kernel time per
    ten-minute run); the local cluster is started without it, the rest of Dask's settings kept."""
    import os

    import dask

    from usvlog._cpu import spare_cpu
    from usvlog.campaign.engine import Runner

    monkeypatch.delenv("MALLOC_TRIM_THRESHOLD_", raising=False)
    monkeypatch.delenv("USVLOG_THREADS", raising=False)
    with Runner(workers=1) as run:
        got = run.map(os.getenv, ["MALLOC_TRIM_THRESHOLD_", "OPENBLAS_NUM_THREADS", "USVLOG_THREADS"])
        spare = run.map(lambda _: spare_cpu(), [0])
        cfg = run.map(dask.config.get, ["distributed.worker.profile.enabled",
                                        "distributed.worker.memory.monitor-interval"])
    assert got == [None, "1", "1"]
    assert spare == [False]   # a worker is one core: the verbs' second-core work stays in it
    assert "USVLOG_THREADS" not in os.environ   # ... and the campaign's own process keeps its cores
    assert cfg == [False, "1s"]   # no sampling thread taking the GIL every 10 ms; a calmer memory monitor
