"""Pictures of runs: a Rerun recording (``usvlog view``) and an HTML report with the paper's
figures (``usvlog report``).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from ..errors import ConfigError, InputError
from ._common import PathLike, Progress, _is_path, _read, _say

if TYPE_CHECKING:  # annotations and docstring links only: importing these at run time pulls numpy and pandas
    import os  # noqa: F401  (named in the docstrings: the API reference links it)

    from ..log.fieldlog import FieldLog  # noqa: F401  (named in the docstrings: the API reference links it)


# -----------------------------------------------------------------------------
# view, report
# -----------------------------------------------------------------------------

def to_rrd(logs, out: PathLike | None = None, *, names: Sequence[str] | None = None, force: bool = False,
           progress: Progress = None) -> Path:
    """Write logs to a Rerun ``.rrd`` recording with its blueprint inside (``usvlog view``).

    Parameters
    ----------
    logs : FieldLog, path, or a list of them
        The runs; several are overlaid.
    out : str or os.PathLike, optional
        Output ``.rrd`` (default: the first log's file with the suffix ``.rrd``).
    names : sequence of str, optional
        Name of each log in the viewer (default: the file names).
    force : bool
        Replace an existing ``out``.
    progress : callable, optional
        Receives a line as each log is read and as writing starts.

    Returns
    -------
    pathlib.Path
        The recording written (open it with ``rerun FILE``).
    """
    from ..io.atomic import check_output  # heavy: numpy
    from ..view.source import VIEW_READ  # heavy: numpy (with the recording's imports below)

    items = list(logs) if isinstance(logs, (list, tuple)) else [logs]
    if not items:
        raise InputError("nothing to view: no logs given")
    if out is None:
        first = items[0]
        src = first if _is_path(first) else first.source
        if not src:
            raise ConfigError("out is needed for a log that was not loaded from a file")
        out = Path(src).with_suffix(".rrd")
    out = Path(out)
    check_output(out, force, parent=True)  # fail before the work, not after
    if names is not None and len(names) != len(items):
        raise InputError(f"{len(names)} names for {len(items)} logs (one name per log)")
    read = []
    for x in items:
        if _is_path(x):
            _say(progress, f"reading {x}")
        read.append(_read(x, progress, drawn=VIEW_READ))
    from ..view.data import refuse_failed_estimate, warnings  # heavy: numpy
    from ..view.rrd import to_rrd as write_rrd  # heavy: rerun is imported only when a recording is made

    for lg in read:
        refuse_failed_estimate(lg)
    for lg in read:
        for w in warnings(lg):
            if not w.startswith("input damaged"):   # _read said those already
                _say(progress, f"warning: {lg.source or 'log'}: {w}")
    _say(progress, f"writing {out}")
    return write_rrd(read, out, names=None if names is None else list(names), force=force)


def report(log, out: PathLike, baseline=None, *, axes: str = "paper", force: bool = False,
           progress: Progress = None) -> Path:
    """Write an HTML report with PNG figures in the style of the paper (``usvlog report``).

    Parameters
    ----------
    log : FieldLog or path
        The run, or its MCAP file.
    out : str or os.PathLike
        Output directory (``report.html`` and the figures; created when missing).
    baseline : FieldLog or path, optional
        A second run (e.g. the PI/PID baseline) compared in Fig. 2.
    axes : str
        ``"paper"`` (X = north to the right, Y = east up, as in the paper) or ``"map"``
        (north up).
    force : bool
        Replace existing files.
    progress : callable, optional
        Receives a line as writing starts.

    Returns
    -------
    pathlib.Path
        The page ``out/report.html``.
    """
    from ..view.report import check_report_outputs, write_report  # heavy: matplotlib, numpy
    from ..view.source import REPORT_READ  # heavy: numpy (with the report's imports above)

    check_report_outputs(out, force)  # fail before the work, not after
    log = _read(log, progress, drawn=REPORT_READ)
    base = _read(baseline, progress, drawn=REPORT_READ) if baseline is not None else None
    from ..view.data import refuse_failed_estimate, warnings  # heavy: numpy (with the report's imports above)

    for lg in (log, base):
        if lg is not None:
            refuse_failed_estimate(lg)
    for w in warnings(log):
        if not w.startswith("input damaged"):   # _read said those already
            _say(progress, f"warning: {w}")
    _say(progress, f"writing report to {out}")
    return write_report(log, out, baseline=base, force=force, axes=axes)
