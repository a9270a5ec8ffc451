"""The report of a windowed log: its big channels decimated as they are read, never whole.

A report's figure is a few thousand pixels wide; an hour at 100 Hz is 360,000 samples a series.
:func:`decimated` reads the state channels of a :class:`usvlog.view.windowed.WindowedLog` a block
at a time and keeps, per :data:`BUCKETS` equal slices of each channel's time span (several per
pixel of any figure's width), the rows that draw every series the figures draw from it as the
whole series draws it (:func:`bucket_extremes`): of each run of finite values within a slice its
first and last row and the rows of its smallest and largest value (so no peak is lost), and one row
of each run of non-finite values (so a line breaks where it broke). A slice still open at the end of
a block waits for the next (:class:`Decimator`). The figures are then drawn from these rows as from
the whole log; the page's numbers come from the small channels and the survey, which are whole.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from ..model.frames import ssa
from . import data as vd
from .report_plot import bucket_runs
from .windowed import WindowedLog, blocks

BUCKETS = 4096
"""Slices of a channel's time span (a figure's axes are under 1,000 pixels wide: four or more a pixel)."""


def bucket_extremes(b: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The rows of a series ``y`` that draw it as the whole does at the resolution of the buckets ``b``.

    Parameters
    ----------
    b : numpy.ndarray
        Each sample's bucket (int, non-decreasing).
    y : numpy.ndarray
        The samples (float; NaN or inf breaks the line).

    Returns
    -------
    numpy.ndarray
        Row indices (not sorted, may repeat): per run of one bucket and one finiteness its first
        row, and per finite run its last row and the first rows of its smallest and largest value.
    """
    ok = np.isfinite(y)
    first, last = bucket_runs(b, ok)
    g = np.repeat(np.arange(len(first)), np.diff(np.r_[first, len(y)]))   # each sample's run
    lo = np.minimum.reduceat(np.where(ok, y, np.inf), first)
    hi = np.maximum.reduceat(np.where(ok, y, -np.inf), first)
    out = [first, last[ok[first]]]
    for at in (np.nonzero(ok & (y == lo[g]))[0], np.nonzero(ok & (y == hi[g]))[0]):
        out.append(at[np.r_[True, g[at][1:] != g[at][:-1]]] if len(at) else at)   # the first of each run
    return np.concatenate(out)


def state_series(f: pd.DataFrame) -> list[np.ndarray]:
    """Every series the report's figures draw of a state channel's frame: the track's north, east
    (and their sum: finite where both are), surge speed, heading (wrapped as drawn) and yaw rate,
    each of the last three also with its one-sigma band's edges."""
    def col(c):
        return f[c].to_numpy(float) if c in f.columns else None

    out = []
    for q in ("n_m", "e_m", "u_mps", "psi_rad", "r_radps"):
        y = col(q)
        if y is None:
            continue
        y = ssa(y) if q == "psi_rad" else y
        out.append(y)
        sd = col(q + "_std") if q not in ("n_m", "e_m") else None
        if sd is not None:
            out += [y - sd, y + sd]
    n, e = col("n_m"), col("e_m")
    if n is not None and e is not None:
        out.append(n + e)
    return out


class Decimator:
    """A channel's rows kept by :func:`bucket_extremes` of its :func:`state_series`, a block at a time.

    Parameters
    ----------
    t_lo, t_hi : int
        The channel's first and last time (ns): its span is cut into ``buckets`` equal slices.
    buckets : int
        Number of slices.
    """

    def __init__(self, t_lo: int, t_hi: int, buckets: int = BUCKETS):
        self.t_lo, self.span, self.buckets = int(t_lo), max(int(t_hi) - int(t_lo), 1), buckets
        self.held: pd.DataFrame | None = None   # the rows of the slice the last block ended in
        self.kept: list[pd.DataFrame] = []

    def _bucket(self, f: pd.DataFrame) -> np.ndarray:
        t = np.asarray(f.index.to_numpy(), np.int64) - self.t_lo
        return np.minimum(t * self.buckets // self.span, self.buckets - 1)

    def _keep(self, f: pd.DataFrame, b: np.ndarray) -> None:
        if len(f):
            rows = np.zeros(len(f), bool)
            for y in state_series(f):
                rows[bucket_extremes(b, y)] = True
            self.kept.append(f.iloc[np.nonzero(rows)[0]])

    def add(self, f: pd.DataFrame) -> None:
        """The channel's next block of rows (in time order)."""
        if self.held is not None:
            f = pd.concat([self.held, f])
        b = self._bucket(f)
        cut = int(np.searchsorted(b, b[-1]))
        self._keep(f.iloc[:cut], b[:cut])
        self.held = f.iloc[cut:].copy()   # not a view: the block is let go

    def frame(self) -> pd.DataFrame:
        """The rows kept, in time order."""
        if self.held is not None:
            self._keep(self.held, self._bucket(self.held))
            self.held = None
        return pd.concat(self.kept)


def decimated(log: WindowedLog) -> WindowedLog:
    """``log`` with its state channels decimated for the figures (and its commands left out: the
    report draws them in no figure; the manoeuvres made from them are the survey's).

    Raises
    ------
    usvlog.io.mcap.windows.NotWindowed
        The file cannot be read in windows after all.
    """
    sv = log.survey
    topics = [t for t, _label, _desc in vd.STATES if t in log.windowed]
    dec = {t: Decimator(sv.first[t], sv.last[t]) for t in topics}
    for blk in blocks(log, topics):
        for t, f in blk.items():
            dec[t].add(f)
    return log.without_windowed({t: d.frame() for t, d in dec.items()})
