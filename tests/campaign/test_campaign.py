"""A generated season through ``usvlog campaign`` on a real Dask LocalCluster of 2 processes.

Two boats over three months, ``alpha``'s d11 stepping +20 % between 2026-05-31 and
2026-06-14, a straight-line run and a corrupt file (tests/campaign/season.py). The campaign
is interrupted after its first runs (Ctrl-C), resumed, and run a third time from the
command line: the interrupted campaign leaves complete outputs, the resumed one does only
what was left, finds the step at the right dates with the right size and nothing on
``bravo``, and the third does no work at all.
"""

from __future__ import annotations

import hashlib
import json

import numpy as np
import pandas as pd
import pytest
from rerun.chunk import RrdReader
from season import ALPHA_DATES, BRAVO_DATES, D11_STEP, M_KG, STEP_BETWEEN, write_season

import usvlog
from usvlog.campaign.tasks import ESTIMATE_FILE, LOG_FILE, ROW_FILE, VESSEL_FILE
from usvlog.cli import main
from usvlog.io.config import load_vessel
from usvlog.io.mcap import read_log

STAGES = ["import", "estimate", "identify"]
OPTS = dict(fix={"m": M_KG}, current=False, stages=STAGES)   # weighed boats, calm water


@pytest.fixture(scope="module")
def season(tmp_path_factory):
    return write_season(tmp_path_factory.mktemp("season"))


def _complete(run_dir, row) -> None:
    """A finished run's directory holds every output of the stages it passed, readable."""
    assert json.loads((run_dir / ROW_FILE).read_text())["key"] == row["key"]
    if row["failed_stage"] == "import":
        return
    assert read_log(run_dir / LOG_FILE).time_range() is not None
    assert len(read_log(run_dir / ESTIMATE_FILE, topics=["/estimate/state"]).get("/estimate/state")) > 0
    if row["failed_stage"] is None:
        assert load_vessel(run_dir / VESSEL_FILE).params.m == M_KG


def test_season_on_a_local_cluster_interrupted_resumed_and_rerun(season, tmp_path, capsys):
    out = tmp_path / "campaign"
    n_runs = len(ALPHA_DATES) + len(BRAVO_DATES) + 2
    seen = []

    def interrupt(row):
        seen.append(row)
        if len(seen) == 3:
            raise KeyboardInterrupt   # Ctrl-C while the other runs are on the workers

    # 1. interrupted: the runs finished so far are complete and in the table
    with pytest.raises(KeyboardInterrupt):
        usvlog.campaign([season["runs"]], out, vessel_map=season["map"], workers=2, on_row=interrupt, **OPTS)
    first = pd.read_parquet(out / "runs.parquet")
    assert len(first) == 3
    dirs = [d for d in (out / "runs").iterdir() if not d.name.startswith(".")]
    assert len(dirs) >= 3   # runs that finished while the cluster was stopping are complete too
    for d in dirs:
        _complete(d, json.loads((d / ROW_FILE).read_text()))

    # 2. resumed: only the rest is done
    notes = []
    res = usvlog.campaign([str(season["runs"]) + "/*"], out, vessel_map=season["map"], workers=2,
                          progress=notes.append, **OPTS)
    assert res.reused == len(dirs) and res.executed == n_runs - len(dirs)
    assert res.cluster is not None and res.cluster.local and res.cluster.workers == 2
    assert any(n.startswith("dask: local cluster of 2 processes; dashboard http") for n in notes)
    t = pd.read_parquet(out / "runs.parquet")
    assert len(t) == n_runs and t["run_id"].is_unique
    by = t.set_index(t["source"].map(lambda s: s.rsplit("/", 1)[-1]))
    for name, row in by.iterrows():
        assert row["sha256"] == hashlib.sha256((season["runs"] / name).read_bytes()).hexdigest()
        _complete(out / "runs" / row["run_id"], json.loads((out / "runs" / row["run_id"] / ROW_FILE).read_text()))

    bad = by.loc[season["corrupt"]]
    assert bad["status"] == "failed" and bad["failed_stage"] == "import"
    assert bad["reason"].startswith("import: ") and season["corrupt"] in bad["reason"]
    straight = by.loc[season["straight"]]
    assert straight["status"] == "ok" and straight["verdict"] == "unusable"
    assert "not determined" in straight["reason"]

    good = by.loc[list(season["truth"])]
    assert (good["status"] == "ok").all() and good["verdict"].isin(["usable", "caveats"]).all()
    assert (good["vessel"] == good.index.str.split("_").str[0]).all()
    truth = pd.Series(season["truth"])
    assert (abs(good["d11"] - truth) < 4 * good["d11_se"] + 0.02 * truth).all()   # each run near its truth
    assert (good["fit_on"] == "validation").all() and (good["fit_track_pct"] > 50).all()
    assert (good["duration_s"].between(85, 95)).all()
    for name, row in good.iterrows():   # along the estimated track: the true path's length
        tr = read_log(season["runs"] / name, topics=["/truth/state"]).get("/truth/state")
        true_m = np.hypot(np.diff(tr["n_m"]), np.diff(tr["e_m"])).sum()
        assert row["distance_m"] == pytest.approx(true_m, rel=0.05)
    assert good["start_utc"].dt.strftime("%Y-%m-%d").tolist() == [n.split("_")[1][:10] for n in good.index]

    # the drift: alpha's d11 stepped between the right dates by the right amount; bravo did not move
    d = res.drift["alpha"]["d11"]
    assert d.drifted and not d.consistency.consistent
    cp = d.change
    assert (cp.to_dict()["last_before"], cp.to_dict()["first_after"]) == STEP_BETWEEN
    assert abs(cp.change_rel - D11_STEP) < max(cp.change_rel_ci95, 0.03)
    assert [p for p, x in res.drift["alpha"].items() if x.drifted] == ["d11"]
    assert not any(x.drifted for x in res.drift["bravo"].values())
    assert res.drift["bravo"]["d11"].consistency.n == len(BRAVO_DATES)   # the straight run is not counted

    # the report: findings on the page, drift PNGs, every run with an estimate on one map
    page = (out / "campaign.html").read_text()
    assert f"d11 changed between {STEP_BETWEEN[0]} and {STEP_BETWEEN[1]}" in page
    assert season["corrupt"] in page and "#f4b6b6" in page   # the failure listed, an unusable row coloured
    for v in ("alpha", "bravo"):
        assert (out / f"drift_{v}.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    ents = {c.entity_path for c in RrdReader(out / "campaign.rrd").stream().to_chunks()}
    with_estimate = t[t["failed_stage"].isna()]["run_id"]
    assert all(f"/runs/{r}/map/gps" in ents for r in with_estimate)
    summary = json.loads((out / "campaign.json").read_text())
    assert summary["failed"] == 1 and summary["unusable"] == 1

    # 3. again, from the command line: nothing to do, no cluster started
    capsys.readouterr()
    rc = main(["campaign", str(season["runs"]), "--out", str(out), "--vessel-map", str(season["map"]),
               "--stages", ",".join(STAGES), "--fix", f"m={M_KG}", "--no-current", "--workers", "2",
               "--no-report", "--json"])
    assert rc == 0
    again = json.loads(capsys.readouterr().out)
    assert again["executed"] == 0 and again["reused"] == n_runs and again["cluster"] is None
    assert again["drift"]["alpha"]["d11"]["drifted"] and not again["drift"]["bravo"]["d11"]["drifted"]
    third = pd.read_parquet(out / "runs.parquet")
    pd.testing.assert_frame_equal(third, t)


def test_joint_fit_and_replay_in_process(season, tmp_path):
    """The joint model of two runs of one boat, validated leave-one-run-out, and the replay stage's columns."""
    srcs = [season["runs"] / f"alpha_{day}.mcap" for day in ALPHA_DATES[:2]]
    res = usvlog.campaign(srcs, tmp_path / "c", vessel=season["map"].parent / "alpha.toml", sequential=True,
                          joint=True, report=False, fix={"m": M_KG}, current=False)
    t = res.table
    assert res.executed == 2 and res.cluster is None
    assert np.isfinite(t["replay_xte_rms_m"]).all() and np.isfinite(t["whatif_xte_rms_m"]).all()
    j = res.joint["alpha"]
    assert j.error is None and set(j.runs) == set(t["run_id"])
    assert abs(j.params["d11"] - 5.0) < 4 * j.stderr["d11"] + 0.05
    assert j.stderr["d11"] < t["d11_se"].min()   # two runs together pin d11 better than either
    assert len(j.loro) == 2 and (j.loro["fit_track_pct"] > 50).all()
    assert load_vessel(j.vessel_file).params.m == M_KG
    assert len(pd.read_parquet(tmp_path / "c" / "joint.parquet")) == 2
