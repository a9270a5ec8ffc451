"""What the recorder reports while it runs: per-source counters and the one-line live status."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from ..nmea import FixSelector
from .timesync import OffsetEstimator


@dataclass(frozen=True)
class SourceStatus:
    """Counters of one source at one moment."""

    name: str
    messages: int         # lines / calls received
    garbage: int          # malformed (kept raw)
    dropped: int          # dropped by the OS before reading (UDP); -1 unknown
    rate_hz: float        # over the last status interval
    clock_offset_s: float | None


@dataclass(frozen=True)
class RecorderStatus:
    """The recorder at one moment: files, bytes, sources, last fix and fix quality."""

    elapsed_s: float
    path: str             # file being written
    files: tuple[str, ...]
    file_bytes: int       # bytes on disk, all parts
    messages_written: int
    sources: tuple[SourceStatus, ...]
    last_fix: tuple[float, float] | None   # lat, lon
    fix_age_s: float | None
    satellites: int | None
    hdop: float | None
    fix_quality: int | None
    error: str | None
    source_errors: tuple[str, ...] = ()    # e.g. "compass: cannot connect to ..." (filled by the session)

    def line(self) -> str:
        """The one-line live status."""
        parts = [f"{self.elapsed_s:6.0f} s"]
        for s in self.sources:
            p = f"{s.name} {s.rate_hz:5.1f}/s"
            if s.garbage:
                p += f" bad {s.garbage}"
            if s.dropped > 0:
                p += f" drop {s.dropped}"
            parts.append(p)
        if self.last_fix is not None:
            fix = f"fix {self.last_fix[0]:.6f},{self.last_fix[1]:.6f}"
            if self.fix_age_s is not None and self.fix_age_s > 2.0:
                fix += f" ({self.fix_age_s:.0f} s old)"
            parts.append(fix)
        else:
            parts.append("no fix")
        if self.satellites is not None and self.satellites >= 0:
            parts.append(f"sats {self.satellites}")
        if self.hdop is not None and math.isfinite(self.hdop):
            parts.append(f"hdop {self.hdop:.1f}")
        parts.append(f"{self.file_bytes / 1e6:.2f} MB")
        parts.extend(self.source_errors)
        if self.error:
            parts.append(f"ERROR {self.error}")
        return " | ".join(parts)

    def to_dict(self) -> dict:
        """JSON-ready dict of the status (times in s, sizes in bytes, positions in degrees).

        Returns
        -------
        dict
        """
        d = {k: getattr(self, k) for k in ("elapsed_s", "path", "file_bytes", "messages_written", "fix_age_s",
                                          "satellites", "hdop", "fix_quality", "error")}
        d["files"] = list(self.files)
        d["source_errors"] = list(self.source_errors)
        d["last_fix"] = list(self.last_fix) if self.last_fix else None
        d["sources"] = [s.__dict__ for s in self.sources]
        return d


@dataclass
class SourceState:
    """Counters and NMEA state of one source (mutated under the recorder's lock)."""

    name: str
    messages: int = 0
    garbage: int = 0
    dropped: int = -1
    rate_hz: float = 0.0
    _last_messages: int = 0
    offset: OffsetEstimator = field(default_factory=OffsetEstimator)
    fixes: FixSelector = field(default_factory=FixSelector)  # one fix per epoch from its NMEA sentences

    def count(self, garbage: bool = False) -> None:
        """One more message.

        Parameters
        ----------
        garbage : bool
            It was malformed.
        """
        self.messages += 1
        if garbage:
            self.garbage += 1

    def update_rate(self, dt_s: float) -> None:
        """Messages per second since the last update.

        Parameters
        ----------
        dt_s : float
            Time since the last update, s.
        """
        self.rate_hz = (self.messages - self._last_messages) / dt_s
        self._last_messages = self.messages

    def snapshot(self) -> SourceStatus:
        """The counters now, frozen.

        Returns
        -------
        SourceStatus
            With the clock offset (receive minus sensor time) in s, None until known.
        """
        est = self.offset.estimate()
        return SourceStatus(self.name, self.messages, self.garbage, self.dropped, self.rate_hz,
                            None if est is None else est.offset_ns / 1e9)
