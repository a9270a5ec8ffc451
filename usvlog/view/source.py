"""Reading a log for ``usvlog view`` and ``usvlog report``: only the channels they draw.

A log's other channels (IMU, raw text, GNSS quality, a recorder's status, ...) are never
drawn, but they count in the log's time range, which both outputs show (the duration, the
time axis, the recording's start). So they are skipped only when the file's summary proves
they lie within the time range of the channels read: every chunk that holds one of them
starts and ends inside it (a chunk's start and end are its messages' first and last log
times). The ones in a chunk past that range are read as well, and the file whole when it
has no usable summary or is damaged.

(A forked copy of the process once read one channel while this one imported rerun or
matplotlib: no faster on a 1-hour log, so the drawn channels are read in one go;
docs/performance.md.)
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from ..io.mcap.reader import chunk_spans
from ..log.fieldlog import FieldLog
from . import data as vd

# what view/rrd.py draws; the report draws the same but the recorded thrust commands (it reads them to find
# the standard manoeuvres)
REPORT_TOPICS = tuple(dict.fromkeys([
    "/gnss/fix", "/local/position", "/compass/heading", "/estimate/innovations", "/identify/fit", "/thrust/command",
    *(t for t, _label, _desc in vd.STATES), *(t for t, _label, _state, _desc in vd.CONTROLLERS),
    *(s for _t, _label, s, _desc in vd.CONTROLLERS)]))
VIEW_TOPICS = tuple(dict.fromkeys((*REPORT_TOPICS, "/thrust/command")))


@dataclass(frozen=True)
class Drawn:
    """What :func:`read_drawn` reads.

    Parameters
    ----------
    topics : tuple of str
        The channels drawn.
    unless : dict, optional
        Channel of ``topics`` -> channels that, when the file holds any of them, keep it from
        being drawn (it is then left like a channel never drawn).
    """

    topics: tuple[str, ...]
    unless: dict[str, tuple[str, ...]] = field(default_factory=dict)


def read_drawn(path, topics: tuple[str, ...] | Drawn, read: Callable[..., FieldLog]) -> FieldLog:
    """The log at ``path`` with the channels ``topics`` (and any other only when needed for
    the time range, see the module's description).

    Parameters
    ----------
    path : str or os.PathLike
        A canonical MCAP file.
    topics : tuple of str or Drawn
        The channels drawn (a :class:`Drawn`: with the channels that keep one from being drawn).
    read : callable
        ``read(path, topics=None | list)`` loads the file (:func:`usvlog.io.mcap.read_log`).

    Returns
    -------
    FieldLog
        Its ``time_range()`` is the one of the whole log; a damaged file is read whole (its
        ``recovery`` report is the whole file's).
    """
    drawn = topics if isinstance(topics, Drawn) else Drawn(tuple(topics))
    spans = chunk_spans(path)
    if spans is None:
        return read(path, topics=None)
    present = {t for _a, _b, ts in spans for t in ts}
    topics = tuple(t for t in drawn.topics if not present.intersection(drawn.unless.get(t, ())))
    others = sorted(present - set(topics))
    if not others:
        return read(path, topics=None)
    log = read(path, topics=list(topics))
    if log.recovery is not None:   # a damaged file: as it reads whole
        return read(path, topics=None)
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


# what the view and the report read
# the view draws the compass only for a log without a state channel (rrd._Writer.draw_series)
VIEW_READ = Drawn(VIEW_TOPICS, unless={"/compass/heading": tuple(t for t, _label, _desc in vd.STATES)})
REPORT_READ = Drawn(REPORT_TOPICS)
