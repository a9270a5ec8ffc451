"""Reading a log for ``usvlog view`` and ``usvlog report``: only the channels they draw.

A log's other channels (IMU, raw text, GNSS quality, a recorder's status, ...) are never
drawn, but they count in the log's time range, which both outputs show (the duration, the
time axis, the recording's start). So they are skipped only when the file's summary proves
they lie within the time range of the channels read: every chunk that holds one of them
starts and ends inside it (a chunk's start and end are its messages' first and last log
times). The ones in a chunk past that range are read as well, and the file whole when it
has no usable summary or is damaged.

While the view imports rerun (~0.5 s, holding the GIL), a forked copy of the process reads one
more channel (:class:`Drawn`), one that costs about as much to read; the log is the same as read
in one go, and read in one go when no second CPU is free (``USVLOG_THREADS=1``). It earns its
place (issue 32): a 1-hour ``usvlog view`` 10.8 % faster with it (median of 4 paired on/off runs,
9.1-11.7 %, load 1.1-1.2; docs/performance.md). The report reads in one go: the same copy beside
its matplotlib import saved 3.3 %.

A long log (:data:`usvlog.view.windowed.MIN_ROWS` rows in a big channel) whose file allows it is
not read whole at all: :func:`read_drawn` gives a :class:`usvlog.view.windowed.WindowedLog` (its
channels :attr:`Drawn.small` decoded, the big ones drawn a time window at a time), surveyed before
the caller's import (no forked copy then: there is no channel to read whole).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from ..io.mcap.reader import chunk_spans
from ..log.fieldlog import FieldLog
from . import data as vd
from .forked import Forked, two_cores
from .windowed import open_windowed

# what view/rrd.py draws; the report draws the same but the recorded thrust commands (it reads them to find
# the standard manoeuvres)
REPORT_TOPICS = tuple(dict.fromkeys([
    "/gnss/fix", "/local/position", "/compass/heading", "/estimate/innovations", "/identify/fit", "/thrust/command",
    *(t for t, _label, _desc in vd.STATES), *(t for t, _label, _state, _desc in vd.CONTROLLERS),
    *(s for _t, _label, s, _desc in vd.CONTROLLERS)]))
VIEW_TOPICS = tuple(dict.fromkeys((*REPORT_TOPICS, "/thrust/command")))


@dataclass(frozen=True)
class Drawn:
    """What :func:`read_drawn` reads and what this process does meanwhile.

    Parameters
    ----------
    topics : tuple of str
        The channels drawn.
    late : tuple of str, default ()
        Channels of ``topics`` in order of preference: the first the file holds is read by a
        forked copy of the process (:class:`usvlog.view.forked.Forked`) while this one runs
        ``meanwhile``, once the others are read (here when no copy can run).
    meanwhile : callable, optional
        Work for this process while the copy reads (e.g. importing what draws the log).
    unless : dict, optional
        Channel of ``topics`` -> channels that, when the file holds any of them, keep it from
        being drawn (it is then left like a channel never drawn).
    small : tuple of str, default ()
        Channels of ``topics`` decoded whole when the others can be drawn a time window at a
        time (:func:`usvlog.view.windowed.open_windowed`); () reads every channel whole.
    """

    topics: tuple[str, ...]
    late: tuple[str, ...] = ()
    meanwhile: Callable[[], object] | None = None
    unless: dict[str, tuple[str, ...]] = field(default_factory=dict)
    small: tuple[str, ...] = ()


def read_drawn(path, topics: tuple[str, ...] | Drawn, read: Callable[..., FieldLog]) -> FieldLog:
    """The log at ``path`` with the channels ``topics`` (and any other only when needed for
    the time range, see the module's description).

    Parameters
    ----------
    path : str or os.PathLike
        A canonical MCAP file.
    topics : tuple of str or Drawn
        The channels drawn; a :class:`Drawn` also names those a forked copy reads while this
        process runs its ``meanwhile`` (the log is the same either way).
    read : callable
        ``read(path, topics=None | list)`` loads the file (:func:`usvlog.io.mcap.read_log`).

    Returns
    -------
    FieldLog
        Its ``time_range()`` is the one of the whole log; a damaged file is read whole (its
        ``recovery`` report is the whole file's).
    """
    drawn = topics if isinstance(topics, Drawn) else Drawn(tuple(topics))
    ran: list[bool] = []

    def meanwhile() -> None:   # once: while the copy reads, or after the read
        if not ran and drawn.meanwhile is not None:
            ran.append(True)
            drawn.meanwhile()
    log = _read_drawn(path, drawn, meanwhile, read)
    meanwhile()
    return log


def _frames(log: FieldLog) -> tuple[dict, dict, bool]:
    """(frames, schemas, damaged) of a log read in a forked copy: what pickles back."""
    return dict(log.channels), {t: log.schemas[t] for t in log.channels if t in log.schemas}, log.recovery is not None


def _read_drawn(path, drawn: Drawn, meanwhile: Callable[[], None], read: Callable[..., FieldLog]) -> FieldLog:
    topics = drawn.topics
    spans = chunk_spans(path)
    if spans is None:
        return read(path, topics=None)
    present = {t for _a, _b, ts in spans for t in ts}
    topics = tuple(t for t in topics if not present.intersection(drawn.unless.get(t, ())))
    if drawn.small:
        windowed = open_windowed(path, topics, tuple(t for t in drawn.small if t in topics), read)
        if windowed is not None:
            return windowed
    others = sorted(present - set(topics))
    late = [t for t in drawn.late if t in present][:1]
    if not others and not late:
        return read(path, topics=None)
    log = read(path, topics=[t for t in topics if t not in late])
    if log.recovery is not None:   # a damaged file: as it reads whole
        return read(path, topics=None)
    if late:
        copy = Forked(lambda: _frames(read(path, topics=late))) if two_cores() else None
        try:
            meanwhile()   # the caller's work now, not after the read
        except BaseException:
            if copy is not None:
                copy.stop()
            raise
        got = copy.result() if copy is not None else None
        frames, schemas, damaged = got if got is not None else _frames(read(path, topics=late))
        if damaged:
            return read(path, topics=None)
        for t, frame in frames.items():
            log.channels[t] = frame
            if t in schemas:
                log.schemas[t] = schemas[t]
    tr = log.time_range()
    if tr is None:
        return read(path, topics=None)
    skipped = set(others)
    while True:   # read what a chunk past the range holds (it widens the range), until none is past it
        tr = log.time_range()
        past = {t for a, b, ts in spans if a < tr[0] or b > tr[1] for t in ts if t in skipped}
        if not past:
            return log
        skipped -= past
        rest = read(path, topics=sorted(past))
        if rest.recovery is not None:
            return read(path, topics=None)
        for t, frame in rest.channels.items():
            log.channels[t] = frame
            if t in rest.schemas:
                log.schemas[t] = rest.schemas[t]


def _import_rerun() -> None:
    from . import rrd  # noqa: F401  heavy: rerun, imported while a forked copy reads a channel


# what the view and the report read (for the view a forked copy reads the channel that costs about
# as much as importing rerun, while this process imports it; 1-hour log: ~0.5 s each)
# the view draws the compass only for a log without a state channel (rrd._Writer.draw_series)
# a log long enough is drawn a time window at a time (usvlog.view.windowed): these channels decoded whole,
# the big ones (the states, the thrust commands) from the file as they are drawn; the rerun import then
# follows the survey of the log, whose whole-run analyses are the read's peak
SMALL = ("/gnss/fix", "/local/position", "/compass/heading", "/estimate/innovations")
VIEW_READ = Drawn(VIEW_TOPICS, late=("/thrust/command", "/truth/state", "/estimate/state"), meanwhile=_import_rerun,
                  unless={"/compass/heading": tuple(t for t, _label, _desc in vd.STATES)}, small=SMALL)
REPORT_READ = Drawn(REPORT_TOPICS, small=SMALL)
