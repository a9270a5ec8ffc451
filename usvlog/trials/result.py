"""Result objects of the manoeuvre finder: a metric with its one-sigma, a manoeuvre, a set of them.

Frozen dataclasses with ``to_dict`` (plain JSON values, finite numbers only) and
``to_dataframe`` (one row per metric). Times are seconds from the log's start.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import pandas as pd

KINDS = ("turning_circle", "zigzag", "speed_steps", "stop", "pivot")
"""The manoeuvre kinds, in the order a table lists them (see docs/manoeuvres.md)."""

TITLES = {"turning_circle": "turning circle", "zigzag": "zig-zag", "speed_steps": "speed steps",
          "stop": "stop / coast-down", "pivot": "pivot turn"}
"""Display name of each kind."""


def _num(x: float) -> float | None:
    return float(x) if x is not None and math.isfinite(float(x)) else None


@dataclass(frozen=True)
class Metric:
    """One measured quantity of a manoeuvre.

    Attributes
    ----------
    name : str
        Name with its unit (``tactical_diameter_m``, ``first_overshoot_deg``).
    value : float
        The value, in the unit its name ends with.
    std : float
        One sigma, same unit (from the estimate's covariance and the spread within the
        manoeuvre; 0 for a value measured on a noise-free truth trajectory).
    """

    name: str
    value: float
    std: float = 0.0

    def to_dict(self) -> dict:
        """``{"value": ..., "std": ...}`` (None for a non-finite std)."""
        return {"value": _num(self.value), "std": _num(self.std)}


@dataclass(frozen=True)
class Manoeuvre:
    """A standard manoeuvre found in a run.

    Attributes
    ----------
    kind : str
        One of :data:`KINDS`.
    start_s, end_s : float
        Execute (the moment the differential, or the new command, is applied) and end of
        the manoeuvre, s from the log's start.
    direction : str
        ``starboard`` or ``port`` (first turn of a zig-zag), ``""`` when it has none.
    metrics : tuple of Metric
        Only the metrics that could be measured (all finite).
    steps : tuple of dict
        Speed steps only: one row per step (``start_s``, ``thrust``, ``speed_mps``,
        ``speed_mps_std``, ``time_constant_s``, ``time_constant_s_std``): the speed-thrust curve.
    thrust_unit : str
        Unit of the thrust values (``N`` for forces, else the command's own unit).
    """

    kind: str
    start_s: float
    end_s: float
    direction: str = ""
    metrics: tuple[Metric, ...] = ()
    steps: tuple[dict, ...] = field(default=())
    thrust_unit: str = "N"

    @property
    def title(self) -> str:
        """Display name of the kind (``turning circle``)."""
        return TITLES.get(self.kind, self.kind)

    def metric(self, name: str) -> Metric | None:
        """The metric called ``name``, or None when it was not measured."""
        for m in self.metrics:
            if m.name == name:
                return m
        return None

    def value(self, name: str) -> float:
        """The value of metric ``name``, NaN when it was not measured."""
        m = self.metric(name)
        return m.value if m is not None else math.nan

    def to_dict(self) -> dict:
        """Plain JSON values: kind, start_s, end_s, direction, metrics {name: {value, std}}
        and, for speed steps, the steps."""
        out = {"kind": self.kind, "start_s": round(float(self.start_s), 3), "end_s": round(float(self.end_s), 3),
               "direction": self.direction, "metrics": {m.name: m.to_dict() for m in self.metrics}}
        if self.steps:
            out["thrust_unit"] = self.thrust_unit
            out["steps"] = [{k: (_num(v) if isinstance(v, float) else v) for k, v in s.items()} for s in self.steps]
        return out


@dataclass(frozen=True)
class Manoeuvres:
    """The standard manoeuvres of one run (``usvlog manoeuvres``).

    Attributes
    ----------
    items : tuple of Manoeuvre
        In time order.
    t0_ns : int
        The log's start (ns since the Unix epoch): every time is seconds from it.
    source : str
        The state the metrics come from (``/estimate/state``, ``/truth/state``).
    """

    items: tuple[Manoeuvre, ...] = ()
    t0_ns: int = 0
    source: str = ""

    def __len__(self) -> int:
        return len(self.items)

    def __iter__(self):
        return iter(self.items)

    def of_kind(self, kind: str) -> list[Manoeuvre]:
        """The manoeuvres of one kind, in time order."""
        return [m for m in self.items if m.kind == kind]

    def to_dict(self) -> dict:
        """``{"t0_ns", "source", "count", "manoeuvres": [...]}`` (plain JSON values)."""
        return {"t0_ns": int(self.t0_ns), "source": self.source, "count": len(self.items),
                "manoeuvres": [m.to_dict() for m in self.items]}

    def to_dataframe(self) -> pd.DataFrame:
        """One row per metric: ``index`` (the manoeuvre's number), ``kind``, ``start_s``,
        ``end_s``, ``direction``, ``metric``, ``value``, ``std``."""
        rows = [{"index": i, "kind": m.kind, "start_s": m.start_s, "end_s": m.end_s, "direction": m.direction,
                 "metric": x.name, "value": x.value, "std": x.std}
                for i, m in enumerate(self.items) for x in m.metrics]
        cols = ["index", "kind", "start_s", "end_s", "direction", "metric", "value", "std"]
        return pd.DataFrame(rows, columns=cols)

    def format(self) -> str:
        """A plain-text table: one block per manoeuvre, one line per metric (value ± sigma)."""
        if not self.items:
            return "no standard manoeuvre found"
        lines = []
        for i, m in enumerate(self.items):
            head = f"{i + 1}. {m.title}{' to ' + m.direction if m.direction else ''}: " \
                   f"{m.start_s:.1f} s to {m.end_s:.1f} s"
            lines.append(head)
            for x in m.metrics:
                lines.append(f"     {x.name:<30} {x.value:>10.3f} ± {x.std:.3f}")
            for s in m.steps:
                lines.append(f"     step at {s['start_s']:.1f} s: thrust {s['thrust']:.2f} {m.thrust_unit} -> "
                             f"{s['speed_mps']:.3f} ± {s['speed_mps_std']:.3f} m/s, time constant "
                             f"{s.get('time_constant_s', math.nan):.2f} s")
        return "\n".join(lines)


__all__ = ["KINDS", "TITLES", "Manoeuvre", "Manoeuvres", "Metric"]
