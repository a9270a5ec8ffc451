"""Step tests between run dates (pure: arrays in, numbers out; used by :mod:`.drift`).

A parameter "changed" between two run dates when the runs before and the runs after
differ by more than their uncertainty allows. The uncertainty of a run is its own
standard error ``se`` **plus** the scatter between runs that those errors do not explain:
identification errors from one run are often 2-3 times too small (coloured residuals,
an unmodelled gust), so trusting them alone makes false alarms.

For runs ``x`` (standard errors ``se``) split into a *before* segment A and an *after*
segment B (never inside one date), ``n`` runs in all:

* the scatter between runs is the pooled sample variance about each segment's plain mean,
  ``s2 = (sum_A (x - mean_A)^2 + sum_B (x - mean_B)^2) / (n - 2)``;
* a run's variance is the larger of its stated ``se^2`` and ``s2``: a run is never taken to
  be better than the runs' own scatter shows (the stated errors of the best-looking runs
  are the ones most often too small), while a run that says it is worse keeps its error;
* each segment's mean is the weighted mean with ``w = 1 / max(se^2, s2)``, ``W = sum w``;
* ``t = (mean_B - mean_A) / sqrt(1/W_A + 1/W_B)``, read with Student's t distribution of
  ``n - 2`` degrees of freedom (two-sided).

When every stated error is below the scatter this is exactly Student's two-sample t-test on
the run values (``scipy.stats.ttest_ind``); when the stated errors explain the scatter it is
the difference of the inverse-variance weighted means over its standard error (read with the
t distribution's wider tails). Weighting by ``1 / (se^2 + tau2)`` with a Paule-Mandel
``tau2`` instead gave 8-10 % false alarms per vessel (instead of 2-3 %) when some runs'
errors were 2-4 times too small and others not (``benchmarks/bench_drift.py``): the
overconfident runs kept too much weight.

The candidate change points are the gaps between consecutive distinct UTC dates that leave
at least ``min_runs`` runs on each side. Every parameter is tested at every candidate, so
the p-values are corrected with Holm's step-down method over all of them (valid whatever
the dependence between the tests; :func:`holm`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import stats

DAY_NS = 86_400 * 10**9


@dataclass(frozen=True)
class StepTest:
    """One split of a time-ordered series: segment means, their errors, t and p.

    Attributes
    ----------
    k : int
        Runs before the split.
    before, after : float
        Weighted means of the two segments (parameter unit).
    before_se, after_se : float
        Their standard errors ``1 / sqrt(W)`` (the scatter included).
    scatter : float
        ``sqrt(s2)``: the runs' scatter about their segment means (standard deviation, parameter unit).
    t : float
        ``(after - before) / sqrt(before_se^2 + after_se^2)``.
    dof : int
        ``n - 2``.
    p : float
        Two-sided probability of a ``|t|`` this large without a step (uncorrected).
    """

    k: int
    before: float
    after: float
    before_se: float
    after_se: float
    scatter: float
    t: float
    dof: int
    p: float


def day_numbers(t_ns) -> np.ndarray:
    """UTC day number (days since 1970-01-01) of each time in ns since the Unix epoch."""
    return np.floor_divide(np.asarray(t_ns, dtype=np.int64), DAY_NS)


def date_splits(t_ns, min_runs: int = 2) -> list[int]:
    """Candidate splits of time-ordered runs: after the last run of a date, never inside one.

    Parameters
    ----------
    t_ns : array_like of int, shape (n,)
        Run start times in time order (ns since the Unix epoch).
    min_runs : int
        Fewest runs on either side.

    Returns
    -------
    list of int
        Numbers of runs before each candidate split (empty with one date).
    """
    d = day_numbers(t_ns)
    n = len(d)
    ks = np.flatnonzero(np.diff(d) != 0) + 1
    return [int(k) for k in ks if k >= min_runs and n - k >= min_runs]


def between_run_variance(x, k: int) -> float:
    """Pooled sample variance of runs ``x`` about their segments' plain means (split after ``k`` runs).

    Parameters
    ----------
    x : numpy.ndarray, shape (n,)
        Time-ordered run values, ``n >= 3``.
    k : int
        Runs before the split (``1 <= k <= n - 1``).

    Returns
    -------
    float
        ``s2`` (parameter unit squared), ``n - 2`` degrees of freedom.
    """
    x = np.asarray(x, float)
    a, b = x[:k], x[k:]
    return float((np.sum((a - a.mean()) ** 2) + np.sum((b - b.mean()) ** 2)) / (len(x) - 2))


def step_test(x, se, k: int) -> StepTest:
    """The step test of runs ``x`` (errors ``se``) split after the first ``k`` (see the module docstring).

    Parameters
    ----------
    x, se : array_like, shape (n,)
        Time-ordered run values and standard errors (finite, ``se > 0``), ``n >= 3``.
    k : int
        Runs before the split.

    Returns
    -------
    StepTest
    """
    x = np.asarray(x, float)
    se = np.asarray(se, float)
    n = len(x)
    if n < 3 or not 1 <= k <= n - 1:
        raise ValueError(f"a step test needs n >= 3 runs and 1 <= k <= n - 1 (got n={n}, k={k})")
    s2 = between_run_variance(x, k)
    w = 1.0 / np.maximum(se ** 2, s2)
    wa, wb = float(w[:k].sum()), float(w[k:].sum())
    a = float(np.sum(w[:k] * x[:k]) / wa)
    b = float(np.sum(w[k:] * x[k:]) / wb)
    ase, bse = 1.0 / math.sqrt(wa), 1.0 / math.sqrt(wb)
    t = (b - a) / math.hypot(ase, bse)
    dof = n - 2
    return StepTest(k=int(k), before=a, after=b, before_se=ase, after_se=bse, scatter=math.sqrt(s2), t=t, dof=dof,
                    p=float(2.0 * stats.t.sf(abs(t), dof)))


def holm(p) -> np.ndarray:
    """Holm's step-down adjusted p-values (family-wise error control under any dependence).

    Parameters
    ----------
    p : array_like, shape (m,)
        Uncorrected p-values.

    Returns
    -------
    numpy.ndarray, shape (m,)
        ``max_{j <= i} min(1, (m - j + 1) p_(j))`` for the i-th smallest, in the input's order.
    """
    p = np.asarray(p, float)
    m = len(p)
    if m == 0:
        return p.copy()
    order = np.argsort(p, kind="stable")
    adj = np.minimum(1.0, np.maximum.accumulate((m - np.arange(m)) * p[order]))
    out = np.empty(m)
    out[order] = adj
    return out


__all__ = ["DAY_NS", "StepTest", "between_run_variance", "date_splits", "day_numbers", "holm", "step_test"]
