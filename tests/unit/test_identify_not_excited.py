"""A channel the validation data barely move is "not excited there", against a calibrated noise.

The noise a channel's spread is judged against is the smoother's own one-sigma
(:func:`usvlog.identify.ahead.smoother_noise`); checked here against the real error of the
smoothed states (the simulation's truth). A validation run that does not turn leaves the yaw
rate's fit % to noise: it is shown as "not excited there" and not judged.
"""

from __future__ import annotations

import numpy as np
import pytest

from usvlog.identify.ahead import smoother_noise
from usvlog.identify.data import run_data
from usvlog.identify.identifier import Identifier
from usvlog.identify.smooth import kinematic_states
from usvlog.sim.simulate import SimSettings, simulate


def _truth_nu(log, run, t):
    st = log.get("/truth/state")
    ts = (np.asarray(st.index, dtype=np.int64) - run.t0_ns) / 1e9
    return np.stack([np.interp(t, ts, st[c].to_numpy(float)) for c in ("u_mps", "v_mps", "r_radps")], -1)


def test_the_smoothers_one_sigma_is_its_real_error():
    log = simulate("excitation", SimSettings(duration_s=400.0), seed=7)
    run = run_data(log)
    ks = kinematic_states(log, run, tune=True)
    err = ks.nu() - _truth_nu(log, run, ks.t)
    noise = smoother_noise(ks.sd)
    for ch in "ur":   # v: its error is the smoother's lag on sway, not noise
        ratio = np.std(err[:, "uvr".index(ch)]) / noise[ch]
        assert 0.7 < ratio < 1.5, (ch, ratio, noise)
    assert smoother_noise(None) == {"u": 0.05, "v": 0.05, "r": 0.01}   # no one-sigma: the defaults


@pytest.fixture(scope="module")
def fitted():
    return Identifier("output-error", holdout=0.0).fit([simulate("excitation", SimSettings(duration_s=300.0), seed=2)])


def test_a_validation_run_that_does_not_turn_leaves_r_not_judged(fitted):
    straight = simulate("straight", SimSettings(duration_s=200.0), seed=5)
    fitted.use_validation([fitted.validate(straight)])
    ex = fitted.excitation_
    assert ex["u"].excited and not ex["r"].excited, ex
    assert ex["r"].spread < np.sqrt(2) * ex["r"].noise
    assert any(r.startswith("the validation log(s) barely excite r (") and "Iz, d33 not validated there" in r
               for r in fitted.reasons_), fitted.reasons_
    assert not any("worse than a constant" in r for r in fitted.reasons_), fitted.reasons_
    assert fitted.verdict_ == "usable", fitted.reasons_   # u validates the model; r's figure is noise
    d = fitted.to_dict()
    assert d["excitation"]["r"]["excited"] is False and d["excitation"]["u"]["excited"] is True


def test_a_validation_run_that_turns_excites_r(fitted):
    turns = simulate("turns", SimSettings(duration_s=200.0), seed=6)
    fitted.use_validation([fitted.validate(turns)])
    assert fitted.excitation_["r"].excited and fitted.excitation_["u"].excited
    assert not any("barely excite" in r for r in fitted.reasons_), fitted.reasons_
