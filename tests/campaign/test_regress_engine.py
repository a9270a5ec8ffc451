"""``usvlog regress --workers`` runs the scenarios as Dask tasks (the campaign engine): same numbers."""

from __future__ import annotations

import usvlog
from usvlog.cli import main


def test_regress_on_a_local_cluster_gives_the_in_process_metrics(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    for seed in (1, 2):
        usvlog.simulate("turns", f"run{seed}.mcap", seed=seed, duration_s=40)
        (tmp_path / f"est{seed}.toml").write_text(f'[dataset]\nlog = "run{seed}.mcap"\n[stages]\nrun = ["estimate"]\n')
    scns = ["est1.toml", "est2.toml"]
    usvlog.regress(scns, update=True)
    here = usvlog.regress(scns)
    seen = []
    there = usvlog.regress(scns, workers=2, progress=seen.append, on_outcome=lambda o: seen.append(o.name))
    assert [o.name for o in there] == [o.name for o in here] == ["est1", "est2"]
    assert [o.metrics for o in there] == [o.metrics for o in here] and not any(o.failed for o in there)
    assert seen[0].startswith("dask: tcp://") and sorted(seen[1:]) == ["est1", "est2"]
    capsys.readouterr()
    assert main(["regress", *scns, "--workers", "1"]) == 0
    assert "2 scenarios" in capsys.readouterr().out
