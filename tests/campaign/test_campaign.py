"""A generated season through ``usvlog campaign`` on a real Dask LocalCluster of 2 processes.

Two boats over three months, ``alpha``'s d11 stepping +20 % between 2026-05-31 and
2026-06-14, a straight-line run and a corrupt file (tests/campaign/season.py). One campaign,
shared by the tests of this module: interrupted after its first runs (Ctrl-C) and resumed,
both on a local cluster. The interrupted campaign leaves complete outputs, the resumed one
does only what was left, finds the step at the right dates with the right size and nothing
on ``bravo``; a third run from the command line does no work at all; the joint fit reuses
finished runs copied into another campaign; a scenario adds the replay stage.
"""

from __future__ import annotations

import hashlib
import json
import shutil

import numpy as np
import pandas as pd
import pytest
from rerun.chunk import RrdReader
from season import ALPHA_DATES, BRAVO_DATES, D11_STEP, M_KG, STEP_BETWEEN, write_season

import usvlog
from usvlog.campaign.report import COLOURS
from usvlog.campaign.tasks import ESTIMATE_FILE, LOG_FILE, ROW_FILE, VESSEL_FILE
from usvlog.cli import main
from usvlog.io.config import load_vessel
from usvlog.io.mcap import read_log

OPTS = dict(fix={"m": M_KG}, current=False)   # weighed boats, calm water; the default stages
N_RUNS = len(ALPHA_DATES) + len(BRAVO_DATES) + 2


@pytest.fixture(scope="module")
def season(tmp_path_factory):
    return write_season(tmp_path_factory.mktemp("season"))


@pytest.fixture(scope="module")
def camp(season, tmp_path_factory):
    """The season's campaign: interrupted after 3 runs, then resumed (both on a 2-process LocalCluster)."""
    out = tmp_path_factory.mktemp("campaign") / "c"
    seen = []

    def interrupt(row):
        seen.append(row)
        if len(seen) == 3:
            raise KeyboardInterrupt   # Ctrl-C while the other runs are on the workers

    with pytest.raises(KeyboardInterrupt):
        usvlog.campaign([season["runs"]], out, vessel_map=season["map"], workers=2, on_row=interrupt, **OPTS)
    first = pd.read_parquet(out / "runs.parquet")
    dirs = [d for d in (out / "runs").iterdir() if not d.name.startswith(".")]
    rows = {d: json.loads((d / ROW_FILE).read_text()) for d in dirs}
    notes: list[str] = []
    res = usvlog.campaign([str(season["runs"]) + "/*"], out, vessel_map=season["map"], workers=2,
                          progress=notes.append, **OPTS)
    return {"out": out, "first": first, "dirs": rows, "res": res, "notes": notes}


def _complete(run_dir, row) -> None:
    """A finished run's directory holds every output of the stages it passed, readable."""
    assert json.loads((run_dir / ROW_FILE).read_text())["key"] == row["key"]
    if row["failed_stage"] == "import":
        return
    assert read_log(run_dir / LOG_FILE).time_range() is not None
    assert len(read_log(run_dir / ESTIMATE_FILE, topics=["/estimate/state"]).get("/estimate/state")) > 0
    if row["failed_stage"] is None and row["verdict"] != "unusable":   # an unusable fit writes no vessel
        assert load_vessel(run_dir / VESSEL_FILE).params.m == M_KG
    else:
        assert not (run_dir / VESSEL_FILE).exists()


def _by_name(t: pd.DataFrame) -> pd.DataFrame:
    return t.set_index(t["source"].map(lambda s: s.rsplit("/", 1)[-1]))


def test_interrupted_then_resumed_on_a_local_cluster(camp, season):
    assert len(camp["first"]) == 3   # the rows finished before Ctrl-C
    assert len(camp["dirs"]) >= 3    # runs that finished while the cluster was stopping are complete too
    for d, row in camp["dirs"].items():
        _complete(d, row)
    res, out = camp["res"], camp["out"]
    assert res.reused == len(camp["dirs"]) and res.executed == N_RUNS - len(camp["dirs"])
    assert res.cluster is not None and res.cluster.local and res.cluster.workers == 2
    assert any(n.startswith("dask: local cluster of 2 processes; dashboard http") for n in camp["notes"])
    t = pd.read_parquet(out / "runs.parquet")
    assert len(t) == N_RUNS and t["run_id"].is_unique
    for name, row in _by_name(t).iterrows():
        assert row["sha256"] == hashlib.sha256((season["runs"] / name).read_bytes()).hexdigest()
        _complete(out / "runs" / row["run_id"], json.loads((out / "runs" / row["run_id"] / ROW_FILE).read_text()))
    assert t["replay_xte_rms_m"].isna().all()   # an open-loop season is not replayed by default


def test_rows_of_the_season(camp, season):
    by = _by_name(camp["res"].table)
    bad = by.loc[season["corrupt"]]
    assert bad["status"] == "failed" and bad["failed_stage"] == "import"
    assert bad["reason"].startswith("import: ") and season["corrupt"] in bad["reason"]
    straight = by.loc[season["straight"]]
    assert straight["status"] == "ok" and straight["verdict"] == "unusable"
    assert "determined" in straight["reason"]

    good = by.loc[list(season["truth"])]
    assert (good["status"] == "ok").all() and good["verdict"].isin(["usable", "caveats"]).all()
    assert (good["estimate_status"].notna()).all() and (good["estimate_reinits"] >= 0).all()
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


def test_the_step_is_found_at_the_right_dates_with_the_right_size(camp):
    res = camp["res"]
    d = res.drift["alpha"]["d11"]
    assert d.drifted and not d.consistency.consistent
    cp = d.change
    assert (cp.to_dict()["last_before"], cp.to_dict()["first_after"]) == STEP_BETWEEN
    assert abs(cp.change_rel - D11_STEP) < max(cp.change_rel_ci95, 0.03)
    assert [p for p, x in res.drift["alpha"].items() if x.drifted] == ["d11"]
    assert not any(x.drifted for x in res.drift["bravo"].values())
    assert res.drift["bravo"]["d11"].consistency.n == len(BRAVO_DATES)   # the straight run is not counted


def test_the_report(camp, season):
    out, t = camp["out"], camp["res"].table
    page = (out / "campaign.html").read_text()
    assert f"d11 changed between {STEP_BETWEEN[0]} and {STEP_BETWEEN[1]}" in page
    assert season["corrupt"] in page
    words = set(t["verdict"].dropna()) | ({"failed"} if (t["status"] == "failed").any() else set())
    for word in words:   # each verdict of the table, and the failure, in its colour
        assert f"background:{COLOURS[word]}" in page.replace(" ", ""), word
    for v in ("alpha", "bravo"):
        assert (out / f"drift_{v}.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    ents = {c.entity_path for c in RrdReader(out / "campaign.rrd").stream().to_chunks()}
    with_estimate = t[t["failed_stage"].isna()]["run_id"]
    assert all(f"/runs/{r}/map/gps" in ents for r in with_estimate)
    # the map is drawn from each run's own small map file: its estimate's rows, one a second
    d = out / "runs" / with_estimate.iloc[0]
    m, e = usvlog.load(d / "map.mcap"), usvlog.load(d / "estimate.mcap")
    assert set(m.topics) == {"/gnss/fix", "/estimate/state"} and m.datum == e.datum
    ms, es = m["/estimate/state"], e["/estimate/state"]
    assert ms.equals(es.loc[ms.index]) and ms.index[-1] == es.index[-1]
    steps = np.diff(ms.index.to_numpy())[:-1] / 1e9
    assert np.allclose(steps, 1.0, atol=0.011) and len(ms) >= (es.index[-1] - es.index[0]) / 1e9
    summary = json.loads((out / "campaign.json").read_text())
    assert summary["failed"] == 1 and summary["unusable"] == 1


def test_a_rerun_from_the_command_line_does_no_work(camp, season, capsys):
    out = camp["out"]
    capsys.readouterr()
    rc = main(["campaign", str(season["runs"]), "--out", str(out), "--vessel-map", str(season["map"]),
               "--fix", f"m={M_KG}", "--no-current", "--workers", "2", "--no-report", "--json"])
    assert rc == 0
    again = json.loads(capsys.readouterr().out)
    assert again["executed"] == 0 and again["reused"] == N_RUNS and again["cluster"] is None
    assert again["drift"]["alpha"]["d11"]["drifted"] and not again["drift"]["bravo"]["d11"]["drifted"]
    pd.testing.assert_frame_equal(pd.read_parquet(out / "runs.parquet"), camp["res"].table)


def test_joint_fit_of_finished_runs_in_another_campaign(camp, season, tmp_path):
    """Two finished runs copied into a new campaign are reused (the key does not name the
    directory); the joint model of the two, validated leave-one-run-out, pins d11 better."""
    t = _by_name(camp["res"].table)
    names = [f"alpha_{day}.mcap" for day in ALPHA_DATES[:2]]
    for n in names:
        rid = t.loc[n, "run_id"]
        shutil.copytree(camp["out"] / "runs" / rid, tmp_path / "c" / "runs" / rid)
    res = usvlog.campaign([season["runs"] / n for n in names], tmp_path / "c", vessel_map=season["map"],
                          sequential=True, joint=True, report=False, **OPTS)
    assert res.executed == 0 and res.reused == 2
    j = res.joint["alpha"]
    assert j.error is None and set(j.runs) == set(res.table["run_id"])
    assert abs(j.params["d11"] - 5.0) < 4 * j.stderr["d11"] + 0.05
    assert j.stderr["d11"] < res.table["d11_se"].min()   # two runs together pin d11 better than either
    assert len(j.loro) == 2 and (j.loro["fit_track_pct"] > 50).all()
    assert load_vessel(j.vessel_file).params.m == M_KG
    assert len(pd.read_parquet(tmp_path / "c" / "joint.parquet")) == 2


def test_a_scenario_adds_the_replay_stage(season, tmp_path):
    src = season["runs"] / f"alpha_{ALPHA_DATES[0]}.mcap"
    res = usvlog.campaign([src], tmp_path / "c", vessel=season["map"].parent / "alpha.toml", sequential=True,
                          stages=["import"], scenario="paper-circle", report=False)
    row = res.table.iloc[0]
    assert row["status"] == "ok" and pd.isna(row["d11"]) and pd.isna(row["estimate_model"])
    assert np.isfinite(row["replay_xte_rms_m"]) and np.isfinite(row["whatif_xte_rms_m"])
