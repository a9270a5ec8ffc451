"""Parameter drift across the runs of a campaign (pure: arrays in, result objects out).

For one vessel and one model parameter the campaign gives per-run estimates ``x`` with
standard errors ``se`` at run start times ``t_ns``. Two questions are asked of them:

* **consistency**: are the estimates one value seen through their errors? The weighted mean
  ``xbar = sum(w x) / sum(w)``, ``w = 1 / se^2``, and ``chi2 = sum(w (x - xbar)^2)`` with
  ``n - 1`` degrees of freedom; the runs are consistent when the chi-square probability of
  a larger value is at least ``alpha`` (default 0.05).
* **change point**: did the value step between two run dates? The candidates are the gaps
  between consecutive distinct dates with at least ``min_runs`` runs on each side (runs of
  one date are never split). At each, the runs before and after are compared by
  :func:`usvlog.campaign.steps.step_test`: two weighted means in which no run counts as
  better than the scatter between the runs shows (so overconfident per-run errors do not
  make false alarms), a t statistic with ``n - 2`` degrees of freedom.
  Every parameter of a vessel is tested at every candidate: the p-values are corrected
  with Holm's method over all those tests (:func:`vessel_drift`). A change is reported
  when its corrected p-value is below ``alpha`` (default 0.05 per vessel); its size is
  ``(after - before) / before`` with a 95 % interval (delta method, t quantile).

No dask, no pandas, no I/O here: the campaign engine gathers the arrays.
"""

from __future__ import annotations

import datetime as _dt
import math
from dataclasses import dataclass

import numpy as np
from scipy import stats

from .steps import StepTest, date_splits, day_numbers, holm, step_test

Z95 = 1.959963984540054


def _p(p: float) -> str:
    return "< 0.0001" if p < 1e-4 else f"= {p:.2g}"


def _day(t_ns: int) -> str:
    return _dt.datetime.fromtimestamp(t_ns / 1e9, tz=_dt.UTC).date().isoformat()


@dataclass(frozen=True, kw_only=True)
class Consistency:
    """Chi-square test of per-run estimates against their weighted mean.

    Attributes
    ----------
    n : int
        Runs with a finite estimate and a finite positive standard error.
    mean : float
        Inverse-variance weighted mean, in the parameter's unit.
    mean_se : float
        Its standard error, same unit (not scaled by the scatter).
    chi2 : float
        ``sum((x - mean)^2 / se^2)``.
    dof : int
        ``n - 1``.
    p_value : float
        Probability of a chi-square at least this large if the runs share one value.
    consistent : bool
        ``p_value >= alpha`` (True with fewer than two runs: nothing to compare).
    """

    n: int
    mean: float
    mean_se: float
    chi2: float
    dof: int
    p_value: float
    consistent: bool

    def to_dict(self) -> dict:
        """JSON-ready fields."""
        return {k: getattr(self, k) for k in ("n", "mean", "mean_se", "chi2", "dof", "p_value", "consistent")}


@dataclass(frozen=True, kw_only=True)
class ChangePoint:
    """The most likely step of one parameter between two run dates.

    Attributes
    ----------
    index : int
        Number of runs before the step (the first run after it is ``index`` in time order).
    last_before_ns, first_after_ns : int
        Start times (ns since the Unix epoch) of the last run before and the first after
        (on two different dates).
    before, after : float
        Weighted means of the two segments (parameter unit).
    before_se, after_se : float
        Their standard errors, the between-run scatter included.
    scatter : float
        The runs' scatter about their segment means (standard deviation, parameter unit).
    change_rel : float
        ``(after - before) / before`` (a fraction; 0.18 is +18 %).
    change_rel_ci95 : float
        Half width of its 95 % interval (fraction).
    statistic : float
        The t statistic of the step.
    dof : int
        Its degrees of freedom (runs - 2).
    p_raw : float
        Two-sided p-value of this step alone.
    p_value : float
        Holm-corrected p-value over every parameter and candidate date tested.
    n_params, n_dates : int
        Parameters tested and candidate change dates (date gaps) tested, for the wording.
    significant : bool
        ``p_value < alpha``.
    """

    index: int
    last_before_ns: int
    first_after_ns: int
    before: float
    after: float
    before_se: float
    after_se: float
    scatter: float = 0.0
    change_rel: float
    change_rel_ci95: float
    statistic: float
    dof: int = 0
    p_raw: float = math.nan
    p_value: float
    n_params: int = 1
    n_dates: int = 1
    significant: bool

    def describe(self, name: str) -> str:
        """One line: ``d33 changed between 2026-06-14 and 2026-06-21 by -12 % ± 3 % (95 %; p = 0.001 after ...)``."""
        tested = (f"after testing {self.n_params} parameter{'s' if self.n_params != 1 else ''} "
                  f"at {self.n_dates} date{'s' if self.n_dates != 1 else ''}")
        return (f"{name} changed between {_day(self.last_before_ns)} and {_day(self.first_after_ns)} by "
                f"{100 * self.change_rel:+.0f} % \u00b1 {100 * self.change_rel_ci95:.0f} % "
                f"(95 %; p {_p(self.p_value)} {tested})")

    def to_dict(self) -> dict:
        """JSON-ready fields, times as ISO dates too."""
        d = {k: getattr(self, k) for k in ("index", "last_before_ns", "first_after_ns", "before", "after",
                                           "before_se", "after_se", "scatter", "change_rel", "change_rel_ci95",
                                           "statistic", "dof", "p_raw", "p_value", "n_params", "n_dates",
                                           "significant")}
        d["last_before"] = _day(self.last_before_ns)
        d["first_after"] = _day(self.first_after_ns)
        return d


@dataclass(frozen=True, kw_only=True)
class ParameterDrift:
    """One parameter of one vessel across its runs.

    Attributes
    ----------
    name : str
        Parameter (paper symbol).
    t_ns : numpy.ndarray of int64
        Run start times used (ns since the Unix epoch), in time order.
    value, se : numpy.ndarray
        Per-run estimates and standard errors, in that order (parameter unit).
    ci95_low, ci95_high : numpy.ndarray
        Per-run 95 % intervals, ``value -+ 1.96 se``.
    consistency : Consistency
        The chi-square test against the weighted mean.
    change : ChangePoint or None
        The most likely step (smallest p-value), significant or not; None without a
        candidate date (one date, or fewer than ``min_runs`` runs on a side).
    """

    name: str
    t_ns: np.ndarray
    value: np.ndarray
    se: np.ndarray
    ci95_low: np.ndarray
    ci95_high: np.ndarray
    consistency: Consistency
    change: ChangePoint | None

    @property
    def drifted(self) -> bool:
        """A significant step was found."""
        return self.change is not None and self.change.significant

    @property
    def dates(self) -> int:
        """Distinct UTC dates among the runs."""
        return int(len(np.unique(day_numbers(self.t_ns))))

    def describe(self) -> str:
        """One line for the report and the console."""
        if self.drifted:
            assert self.change is not None
            return self.change.describe(self.name)
        c = self.consistency
        nd = self.dates
        scatter = math.sqrt(c.chi2 / c.dof) if c.dof > 0 else 1.0
        line = (f"{self.name}: no change beyond its uncertainty across {nd} date{'s' if nd != 1 else ''} "
                f"({c.n} run{'s' if c.n != 1 else ''})")
        if c.n:
            line += f", {c.mean:.4g} \u00b1 {Z95 * c.mean_se * max(1.0, scatter):.2g} (95 %)"
        if not c.consistent:
            line += f"; the runs scatter {scatter:.1f} times their stated errors"
        return line

    def to_dict(self) -> dict:
        """JSON-ready summary (without the per-run arrays)."""
        return {"name": self.name, "runs": int(len(self.value)), "consistency": self.consistency.to_dict(),
                "change": self.change.to_dict() if self.change else None, "drifted": self.drifted,
                "summary": self.describe()}


def _clean(t_ns, x, se):
    t = np.asarray(t_ns, dtype=np.int64)
    x = np.asarray(x, float)
    se = np.asarray(se, float)
    if not (t.shape == x.shape == se.shape) or t.ndim != 1:
        raise ValueError(f"t_ns, x, se must be 1-D of one length (got {t.shape}, {x.shape}, {se.shape})")
    ok = np.isfinite(x) & np.isfinite(se) & (se > 0)
    order = np.argsort(t[ok], kind="stable")
    return t[ok][order], x[ok][order], se[ok][order]


def _wmean(x, se):
    w = 1.0 / se ** 2
    m = float(np.sum(w * x) / np.sum(w))
    return m, float(1.0 / math.sqrt(np.sum(w))), float(np.sum(w * (x - m) ** 2))


def consistency(x, se, *, alpha: float = 0.05) -> Consistency:
    """Chi-square test of estimates ``x`` (standard errors ``se``) against their weighted mean.

    Parameters
    ----------
    x, se : array_like, shape (n,)
        Per-run estimates and standard errors (same unit); non-finite or non-positive
        ``se`` rows are left out.
    alpha : float
        Level of the test.

    Returns
    -------
    Consistency
    """
    x = np.asarray(x, float)
    se = np.asarray(se, float)
    ok = np.isfinite(x) & np.isfinite(se) & (se > 0)
    x, se = x[ok], se[ok]
    n = int(len(x))
    if n == 0:
        return Consistency(n=0, mean=math.nan, mean_se=math.nan, chi2=0.0, dof=0, p_value=1.0, consistent=True)
    m, mse, chi2 = _wmean(x, se)
    dof = n - 1
    p = float(stats.chi2.sf(chi2, dof)) if dof > 0 else 1.0
    return Consistency(n=n, mean=m, mean_se=mse, chi2=chi2, dof=dof, p_value=p, consistent=p >= alpha)


def _candidates(t, x, se, min_runs: int) -> list[StepTest]:
    if len(x) < 3:
        return []
    return [step_test(x, se, k) for k in date_splits(t, min_runs)]


def _change(t, st: StepTest, p_value: float, *, n_params: int, n_dates: int, alpha: float) -> ChangePoint:
    before, after = st.before, st.after
    rel = (after - before) / before if before else math.nan
    # delta method for after / before - 1
    rel_se = abs(after / before) * math.hypot(st.after_se / after, st.before_se / before) if before and after \
        else math.nan
    q = float(stats.t.ppf(0.975, st.dof))
    return ChangePoint(index=st.k, last_before_ns=int(t[st.k - 1]), first_after_ns=int(t[st.k]), before=before,
                       after=after, before_se=st.before_se, after_se=st.after_se, scatter=st.scatter, change_rel=rel,
                       change_rel_ci95=q * rel_se, statistic=st.t, dof=st.dof, p_raw=st.p, p_value=p_value,
                       n_params=n_params, n_dates=n_dates, significant=p_value < alpha)


def change_point(t_ns, x, se, *, min_runs: int = 2, alpha: float = 0.05) -> ChangePoint | None:
    """The most likely step of one parameter tested alone (corrected over its candidate dates only).

    Parameters
    ----------
    t_ns : array_like of int, shape (n,)
        Run start times, ns since the Unix epoch (any order; sorted here).
    x, se : array_like, shape (n,)
        Per-run estimates and standard errors (non-finite rows are left out).
    min_runs : int
        Fewest runs on either side of a step.
    alpha : float
        Level below which the corrected p-value is significant.

    Returns
    -------
    ChangePoint or None
        None without a candidate date. For a vessel's parameters together use
        :func:`vessel_drift` (the correction then covers every parameter).
    """
    t, x, se = _clean(t_ns, x, se)
    tests = _candidates(t, x, se, min_runs)
    if not tests:
        return None
    adj = holm([s.p for s in tests])
    i = int(np.argmin([s.p for s in tests]))
    return _change(t, tests[i], float(adj[i]), n_params=1, n_dates=len(tests), alpha=alpha)


def vessel_drift(t_ns, params: dict, *, alpha: float = 0.05, alpha_consistency: float = 0.05,
                 min_runs: int = 2) -> dict[str, ParameterDrift]:
    """Drift of every parameter of one vessel, corrected for testing them all at every date.

    Parameters
    ----------
    t_ns : array_like of int, shape (n,)
        Run start times, ns since the Unix epoch.
    params : dict of str to (array_like, array_like)
        ``{name: (x, se)}``, each of shape (n,): per-run estimates and standard errors
        (non-finite or non-positive ``se`` rows are left out for that parameter).
    alpha : float
        Family-wise level over all parameters and candidate dates (Holm).
    alpha_consistency : float
        Level of each parameter's chi-square consistency test.
    min_runs : int
        Fewest runs on either side of a step.

    Returns
    -------
    dict of str to ParameterDrift
        In the order of ``params``.
    """
    cleaned = {p: _clean(t_ns, x, se) for p, (x, se) in params.items()}
    tests = {p: _candidates(t, x, se, min_runs) for p, (t, x, se) in cleaned.items()}
    flat = [(p, i) for p, ts in tests.items() for i in range(len(ts))]
    adj = dict(zip(flat, holm([tests[p][i].p for p, i in flat])))
    n_params = sum(1 for ts in tests.values() if ts)
    gaps = {int(day_numbers(cleaned[p][0][s.k])) for p, ts in tests.items() for s in ts}
    out = {}
    for p, (t, x, se) in cleaned.items():
        change = None
        if tests[p]:
            i = int(np.argmin([s.p for s in tests[p]]))
            change = _change(t, tests[p][i], float(adj[(p, i)]), n_params=n_params, n_dates=len(gaps), alpha=alpha)
        out[p] = ParameterDrift(name=p, t_ns=t, value=x, se=se, ci95_low=x - Z95 * se, ci95_high=x + Z95 * se,
                                consistency=consistency(x, se, alpha=alpha_consistency), change=change)
    return out


def parameter_drift(name: str, t_ns, x, se, *, alpha: float = 0.05, alpha_consistency: float = 0.05,
                    min_runs: int = 2) -> ParameterDrift:
    """Consistency test and change point of one parameter tested alone (:func:`vessel_drift` of one).

    Parameters
    ----------
    name : str
        Parameter name (for the descriptions).
    t_ns : array_like of int, shape (n,)
        Run start times, ns since the Unix epoch.
    x, se : array_like, shape (n,)
        Per-run estimates and standard errors (non-finite rows are left out).
    alpha, alpha_consistency, min_runs
        See :func:`vessel_drift`.

    Returns
    -------
    ParameterDrift
    """
    return vessel_drift(t_ns, {name: (x, se)}, alpha=alpha, alpha_consistency=alpha_consistency,
                        min_runs=min_runs)[name]


__all__ = ["ChangePoint", "Consistency", "ParameterDrift", "Z95", "change_point", "consistency", "parameter_drift",
           "vessel_drift"]
