"""FieldLog: the in-memory form of one run.

One pandas DataFrame per topic, indexed by int64 ``t_ns`` (ns since the Unix epoch,
the MCAP log time), plus metadata records ``{name: {key: str}}`` as stored in MCAP.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import re
from collections.abc import Callable, Iterator, MutableMapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from .._version import __version__
from ..errors import InputError
from ..model.frames import Datum
from ..model.vessel import Vessel

if TYPE_CHECKING:   # pandas is imported where a frame is made (inspect never needs it)
    import pandas as pd

META_DATUM = "usvlog.datum"
META_VESSEL = "usvlog.vessel"
META_PROVENANCE = "usvlog.provenance"  # stored as usvlog.provenance/0, /1, ... in order


@dataclass(frozen=True)
class LostChunk:
    """A chunk of a damaged file that was not loaded.

    Attributes
    ----------
    offset, size : int
        Where the chunk record starts in the file and its length (bytes; the length
        is the damaged range's when the record's own length is not trustworthy).
    start_ns, end_ns : int or None
        The time range of its messages (ns since the Unix epoch): from the summary's
        chunk index, else from the chunk's header when plausible, else None.
    topics : tuple of str or None
        The channels that had messages in it (from the chunk index, or the message
        indexes that follow the chunk), None when unknown.
    reason : str
        Why it was not loaded (e.g. "CRC mismatch").
    """

    offset: int
    size: int
    start_ns: int | None
    end_ns: int | None
    topics: tuple[str, ...] | None
    reason: str

    def to_dict(self) -> dict:
        """The chunk as a JSON-ready dict: the attributes by name, ``topics`` as a list (or None)."""
        return {"offset": self.offset, "size": self.size, "start_ns": self.start_ns, "end_ns": self.end_ns,
                "topics": None if self.topics is None else list(self.topics), "reason": self.reason}


@dataclass(frozen=True)
class RecoveryReport:
    """What was recovered from a damaged file (truncated, corrupted, or with bytes after its end).

    Attributes
    ----------
    file_size : int
        Size of the file (bytes).
    bytes_recovered : int
        Bytes of the file that were used: ``file_size - bytes_lost - trailing_bytes``.
    bytes_lost : int
        Bytes in damaged ranges (chunks that failed, records that did not parse, a cut-off end).
    messages_recovered : int
        Messages loaded.
    lost_from_ns, lost_to_ns : int or None
        For a file cut short: the end of the recovered data and the end of the cut
        chunk (when its header survived). Otherwise the earliest start and latest end
        of the lost chunks whose time range is known (ns since the Unix epoch).
    reason : str
        The first damage found (and how many more).
    lost_chunks : tuple of LostChunk
        Every chunk not loaded, with its time range and channels where known.
    damaged_ranges : tuple of (offset, length)
        The byte ranges skipped (bytes).
    messages_skipped : int
        Messages in loaded chunks that could not be read (malformed record, payload
        not valid for its channel's schema, or a channel whose definition was lost).
    skipped_by_topic : dict
        ``messages_skipped`` by channel.
    trailing_bytes : int
        Bytes after the footer's closing magic (not part of the MCAP file).
    metadata_lost : tuple of str
        Names of metadata records the summary lists that could not be read.
    """

    file_size: int
    bytes_recovered: int     # bytes of the file that were used (complete records)
    bytes_lost: int          # bytes in damaged ranges
    messages_recovered: int
    lost_from_ns: int | None  # earliest time that may be missing (end of recovered data)
    lost_to_ns: int | None    # latest time known to be missing, when known (else None)
    reason: str
    lost_chunks: tuple[LostChunk, ...] = ()
    damaged_ranges: tuple[tuple[int, int], ...] = ()
    messages_skipped: int = 0
    skipped_by_topic: dict[str, int] = field(default_factory=dict)
    trailing_bytes: int = 0
    metadata_lost: tuple[str, ...] = ()

    @property
    def nothing_recovered(self) -> bool:
        """True when no message could be loaded (``inspect`` exits 1 on such a file)."""
        return self.messages_recovered == 0

    def describe(self) -> str:
        """Everything lost, in one long line (verbs print the shorter :meth:`one_line`).

        Messages recovered, bytes lost of the file size and the reason; then each lost
        chunk (byte offset, size, reason, its time range as ISO 8601 UTC when known, its
        channels), the time after which data is lost for a file cut short, messages
        skipped by channel, metadata records lost and bytes after the footer, each part
        only when there is something to say.
        """
        s = (f"recovered {self.messages_recovered} messages; {self.bytes_lost} of {self.file_size} bytes lost"
             f" ({self.reason})")
        if self.lost_chunks:
            s += f"; {len(self.lost_chunks)} chunk(s) lost: " + "; ".join(
                f"byte {c.offset} ({c.size} bytes, {c.reason})"
                + (f" {format_time(c.start_ns)} to {format_time(c.end_ns)}"
                   if c.start_ns is not None and c.end_ns is not None else "")
                + (f" on {', '.join(c.topics)}" if c.topics else " channels unknown" if c.topics is None else "")
                for c in self.lost_chunks)
        if self.lost_from_ns is not None and not self.lost_chunks:
            s += f"; data after {format_time(self.lost_from_ns)} lost"
        if self.messages_skipped:
            s += f"; {self.messages_skipped} message(s) skipped (" + ", ".join(
                f"{k} {v}" for k, v in self.skipped_by_topic.items()) + ")"
        if self.metadata_lost:
            s += f"; metadata lost: {', '.join(self.metadata_lost)}"
        if self.trailing_bytes:
            s += f"; {self.trailing_bytes} bytes of garbage after the footer"
        return s

    def one_line(self) -> str:
        """One line for a verb to print (and store in provenance) when its input was damaged, e.g.
        ``input damaged: 48213 bytes / 2 chunks lost, data missing 12:01:03-12:01:09 on /gnss/fix``."""
        if self.nothing_recovered:
            head = f"input damaged: nothing recovered ({self.reason})"
        elif self.bytes_lost or self.lost_chunks:
            head = f"input damaged: {self.bytes_lost} bytes / {len(self.lost_chunks)} chunk(s) lost"
        else:
            head = "input damaged"
        spans = []
        for c in self.lost_chunks:
            last = c is self.lost_chunks[-1]
            when = (f"{_hms(c.start_ns)}-{_hms(c.end_ns)}" if c.start_ns is not None and c.end_ns is not None
                    else f"after {_hms(self.lost_from_ns)}" if self.lost_from_ns is not None and last
                    else "at unknown times")
            spans.append(f"{when} on {', '.join(c.topics) if c.topics else 'unknown channels'}")
        if not self.lost_chunks and self.lost_from_ns is not None:
            spans.append(f"after {_hms(self.lost_from_ns)}")
        if spans and not self.nothing_recovered:
            head += ", data missing " + "; ".join(spans[:3]) + (f" (+{len(spans) - 3} more)" if len(spans) > 3 else "")
        tail = []
        if self.messages_skipped:
            tail.append(f"{self.messages_skipped} message(s) unreadable")
        if self.metadata_lost:
            tail.append(f"metadata lost: {', '.join(self.metadata_lost)}")
        if self.trailing_bytes:
            tail.append(f"{self.trailing_bytes} bytes of garbage after the end")
        if not tail and head == "input damaged":
            tail.append(self.reason)
        return head + (": " if head == "input damaged" else "; ") + "; ".join(tail) if tail else head

    def to_dict(self) -> dict:
        """The report as a JSON-ready dict (``--json`` output, provenance).

        Returns
        -------
        dict
            Every attribute by name (sizes in bytes, times in ns since the Unix epoch,
            ``lost_chunks`` as :meth:`LostChunk.to_dict` dicts, ``damaged_ranges`` as
            ``[offset, length]`` lists), plus ``nothing_recovered`` and ``summary``
            (:meth:`one_line`).
        """
        return {"file_size": self.file_size, "bytes_recovered": self.bytes_recovered,
                "bytes_lost": self.bytes_lost, "messages_recovered": self.messages_recovered,
                "lost_from_ns": self.lost_from_ns, "lost_to_ns": self.lost_to_ns, "reason": self.reason,
                "lost_chunks": [c.to_dict() for c in self.lost_chunks],
                "damaged_ranges": [list(r) for r in self.damaged_ranges],
                "messages_skipped": self.messages_skipped, "skipped_by_topic": dict(self.skipped_by_topic),
                "trailing_bytes": self.trailing_bytes, "metadata_lost": list(self.metadata_lost),
                "nothing_recovered": self.nothing_recovered, "summary": self.one_line()}


def _hms(t_ns: int) -> str:
    """UTC time of day, to 0.1 s."""
    d = _dt.datetime.fromtimestamp(t_ns / 1e9, tz=_dt.UTC)
    return d.strftime("%H:%M:%S.") + f"{d.microsecond // 100000}"


def format_time(t_ns: int) -> str:
    """ns since the Unix epoch -> ISO 8601 UTC text with milliseconds.

    ``1700000000123456789`` -> ``"2023-11-14T22:13:20.123+00:00"`` (the sub-millisecond
    part is dropped; the inverse, to the ns, is :func:`parse_time`).
    """
    return _dt.datetime.fromtimestamp(t_ns / 1e9, tz=_dt.UTC).isoformat(timespec="milliseconds")


_FRACTION = re.compile(r"(?<=\d)[.,](\d+)")
_EPOCH = _dt.datetime(1970, 1, 1, tzinfo=_dt.UTC)


def parse_time(text: str) -> int:
    """ISO 8601 time -> ns since the epoch, exact (fractions to the ns); UTC when it has no
    zone. Raises ValueError when ``text`` is not one."""
    s = str(text).strip().replace("Z", "+00:00").replace("z", "+00:00")
    frac = _FRACTION.search(s)
    ns = 0
    if frac is not None:
        ns = int((frac.group(1) + "000000000")[:9])
        s = s[:frac.start()] + s[frac.end():]
    t = _dt.datetime.fromisoformat(s)
    if t.tzinfo is None:
        t = t.replace(tzinfo=_dt.UTC)
    d = t - _EPOCH
    return (d.days * 86_400 + d.seconds) * 1_000_000_000 + ns


@dataclass
class DeferredSource:
    """Channels of a file not decoded when it was read (see :class:`Channels`).

    Attributes
    ----------
    path : str
        The file they are in.
    size : int
        Its size when it was read (bytes).
    mtime_ns : int
        Its modification time when it was read (ns since the Unix epoch).
    topics : dict of str to tuple
        Topic -> how the file stores it: (message encoding, schema name, schema encoding,
        schema bytes), for every canonical channel of the file.
    loader : callable
        ``loader(path, topics)`` -> ``{topic: DataFrame}``: decodes channels of the file
        (:func:`usvlog.io.mcap.reader.read_log`'s decoding).
    """

    path: str
    size: int
    mtime_ns: int
    topics: dict[str, tuple]
    loader: Callable[[str, list[str]], dict[str, pd.DataFrame]]

    def changed(self) -> str | None:
        """Why the file is no longer the one read (size or modification time differ), else None."""
        try:
            st = os.stat(self.path)
        except OSError as err:
            return f"cannot be read any more ({err.strerror or err})"
        if st.st_size != self.size or st.st_mtime_ns != self.mtime_ns:
            return "changed since it was read"
        return None

    def load(self, topics: list[str]) -> dict[str, pd.DataFrame]:
        """Decode ``topics`` (some of :attr:`topics`) from the file, which must be unchanged.

        Raises
        ------
        InputError
            The file changed (size or modification time) or went since it was read.
        """
        why = self.changed()
        if why is not None:
            raise InputError(f"{self.path} {why}: channel(s) {', '.join(sorted(topics))} not loaded "
                             "(load the log again)")
        return self.loader(self.path, sorted(topics))


class Channels(MutableMapping):
    """Topic -> DataFrame, where channels of the file read may still be undecoded (deferred).

    A plain mapping for every use (``in``, ``[]``, ``get``, iteration, ``items()``): a
    deferred channel is listed with the others and decoded from its file the first time its
    frame is asked for (all the deferred ones at once by ``values()``/``items()``). Setting
    or deleting a channel drops its deferred copy.

    Parameters
    ----------
    frames : dict, optional
        Topic -> DataFrame already in memory.
    deferred : DeferredSource, optional
        The file the channels were read from.
    topics : iterable of str, optional
        Its channels left in it (default: those of ``deferred.topics`` not in ``frames``).
    """

    def __init__(self, frames: dict[str, pd.DataFrame] | None = None, deferred: DeferredSource | None = None,
                 topics=None):
        self._frames: dict[str, pd.DataFrame] = dict(frames or {})
        self._deferred = deferred
        if deferred is None:
            self._own: set[str] = set()
        else:
            self._own = {t for t in (deferred.topics if topics is None else topics) if t not in self._frames}

    @property
    def deferred(self) -> DeferredSource | None:
        """The source of the channels not decoded yet (None when every one is in memory)."""
        return self._deferred if self.deferred_topics() else None

    def deferred_topics(self) -> list[str]:
        """The channels not decoded yet, sorted."""
        if self._deferred is None:
            return []
        return sorted(t for t in self._own if t not in self._frames)

    def decoded(self) -> dict[str, pd.DataFrame]:
        """The channels in memory (without decoding the deferred ones)."""
        return dict(self._frames)

    def load_deferred(self, topics: list[str] | None = None) -> None:
        """Decode deferred channels (``topics``, default all) now, in one pass over the file."""
        todo = self.deferred_topics()
        if topics is not None:
            todo = [t for t in todo if t in set(topics)]
        if todo:
            assert self._deferred is not None
            self._frames.update(self._deferred.load(todo))
            self._own.difference_update(todo)

    def redefer(self, topics: list[str]) -> None:
        """Drop the frames of ``topics`` (channels of the file read, their frames unchanged
        since): they are decoded again if touched, and copied undecoded when the log is
        written. Topics the file does not hold are left alone.
        """
        if self._deferred is None:
            return
        for t in topics:
            if t in self._deferred.topics and t in self._frames:
                del self._frames[t]
                self._own.add(t)

    def __getitem__(self, topic: str) -> pd.DataFrame:
        if topic not in self._frames and topic in self._own:
            self.load_deferred([topic])
        return self._frames[topic]

    def __setitem__(self, topic: str, frame: pd.DataFrame) -> None:
        self._own.discard(topic)
        self._frames[topic] = frame

    def __delitem__(self, topic: str) -> None:
        if topic in self._own:
            self._own.discard(topic)
            if topic not in self._frames:
                return
        del self._frames[topic]

    def __contains__(self, topic: object) -> bool:
        return topic in self._frames or topic in self._own

    def __iter__(self) -> Iterator[str]:
        yield from self._frames
        yield from (t for t in sorted(self._own) if t not in self._frames)

    def __len__(self) -> int:
        return len(self._frames) + sum(1 for t in self._own if t not in self._frames)

    def values(self):  # type: ignore[override]
        """Every frame (the deferred ones decoded first, in one pass)."""
        self.load_deferred()
        return self._frames.values()

    def items(self):  # type: ignore[override]
        """(topic, frame) of every channel (the deferred ones decoded first, in one pass)."""
        self.load_deferred()
        return self._frames.items()

    def copy(self) -> Channels:
        """A shallow copy that keeps the deferred channels deferred (frames shared)."""
        out = Channels(self._frames, self._deferred)
        out._own = set(self._own)
        return out

    def __repr__(self) -> str:
        return f"Channels({sorted(self._frames)}, deferred={self.deferred_topics()})"


@dataclass
class FieldLog:
    """One run in memory: a pandas DataFrame per channel plus the run's metadata.

    ``usvlog.load`` reads one from a canonical MCAP file and ``usvlog.save`` writes one; the
    importers and the simulator make them, and every stage (estimate, identify, replay) returns
    a copy with its results added as new channels.

    Attributes
    ----------
    channels : dict of str to pandas.DataFrame
        Topic (``/gnss/fix``, ``/compass/heading``, ...) -> frame indexed by int64 ``t_ns``
        (ns since the Unix epoch, the MCAP log time), one row per message; columns carry their
        unit in the name (``lat_deg``, ``heading_rad``, ``u_mps``).
    meta : dict of str to dict of str to str
        Metadata records as stored in MCAP: ``usvlog.datum`` (see :attr:`datum`),
        ``usvlog.vessel`` (see :attr:`vessel`), ``usvlog.provenance/N`` (see :attr:`provenance`).
    schemas : dict of str to dict
        Topic -> JSON Schema read from the file (empty for channels made in memory).
    recovery : RecoveryReport or None
        What was lost when the file was damaged (None when it was read whole).
    source : str or None
        The path the log was loaded from.

    A log read with a subset of its channels decoded keeps the others in its file
    (``channels`` is then a :class:`Channels`, see :attr:`deferred`): they are listed like
    the rest and decoded when first touched.
    """

    channels: MutableMapping[str, pd.DataFrame] = field(default_factory=dict)
    meta: dict[str, dict[str, str]] = field(default_factory=dict)
    schemas: dict[str, dict] = field(default_factory=dict)  # topic -> schema read from file (if any)
    recovery: RecoveryReport | None = None
    source: str | None = None  # path it was loaded from

    # -- channels -------------------------------------------------------------------
    def __contains__(self, topic: str) -> bool:
        """True when the log has channel ``topic``."""
        return topic in self.channels

    def __getitem__(self, topic: str) -> pd.DataFrame:
        """The frame of channel ``topic`` (indexed by ``t_ns``, ns since the Unix epoch).

        Raises
        ------
        InputError
            When the log has no such channel (the message names the channels it has).
        """
        try:
            return self.channels[topic]
        except KeyError:
            where = f"{self.source}: " if self.source else ""
            have = ", ".join(sorted(self.channels)) or "none"
            raise InputError(f"{where}channel {topic} is missing (channels: {have})") from None

    def get(self, topic: str) -> pd.DataFrame | None:
        """The frame of channel ``topic``, or None when the log has no such channel."""
        return self.channels.get(topic)

    def set(self, topic: str, frame: pd.DataFrame) -> None:
        """Add or replace a channel.

        Parameters
        ----------
        topic : str
            Channel name, e.g. ``/estimate/state``.
        frame : pandas.DataFrame
            One row per message. Its index becomes int64 ``t_ns`` (ns since the Unix epoch): an
            integer index is taken as ns, a DatetimeIndex is converted.
        """
        idx = frame.index
        if idx.name != "t_ns" or idx.dtype != np.int64:
            import pandas as pd  # (loaded already: a frame is given)

            if isinstance(idx, pd.DatetimeIndex):
                vals = idx.as_unit("ns").asi8
            else:
                vals = np.asarray(idx, dtype=np.int64)
            frame = frame.set_axis(pd.Index(vals, name="t_ns"), axis=0)
        self.channels[topic] = frame

    @property
    def deferred(self) -> DeferredSource | None:
        """The file holding the channels not decoded yet, or None when all are in memory."""
        ch = self.channels
        return ch.deferred if isinstance(ch, Channels) else None

    @property
    def topics(self) -> list[str]:
        """The channel names, sorted."""
        return sorted(self.channels)

    def redefer(self, topics) -> None:
        """Leave ``topics`` (channels of the file this log was read from, their frames unchanged
        since) in that file again: their frames are freed, decoded again if touched, and copied
        undecoded when the log is written. Nothing happens for a log not read with deferred
        channels, or for topics its file does not hold.

        Parameters
        ----------
        topics : iterable of str
            The channels.
        """
        if isinstance(self.channels, Channels):
            self.channels.redefer(list(topics))

    def time_range(self) -> tuple[int, int] | None:
        """(first, last) time stamp over every channel in ns since the Unix epoch; None when empty."""
        lo = [int(f.index.min()) for f in self.channels.values() if len(f)]
        hi = [int(f.index.max()) for f in self.channels.values() if len(f)]
        return (min(lo), max(hi)) if lo else None

    # -- metadata -------------------------------------------------------------------
    @property
    def datum(self) -> Datum | None:
        """Origin (latitude, longitude in degrees, altitude in m) of the local NED frame, if stored."""
        d = self.meta.get(META_DATUM)
        return Datum.from_dict(d) if d else None

    @datum.setter
    def datum(self, value: Datum) -> None:
        self.meta[META_DATUM] = value.to_dict()

    @property
    def vessel(self) -> Vessel | None:
        """The vessel stored with the run (model parameters in SI units, thrusters), if any."""
        d = self.meta.get(META_VESSEL)
        return Vessel.from_dict(d) if d else None

    @vessel.setter
    def vessel(self, value: Vessel) -> None:
        self.meta[META_VESSEL] = value.to_dict()

    @property
    def provenance(self) -> list[dict[str, str]]:
        """Provenance records in order: producer, usvlog version, source, settings (JSON text)."""
        keys = sorted((k for k in self.meta if k.startswith(META_PROVENANCE + "/")),
                      key=lambda k: int(k.rsplit("/", 1)[1]))
        return [self.meta[k] for k in keys]

    def add_provenance(self, *, producer: str, source: str = "", settings: dict | None = None,
                       **extra) -> None:
        """Append a provenance record: what produced (or changed) this log, from what, how.

        Parameters
        ----------
        producer : str
            What made the change, e.g. ``"usvlog estimate"``.
        source : str
            The input it came from (a file name).
        settings : dict, optional
            Settings used; stored as JSON text.
        **extra
            Further fields; values that are not text are stored as JSON.
        """
        rec = {"producer": producer, "usvlog_version": __version__, "source": source,
               "settings": json.dumps(settings or {}, sort_keys=True, default=str)}
        rec.update({k: v if isinstance(v, str) else json.dumps(v, sort_keys=True, default=str)
                    for k, v in extra.items()})
        n = len(self.provenance)
        self.meta[f"{META_PROVENANCE}/{n}"] = rec

    def copy(self, deep: bool = False) -> FieldLog:
        """A copy whose channels and metadata can be added, replaced or removed independently.

        By default the copy **shares the DataFrames** with this log (so copying a large log costs
        nothing): adding, replacing (:meth:`set`) or removing a channel in either log does not
        affect the other, and metadata records are copied, but changing a shared frame in place
        (``log["/gnss/fix"].loc[...] = ...``) changes it in both. ``deep=True`` copies the frames
        too.

        Parameters
        ----------
        deep : bool
            Also copy every DataFrame.

        Returns
        -------
        FieldLog
        """
        if deep:
            channels = {k: f.copy(deep=True) for k, f in self.channels.items()}
        elif isinstance(self.channels, Channels):
            channels = self.channels.copy()   # deferred channels stay deferred
        else:
            channels = dict(self.channels)
        return FieldLog(channels=channels, meta={k: dict(v) for k, v in self.meta.items()},
                        schemas=dict(self.schemas), recovery=self.recovery, source=self.source)

    def equals(self, other: FieldLog) -> bool:
        """True when both logs have the same channels (values, index, column order) and metadata."""
        if set(self.channels) != set(other.channels) or self.meta != other.meta:
            return False
        return all(self.channels[k].equals(other.channels[k]) and
                   list(self.channels[k].columns) == list(other.channels[k].columns)
                   for k in self.channels)
