"""Candidates are not ranked by a held-out track that has no skill left.

Truth: usvlog's catamaran (vessels/catamaran.toml) with its sway inertia raised to 400 kg, 4.7 times
its surge inertia -- a Munk moment and a sway-yaw coupling the paper's model cannot hold -- run
through manoeuvres of the kind of the shared Fossen Otter runs (speed steps, a zig-zag, turning
circles both ways, a coast, pivot turns, a random segment) in a 0.25 m/s current toward 200 deg,
GNSS at 5 Hz and compass at 10 Hz, simulated. The last 40 % (pivots and the random segment) is held
out. There the paper model's free-run heading drifts and every candidate's track fit is below 0:
the track no longer says which model is better. The candidate returned is then the one whose surge
and yaw rate validate best, with the current it fitted (before, the least bad track picked a fit
whose u validated 20 points worse: 45.3 % against 65.9 %).
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

from usvlog.identify import Identifier
from usvlog.model.vessel import Vessel, VesselParams, vessel_from_toml

sys.path.insert(0, str(Path(__file__).parent))
from otter_like import otter_like_run  # noqa: E402

CATAMARAN = Path(__file__).resolve().parents[2] / "vessels" / "catamaran.toml"
CURRENT = 0.25 * np.array([math.cos(math.radians(200.0)), math.sin(math.radians(200.0))])
DURATION_S = 400.0


@pytest.fixture(scope="module")
def fit():
    cat = vessel_from_toml(CATAMARAN.read_text(), str(CATAMARAN))
    hull = vessel_from_toml(CATAMARAN.read_text().replace("m22 = 162.5", "m22 = 400.0"), str(CATAMARAN))
    assert hull.extended.m22 == 400.0
    log = otter_like_run(hull, duration_s=DURATION_S, seed=10, current_mps=0.25, current_dir_deg=200.0,
                         gps_rate_hz=5.0)
    guess = Vessel(name="guess", params=VesselParams(m=30.0, Iz=8.0, d11=4.0, d22=4.0, d33=4.0, xg=0.0),
                   thrusters=cat.thrusters)
    return Identifier(holdout=0.4).fit(log, guess)


def test_every_candidate_track_is_without_skill(fit):
    """The trait this file is about: no candidate's held-out track beats its mean."""
    ok = [c for c in fit.candidates_ if not c.failed]
    assert len(ok) >= 3
    assert all(c.fit_percent["track"] < 0 for c in ok), [(c.start.name, c.fit_percent) for c in ok]


def test_the_surge_and_yaw_evidence_decides(fit):
    ok = [c for c in fit.candidates_ if not c.failed]
    best_u = max(c.fit_percent["u"] for c in ok)
    got = fit.validation_fit_percent_()
    assert got["u"] >= best_u - 2.0, ([(c.start.name, c.fit_percent) for c in ok], fit.chosen_.start.name)
    assert got["r"] >= max(c.fit_percent["r"] for c in ok) - 10.0
    # the paper model's m against the hull's surge inertia m11: returned as usable only within the
    # 30 % a standard error allows; refused, the reason is the smoother's bias on the fit returned
    # (its m 111 kg, +30 % on m11 85 kg; fitted again on its own smoothed motion +73 %)
    if fit.verdict_ != "unusable":
        assert abs(fit.params_.m / 85.28 - 1.0) <= 0.3, (fit.params_, fit.reasons_)
    else:
        assert any("biased by the smoother" in r for r in fit.reasons_), fit.reasons_


def test_the_current_returned_is_the_truth(fit):
    assert np.abs(np.asarray(fit.current_[0]) - CURRENT).max() < 0.05, (fit.current_, CURRENT)
