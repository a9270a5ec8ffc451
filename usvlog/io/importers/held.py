"""Sample-and-hold resampling: a sensor's values repeated on a faster row grid.

A log resampled onto a regular grid (a 10 Hz CSV made from a DataFlash log, say) holds
each GNSS fix until the next one arrives, so a 5 Hz receiver shows up as pairs of
identical rows. The repeats are not measurements: fed to a filter as independent
fixes they double its confidence. :func:`detect_held` decides from a stretch of the
stream whether its repeats are holds, and :func:`held_mask` marks them, batch by
batch, so that one row per real update is kept (the first row of each run: that is
when the update arrived).

A receiver at rest that repeats exactly the same fix is not a hold: its repeats come
at irregular run lengths (one long run while still) and the fixes that do change do so
at the row rate. A stream is held only when a good part of its rows repeat the row
before, its rows (repeats and changes alike) come at one regular row rate, and the changes come at a slower *regular*
rate. In a held stream a run longer than one and a half update periods (a still boat)
still keeps one row per period after that: those are the receiver's real updates (a run
up to 1.5 periods long is one late update of a jittery receiver, held).

Pure numpy: arrays in, results out (any importer can call it).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

HELD_MIN_REPEAT_FRACTION = 0.2
"""At least this share of the rows must repeat the row before for a stream to be held."""
HELD_MIN_REGULAR = 0.6
"""At least this share of the intervals between changes must be the regular update period."""
HELD_MIN_GRID = 0.9
"""At least this share of the intervals between rows must be the row interval (a resampled grid:
a fix republished a few times between updates is not held, see
:mod:`usvlog.io.importers.audit`)."""
HELD_MIN_ROWS = 20
"""Streams with fewer rows are not judged."""
_SLOT_LATE = 1.5    # in a run of equal values, a repeat this many periods in is a real update


@dataclass(frozen=True)
class Held:
    """A held stream: its row interval, its real update period and what was seen.

    Attributes
    ----------
    row_s : float
        Median interval between rows (s).
    update_s : float
        Real update period (s): mean of the regular intervals between changes.
    repeats : int
        Rows of the looked-at stretch that repeat the row before.
    rows : int
        Rows looked at.
    regular : float
        Share of the intervals between changes that are the update period.
    """

    row_s: float
    update_s: float
    repeats: int
    rows: int
    regular: float

    @property
    def rate_hz(self) -> float:
        """The sensor's true update rate (Hz)."""
        return 1.0 / self.update_s

    @property
    def row_rate_hz(self) -> float:
        """The row rate of the resampled stream (Hz)."""
        return 1.0 / self.row_s

    def describe(self) -> str:
        """One line for the import report."""
        return (f"held between updates: values change every {self.update_s:.3g} s ({self.rate_hz:.3g} Hz) "
                f"in {self.row_rate_hz:.3g} Hz rows ({self.repeats} of {self.rows} rows looked at repeat "
                f"the row before; {self.regular:.0%} of the changes regular): one row kept per update")


@dataclass(frozen=True)
class HoldState:
    """Where :func:`held_mask` stopped: the last row's values, its run's start, its slot."""

    values: tuple
    t_start: int
    slot: int


def _same(cols: list[np.ndarray]) -> np.ndarray:
    """Rows whose every value equals the row before's (row 0: False)."""
    n = len(cols[0])
    same = np.zeros(n, bool)
    if n > 1:
        same[1:] = True
        for c in cols:
            same[1:] &= c[1:] == c[:-1]
    return same


def detect_held(t_ns, *values) -> Held | None:
    """Whether a stream's repeated values are sample-and-hold copies, and its true rate.

    Parameters
    ----------
    t_ns : array_like of int
        Row times (ns), in order.
    *values : array_like
        The value columns that repeat together (latitude and longitude for a fix).

    Returns
    -------
    Held or None
        None when fewer than :data:`HELD_MIN_ROWS` rows, fewer than
        :data:`HELD_MIN_REPEAT_FRACTION` of them repeat, the repeats do not come at the
        rows are not on a regular grid, or the changes are not at a slower regular rate (a receiver at rest).
    """
    t = np.asarray(t_ns, np.int64)
    cols = [np.asarray(v, float) for v in values]
    n = len(t)
    if n < HELD_MIN_ROWS or not cols:
        return None
    same = _same(cols)
    dt = np.diff(t).astype(float)
    pos = dt[dt > 0]
    if int(same.sum()) < HELD_MIN_REPEAT_FRACTION * n or len(pos) == 0:
        return None
    row = float(np.median(pos))
    if np.mean(np.abs(dt - row) <= 0.25 * row) < HELD_MIN_GRID:   # not rows on a regular grid
        return None
    starts = np.flatnonzero(~same)
    upd = np.diff(t[starts]).astype(float)
    if len(upd) < 5:
        return None
    med = float(np.median(upd))
    if med < 1.5 * row:
        return None
    regular = np.abs(upd - med) <= 1.01 * row + 0.1 * med
    share = float(np.mean(regular))
    if share < HELD_MIN_REGULAR:
        return None
    return Held(row_s=row / 1e9, update_s=float(np.mean(upd[regular])) / 1e9, repeats=int(same.sum()),
                rows=n, regular=share)


def held_mask(t_ns, values: list, update_s: float, state: HoldState | None = None
              ) -> tuple[np.ndarray, HoldState | None]:
    """Mark the held repeats of one batch of a held stream.

    A row is kept when its values differ from the row before, or, within a run of equal
    values, when it is the first row 1.5, 2.5, 3.5, ... update periods after the run's
    start (a still receiver's real updates, one per period); the other rows of a run are
    held repeats.

    Parameters
    ----------
    t_ns : array_like of int
        Row times (ns), in order.
    values : list of array_like
        The value columns (as given to :func:`detect_held`).
    update_s : float
        The true update period (s), :attr:`Held.update_s`.
    state : HoldState, optional
        What the previous batch ended with (None for the first).

    Returns
    -------
    held : ndarray of bool
        True for the held repeats (to drop).
    state : HoldState or None
        To pass with the next batch.
    """
    t = np.asarray(t_ns, np.int64)
    cols = [np.asarray(v, float) for v in values]
    n = len(t)
    if n == 0:
        return np.zeros(0, bool), state
    same = _same(cols)
    same[0] = state is not None and all(c[0] == v for c, v in zip(cols, state.values))
    idx = np.arange(n)
    start = np.maximum.accumulate(np.where(~same, idx, -1))
    t_start = np.where(start >= 0, t[np.maximum(start, 0)], state.t_start if state is not None else t[0])
    x = (t - t_start) / (update_s * 1e9)
    slot = np.maximum(0, np.floor(x - (_SLOT_LATE - 1.0) + 1e-6)).astype(np.int64)
    prev = np.empty(n, np.int64)
    prev[1:] = slot[:-1]
    prev[0] = state.slot if state is not None else -1
    held = same & (slot == prev)
    return held, HoldState(tuple(float(c[-1]) for c in cols), int(t_start[-1]), int(slot[-1]))
