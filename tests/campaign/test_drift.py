"""Drift statistics against their definitions and against simulated series with known truth."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from usvlog.campaign.drift import Z95, change_point, consistency, parameter_drift, vessel_drift
from usvlog.campaign.steps import date_splits, holm, step_test

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
    assert alarms / reps <= 0.05 + 3 * np.sqrt(0.05 * 0.95 / reps)
    covered = 0
    for _ in range(reps):   # a step at a known place: its 95 % interval covers the true size
        x = np.where(np.arange(n) < 3, 5.0, 5.5) + rng.normal(0, se)
        cp = change_point(t, x, se, alpha=1.0)
        covered += cp.index == 3 and abs(cp.change_rel - 0.1) <= cp.change_rel_ci95
    assert covered / reps > 0.90


def test_too_few_runs_give_no_change_point():
    assert change_point([T0, T0 + DAY, T0 + 2 * DAY], [1.0, 2.0, 3.0], [0.1, 0.1, 0.1]) is None
    d = parameter_drift("Iz", [T0], [10.0], [1.0])
    assert not d.drifted and d.consistency.consistent and d.change is None
    assert d.describe().startswith("Iz: no change beyond its uncertainty across 1 date (1 run)")


PARAMS = ("m", "Iz", "d11", "d22", "d33", "xg")
HOUR = 3600 * 10**9


def _flat(rng, n, value=5.0, rel=0.01):
    """Runs of an unchanged parameter: 1 % scatter, stated errors three times too small."""
    return value * (1 + rng.normal(0, rel, n)), np.full(n, value * rel / 3)


def test_runs_of_one_date_say_nothing_changed():
    """Four runs on one day: no candidate change (the test before split a date's runs 2 | 2)."""
    rng = np.random.default_rng(3)
    t = T0 + 29 * DAY + (9 + np.arange(4)) * HOUR            # 2026-06-01, 09:00 ... 12:00
    res = vessel_drift(t, {p: _flat(rng, 4) for p in PARAMS})
    assert date_splits(t) == []
    for d in res.values():
        assert d.change is None and not d.drifted
        assert d.describe().startswith(f"{d.name}: no change beyond its uncertainty across 1 date (4 runs)")
    import pandas as pd

    from usvlog.campaign.core import CampaignResult

    found = CampaignResult(out=None, table=pd.DataFrame(), drift={"alpha": res}).findings()
    assert found == ["alpha: no parameter changed beyond its uncertainty across 1 date (4 usable runs)"]


def test_runs_of_one_date_are_never_split():
    t = T0 + np.array([0, 0, 1, 1, 1, 2, 2, 3]) * 7 * DAY + np.array([9, 11, 9, 10, 12, 9, 10, 9]) * HOUR
    assert date_splits(t) == [2, 5]                  # not 3, 4 (inside a date) nor 7 (one run after)
    assert date_splits(t, min_runs=1) == [2, 5, 7]
    assert date_splits(t, min_runs=3) == [5]


def test_a_clear_step_between_two_dates_is_found_with_its_dates_and_sign():
    rng = np.random.default_rng(11)
    day = np.repeat([42, 49], 4)                     # 2026-06-14 and 2026-06-21, four runs each
    t = T0 + day * DAY + np.tile(9 + np.arange(4), 2) * HOUR
    vals = {p: _flat(rng, 8) for p in PARAMS}
    x, se = vals["d33"]
    vals["d33"] = (np.where(day == 49, 0.85, 1.0) * x, se)   # -15 % from the second date
    res = vessel_drift(t, vals)
    assert [p for p, d in res.items() if d.drifted] == ["d33"]
    cp = res["d33"].change
    assert (cp.to_dict()["last_before"], cp.to_dict()["first_after"]) == ("2026-06-14", "2026-06-21")
    assert cp.change_rel < 0 and abs(cp.change_rel + 0.15) < cp.change_rel_ci95 < 0.05
    assert cp.n_params == 6 and cp.n_dates == 1 and cp.p_value < 1e-4
    line = res["d33"].describe()
    assert line.startswith("d33 changed between 2026-06-14 and 2026-06-21 by -1")
    assert line.endswith("(95 %; p < 0.0001 after testing 6 parameters at 1 date)")


def test_a_single_outlier_run_does_not_make_a_change():
    """One run 30 % off with a small stated error (what a real identification sometimes gives):
    the scatter it brings to its side counts, so it is no step at any of the four dates."""
    rng = np.random.default_rng(5)
    t = T0 + np.repeat(np.arange(5), 2) * 7 * DAY + np.tile([9, 11], 5) * HOUR
    for where in (9, 4, 0):                          # in the last date, in the middle, in the first
        x, se = _flat(rng, 10)
        x[where] *= 1.30
        d = parameter_drift("d11", t, x, se)
        assert not d.drifted, d.describe()
        assert d.change is not None and d.change.p_value > 0.05


def test_the_correction_covers_every_parameter():
    """A step with p = 0.02 is a change when d11 alone is tested, not after testing six parameters."""
    t = T0 + np.repeat([0, 7], 3) * DAY + np.tile([9, 10, 11], 2) * HOUR
    a = np.array([5.0, 5.1, 4.9])
    x = np.concatenate([a, a + 0.3])
    se = np.full(6, 0.02)                            # below the scatter: Student's t-test
    p_raw = stats.ttest_ind(x[3:], x[:3]).pvalue
    assert 0.01 < p_raw < 0.05 / 6 * 3
    alone = parameter_drift("d11", t, x, se)
    assert alone.drifted and alone.change.p_value == pytest.approx(p_raw)
    flat = np.concatenate([a, a])                    # the other five: no step at all (p = 1)
    res = vessel_drift(t, {p: ((x if p == "d11" else flat), se) for p in PARAMS})
    d = res["d11"]
    assert not d.drifted and d.change.p_raw == pytest.approx(p_raw)
    assert d.change.p_value == pytest.approx(6 * p_raw)          # Holm: the smallest of 6 times 6
    assert not any(r.drifted for r in res.values())


def test_holm_against_its_definition():
    p = np.array([0.04, 0.001, 0.03, 0.5, 0.012])
    # sorted: 0.001*5, 0.012*4, 0.03*3, 0.04*2, 0.5*1, each at least the one before it
    want = {1: 0.005, 4: 0.048, 2: 0.09, 0: 0.09, 3: 0.5}
    assert holm(p) == pytest.approx([want[i] for i in range(5)])
    assert holm([]).size == 0 and holm([0.3, 0.9]) == pytest.approx([0.6, 0.9])


def test_the_statistic_by_hand():
    rng = np.random.default_rng(2)
    x = 5.0 + rng.normal(0, 0.1, 7)
    x[4:] += 0.2
    k, n = 4, 7
    # stated errors below the scatter: exactly Student's two-sample t-test
    st = step_test(x, np.full(n, 0.01), k)
    ref = stats.ttest_ind(x[k:], x[:k])
    assert st.t == pytest.approx(ref.statistic) and st.p == pytest.approx(ref.pvalue) and st.dof == n - 2
    assert st.before == pytest.approx(x[:k].mean()) and st.after == pytest.approx(x[k:].mean())
    s2 = (((x[:k] - x[:k].mean()) ** 2).sum() + ((x[k:] - x[k:].mean()) ** 2).sum()) / (n - 2)
    assert st.scatter == pytest.approx(np.sqrt(s2))
    # stated errors larger than the scatter: inverse-variance weighted means, t with n - 2 dof
    se = np.array([0.3, 0.5, 0.4, 0.6, 0.35, 0.45, 0.5])
    w = 1 / se**2
    a, b = (w[:k] * x[:k]).sum() / w[:k].sum(), (w[k:] * x[k:]).sum() / w[k:].sum()
    tt = (b - a) / np.sqrt(1 / w[:k].sum() + 1 / w[k:].sum())
    st = step_test(x, se, k)
    assert (st.before, st.after, st.t) == pytest.approx((a, b, tt))
    assert st.p == pytest.approx(2 * stats.t.sf(abs(tt), n - 2))
    # mixed: each run's variance is the larger of its own and the scatter
    se = np.array([0.01, 0.5, 0.01, 0.01, 0.3, 0.01, 0.01])
    w = 1 / np.maximum(se**2, s2)
    a, b = (w[:k] * x[:k]).sum() / w[:k].sum(), (w[k:] * x[k:]).sum() / w[k:].sum()
    st = step_test(x, se, k)
    assert (st.before, st.after) == pytest.approx((a, b))
    assert st.t == pytest.approx((b - a) / np.sqrt(1 / w[:k].sum() + 1 / w[k:].sum()))
    # the reported change and its 95 % interval (delta method, t quantile)
    t = T0 + np.array([0, 0, 1, 1, 2, 2, 2]) * 7 * DAY + np.arange(7) * HOUR
    cp = parameter_drift("Iz", t, x, np.full(n, 0.01), alpha=1.0).change
    best = min((step_test(x, np.full(n, 0.01), kk) for kk in (2, 4)), key=lambda s: s.p)
    rel_se = best.after / best.before * np.hypot(best.after_se / best.after, best.before_se / best.before)
    assert cp.index == best.k and cp.change_rel == pytest.approx(best.after / best.before - 1)
    assert cp.change_rel_ci95 == pytest.approx(stats.t.ppf(0.975, n - 2) * rel_se)
    assert cp.p_value == pytest.approx(min(1.0, 2 * best.p))    # Holm over the two candidate dates
