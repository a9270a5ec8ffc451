"""The big channels of a windowed log sent to the recording a block at a time.

:func:`draw_blocks` (a method of :class:`usvlog.view.rrd_writer._Writer`, ``self``) draws the
time series of a :class:`usvlog.view.windowed.WindowedLog`'s state channels and recorded forces
(:func:`usvlog.view.rrd_series.draw_state_series`) from one block of rows after another
(:func:`usvlog.view.windowed.blocks`), so neither the channels nor rerun's columns of a whole
series are ever in memory. The recording holds the same entities and values as the whole log's
drawing:

* first the series are called once on a made-up row of each channel, sending nothing: they are
  then known in the order the whole log's drawing meets them; each one's plot, colour and range
  are settled in that order once every block is sent (:meth:`~usvlog.view.rrd_writer._Writer.settle`);
* a heading breaks where it wraps between two blocks as within one (the last sample carried);
* the recorded forces are computed with the whole channel's unit and choice of forces (the survey's);
* the rows the tracks draw are kept as the blocks pass (every step-th row of a state channel and its
  last, the step :func:`usvlog.view.data.thin_indices` takes for the whole channel, from the survey):
  the writer's log is then the log with its big channels so thinned, and the rest (tracks, the boat,
  events, findings, manoeuvres) is drawn from it as from a whole log.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from .windowed import blocks

if TYPE_CHECKING:
    from .rrd_writer import _Writer


def _made_up(frame: pd.DataFrame) -> pd.DataFrame:
    """The first row of a channel with every float finite (0): each series it has is called."""
    row = frame.iloc[:1].copy()
    for c in row.columns:
        if pd.api.types.is_float_dtype(row[c].dtype):
            row[c] = 0.0
    return row


def draw_blocks(self: _Writer) -> None:
    """The windowed log's state series and recorded forces a block at a time; afterwards the
    writer's log holds its state channels thinned for the tracks (see the module)."""
    log = self.log
    sv = log.survey
    self.pending, self.dry = {}, True
    self.tau_facts = {"unit": sv.thrust_unit, "forces": sv.thrust_forces}
    self.log = log.without_windowed({t: _made_up(h) for t, h in sv.heads.items()})
    self.draw_state_series()
    self.dry = False
    at = dict.fromkeys(sv.steps, 0)
    kept: dict[str, list] = {t: [] for t in sv.steps}
    for blk in blocks(log):
        self.log = log.without_windowed(blk)
        self.draw_state_series()
        for t, step in sv.steps.items():
            f = blk.get(t)
            if f is None:
                continue
            i = np.arange(at[t], at[t] + len(f))
            rows = np.nonzero((i % step == 0) | (i == sv.rows[t] - 1))[0]
            kept[t].append(f[[c for c in ("n_m", "e_m") if c in f.columns]].iloc[rows])
            at[t] += len(f)
    self.settle()
    self.log = log.without_windowed({t: pd.concat(fs) for t, fs in kept.items() if fs})
    self.thinned = True
