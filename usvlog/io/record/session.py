"""A recording session: open the sources, record until stopped, finish the file."""

from __future__ import annotations

import dataclasses
import threading
import time
from dataclasses import dataclass

from ...errors import ConfigError
from .output import check_outputs
from .recorder import Recorder
from .sources import Source, open_sources, shutdown
from .status import RecorderStatus


@dataclass(frozen=True)
class RecordSummary:
    """How a recording ended.

    Attributes
    ----------
    files : tuple of str
        The files written, in order.
    duration_s : float
        From the start of recording to the stop, s.
    stopped_by : str
        ``stop`` (signal or event), ``duration`` or ``error``.
    status : RecorderStatus
        The last status, after closing.
    source_errors : dict
        Source name -> its last error, for sources that had one.
    """

    files: tuple[str, ...]
    duration_s: float
    stopped_by: str                  # "stop" (signal), "duration", "error"
    status: RecorderStatus           # the last status, after closing
    source_errors: dict

    def to_dict(self) -> dict:
        """JSON-ready dict (``usvlog record --json``)."""
        return {"files": list(self.files), "duration_s": self.duration_s, "stopped_by": self.stopped_by,
                "status": self.status.to_dict(), "source_errors": dict(self.source_errors)}


def record(out, *, gnss: str | None = None, compass: str | None = None, thrust: str | None = None,
           vessel=None, rotate_mb: float | None = None, rotate_min: float | None = None,
           duration_s: float | None = None, force: bool = False, flush_s: float = 1.0,
           stop: threading.Event | None = None, on_status=None, status_every_s: float = 1.0,
           sources: list[Source] | None = None, subscribers=()) -> RecordSummary:
    """Record live sources into ``out`` until ``stop`` is set, ``duration_s`` passes or storage fails.

    Parameters
    ----------
    out : str or os.PathLike
        Output MCAP file (``OUT_000.mcap``, ``OUT_001.mcap``, ... when rotating).
    gnss, compass, thrust : str, optional
        Source URLs (see :func:`.sources.parse_source`); at least one.
    vessel : Vessel, optional
        Stored in every part.
    rotate_mb, rotate_min : float, optional
        Start a new part after this many MB (1e6 bytes) / minutes.
    duration_s : float, optional
        Stop after this many seconds.
    force : bool
        Overwrite existing outputs.
    flush_s : float
        Longest time a message waits in memory, s.
    stop : threading.Event, optional
        Set it to stop (a signal handler does).
    on_status : callable, optional
        ``on_status(RecorderStatus)``, about every ``status_every_s`` s.
    status_every_s : float
        Status interval, s.
    sources : list of Source, optional
        The sources for these URLs already opened by :func:`.sources.open_sources`, and
        possibly started (``usvlog record`` opens them before its heavy imports); their
        backlog goes into the file with its read times and the receive clock starts when
        the first was opened. Closed here whatever happens.
    subscribers : iterable of (callable, topics), optional
        Subscribed to the recorder (:meth:`.recorder.Recorder.subscribe`) before the first
        message: ``callback(topic, row, t_ns)`` for every message on ``topics`` (None: all).
        They run on the writing threads and must not block (e.g. a live view's queue).

    Returns
    -------
    RecordSummary
    """
    try:
        if not (gnss or compass or thrust):
            raise ConfigError("no source: give at least one of --gnss, --compass, --thrust")
        if duration_s is not None and not duration_s > 0:
            raise ConfigError(f"--duration-s {duration_s} must be > 0")
        check_outputs(out, rotating=rotate_mb is not None or rotate_min is not None, force=force)
        if sources is None:
            sources = open_sources(gnss, compass, thrust)  # a busy port or a missing device fails here
    except Exception:
        shutdown(sources or [])
        raise
    stop = stop or threading.Event()
    sources_desc = {k: v for k, v in (("gnss", gnss), ("compass", compass), ("thrust", thrust)) if v}
    clock = min((s.opened_ns for s in sources), key=lambda c: c[1], default=None)
    try:
        rec = Recorder(out, vessel=vessel, flush_s=flush_s, rotate_mb=rotate_mb, rotate_min=rotate_min,
                       force=force, sources=sources_desc, clock=clock)
    except Exception:
        shutdown(sources)
        raise
    for callback, topics in subscribers:
        rec.subscribe(callback, topics)
    t0 = time.monotonic()
    for s in sources:
        s.attach(rec)
        if s.ident is None:   # not started yet
            s.start()
    stopped_by = "stop"
    try:
        while True:
            wait = status_every_s
            if duration_s is not None:
                wait = min(wait, max(0.0, duration_s - (time.monotonic() - t0)))
            if stop.wait(wait):
                break
            if rec.error is not None:
                stopped_by = "error"
                break
            if on_status is not None:
                errs = tuple(f"{s.source_name}: {s.error}" for s in sources if s.error)
                on_status(dataclasses.replace(rec.status(), source_errors=errs))
            if duration_s is not None and time.monotonic() - t0 >= duration_s:
                stopped_by = "duration"
                break
    finally:
        shutdown(sources)
        rec.close()  # raises the storage error, if any
    return RecordSummary(files=tuple(str(p) for p in rec.paths), duration_s=time.monotonic() - t0,
                         stopped_by=stopped_by, status=rec.status(),
                         source_errors={s.source_name: s.error for s in sources if s.error})
