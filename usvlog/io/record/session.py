"""A recording session: open the sources, record until stopped, finish the file."""

from __future__ import annotations

import dataclasses
import threading
import time
from dataclasses import dataclass

from ...errors import ConfigError
from .output import check_outputs
from .recorder import Recorder
from .sources import Source, parse_source
from .status import RecorderStatus


@dataclass(frozen=True)
class RecordSummary:
    files: tuple[str, ...]
    duration_s: float
    stopped_by: str                  # "stop" (signal), "duration", "error"
    status: RecorderStatus           # the last status, after closing
    source_errors: dict

    def to_dict(self) -> dict:
        return {"files": list(self.files), "duration_s": self.duration_s, "stopped_by": self.stopped_by,
                "status": self.status.to_dict(), "source_errors": dict(self.source_errors)}


def open_sources(gnss: str | None = None, compass: str | None = None,
                 thrust: str | None = None) -> list[Source]:
    """Sources for the given URLs, endpoints open, not started (``attach`` a recorder, then
    ``start``). GNSS and compass may share one URL."""
    wanted = [("gnss", gnss, "nmea"), ("compass", compass, "nmea"), ("thrust", thrust, "json")]
    by_url: dict[str, list] = {}
    for name, url, kind in wanted:
        if url:
            spec = parse_source(url, f"--{name}")
            entry = by_url.setdefault(spec.url, [[], spec, kind])
            if entry[2] != kind:
                raise ConfigError(f"--{name} {url}: one source cannot carry both NMEA and JSON lines")
            entry[0].append(name)
    out = []
    try:
        for names, spec, kind in by_url.values():
            out.append(Source("+".join(names), spec, None, kind))
    except Exception:
        for s in out:
            s.close()
        raise
    return out


def record(out, *, gnss: str | None = None, compass: str | None = None, thrust: str | None = None,
           vessel=None, rotate_mb: float | None = None, rotate_min: float | None = None,
           duration_s: float | None = None, force: bool = False, flush_s: float = 1.0,
           stop: threading.Event | None = None, on_status=None, status_every_s: float = 1.0) -> RecordSummary:
    """Record live sources into ``out`` until ``stop`` is set, ``duration_s`` passes or storage fails.

    ``on_status(RecorderStatus)`` is called about every ``status_every_s``.
    """
    if not (gnss or compass or thrust):
        raise ConfigError("no source: give at least one of --gnss, --compass, --thrust")
    if duration_s is not None and not duration_s > 0:
        raise ConfigError(f"--duration-s {duration_s} must be > 0")
    stop = stop or threading.Event()
    sources_desc = {k: v for k, v in (("gnss", gnss), ("compass", compass), ("thrust", thrust)) if v}
    check_outputs(out, rotating=rotate_mb is not None or rotate_min is not None, force=force)
    sources = open_sources(gnss, compass, thrust)  # a busy port or a missing device fails here
    try:
        rec = Recorder(out, vessel=vessel, flush_s=flush_s, rotate_mb=rotate_mb, rotate_min=rotate_min,
                       force=force, sources=sources_desc)
    except Exception:
        for s in sources:
            s.close()
        raise
    t0 = time.monotonic()
    for s in sources:
        s.attach(rec)
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
        for s in sources:
            s.stop()
        for s in sources:
            s.join(timeout=2.0)
        rec.close()  # raises the storage error, if any
    return RecordSummary(files=tuple(str(p) for p in rec.paths), duration_s=time.monotonic() - t0,
                         stopped_by=stopped_by, status=rec.status(),
                         source_errors={s.source_name: s.error for s in sources if s.error})
