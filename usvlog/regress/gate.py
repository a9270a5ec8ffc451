"""Accepted metric baselines and the regression gate: pure comparison, no I/O.

A baseline entry holds the accepted value of one metric and how far it may move
before the change counts: ``abs + rel * |baseline|``, in the direction that is
worse (``larger``, ``smaller`` or ``either``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from xml.sax.saxutils import escape, quoteattr

from ..errors import ConfigError

WORSE = ("larger", "smaller", "either")


@dataclass(frozen=True, kw_only=True)
class BaselineEntry:
    """Accepted value of one metric and how far it may move before it counts as a change.

    Parameters
    ----------
    value : float
        Accepted value, in the metric's own unit.
    worse : {"larger", "smaller", "either"}, default "larger"
        Direction that is a regression.
    abs_tol : float, default 0.0
        Absolute allowance, in the metric's unit (>= 0).
    rel_tol : float, default 0.0
        Allowance relative to ``|value|`` (>= 0).
    description : str, default ""

    Raises
    ------
    usvlog.errors.ConfigError
        On an unknown direction or a negative tolerance.
    """

    value: float
    worse: str = "larger"
    abs_tol: float = 0.0
    rel_tol: float = 0.0
    description: str = ""

    def __post_init__(self):
        if self.worse not in WORSE:
            raise ConfigError(f"baseline 'worse' must be one of {', '.join(WORSE)}, not {self.worse!r}")
        if self.abs_tol < 0 or self.rel_tol < 0:
            raise ConfigError("baseline tolerances must be >= 0")

    @property
    def allowance(self) -> float:
        """How far the metric may move: abs_tol + rel_tol |value|."""
        return self.abs_tol + self.rel_tol * abs(self.value)

    def to_dict(self) -> dict:
        """Fields as a dict (the baseline file's table; ``description`` only if set)."""
        d = {"value": self.value, "worse": self.worse, "abs_tol": self.abs_tol, "rel_tol": self.rel_tol}
        if self.description:
            d["description"] = self.description
        return d

    @classmethod
    def from_dict(cls, name: str, d: dict) -> BaselineEntry:
        """Entry from a baseline file's table for metric ``name`` (named in errors).

        Raises
        ------
        usvlog.errors.ConfigError
            If ``value`` is missing or a field is invalid.
        """
        try:
            return cls(value=float(d["value"]), worse=str(d.get("worse", "larger")),
                       abs_tol=float(d.get("abs_tol", 0.0)), rel_tol=float(d.get("rel_tol", 0.0)),
                       description=str(d.get("description", "")))
        except (KeyError, TypeError, ValueError) as err:
            raise ConfigError(f"baseline metric {name}: {err}") from err


@dataclass(frozen=True)
class Check:
    """Outcome of comparing one metric of one scenario with its baseline.

    ``verdict`` is ``ok``, ``improved``, ``REGRESSED``, ``new`` (no baseline yet) or
    ``missing`` (not produced); ``baseline`` and ``now`` are in the metric's unit;
    ``message`` explains a regression.
    """

    scenario: str
    metric: str
    baseline: float | None
    now: float | None
    verdict: str            # "ok" | "improved" | "REGRESSED" | "new" | "missing"
    message: str = ""

    @property
    def change(self) -> float | None:
        """now - baseline, or None if either is missing."""
        if self.baseline is None or self.now is None:
            return None
        return self.now - self.baseline

    @property
    def failed(self) -> bool:
        """True for ``REGRESSED`` and ``missing`` (the gate fails)."""
        return self.verdict in ("REGRESSED", "missing")

    def to_dict(self) -> dict:
        """JSON-ready dict of the fields plus ``change``."""
        return {"scenario": self.scenario, "metric": self.metric, "baseline": self.baseline,
                "now": self.now, "change": self.change, "verdict": self.verdict, "message": self.message}


def compare(scenario: str, metrics: dict[str, float], baseline: dict[str, BaselineEntry]) -> list[Check]:
    """Compare measured metrics with their baselines; one Check per metric.

    Parameters
    ----------
    scenario : str
        Scenario name, copied into the checks.
    metrics : dict of str to float
        Measured values (None or NaN: not produced).
    baseline : dict of str to BaselineEntry

    Returns
    -------
    list of Check
        Sorted by metric name, over the union of measured and baseline metrics.
    """
    out = []
    for name in sorted(set(metrics) | set(baseline)):
        now = metrics.get(name)
        entry = baseline.get(name)
        if entry is None:
            out.append(Check(scenario, name, None, now, "new", "no baseline yet (run with --update)"))
            continue
        if now is None or (isinstance(now, float) and math.isnan(now)):
            out.append(Check(scenario, name, entry.value, None, "missing",
                             f"{name} was not produced (baseline {entry.value:.6g})"))
            continue
        d = now - entry.value
        allow = entry.allowance
        worse = {"larger": d > allow, "smaller": -d > allow, "either": abs(d) > allow}[entry.worse]
        better = {"larger": -d > allow, "smaller": d > allow, "either": False}[entry.worse]
        if worse:
            direction = {"larger": "rose", "smaller": "fell", "either": "moved"}[entry.worse]
            msg = (f"{name} {direction} from {entry.value:.6g} to {now:.6g} "
                   f"(allowed +-{allow:.3g}; {entry.worse} is worse)")
            out.append(Check(scenario, name, entry.value, now, "REGRESSED", msg))
        elif better:
            out.append(Check(scenario, name, entry.value, now, "improved",
                             "better than the baseline beyond tolerance (accept with --update)"))
        else:
            out.append(Check(scenario, name, entry.value, now, "ok"))
    return out


def updated_baseline(metrics: dict[str, float], old: dict[str, BaselineEntry],
                     default_worse: dict[str, str] | None = None,
                     default_tol: dict[str, tuple[float, float]] | None = None) -> dict[str, BaselineEntry]:
    """New baseline: accepted values replaced, tolerances and directions kept.

    Parameters
    ----------
    metrics : dict of str to float
        Measured values; None or NaN ones are dropped.
    old : dict of str to BaselineEntry
        The current baseline.
    default_worse : dict of str to str, optional
        Direction for metrics new to the baseline (default ``larger``).
    default_tol : dict of str to (float, float), optional
        (abs_tol, rel_tol) for new metrics (default (0, 0.05)).

    Returns
    -------
    dict of str to BaselineEntry
    """
    new = {}
    for name, v in sorted(metrics.items()):
        if v is None or (isinstance(v, float) and math.isnan(v)):
            continue
        e = old.get(name)
        if e is not None:
            new[name] = BaselineEntry(value=float(v), worse=e.worse, abs_tol=e.abs_tol, rel_tol=e.rel_tol,
                                      description=e.description)
        else:
            worse = "larger" if default_worse is None else default_worse.get(name, "larger")
            a, r = (0.0, 0.05) if default_tol is None else default_tol.get(name, (0.0, 0.05))
            new[name] = BaselineEntry(value=float(v), worse=worse, abs_tol=a, rel_tol=r)
    return new


def junit_xml(checks: list[Check], durations: dict[str, float] | None = None,
              errors: dict[str, str] | None = None) -> str:
    """JUnit XML: one testsuite per scenario, one testcase per metric.

    Parameters
    ----------
    checks : list of Check
    durations : dict of str to float, optional
        Run time of each scenario, s.
    errors : dict of str to str, optional
        Scenarios that failed to run, with the message (an ``error`` testcase each).

    Returns
    -------
    str
        The XML document.
    """
    durations = durations or {}
    errors = errors or {}
    scen = sorted({c.scenario for c in checks} | set(errors))
    parts = ['<?xml version="1.0" encoding="UTF-8"?>']
    n_fail = sum(c.failed for c in checks)
    parts.append(f'<testsuites name="usvlog regress" tests="{len(checks) + len(errors)}" '
                 f'failures="{n_fail}" errors="{len(errors)}">')
    for s in scen:
        cs = [c for c in checks if c.scenario == s]
        err = errors.get(s)
        parts.append(f'  <testsuite name={quoteattr(s)} tests="{len(cs) + (1 if err else 0)}" '
                     f'failures="{sum(c.failed for c in cs)}" errors="{1 if err else 0}" '
                     f'time="{durations.get(s, 0.0):.3f}">')
        if err:
            parts.append(f'    <testcase classname={quoteattr(s)} name="run">'
                         f'<error message={quoteattr(err)}>{escape(err)}</error></testcase>')
        for c in cs:
            parts.append(f'    <testcase classname={quoteattr(s)} name={quoteattr(c.metric)}>')
            if c.failed:
                parts.append(f'      <failure message={quoteattr(c.message)}>{escape(c.message)}</failure>')
            else:
                out = escape(f"{c.verdict}: now={c.now} baseline={c.baseline}")
                parts.append(f"      <system-out>{out}</system-out>")
            parts.append("    </testcase>")
        parts.append("  </testsuite>")
    parts.append("</testsuites>")
    return "\n".join(parts) + "\n"
