"""Parameter drift across the runs of a campaign (pure: arrays in, result objects out).

For one vessel and one model parameter the campaign gives per-run estimates ``x`` with
standard errors ``se`` at run start times ``t_ns``. Two questions are asked of them:

* **consistency**: are the estimates one value seen through their errors? The weighted mean
  ``xbar = sum(w x) / sum(w)``, ``w = 1 / se^2``, and ``chi2 = sum(w (x - xbar)^2)`` with
  ``n - 1`` degrees of freedom; the runs are consistent when the chi-square probability of
  a larger value is at least ``alpha`` (default 0.05).
* **change point**: did the value step once? Every split of the time-ordered runs into a
  before and an after segment (at least ``min_segment`` runs each) is fitted with two
  weighted means; the split that lowers the chi-square most is the candidate. Its drop
  ``D = chi2_const - chi2_split`` is compared with chi-square(1) after dividing by the
  split model's reduced chi-square when that exceeds 1 (so errors that the runs' own
  scatter shows to be too small do not fake a step), and the probability is multiplied by
  the number of splits tried (Bonferroni). A step is reported when that probability is
  below ``alpha_step`` (default 0.01); its size is ``(after - before) / before`` with a
  95 % interval from the two means' standard errors (scaled the same way).

No dask, no pandas, no I/O here: the campaign engine gathers the arrays.
"""

from __future__ import annotations

import datetime as _dt
import math
from dataclasses import dataclass

import numpy as np
from scipy import stats

Z95 = 1.959963984540054


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
    """The best single step in a time-ordered series of estimates.

    Attributes
    ----------
    index : int
        Number of runs before the step (the first run after it is ``index`` in time order).
    last_before_ns, first_after_ns : int
        Start times (ns since the Unix epoch) of the last run before and the first after.
    before, after : float
        Weighted means of the two segments (parameter unit).
    before_se, after_se : float
        Their standard errors, scaled by the split model's reduced chi-square when > 1.
    change_rel : float
        ``(after - before) / before`` (a fraction; 0.18 is +18 %).
    change_rel_ci95 : float
        Half width of its 95 % interval (fraction).
    statistic : float
        Chi-square drop of the split, divided by the scatter scale.
    p_value : float
        Bonferroni-corrected probability of a drop this large without a step.
    significant : bool
        ``p_value < alpha_step``.
    """

    index: int
    last_before_ns: int
    first_after_ns: int
    before: float
    after: float
    before_se: float
    after_se: float
    change_rel: float
    change_rel_ci95: float
    statistic: float
    p_value: float
    significant: bool

    def describe(self, name: str) -> str:
        """One line: ``d11 changed between 2026-05-03 and 2026-06-14 by +18 % +- 4 % (95 %)``."""
        return (f"{name} changed between {_day(self.last_before_ns)} and {_day(self.first_after_ns)} by "
                f"{100 * self.change_rel:+.0f} % \u00b1 {100 * self.change_rel_ci95:.0f} % (95 %), "
                f"from {self.before:.4g} to {self.after:.4g}")

    def to_dict(self) -> dict:
        """JSON-ready fields, times as ISO dates too."""
        d = {k: getattr(self, k) for k in ("index", "last_before_ns", "first_after_ns", "before", "after",
                                           "before_se", "after_se", "change_rel", "change_rel_ci95",
                                           "statistic", "p_value", "significant")}
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
        The best step (None with fewer than ``2 * min_segment`` runs).
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

    def describe(self) -> str:
        """One line for the report and the console."""
        c = self.consistency
        if self.drifted:
            assert self.change is not None
            return self.change.describe(self.name) + f" (chi2 {c.chi2:.1f} on {c.dof} dof, p {c.p_value:.2g})"
        word = "consistent" if c.consistent else "inconsistent (no single step explains it)"
        return (f"{self.name} {word} across {c.n} runs: {c.mean:.4g} \u00b1 {Z95 * c.mean_se:.2g} (95 %), "
                f"chi2 {c.chi2:.1f} on {c.dof} dof, p {c.p_value:.2g}")

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


def change_point(t_ns, x, se, *, min_segment: int = 2, alpha_step: float = 0.01) -> ChangePoint | None:
    """The single step that best explains the estimates (see the module docstring).

    Parameters
    ----------
    t_ns : array_like of int, shape (n,)
        Run start times, ns since the Unix epoch (any order; sorted here).
    x, se : array_like, shape (n,)
        Per-run estimates and standard errors.
    min_segment : int
        Fewest runs on either side of the step.
    alpha_step : float
        Level below which the (Bonferroni-corrected) step is significant.

    Returns
    -------
    ChangePoint or None
        None with fewer than ``2 * min_segment`` usable runs.
    """
    t, x, se = _clean(t_ns, x, se)
    n = len(x)
    if n < 2 * min_segment or min_segment < 1:
        return None
    _, _, chi_const = _wmean(x, se)
    best = None
    for k in range(min_segment, n - min_segment + 1):
        a = _wmean(x[:k], se[:k])
        b = _wmean(x[k:], se[k:])
        chi_split = a[2] + b[2]
        if best is None or chi_split < best[1]:
            best = (k, chi_split, a, b)
    assert best is not None
    k, chi_split, a, b = best
    dof_split = n - 2
    scale = max(1.0, chi_split / dof_split) if dof_split > 0 else 1.0
    stat = (chi_const - chi_split) / scale
    tries = n - 2 * min_segment + 1
    p = min(1.0, tries * float(stats.chi2.sf(stat, 1)))
    s = math.sqrt(scale)
    before, after, bse, ase = a[0], b[0], a[1] * s, b[1] * s
    rel = (after - before) / before if before else math.nan
    # delta method for the ratio after / before
    rel_se = abs(after / before) * math.hypot(ase / after, bse / before) if before and after else math.nan
    return ChangePoint(index=k, last_before_ns=int(t[k - 1]), first_after_ns=int(t[k]), before=before, after=after,
                       before_se=bse, after_se=ase, change_rel=rel, change_rel_ci95=Z95 * rel_se, statistic=stat,
                       p_value=p, significant=p < alpha_step)


def parameter_drift(name: str, t_ns, x, se, *, alpha: float = 0.05, alpha_step: float = 0.01,
                    min_segment: int = 2) -> ParameterDrift:
    """Consistency test and change point of one parameter over one vessel's runs.

    Parameters
    ----------
    name : str
        Parameter name (for the descriptions).
    t_ns : array_like of int, shape (n,)
        Run start times, ns since the Unix epoch.
    x, se : array_like, shape (n,)
        Per-run estimates and standard errors (non-finite rows are left out).
    alpha, alpha_step, min_segment
        See :func:`consistency` and :func:`change_point`.

    Returns
    -------
    ParameterDrift
    """
    t, xs, ses = _clean(t_ns, x, se)
    return ParameterDrift(name=name, t_ns=t, value=xs, se=ses, ci95_low=xs - Z95 * ses, ci95_high=xs + Z95 * ses,
                          consistency=consistency(xs, ses, alpha=alpha),
                          change=change_point(t, xs, ses, min_segment=min_segment, alpha_step=alpha_step))


__all__ = ["ChangePoint", "Consistency", "ParameterDrift", "Z95", "change_point", "consistency", "parameter_drift"]
