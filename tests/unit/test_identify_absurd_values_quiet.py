"""The boat checks of absurd parameter values answer without numpy's overflow warnings.

A fit from a poor start tries values whose products overflow (m22 m66 of 1e200 kg each, as on a
VantTec bag's extended fit); the checks must still say "not a boat" or give a bound, and must not
print RuntimeWarnings through the Python API.
"""

from __future__ import annotations

import math
import warnings

import numpy as np

from usvlog.identify.extended_oe import ext_physical_problem
from usvlog.identify.velocity import EXTENDED, MAX_COUPLING

HUGE = 1e200
# m11, m22, m26, m66, d11, d22, d33, d11q, d22q, d33q (EXTENDED_PARAM_NAMES order)
BOAT = np.array([85.0, 160.0, 12.0, 43.0, 77.0, 160.0, 43.0, 0.0, 200.0, 430.0])


def test_overflowing_products_are_judged_without_a_warning():
    huge = BOAT.copy()
    huge[[1, 3]] = HUGE
    coupled = BOAT.copy()
    coupled[2] = HUGE      # m26^2 overflows: a coupling no boat has
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert EXTENDED.signed_max(huge) == math.inf                     # sqrt of an overflowed product
        assert EXTENDED.signed_max(BOAT) == math.sqrt(MAX_COUPLING * 160.0 * 43.0)   # the bound by hand
        assert ext_physical_problem(coupled) == "m22 m66 - m26^2 not positive"
        assert EXTENDED.not_a_boat(coupled)
        assert not EXTENDED.not_a_boat(BOAT) and ext_physical_problem(BOAT) == ""
