"""Standard manoeuvres (usvlog.trials) against the truth.

Simulated open-loop runs of the paper's vessel (GPS 1.5 m, compass 2 deg noise): the executes
are known from the thrust programs, the metrics are computed on the noise-free /truth/state with
the same definitions and, where the paper's model gives them in closed form (steady speed
tau_u / d11, pivot yaw rate tau_r / d33, coast-down time constant m / d11), checked against
those too. The manoeuvres measured on the noisy log's estimate must match: tactical diameter and
advance within 5 %, overshoot angles within 1 deg, start times within 3 s.

The Otter runs of ../shared/trainlogs (another hull, another simulator; their truth file's
``phase`` column marks each manoeuvre) are measured the same way when present.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import usvlog
from usvlog.errors import InputError
from usvlog.trials import (
    Commands,
    CommandsBuilder,
    Settings,
    Track,
    TrackBuilder,
    commands_from_frame,
    find,
    find_manoeuvres,
    track_from_frame,
    uses_forces,
)
from usvlog.trials.detect import holds
from usvlog.trials.metrics import nominal_angle

sys.path.insert(0, str(Path(__file__).parent))
import manoeuvre_runs as R  # noqa: E402

TRAINLOGS = Path(__file__).resolve().parents[3] / "shared" / "trainlogs"
if not TRAINLOGS.is_dir():
    TRAINLOGS = Path("/work/shared/trainlogs")


def _measured(log):
    """(manoeuvres on the estimate, manoeuvres on the truth) of a simulated log."""
    t0 = log.time_range()[0]
    est = usvlog.estimate(log)
    return (find_manoeuvres(est.state, log["/thrust/command"], t0),
            find_manoeuvres(log["/truth/state"], log["/thrust/command"], t0, source="/truth/state"))


@pytest.fixture(scope="module")
def turning():
    return _measured(R.turning_circle_run())


@pytest.fixture(scope="module")
def zigzag():
    return _measured(R.zigzag_run())


@pytest.fixture(scope="module")
def steps():
    return _measured(R.steps_stop_pivot_run())


def _rel(a: float, b: float) -> float:
    return abs(a / b - 1.0)


def test_turning_circle_against_the_truth(turning):
    est, truth = turning
    assert [m.kind for m in est] == ["turning_circle"] == [m.kind for m in truth]
    e, t = est.items[0], truth.items[0]
    assert abs(e.start_s - R.RUN_IN_S) < 3.0 and abs(t.start_s - R.RUN_IN_S) < 3.0
    assert e.direction == t.direction == "starboard"     # tau_r > 0: port thruster harder
    for name in ("tactical_diameter_m", "advance_m", "transfer_m"):
        assert _rel(e.value(name), t.value(name)) < 0.05, (name, e.value(name), t.value(name))
    # the steady diameter 2 U / r is the circle's: the truth's positions at 180 and 360 deg lie across it
    log = R.turning_circle_run()
    tr = log["/truth/state"]
    turned = np.unwrap(tr["psi_rad"].to_numpy())
    turned -= turned[np.searchsorted((tr.index.to_numpy() - log.time_range()[0]) * 1e-9, R.RUN_IN_S)]
    k180, k360 = np.searchsorted(turned, math.pi), np.searchsorted(turned, 2 * math.pi)
    across = math.hypot(tr["n_m"].iloc[k360] - tr["n_m"].iloc[k180], tr["e_m"].iloc[k360] - tr["e_m"].iloc[k180])
    assert _rel(t.value("steady_turning_diameter_m"), across) < 0.03
    assert _rel(e.value("steady_turning_diameter_m"), across) < 0.05
    assert _rel(e.value("steady_turn_rate_degps"), t.value("steady_turn_rate_degps")) < 0.03
    # one-sigmas from the covariance: positive, and the errors within 3 of them
    for name in ("tactical_diameter_m", "advance_m"):
        m = e.metric(name)
        assert 0 < m.std < 2.0 and abs(m.value - t.value(name)) < 3 * m.std + 0.05 * t.value(name)


def test_zigzag_against_the_truth(zigzag):
    est, truth = zigzag
    assert [m.kind for m in est] == ["zigzag"] == [m.kind for m in truth]
    e, t = est.items[0], truth.items[0]
    assert abs(e.start_s - R.RUN_IN_S) < 3.0
    assert e.value("zigzag_angle_deg") == t.value("zigzag_angle_deg") == R.ZIGZAG_DEG
    assert abs(t.value("checking_angle_deg") - R.ZIGZAG_DEG) < 0.5   # the kernel reverses at 20 deg
    for name in ("first_overshoot_deg", "second_overshoot_deg"):
        assert abs(e.value(name) - t.value(name)) < 1.0, (name, e.value(name), t.value(name))
        assert t.value(name) > 1.0   # a real overshoot, not a flat zero
    assert abs(e.value("period_s") - t.value("period_s")) < 0.5
    assert abs(e.value("initial_turning_time_s") - t.value("initial_turning_time_s")) < 0.5


def test_speed_steps_stop_and_pivot_against_the_truth(steps):
    est, truth = steps
    assert [m.kind for m in est] == ["speed_steps", "stop", "pivot"] == [m.kind for m in truth]
    d11 = d33 = 5.0    # the paper's vessel: m 33 kg, d11 = d33 = 5
    sp_e, sp_t = est.items[0], truth.items[0]
    assert abs(sp_e.start_s - R.STEPS[0][0]) < 3.0
    assert [s["thrust"] for s in sp_t.steps] == pytest.approx([f for _, f in R.STEPS], abs=1e-3)
    for se, st, (_, f) in zip(sp_e.steps, sp_t.steps, R.STEPS):
        assert st["speed_mps"] == pytest.approx(f / d11, rel=0.01)          # the model's steady speed
        assert abs(se["speed_mps"] - st["speed_mps"]) < 0.05
    assert sp_t.value("time_constant_s") == pytest.approx(33.0 / d11, rel=0.03)   # m / d11
    stop_e, stop_t = est.items[1], truth.items[1]
    assert abs(stop_e.start_s - R.STOP_AT) < 3.0
    # linear damping: u falls to 15 % after (m / d11) ln(1 / 0.15), covering u0 (m / d11) 0.85
    tau = 33.0 / d11
    assert stop_t.value("stopping_time_s") == pytest.approx(tau * math.log(1 / 0.15), rel=0.03)
    assert stop_t.value("stopping_distance_m") == pytest.approx(0.6 * tau * 0.85, rel=0.05)
    for name in ("stopping_distance_m", "head_reach_m", "stopping_time_s"):
        m = stop_e.metric(name)
        assert abs(m.value - stop_t.value(name)) < 3 * m.std, (name, m, stop_t.value(name))
    pv_e, pv_t = est.items[2], truth.items[2]
    assert abs(pv_e.start_s - R.PIVOT_AT) < 3.0 and pv_e.direction == "starboard"
    rate = math.degrees(0.3 * 2 * R.PIVOT_FORCE / d33)
    assert pv_t.value("yaw_rate_degps") == pytest.approx(rate, rel=0.02)
    assert _rel(pv_e.value("yaw_rate_degps"), pv_t.value("yaw_rate_degps")) < 0.05
    assert pv_e.value("speed_mps") < 0.2


def test_results_to_json_and_frame(steps):
    est, _ = steps
    d = json.loads(json.dumps(est.to_dict(), allow_nan=False))   # every number finite
    assert d["count"] == 3 and [m["kind"] for m in d["manoeuvres"]] == ["speed_steps", "stop", "pivot"]
    for m in d["manoeuvres"]:
        assert set(m) >= {"kind", "start_s", "end_s", "direction", "metrics"}
        assert m["metrics"] and all(set(v) == {"value", "std"} for v in m["metrics"].values())
    assert len(d["manoeuvres"][0]["steps"]) == len(R.STEPS)
    df = est.to_dataframe()
    assert list(df.columns) == ["index", "kind", "start_s", "end_s", "direction", "metric", "value", "std"]
    assert np.isfinite(df["value"]).all() and (df["std"] >= 0).all()
    assert "pivot turn to starboard" in est.format()


def test_closed_loop_run_has_no_standard_manoeuvre():
    log = usvlog.simulate("paper-circle", duration_s=60)   # the controller's commands vary all the time
    found = usvlog.manoeuvres(log)
    assert len(found) == 0 and found.format() == "no standard manoeuvre found"


def test_holds_and_settings():
    t = np.arange(0, 30, 0.1)
    left = np.where(t < 10, 1.0, 3.0) + 0.01 * np.sin(t)     # jitter below the tolerance
    right = np.where(t < 20, 1.0, -1.0)
    hs = holds(Commands(t, left, right), tol=0.1)
    got = [(round(h.start, 1), round(h.left), round(h.right)) for h in hs]
    assert got == [(0.0, 1, 1), (10.0, 3, 1), (20.0, 3, -1)]
    assert hs[2].diff == pytest.approx(4.0, abs=0.02) and hs[1].common == pytest.approx(4.0, abs=0.02)
    with pytest.raises(InputError, match="min_turn_deg"):
        Settings(min_turn_deg=-1)
    assert nominal_angle(20.3) == 20.0 and nominal_angle(26.1) == 25.0 and nominal_angle(12.6) == 13.0


def test_idle_commands_find_nothing():
    t = np.arange(0, 60, 0.1)
    z = np.zeros_like(t)
    track = Track(t, z, z, z, z, z, z, z, z, z, z, z)
    assert len(find(track, Commands(t, z, z))) == 0


def _blocks(frame: pd.DataFrame, rng, n: int = 40):
    """``frame`` cut anywhere into ``n`` + 1 blocks (some of one row or none)."""
    cuts = np.sort(np.r_[0, 1, 1, rng.integers(0, len(frame), n - 3)])
    return [frame.iloc[a:b] for a, b in zip(np.r_[0, cuts], np.r_[cuts, len(frame)])]


def _same_arrays(a, b) -> bool:
    return all(np.array_equal(getattr(a, k), getattr(b, k)) for k in a.__dataclass_fields__ if k != "unit")


def test_track_made_block_by_block_equals_the_whole_frames():
    """TrackBuilder over blocks cut anywhere: the track of the whole frame bit for bit (the heading
    unwrapped across the blocks as np.unwrap does the whole run; non-finite rows dropped)."""
    rng = np.random.default_rng(5)
    n = 6000
    psi = np.cumsum(rng.normal(0.0, 1.2, n))   # steps up to pi and beyond: np.unwrap's every branch
    psi = (psi + np.pi) % (2 * np.pi) - np.pi
    psi[[7, 2000]] = np.nan
    frame = pd.DataFrame({c: rng.normal(size=n) for c in ("n_m", "e_m", "u_mps", "v_mps", "r_radps", "n_m_std",
                                                          "e_m_std", "psi_rad_std", "u_mps_std", "r_radps_std")},
                         index=pd.Index(10**18 + np.arange(n, dtype=np.int64) * 10**7, name="t_ns"))
    frame["psi_rad"], frame.iloc[50, 0] = psi, np.inf
    frame.iloc[60, frame.columns.get_loc("psi_rad_std")] = np.nan
    t0 = 10**18 - 5 * 10**8
    whole = track_from_frame(frame, t0)
    assert np.array_equal(whole.psi, np.unwrap(psi[np.isfinite(psi) & np.isfinite(frame["n_m"].to_numpy())]))
    assert len(whole.t) == n - 3 and whole.psi_std[58] == 0.0   # a NaN sigma is zero (rows 7 and 50 dropped)
    made = TrackBuilder(n, t0)
    for b in _blocks(frame, rng):
        made.add(b)
    assert _same_arrays(made.track(), whole)
    with pytest.raises(InputError, match="finite rows"):
        TrackBuilder(n, t0).add(frame.iloc[:12].assign(n_m=np.nan)).track()


@pytest.mark.parametrize("forces", [True, False])
def test_commands_made_block_by_block_equal_the_whole_frames(forces):
    """CommandsBuilder over blocks: the commands of the whole frame (the forces or the commands,
    non-finite rows dropped, times out of order sorted as the whole frame's stable sort)."""
    rng = np.random.default_rng(6)
    n = 3000
    t = 10**18 + np.arange(n, dtype=np.int64) * 10**7
    t[[100, 101, 2500]] = t[[101, 100, 10]]   # out of order, one repeated
    frame = pd.DataFrame({"left": rng.normal(size=n), "right": rng.normal(size=n),
                          "unit": pd.array(["normalized"] * n, dtype="str"),
                          "thrust_left_n": rng.normal(size=n), "thrust_right_n": rng.normal(size=n)},
                         index=pd.Index(t, name="t_ns"))
    frame.iloc[3, 0] = frame.iloc[4, 4] = np.nan
    if not forces:
        frame.iloc[::5, 3] = np.nan   # forces on 80 % of the rows: the commands are taken
    whole = commands_from_frame(frame, 10**18)
    left = int(np.isfinite(frame["thrust_left_n"].to_numpy()).sum())
    assert uses_forces(frame.columns, left, n) is forces and whole.unit == ("N" if forces else "normalized")
    made = CommandsBuilder(n, 10**18, forces, "normalized")
    for b in _blocks(frame, rng):
        made.add(b)
    got = made.commands()
    assert _same_arrays(got, whole) and got.unit == whole.unit and np.all(np.diff(got.t) >= 0)
    assert commands_from_frame(frame.drop(columns=["unit", "thrust_left_n"]), 0).unit == "command"


# -----------------------------------------------------------------------------
# the Otter runs (another hull and simulator), when present
# -----------------------------------------------------------------------------

OTTER_COLUMNS = {"time_s": "t", "lat_deg": "lat_deg", "lon_deg": "lon_deg", "heading_deg": "heading_deg",
                 "thrust_left": "thrust_cmd_left_N", "thrust_right": "thrust_cmd_right_N"}
PHASE_OF = {"speed_steps": ("speed_step",), "zigzag": ("zigzag",), "turning_circle": ("turn_stbd", "turn_port"),
            "stop": ("coast", "final_coast"), "pivot": ("pivot", "pivot_rev")}


def _otter(run: str):
    res = usvlog.import_log(TRAINLOGS / f"otter_train_{run}_sensor.csv.gz", None, fmt="csv", columns=OTTER_COLUMNS,
                            thrust_unit="newton", start_utc="2026-06-01T12:00:00Z")
    log = res.log
    t0 = log.time_range()[0]
    est = usvlog.manoeuvres(log)
    d = pd.read_csv(TRAINLOGS / f"otter_train_{run}_truth10hz.csv.gz")
    z = np.zeros(len(d))
    track = Track(d.t.to_numpy(), d.x_north_m.to_numpy(), d.y_east_m.to_numpy(), np.unwrap(d.psi_rad.to_numpy()),
                  d.u_mps.to_numpy(), d.v_mps.to_numpy(), d.r_radps.to_numpy(), z, z, z, z, z)
    from usvlog.trials import commands_from_frame

    truth = find(track, commands_from_frame(log["/thrust/command"], t0))
    return est, truth, d


@pytest.mark.skipif(not TRAINLOGS.is_dir(), reason="../shared/trainlogs is not here")
@pytest.mark.parametrize("run", ["a", "b"])
def test_otter_runs_against_phase_and_truth(run):
    est, truth, d = _otter(run)
    starts = d.t.to_numpy()[np.r_[0, np.flatnonzero(d.phase.to_numpy()[1:] != d.phase.to_numpy()[:-1]) + 1]]
    phases = d.phase.to_numpy()[np.searchsorted(d.t.to_numpy(), starts)]
    # every marked manoeuvre found, starting within 3 s of its phase; nothing found in the PRBS part
    for kind, names in PHASE_OF.items():
        for name in names:
            t_phase = float(starts[list(phases).index(name)])
            hits = [m for m in est.of_kind(kind) if abs(m.start_s - t_phase) < 3.0]
            assert hits, (kind, name, t_phase, [m.start_s for m in est])
    prbs = float(starts[list(phases).index("prbs")]), float(starts[list(phases).index("final_coast")])
    assert not [m for m in est if prbs[0] + 3 < m.start_s < prbs[1] - 3]
    assert [m.kind for m in est] == [m.kind for m in truth]
    for e, t in zip(est, truth):
        if e.kind == "turning_circle":
            # the issue's figures: tactical diameter and advance within 5 % (the manoeuvres' own estimate)
            assert _rel(e.value("tactical_diameter_m"), t.value("tactical_diameter_m")) < 0.05
            assert _rel(e.value("steady_turn_rate_degps"), t.value("steady_turn_rate_degps")) < 0.02
            assert abs(e.value("advance_m") - t.value("advance_m")) < 0.05 * t.value("advance_m")
        if e.kind == "zigzag":
            assert e.value("zigzag_angle_deg") == t.value("zigzag_angle_deg") == {"a": 15.0, "b": 25.0}[run]
            assert abs(e.value("period_s") - t.value("period_s")) < 0.2
            for name in ("first_overshoot_deg", "second_overshoot_deg"):
                assert abs(e.value(name) - t.value(name)) < 1.0   # the figure
        if e.kind == "pivot":
            assert _rel(e.value("yaw_rate_degps"), t.value("yaw_rate_degps")) < 0.05
