"""An estimate whose output is made a time window at a time: :class:`WindowedEstimate`.

:func:`usvlog.estimate.estimate` holds the run's output whole: the smoothed states of every
grid row, then their frame. Here the smoother hands each block of rows to a store as it makes
them (from the last block to the first, :func:`usvlog.estimate.run.run_fast` with a sink), and
:meth:`WindowedEstimate.frames` reads them back in time order, a window of steps at a time, as
the frames of ``/estimate/state`` and ``/estimate/innovations`` (the report's sideslip figures
gathered on the way): memory of a window, not of the run, beyond the problem's arrays. With the
thrust given in time windows too (:data:`usvlog.estimate.problem.ThrustFrames`), the log need not
hold it. The frames joined are those of :func:`usvlog.estimate.estimate`, number for number.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping
from dataclasses import replace
from typing import Protocol

import numpy as np
import pandas as pd

from ..log.fieldlog import FieldLog
from ..model.vessel import Vessel, default_vessel
from .core import EstimateResult, SolvedRun, _grid_frame, course_held, solve_log
from .kernels import SMOOTH_BLOCK
from .layout import INNOVATION_TOPIC, STATE_TOPIC
from .problem import ThrustFrames
from .report import EstimateReport, Sideslip
from .settings import EstimateSettings

WINDOW_STEPS = 32 * SMOOTH_BLOCK
"""Filter steps per window of :meth:`WindowedEstimate.frames` (65,536: ~11 minutes at 100 Hz)."""


class RowStore(Protocol):
    """Where the smoothed rows wait for their frames: :meth:`put` takes a block of rows (any
    order), :meth:`get` gives rows back (as put: the states, their one-sigma and the
    covariance blocks, (n, 3, 3) or (0, 3, 3) when none were put)."""

    def put(self, r0: int, X: np.ndarray, SD: np.ndarray, PB: np.ndarray) -> None:
        """Keep rows r0 .. r0 + len(X)."""

    def get(self, r0: int, r1: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Rows r0 .. r1 (C-contiguous arrays of their own)."""


class WindowedEstimate:
    """The estimate of a run, its output frames made a time window at a time.

    Built, it has run the filter and smoother (:func:`usvlog.estimate.core.solve_log`: the same
    run as :func:`usvlog.estimate.estimate`, raising as it does), the output rows put into
    ``store``. Then :meth:`frames` yields the output frames window by window, and
    :meth:`result` gives the estimate (its report complete once the frames were all taken).

    Parameters
    ----------
    log : FieldLog
        The run (as :func:`usvlog.estimate.estimate` takes it; without the thrust when
        ``thrust`` is given).
    settings : EstimateSettings
        Not with ``estimate_delays`` (the delay search cuts the log on its own).
    vessel : Vessel, optional
        Default the log's own, else the built-in one.
    thrust : callable, optional
        The log's ``/thrust/command`` in time windows (:data:`ThrustFrames`); default the log's.
    store : RowStore
        Keeps the output rows between the smoother and the frames.
    """

    def __init__(self, log: FieldLog, settings: EstimateSettings, vessel: Vessel | None,
                 thrust: ThrustFrames | None, store: RowStore):
        if settings.estimate_delays:
            raise ValueError("WindowedEstimate: not with estimate_delays (the search reads the log whole)")
        self.vessel = vessel or log.vessel or default_vessel()
        self._store = store
        run = solve_log(log, settings, self.vessel, thrust, store.put)
        pb, none = run.pb, np.zeros((0, 2))   # (what the frames and the report need of the problem: memory)
        self._run: SolvedRun | None = replace(run, pb=replace(pb, dts=none[:, 0], taus=none, qjump=none[:, 0],
                                                              mz=none, mR=none))
        self.settings = run.settings
        self._report: EstimateReport | None = None

    def frames(self, steps: int | None = None) -> Iterator[dict[str, pd.DataFrame]]:
        """The output frames in consecutive time windows of ``steps`` filter steps (default
        :data:`WINDOW_STEPS`).

        Yields
        ------
        dict
            ``/estimate/state`` and ``/estimate/innovations`` -> the rows of the window
            (either may be empty). A GNSS-only kinematic run is one window (its heading, the
            course, is held across the run).
        """
        run = self._run
        if run is None:
            raise RuntimeError("WindowedEstimate.frames: taken already")
        pb = run.pb
        N = len(pb.t_ns)
        steps = N if course_held(pb) else max(1, steps or WINDOW_STEPS)
        slip = Sideslip() if pb.mode == "gnss+compass" else None
        r0 = j0 = 0
        for k0 in range(0, N, steps):
            k1 = min(N, k0 + steps)
            r1 = r0 + int(np.count_nonzero(pb.is_grid[k0:k1]))
            j1 = int(np.searchsorted(pb.mstep, k1))
            state = _grid_frame(pb, *self._store.get(r0, r1), slice(k0, k1))
            if slip is not None:
                slip.add(state)
            yield {STATE_TOPIC: state, INNOVATION_TOPIC: run.innovations(j0, j1)}
            r0, j0 = r1, j1
        self._report = run.report(slip.figures() if slip is not None else None)
        self._run = None   # (memory: the report is all that is left to give)

    def result(self, frames: Mapping[str, pd.DataFrame],
               make_forward: Callable[[], pd.DataFrame] | None = None) -> EstimateResult:
        """The estimate, after :meth:`frames` was taken to its end.

        Parameters
        ----------
        frames : mapping
            Where its ``state`` and ``innovations`` come from when asked for (e.g. the
            channels of the file they were written to, decoded when touched).
        make_forward : callable, optional
            Makes its ``forward`` frame when asked for (none: not available).
        """
        if self._report is None:
            raise RuntimeError("WindowedEstimate.result: the frames were not all taken (its report needs them)")
        return EstimateResult(report=self._report, settings=self.settings, vessel=self.vessel, _frames=frames,
                              _make_forward=make_forward)
