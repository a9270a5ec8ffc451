"""The shared error measures: values by hand, and their stated handling of NaN and inf."""

from __future__ import annotations

import math

import numpy as np
import pytest

from usvlog.model.stats import fit_percent, rms


def test_rms_by_hand():
    assert rms([3.0, -4.0]) == pytest.approx(math.sqrt(12.5), abs=1e-15)
    assert rms([[1.0, 1.0], [1.0, -1.0]]) == 1.0          # every element of any shape
    assert math.isnan(rms([]))


def test_rms_nan_and_inf_propagate_unless_omitted():
    x = np.array([3.0, np.nan, -4.0, np.inf])
    assert math.isnan(rms(x[:3]))
    assert rms(x[[0, 2, 3]]) == math.inf
    assert rms(x, omit_nonfinite=True) == pytest.approx(math.sqrt(12.5), abs=1e-15)
    assert math.isnan(rms([np.nan, -np.inf], omit_nonfinite=True))


def test_fit_percent_by_hand():
    y = np.array([1.0, 2.0, 3.0, 4.0])
    assert fit_percent(y, y) == 100.0
    assert fit_percent(y, np.full(4, 2.5)) == pytest.approx(0.0, abs=1e-12)   # the mean predicts nothing
    # |y - yhat| = sqrt(4 * 0.25) = 1, |y - mean| = sqrt(5): 100 (1 - 1/sqrt 5)
    assert fit_percent(y, y + 0.5) == pytest.approx(100 * (1 - 1 / math.sqrt(5)), abs=1e-12)
    assert math.isnan(fit_percent(np.ones(3), np.zeros(3)))                   # constant y


def test_fit_percent_stacks_columns_and_drops_rows_with_nan():
    y = np.array([[0.0, 0.0], [2.0, 4.0], [np.nan, 1.0], [4.0, 8.0]])
    yhat = np.array([[1.0, 0.0], [2.0, 4.0], [5.0, 5.0], [4.0, 7.0]])
    # rows 0, 1, 3: means (2, 4); |y - mean| = sqrt(4 + 16 + 0 + 0 + 4 + 16) = sqrt 40; |y - yhat| = sqrt 2
    assert fit_percent(y, yhat) == pytest.approx(100 * (1 - math.sqrt(2) / math.sqrt(40)), abs=1e-12)
    assert math.isnan(fit_percent([np.nan, 1.0], [1.0, np.nan]))
