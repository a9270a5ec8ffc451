"""The identifier's whiteness check of the yaw rate's 5 s-ahead residuals (a caveat, not a refusal).

Truth: a 600 s run of the paper's vessel from usvlog's simulator. Identified with the paper model
(the true structure), the held-out residuals of r are white; the same held-out data with the
identified d33 made 50 % too large are not, and the verdict then says so in one line. The JSON
carries the figures.
"""

from __future__ import annotations

import numpy as np
import pytest

from usvlog.identify import Identifier
from usvlog.sim.simulate import SimSettings, simulate


@pytest.fixture(scope="module")
def fitted():
    log = simulate("excitation", SimSettings(duration_s=600.0), seed=2)
    return Identifier(holdout=0.5).fit(log, log.vessel)


def test_true_structure_is_white_and_says_nothing(fitted):
    w = fitted.whiteness_["r"]
    assert w.white and len(w.lags) >= 10, (w.outside, w.allowed, len(w.lags))
    assert not any("correlated residuals" in r for r in fitted.reasons_)
    d = fitted.to_dict()["whiteness"]["r"]
    assert d["white"] and d["step_s"] == 5.0 and d["outside"] == w.outside


def test_wrong_yaw_damping_leaves_correlated_residuals(fitted):
    wrong = fitted.theta_.copy()
    wrong[4] *= 1.5
    fitted.theta_ = wrong
    try:
        w = fitted._whiteness(fitted._held)["r"]
        assert not w.white, (w.outside, w.allowed)
        fitted.whiteness_ = {"r": w}
        reasons, _ = fitted._verdict(fitted.vessel_in_, fitted.runs_, fitted._kin)
        line = [r for r in reasons if "correlated residuals" in r]
        assert len(line) == 1 and "yaw rate predicted 5 s ahead" in line[0], reasons
    finally:
        fitted.theta_ = np.asarray(fitted.params_.as_array(), float)
