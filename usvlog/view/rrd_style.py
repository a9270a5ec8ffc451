"""What every part of the Rerun recording shares: entity names, colours, and arrays as columns.

The colours of the roles (one log) and of the runs (several logs), the distinct colours of the
series in one plot, entity names made safe, and the arrays the writer
(:mod:`usvlog.view.rrd_writer`) sends: a float column of a frame, a scalar series as one
rerun column, a wrapped heading broken where it wraps.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import rerun as rr

from ..log.fieldlog import FieldLog

# colours of the roles (single log); several logs are coloured by run instead
ROLE = {
    "gps": (150, 150, 150), "gps_rejected": (230, 30, 30), "estimate": (31, 119, 180),
    "truth": (60, 60, 60), "whatif": (148, 103, 189), "path": (255, 170, 0), "boat": (255, 90, 0),
    "closest": (40, 170, 60), "carrot": (220, 0, 200), "heading": (31, 119, 180),
    "desired": (255, 127, 14), "cog": (40, 170, 60), "recorded": (120, 120, 120),
    "control": (214, 39, 40), "replay": (140, 86, 75), "compass": (150, 150, 150),
    "n": (31, 119, 180), "e": (214, 39, 40),
}
# distinct colours of the series in one plot (Tableau 10)
SERIES_PALETTE = [(31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189), (140, 86, 75),
                  (227, 119, 194), (127, 127, 127), (188, 189, 34), (23, 190, 207)]
RUN_COLORS = [(31, 119, 180), (214, 39, 40), (44, 160, 44), (148, 103, 189), (255, 127, 14), (23, 190, 207)]


def _mix(c, w, k):
    return tuple(int(round(a * (1 - k) + b * k)) for a, b in zip(c, w))


def _safe(name: str) -> str:
    s = re.sub(r"[^A-Za-z0-9_-]+", "_", name).strip("_")
    return s or "run"


def default_names(logs: list[FieldLog]) -> list[str]:
    """Entity names of the logs: each file's stem made safe (``run<i>`` without a source),
    with ``_2``, ``_3`` ... appended to repeats."""
    out: list[str] = []
    for i, log in enumerate(logs):
        base = _safe(Path(log.source).stem) if log.source else f"run{i}"
        name, k = base, 2
        while name in out:
            name, k = f"{base}_{k}", k + 1
        out.append(name)
    return out


def _col(frame, name) -> np.ndarray:
    return np.asarray(frame[name].to_numpy(), dtype=float)


def scalar_column(y: np.ndarray) -> rr.ComponentColumnList:
    """``rr.Scalars.columns(scalars=y)``, one scalar per row, without its per-row partition sizes
    (a float array of ones summed into the offsets: 9 of its 9.4 ms for 360k samples).

    Parameters
    ----------
    y : numpy.ndarray
        The samples (float64), one per row.

    Returns
    -------
    rerun.ComponentColumnList
        The column for ``send_columns``: the same arrow data as ``rr.Scalars.columns``.
    """
    batch = rr.Scalars.from_fields(scalars=y).as_component_batches()[0]
    return rr.ComponentColumnList([rr.ComponentColumn(batch.component_descriptor(), batch,
                                                      offsets=np.arange(len(y) + 1, dtype=np.int32))])


def break_wraps(t_ns: np.ndarray, deg: np.ndarray, limit: float = 180.0) -> tuple[np.ndarray, np.ndarray]:
    """(t_ns, deg) with a NaN sample put in half-way across every step larger than ``limit``
    degrees (a wrapped heading), so the line breaks there instead of crossing the plot."""
    jump = np.nonzero(np.abs(np.diff(deg)) > limit)[0]
    if not len(jump):
        return t_ns, deg
    t_mid = t_ns[jump] + (t_ns[jump + 1] - t_ns[jump]) // 2
    return np.insert(t_ns, jump + 1, t_mid), np.insert(deg, jump + 1, np.nan)
