"""``usvlog estimate LOG --out OUT`` from a file to a file a time window at a time: memory flat
in the log's length (:func:`estimate_file`).

Standard library only at the top (as in the whole :mod:`usvlog.api` package): the heavy parts are
imported inside the functions.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..errors import StorageError, UsvlogError
from ._common import PathLike

if TYPE_CHECKING:  # annotations only: importing these at run time pulls numpy and pandas
    from ..estimate import EstimateResult, EstimateSettings
    from ..model.vessel import Vessel

THRUST = "/thrust/command"


def estimate_file(path: PathLike, out: PathLike, settings: EstimateSettings, vessel: Vessel | None,
                  force: bool = False, started: Callable[[], None] | None = None) -> EstimateResult | None:
    """The estimate of a canonical MCAP file written to ``out`` (the file plus ``/estimate/*``),
    a time window at a time.

    The small channels the estimator reads (fixes, headings...) are decoded whole; the thrust
    is read in time windows (:func:`usvlog.io.mcap.windows.iter_windows`) whenever the problem
    is built; the smoothed rows wait in a scratch file beside ``out``, from which the state and
    innovation frames are made in time windows (:class:`usvlog.estimate.windowed.WindowedEstimate`)
    into a spool beside ``out`` (:class:`usvlog.io.mcap.writer.Spool`); then ``out`` is written
    from the input's channels and the spool, copied undecoded
    (:func:`usvlog.io.mcap.writer.write_log_merged`). The numbers and the file's bytes are those
    of :func:`usvlog.estimate.estimate` saved with :func:`usvlog.io.mcap.write_log`. ``started`` is
    called once the file is read, as the work starts (a progress line).

    Returns
    -------
    EstimateResult or None
        Its ``state`` and ``innovations`` decoded from ``out`` when first asked for, its
        ``forward`` made by estimating the file again. None when the file cannot be read or
        written so (damaged, no summary statistics, the thrust out of time order...) or the
        settings search the sensor delays (they cut the log on their own): nothing is
        written, and the caller estimates the log whole.
    """
    from ..estimate.core import INPUT_TOPICS  # heavy: numpy, pandas, the numba kernels
    from ..estimate.layout import INNOVATION_TOPIC, STATE_TOPIC  # heavy: with the estimator
    from ..estimate.windowed import WindowedEstimate  # heavy: with the estimator
    from ..io.atomic import check_output  # light: os and pathlib
    from ..io.mcap import read_log  # heavy: the compiled MCAP reader
    from ..io.mcap.decode import _return_freed_memory  # heavy: with the reader
    from ..io.mcap.windows import NotWindowed, iter_windows, topic_counts  # heavy: with the reader
    from ..io.mcap.writer import Spool, merged_ids, write_log_merged  # heavy: the compiled MCAP writer

    check_output(out, force, parent=True)
    if settings.estimate_delays:
        return None
    counts = topic_counts(path)
    if not counts:
        return None
    log = read_log(path, topics=[t for t in INPUT_TOPICS if t != THRUST], defer=True)
    if log.recovery is not None or log.deferred is None:
        return None
    if started is not None:
        started()

    def thrust():
        for window in iter_windows(path, [THRUST]):
            if THRUST in window:
                yield window[THRUST]
        _return_freed_memory()   # the windows' decoding, freed: glibc would keep it from the system

    new = [STATE_TOPIC, INNOVATION_TOPIC]
    out_p = Path(out)
    scratch, spool = (out_p.parent / f".{out_p.name}.{k}" for k in ("rows", "spool"))
    try:
        with open(scratch, "w+b") as fh:
            est = WindowedEstimate(log, settings, vessel, thrust if counts.get(THRUST) else None, RowFile(fh))
            log.redefer(INPUT_TOPICS)   # (its channels go back to the file: memory)
            sp = Spool(spool, new, merged_ids(log, new))
            for frames in est.frames():
                sp.add({t: f for t, f in frames.items() if len(f)})
            spooled = sp.close()
        result = est.result({})
        result.add_records(log, log.source or "")
        write_log_merged(log, out, [spooled], new, force=force)
    except NotWindowed:
        return None
    except UsvlogError:
        raise
    except OSError as err:   # a scratch file or spool beside the output that cannot be written
        raise StorageError(f"{out_p}: cannot write beside it ({err.strerror or err})") from err
    finally:
        scratch.unlink(missing_ok=True)
        spool.unlink(missing_ok=True)
    return est.result(read_log(out, topics=[], defer=True).channels,
                      _Forward(str(path), settings, vessel))


class RowFile:
    """The smoothed rows of an estimate kept in a file (a :class:`usvlog.estimate.windowed.RowStore`):
    each row its states, their one-sigma and (when put) its covariance block, as float64."""

    def __init__(self, fh):
        self._fh = fh
        self._cols = (0, False)   # (states a row, covariance block): as last put

    def put(self, r0: int, X, SD, PB) -> None:
        """Write rows r0 .. r0 + len(X) (states, one-sigma, covariance blocks (n, 3, 3) or none)."""
        import numpy as np  # (loaded with the estimator)

        cov = len(PB) > 0
        self._cols = (X.shape[1], cov)
        rec = np.concatenate([X, SD, *([PB.reshape(len(PB), 9)] if cov else [])], axis=1)
        self._fh.seek(r0 * rec.shape[1] * 8)
        self._fh.write(memoryview(np.ascontiguousarray(rec)).cast("B"))

    def get(self, r0: int, r1: int) -> tuple[Any, Any, Any]:
        """Rows r0 .. r1 as put: states, one-sigma, covariance blocks ((0, 3, 3) when none were put)."""
        import numpy as np  # (loaded with the estimator)

        nc, cov = self._cols
        width = 2 * nc + (9 if cov else 0)
        rec = np.empty((r1 - r0, width))
        self._fh.seek(r0 * width * 8)
        if self._fh.readinto(memoryview(rec).cast("B")) != rec.nbytes:
            raise OSError(f"{self._fh.name}: rows {r0}..{r1} not all there")
        PB = rec[:, 2 * nc:].reshape(-1, 3, 3).copy() if cov else np.empty((0, 3, 3))
        return rec[:, :nc].copy(), rec[:, nc:2 * nc].copy(), PB


@dataclass(frozen=True)
class _Forward:
    """Makes the forward frame of :func:`estimate_file`'s result: the file estimated again, whole
    (the same numbers)."""

    path: str
    settings: Any
    vessel: Any

    def __call__(self):
        from ..estimate import estimate  # heavy: the estimator
        from ..estimate.core import INPUT_TOPICS  # heavy: with the estimator
        from ..io.mcap import read_log  # heavy: the compiled MCAP reader

        return estimate(read_log(self.path, topics=list(INPUT_TOPICS)), self.settings, self.vessel).forward
