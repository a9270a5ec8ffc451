"""The estimate made a time window at a time (usvlog.estimate.windowed, usvlog.api.estimate_file):
the same frames, report and file bytes as the whole log estimated in memory and written
(estimate + write_log), over many windows of the thrust, of the smoother's rows and of the
output; a file that cannot be read so is estimated whole."""

import json

import numpy as np
import pandas as pd
import pytest

import usvlog.api.estimate_file as ef
from usvlog.errors import InputError
from usvlog.estimate import EstimateSettings, build_problem, estimate
from usvlog.estimate import windowed as W
from usvlog.estimate.core import INPUT_TOPICS
from usvlog.estimate.layout import INNOVATION_TOPIC, STATE_TOPIC, THRUST_TOPIC
from usvlog.estimate.problem import held_thrust
from usvlog.estimate.report import Sideslip, sideslip_figures
from usvlog.io.mcap import read_log, write_log
from usvlog.io.mcap import windows as mcap_windows
from usvlog.model.vessel import default_vessel
from usvlog.sim.simulate import SimSettings, simulate


@pytest.fixture(scope="module")
def run():
    """A 300 s excitation run: 30,000 filter steps, 15 smoother blocks."""
    return simulate("excitation", SimSettings(duration_s=300.0), seed=11)


def _cut(frame: pd.DataFrame, n: int) -> list[pd.DataFrame]:
    """``frame`` in ``n`` consecutive pieces of uneven length."""
    edges = np.unique(np.r_[0, np.sort(np.random.default_rng(n).integers(1, len(frame), n - 1)), len(frame)])
    return [frame.iloc[a:b] for a, b in zip(edges[:-1], edges[1:])]


class _Rows:
    """A RowStore in memory (the rows, as put)."""

    def __init__(self):
        self.rows = {}

    def put(self, r0, X, SD, PB):
        for i in range(len(X)):
            self.rows[r0 + i] = (X[i].copy(), SD[i].copy(), PB[i].copy() if len(PB) else None)

    def get(self, r0, r1):
        X, SD, PB = zip(*(self.rows[r] for r in range(r0, r1)))
        return np.array(X), np.array(SD), np.array(PB) if PB[0] is not None else np.empty((0, 3, 3))


def _equal_reports(a, b):
    assert json.dumps(a.to_dict(), sort_keys=True) == json.dumps(b.to_dict(), sort_keys=True)


@pytest.mark.parametrize("settings, cut", [
    (EstimateSettings(), 7),                                         # kinematic with sway damping (the default)
    (EstimateSettings(sway_damping=False), 3),                       # NED kinematic: the covariance block
    (EstimateSettings(model="dynamic"), 5),                          # dynamic with current states
    (EstimateSettings(gps_only=True), 4),                            # GNSS only: the course held, one window
    (EstimateSettings(smoother=False), 2),                           # the forward rows, at once
])
def test_windows_give_the_whole_estimate(run, settings, cut):
    whole = estimate(run, settings)
    thrust = run[THRUST_TOPIC]
    log = run.copy()
    del log.channels[THRUST_TOPIC]   # the thrust only through its windows
    est = W.WindowedEstimate(log, settings, None, lambda: _cut(thrust, cut), _Rows())
    wins = list(est.frames(997))   # windows that do not line up with the smoother's blocks
    assert len(wins) == (1 if settings.gps_only else -(-whole.report.steps // 997))
    for topic, frame in ((STATE_TOPIC, whole.state), (INNOVATION_TOPIC, whole.innovations)):
        joined = pd.concat([w[topic] for w in wins])
        pd.testing.assert_frame_equal(joined, frame, check_exact=True)
    res = est.result({STATE_TOPIC: whole.state})
    _equal_reports(res.report, whole.report)
    assert res.state is whole.state and res.settings == whole.settings


def test_a_compass_the_track_contradicts_is_dropped_the_same_way(run):
    log = run.copy()
    comp = log["/compass/heading"]
    wild = np.random.default_rng(4).uniform(-np.pi, np.pi, len(comp))
    log.set("/compass/heading", comp.assign(heading_rad=wild))
    whole = estimate(log, EstimateSettings())
    assert "disagrees" in whole.report.mode_reason   # run twice: with the compass, then GNSS only
    est = W.WindowedEstimate(log, EstimateSettings(), None, None, _Rows())
    wins = list(est.frames(4096))
    pd.testing.assert_frame_equal(pd.concat([w[STATE_TOPIC] for w in wins]), whole.state, check_exact=True)
    _equal_reports(est.result({}).report, whole.report)


def test_held_thrust_is_the_same_for_any_cut(run):
    thrust = run[THRUST_TOPIC].copy()
    bad = np.arange(len(thrust)) % 50 == 0
    thrust.loc[bad, ["thrust_left_n", "left"]] = np.nan   # skipped records: the one before holds
    t = np.asarray(thrust.index, np.int64)
    steps = np.sort(np.r_[t[0] - 5_000_000_000, t[::7] + 3, t[-1] + 10**9])   # before the first, between, after
    v = default_vessel()
    whole, skipped = held_thrust(run, steps, lambda: [thrust], v)
    assert skipped == bad.sum()
    # each step: the forces of the last good record at or before it, 0 before the first
    good = thrust[~bad]
    tu, tr = v.thrusters.tau_from_forces(good["thrust_left_n"].to_numpy(), good["thrust_right_n"].to_numpy())
    for k in (0, 1, 2, 500, len(steps) - 2, len(steps) - 1):
        i = np.flatnonzero(np.asarray(good.index, np.int64) <= steps[k])
        assert tuple(whole[k]) == ((tu[i[-1]], tr[i[-1]]) if len(i) else (0.0, 0.0))
    for n in (2, 9, 40):
        held, sk = held_thrust(run, steps, lambda n=n: _cut(thrust, n), v)
        assert sk == skipped and np.array_equal(held, whole)


def test_held_thrust_in_command_units_for_every_window_when_one_cannot_be_converted(run):
    thrust = run[THRUST_TOPIC].copy()
    thrust["unit"] = np.where(np.arange(len(thrust)) > len(thrust) // 2, "pwm_us", "newton")
    thrust.loc[thrust.index[len(thrust) // 2 + 1:], ["thrust_left_n", "thrust_right_n"]] = np.nan
    steps = np.asarray(thrust.index, np.int64)[::3] + 1
    v = default_vessel()   # (no thruster map: pwm_us cannot become newtons)
    with pytest.raises(InputError):
        held_thrust(run, steps, lambda: [thrust], v)
    whole, _ = held_thrust(run, steps, lambda: [thrust], v, vessel_free=True)
    assert (whole[:, 0] == 0).all()   # command units everywhere: no force, a moment in command units
    held, _ = held_thrust(run, steps, lambda: _cut(thrust, 6), v, vessel_free=True)
    assert np.array_equal(held, whole)


def test_the_problem_from_thrust_windows_is_the_problem(run):
    s = EstimateSettings(model="dynamic")
    a = build_problem(run, s, default_vessel())
    b = build_problem(run, s, default_vessel(), lambda: _cut(run[THRUST_TOPIC], 11))
    for k, x in vars(a).items():
        if isinstance(x, np.ndarray):
            assert np.array_equal(x, getattr(b, k)), k


def test_sideslip_over_windows_is_the_whole_ones():
    rng = np.random.default_rng(2)
    t = np.cumsum(rng.choice([10_000_000, 20_000_000, 30_000_000], 5001))   # steps of three sizes: the median
    state = pd.DataFrame({"u_mps": rng.normal(1, 1, len(t)), "v_mps": rng.normal(0, 0.3, len(t))},
                         index=pd.Index(t, name="t_ns"))
    for n in (1, 2, 13):
        slip = Sideslip()
        for part in _cut(state, n) if n > 1 else [state]:
            slip.add(part)
        assert slip.figures() == sideslip_figures(state)
    for even in (state.iloc[:1000], state.iloc[:1001]):   # an even and an odd number of steps
        halves = Sideslip()
        halves.add(even.iloc[:400])
        halves.add(even.iloc[400:])
        assert halves.figures() == sideslip_figures(even)
    assert sideslip_figures(state.assign(u_mps=0.0, v_mps=0.0)) is None


def test_estimate_file_writes_what_the_whole_log_gives(tmp_path, run, monkeypatch):
    path = tmp_path / "raw.mcap"
    write_log(run, path, chunk_size=1 << 14)   # small chunks: many thrust windows
    monkeypatch.setattr(W, "WINDOW_STEPS", 3000)   # many output windows
    seen = []
    real = mcap_windows.iter_windows

    def spy(*a, **k):
        for w in real(*a, **k):
            seen.append(w)
            yield w

    monkeypatch.setattr(mcap_windows, "iter_windows", spy)
    res = ef.estimate_file(str(path), tmp_path / "e.mcap", EstimateSettings(model="dynamic"), None)
    assert res is not None and len(seen) > 10
    # the verb before: the log read with the input channels left in the file, estimated whole, written
    whole_log = read_log(path, topics=list(INPUT_TOPICS), defer=True)
    whole = estimate(whole_log, EstimateSettings(model="dynamic"))
    out = whole.to_log(whole_log)
    out.redefer(INPUT_TOPICS)
    write_log(out, tmp_path / "e_whole.mcap")
    assert (tmp_path / "e.mcap").read_bytes() == (tmp_path / "e_whole.mcap").read_bytes()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["e.mcap", "e_whole.mcap", "raw.mcap"]   # no scratch left
    _equal_reports(res.report, whole.report)
    pd.testing.assert_frame_equal(res.state, whole.state, check_exact=True)      # decoded from the file
    pd.testing.assert_frame_equal(res.innovations, whole.innovations, check_exact=True)
    pd.testing.assert_frame_equal(res.forward, whole.forward, check_exact=True)  # the file estimated again


def test_a_file_that_cannot_be_windowed_is_estimated_whole(tmp_path, excitation_file, monkeypatch):
    import usvlog

    damaged = tmp_path / "damaged.mcap"
    data = excitation_file.read_bytes()
    damaged.write_bytes(data[: len(data) * 2 // 3])   # truncated: no summary, chunks lost
    calls = []
    real = ef.estimate_file
    monkeypatch.setattr(ef, "estimate_file", lambda *a, **k: calls.append(real(*a, **k)) or calls[-1])
    said = []
    res = usvlog.estimate(str(damaged), tmp_path / "e.mcap", progress=said.append)
    assert calls == [None]   # not windowed: the whole log instead
    assert any("damaged" in s for s in said) and sum(s.startswith("estimating") for s in said) == 1
    back = read_log(tmp_path / "e.mcap")
    ref = estimate(read_log(damaged), EstimateSettings())
    pd.testing.assert_frame_equal(back[STATE_TOPIC], ref.state, check_exact=True)
    pd.testing.assert_frame_equal(res.state, ref.state, check_exact=True)


def test_thrust_out_of_order_falls_back_to_the_whole_log_and_its_error(tmp_path, run):
    log = run.copy()
    thrust = log[THRUST_TOPIC]
    t = np.asarray(thrust.index, np.int64).copy()
    t[5000], t[5001] = t[5001], t[5000]   # two records swapped: time goes backwards once
    log.set(THRUST_TOPIC, thrust.set_axis(pd.Index(t, name="t_ns"), axis=0))
    path = tmp_path / "raw.mcap"
    write_log(log, path)
    assert ef.estimate_file(str(path), tmp_path / "e.mcap", EstimateSettings(model="dynamic"), None) is None
    assert not any(p.name.startswith(".") for p in tmp_path.iterdir())
    import usvlog

    with pytest.raises(InputError, match="time goes backwards"):
        usvlog.estimate(str(path), tmp_path / "e.mcap", model="dynamic")
