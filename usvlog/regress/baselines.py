"""Read and write baseline files (TOML) of accepted regression metrics."""

from __future__ import annotations

import math
from pathlib import Path

from ..errors import ConfigError
from ..io.atomic import write_text_atomic
from ..io.config import read_toml
from .gate import BaselineEntry
from .stages import regress_scenario_from_dict


def read_baseline(path) -> dict[str, BaselineEntry]:
    """The accepted metrics of a baseline file.

    Parameters
    ----------
    path : path-like
        A TOML file with one ``[metrics."NAME"]`` table per metric (see
        :meth:`~usvlog.regress.gate.BaselineEntry.from_dict`).

    Returns
    -------
    dict
        Metric name -> :class:`~usvlog.regress.gate.BaselineEntry`; empty when the file
        does not exist (a scenario run for the first time has no baseline yet).

    Raises
    ------
    ConfigError
        The file is not valid TOML, ``[metrics]`` is not a table of tables, or an entry
        is invalid (the message names the file).
    StorageError
        The file cannot be read.
    """
    p = Path(path)
    if not p.exists():
        return {}
    doc = read_toml(p)
    metrics = doc.get("metrics", {})
    if not isinstance(metrics, dict):
        raise ConfigError(f"{p}: [metrics] must be a table of metric tables")
    try:
        return {k: BaselineEntry.from_dict(k, v) for k, v in metrics.items()}
    except ConfigError as err:
        raise ConfigError(f"{p}: {err}") from err


def _num(v: float) -> str:
    if math.isinf(v):
        return "inf" if v > 0 else "-inf"
    if math.isnan(v):
        return "nan"
    return repr(float(v))


def _q(s: str) -> str:
    return '"' + s.replace("\\", "\\\\").replace('"', '\\"') + '"'


def format_baseline(entries: dict[str, BaselineEntry], header: str = "") -> str:
    """The text of a baseline file: a ``[metrics."NAME"]`` TOML table per entry, in name order.

    Floats are written with ``repr`` (so they read back exactly), infinities and NaN as
    TOML's ``inf``/``-inf``/``nan``; ``description`` only when set.

    Parameters
    ----------
    entries : dict
        Metric name -> :class:`~usvlog.regress.gate.BaselineEntry`.
    header : str
        Text put first as ``#`` comment lines (one per line), then a blank line.

    Returns
    -------
    str
        TOML text, as :func:`read_baseline` reads it.
    """
    lines = [f"# {line}" for line in header.splitlines()] + ([""] if header else [])
    for name in sorted(entries):
        e = entries[name]
        lines.append(f"[metrics.{_q(name)}]")
        lines.append(f"value = {_num(e.value)}")
        lines.append(f"worse = {_q(e.worse)}")
        lines.append(f"abs_tol = {_num(e.abs_tol)}")
        lines.append(f"rel_tol = {_num(e.rel_tol)}")
        if e.description:
            lines.append(f"description = {_q(e.description)}")
        lines.append("")
    return "\n".join(lines)


def write_baseline(path, entries: dict[str, BaselineEntry], header: str = "") -> None:
    """Write a baseline file (:func:`format_baseline`) atomically, replacing any old one.

    Parameters
    ----------
    path : path-like
        The baseline file.
    entries : dict
        Metric name -> :class:`~usvlog.regress.gate.BaselineEntry`.
    header : str
        Comment lines put first.

    Raises
    ------
    StorageError
        The file cannot be written.
    """
    write_text_atomic(path, format_baseline(entries, header), force=True)


def is_regress_scenario(path) -> bool:
    """A TOML file with a [dataset] section is a regression scenario."""
    try:
        return "dataset" in read_toml(path)
    except ConfigError:
        return True  # let loading report the error


def find_regress_scenarios(paths) -> list[Path]:
    """Scenario files named, or every regression scenario in the directories named."""
    out: list[Path] = []
    for p in map(Path, paths):
        if p.is_dir():
            out += [f for f in sorted(p.glob("*.toml")) if is_regress_scenario(f)]
        elif p.exists():
            out.append(p)
        else:
            raise ConfigError(f"{p}: no such scenario file or directory")
    return out


def load_regress_scenario(path):
    """Read a regression scenario file.

    Parameters
    ----------
    path : path-like
        The scenario TOML file; the dataset and baseline paths in it are relative to its
        directory.

    Returns
    -------
    usvlog.regress.stages.RegressScenario

    Raises
    ------
    ConfigError
        Invalid TOML or an invalid scenario (see
        :func:`~usvlog.regress.stages.regress_scenario_from_dict`).
    StorageError
        The file is missing or unreadable.
    """
    p = Path(path).resolve()
    return regress_scenario_from_dict(read_toml(p), p)
