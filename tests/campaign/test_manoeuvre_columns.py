"""Campaign columns of the standard manoeuvres: a season's run with a turning circle and one
without any, through the campaign's own stages, against the truth's manoeuvres."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

import usvlog
from usvlog.campaign import columns as C
from usvlog.trials import find_manoeuvres

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "unit"))
import manoeuvre_runs as R  # noqa: E402


def test_tactical_diameter_per_run(tmp_path):
    log = R.turning_circle_run(seed=4)
    usvlog.save(log, tmp_path / "circle.mcap")
    usvlog.simulate("paper-circle", tmp_path / "closed.mcap", duration_s=30)
    season = usvlog.campaign([tmp_path / "circle.mcap", tmp_path / "closed.mcap"], tmp_path / "season",
                             stages=["import", "estimate"], sequential=True)
    t = season.table.set_index(season.table["source"].map(lambda s: Path(s).stem))
    truth = find_manoeuvres(log["/truth/state"], log["/thrust/command"], log.time_range()[0]).items[0]
    row = t.loc["circle"]
    assert row["status"] == "ok" and row["manoeuvres"] == 1
    assert abs(row["tactical_diameter_m"] / truth.value("tactical_diameter_m") - 1) < 0.05
    assert abs(row["advance_m"] / truth.value("advance_m") - 1) < 0.05
    assert 0 < row["tactical_diameter_m_std"] < 1.0
    assert abs(row["turn_rate_degps"] / truth.value("steady_turn_rate_degps") - 1) < 0.03
    assert np.isnan(row["zigzag_overshoot_deg"]) and np.isnan(row["stopping_distance_m"])
    closed = t.loc["closed"]
    assert closed["status"] == "ok" and closed["manoeuvres"] == 0 and np.isnan(closed["tactical_diameter_m"])


def test_a_run_without_thrust_has_no_manoeuvre_columns():
    log = R.turning_circle_run(seed=4, duration_s=40)
    state = log["/truth/state"]
    del log.channels["/thrust/command"]
    assert C.manoeuvre_columns(state, log) == {}
    assert set(C.MANOEUVRE_COLUMNS) <= set(C.SCHEMA)


def test_check_columns_are_the_check_verbs_findings():
    """The campaign's check columns count what `usvlog check` finds: left and right thrust swapped
    is an error there and here, with the same code."""
    from usvlog.campaign.columns import check_columns
    from usvlog.check import check_log
    from usvlog.sim.simulate import SimSettings, simulate

    log = simulate("excitation", SimSettings(duration_s=120.0), seed=2)
    clean = check_columns(log)
    th = log["/thrust/command"]
    for a, b in (("left", "right"), ("thrust_left_n", "thrust_right_n")):
        th[a], th[b] = th[b].to_numpy().copy(), th[a].to_numpy().copy()
    bad = check_columns(log)
    res = check_log(log)
    assert bad["check_errors"] == sum(f.severity == "error" for f in res.findings)
    assert bad["check_warnings"] == sum(f.severity == "warning" for f in res.findings)
    assert bad["check_errors"] > clean["check_errors"] == 0 and "thrusters.swapped" in bad["check_findings"]
    assert all(f"{f.code}@{f.channel}" in bad["check_findings"] for f in res.findings
               if f.severity in ("error", "warning"))


def test_identify_columns_carry_the_30_s_ahead_fit():
    """The campaign's identification columns carry the 30 s-ahead prediction fit % the verdict reads,
    for u and r, on a simulated run identified with a held-out part."""
    import math

    from usvlog.campaign.columns import SCHEMA, identify_columns
    from usvlog.identify.identifier import Identifier
    from usvlog.sim.simulate import SimSettings, simulate

    log = simulate("excitation", SimSettings(duration_s=200.0), seed=4)
    idf = Identifier("output-error", holdout=0.3).fit([log])
    cols = identify_columns(idf)
    for k in ("u", "r"):
        name = f"fit_ahead_30s_{k}_pct"
        assert SCHEMA[name] == "float"
        assert cols[name] == idf.fit_percent_ahead_["30"][k] and math.isfinite(cols[name])
    assert cols["fit_ahead_30s_r_pct"] > 50.0   # the paper's model predicts its own simulated boat's yaw
