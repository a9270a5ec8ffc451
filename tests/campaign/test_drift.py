"""Drift statistics against their definitions and against simulated series with known truth."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from usvlog.campaign.drift import Z95, change_point, consistency, parameter_drift

DAY = 86_400 * 10**9
T0 = 1_777_766_400 * 10**9   # 2026-05-03 00:00 UTC


def test_consistency_is_the_weighted_mean_and_its_chi_square():
    x = np.array([5.0, 5.2, 4.9, 5.1])
    se = np.array([0.1, 0.2, 0.1, 0.4])
    c = consistency(x, se)
    w = 1 / se**2
    m = (w * x).sum() / w.sum()
    chi2 = (w * (x - m) ** 2).sum()
    assert c.mean == pytest.approx(m) and c.mean_se == pytest.approx(w.sum() ** -0.5)
    assert c.chi2 == pytest.approx(chi2) and c.dof == 3
    assert c.p_value == pytest.approx(stats.chi2.sf(chi2, 3))


def test_rows_without_a_standard_error_are_left_out():
    c = consistency([5.0, 5.1, 99.0, 7.0], [0.1, 0.1, np.nan, 0.0])
    assert c.n == 2 and c.mean == pytest.approx(5.05)


def test_a_step_is_found_with_its_dates_and_size():
    rng = np.random.default_rng(1)
    t = T0 + np.arange(10) * 14 * DAY
    truth = np.where(np.arange(10) < 4, 5.0, 6.0)    # +20 % after the 4th run
    se = np.full(10, 0.05)
    x = truth + rng.normal(0, 0.05, 10)
    d = parameter_drift("d11", t[::-1], x[::-1], se)   # given out of order: sorted by time
    assert d.drifted
    cp = d.change
    assert cp.index == 4 and cp.last_before_ns == t[3] and cp.first_after_ns == t[4]
    assert abs(cp.change_rel - 0.20) < cp.change_rel_ci95
    assert cp.change_rel_ci95 < 0.05
    assert "d11 changed between 2026-06-14 and 2026-06-28 by +" in d.describe()
    assert np.allclose(d.ci95_high - d.value, Z95 * 0.05)


def test_false_alarms_and_interval_coverage_over_simulated_seasons():
    rng = np.random.default_rng(7)
    n, reps = 8, 600
    t = T0 + np.arange(n) * 7 * DAY
    se = rng.uniform(0.03, 0.1, n)
    alarms = 0
    for _ in range(reps):   # no step: the corrected test must alarm at most at its level
        x = 5.0 + rng.normal(0, se)
        alarms += change_point(t, x, se).significant
    assert alarms / reps <= 0.01 + 3 * np.sqrt(0.01 * 0.99 / reps)
    covered = 0
    for _ in range(reps):   # a step at a known place: its 95 % interval covers the true size
        x = np.where(np.arange(n) < 3, 5.0, 5.5) + rng.normal(0, se)
        cp = change_point(t, x, se, alpha_step=1.0)
        covered += cp.index == 3 and abs(cp.change_rel - 0.1) <= cp.change_rel_ci95
    assert covered / reps > 0.90


def test_too_few_runs_give_no_change_point():
    assert change_point([T0, T0 + DAY, T0 + 2 * DAY], [1.0, 2.0, 3.0], [0.1, 0.1, 0.1]) is None
    d = parameter_drift("Iz", [T0], [10.0], [1.0])
    assert not d.drifted and d.consistency.consistent and "consistent across 1 runs" in d.describe()
