"""Reading a log for ``usvlog view`` and ``usvlog report``: only the channels they draw.

A log's other channels (IMU, raw text, GNSS quality, a recorder's status, ...) are never
drawn, but they count in the log's time range, which both outputs show (the duration, the
time axis, the recording's start). So they are skipped only when the file's summary proves
they lie within the time range of the channels read: every chunk that holds one of them
starts and ends inside it (a chunk's start and end are its messages' first and last log
times). The ones in a chunk past that range are read as well, and the file whole when it
has no usable summary or is damaged.
"""

from __future__ import annotations

from collections.abc import Callable

from ..io.mcap.reader import chunk_spans
from ..log.fieldlog import FieldLog
from . import data as vd

# what view/rrd.py draws; the report draws the same but the recorded thrust commands
REPORT_TOPICS = tuple(dict.fromkeys([
    "/gnss/fix", "/compass/heading", "/estimate/innovations", "/identify/fit",
    *(t for t, _label, _desc in vd.STATES), *(t for t, _label, _state, _desc in vd.CONTROLLERS),
    *(s for _t, _label, s, _desc in vd.CONTROLLERS)]))
VIEW_TOPICS = (*REPORT_TOPICS, "/thrust/command")


def read_drawn(path, topics: tuple[str, ...], read: Callable[..., FieldLog]) -> FieldLog:
    """The log at ``path`` with the channels ``topics`` (and any other only when needed for
    the time range, see the module's description).

    Parameters
    ----------
    path : str or os.PathLike
        A canonical MCAP file.
    topics : tuple of str
        The channels drawn.
    read : callable
        ``read(path, topics=None | list)`` loads the file (:func:`usvlog.io.mcap.read_log`).

    Returns
    -------
    FieldLog
        Its ``time_range()`` is the one of the whole log; a damaged file is read whole (its
        ``recovery`` report is the whole file's).
    """
    spans = chunk_spans(path)
    if spans is None:
        return read(path, topics=None)
    others = sorted({t for _a, _b, ts in spans for t in ts} - set(topics))
    if not others:
        return read(path, topics=None)
    log = read(path, topics=list(topics))
    tr = log.time_range()
    if log.recovery is not None or tr is None:   # a damaged file: as it reads whole
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
