"""Equation error with its water current: a candidate that carries the current its own residuals give.

Plain equation error fits no current, so in a current it was judged (and, when chosen, returned)
with none. The candidate "equation error with its water current" finds each run's current from the
surge and yaw equations' residuals (``candidates._equation_error_current``). Truth: the paper's
vessel simulated through the manoeuvres of the shared Otter runs (turning circles both ways: the
current shows in the surge force against heading), 592 s, 5 Hz GNSS, a 0.25 m/s current toward 200
deg, and the same run in still water.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np

from usvlog.identify import Identifier
from usvlog.model.vessel import default_vessel

sys.path.insert(0, str(Path(__file__).parent))
from otter_like import otter_like_run  # noqa: E402

NAME = "equation error with its water current"


def _fit(current_mps):
    ves = default_vessel()
    log = otter_like_run(ves, duration_s=592.0, seed=3, current_mps=current_mps, gps_rate_hz=5.0)
    idf = Identifier(holdout=0.4).fit(log, ves)
    cands = {c.start.name: c for c in idf.candidates_}
    return idf, cands[NAME], cands["equation error"]


def test_equation_error_finds_the_current_and_is_judged_with_it():
    d = math.radians(200.0)
    truth = 0.25 * np.array([math.cos(d), math.sin(d)])
    idf, ec, ee = _fit(0.25)
    assert not ec.failed and not ee.failed
    assert np.all(ee.currents == 0.0)                              # plain equation error: none
    assert np.hypot(*(ec.currents[0] - truth)) < 0.05, (ec.currents, truth)
    # judged with it on the held-out part: the surge and the track follow the boat, as without it they do not
    assert ec.fit_percent["u"] > ee.fit_percent["u"] + 20.0, (ec.fit_percent, ee.fit_percent)
    assert ec.score > ee.score + 20.0
    # returned, it is the current the result reports (equation error's own: none)
    idf._set_result(ec, idf.runs_)
    assert np.allclose(idf.current_[0], ec.currents[0]) and np.allclose(idf.theta_, ec.theta)
    idf._set_result(ee, idf.runs_)
    assert idf.current_[0] == (0.0, 0.0)


def test_in_still_water_its_current_is_small_and_plain_equation_error_is_the_floor():
    idf, ec, ee = _fit(0.0)
    assert np.hypot(*ec.currents[0]) < 0.05, ec.currents
    # the floor of the pick is plain equation error: the returned fit never validates worse than it
    assert idf.chosen_.score >= ee.score
