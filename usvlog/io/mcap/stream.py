"""Streaming an MCAP file's verified chunks, and the reads that need only its summary.

:func:`iter_chunks` opens a :class:`ChunkStream`: the file memory-mapped, the walk of
:mod:`.walk` run a window at a time, the pages behind it given back, so memory stays at
about one chunk whatever the file's size. It keeps the messages whose channel is defined
(the rules of :func:`.reader.read_log`) and, after the walk, gives the file's channels
(:class:`ChannelInfo`), metadata and recovery report. :func:`.decode._read_streamed` decodes
frames from it; :func:`scan_file` gathers the whole walk into one buffer instead.
:func:`chunk_spans` and :func:`channel_ids` read the summary alone (footer and summary,
CRC checked).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...errors import FormatError
from ...log.fieldlog import RecoveryReport
from ..atomic import reading
from .codec import loadable
from .container import (
    _find_footer,
    _find_footer_windowed,
    _layout_windowed,
    _read_summary,
    _Scan,
    _Summary,
    _summary_channel,
)
from .format import MAGIC
from .recovery import _finish_windowed, _report_if_lost, _widen
from .walk import _chunks_wanted, _chunks_without, _scan_fast, _walk


@dataclass(frozen=True)
class Chunk:
    """One verified chunk's messages (see :func:`iter_chunks`).

    Attributes
    ----------
    offset : int
        Byte offset of the chunk record in the file; -1 for messages outside chunks.
    start_ns, end_ns : int or None
        The chunk's time range from its header (ns since the Unix epoch); None outside chunks.
    data : numpy.ndarray
        uint8 bytes the messages lie in (the chunk's decompressed records).
    channel_id, sequence, log_time_ns, start, end : numpy.ndarray
        int64, one per message in file order: channel id, sequence number, log time (ns since
        the Unix epoch) and the payload's span ``data[start:end]``. Only messages whose
        channel is defined (the rules of :func:`read_log`) are here.
    """

    offset: int
    start_ns: int | None
    end_ns: int | None
    data: np.ndarray
    channel_id: np.ndarray
    sequence: np.ndarray
    log_time_ns: np.ndarray
    start: np.ndarray
    end: np.ndarray


@dataclass(frozen=True)
class ChannelInfo:
    """A channel of an MCAP file: topic, encodings, schema name and the schema's bytes."""

    topic: str
    message_encoding: str
    schema_name: str
    schema_encoding: str
    schema_data: bytes

    @property
    def canonical(self) -> bool:
        """JSON messages with a JSON Schema, or CDR ones with a ros2msg schema usvlog wrote:
        a channel :func:`read_log` loads."""
        return loadable(self.message_encoding, self.schema_encoding, self.schema_name)


_RELEASE_BYTES = 8 << 20    # a memory-mapped file drops the pages behind the walk this often (bytes)


_WINDOW_BYTES = 8 << 20      # top-level records walked at a time when streaming (bytes)


def by_channel(cid: np.ndarray) -> list[tuple[int, np.ndarray]]:
    """Messages grouped by channel.

    Parameters
    ----------
    cid : numpy.ndarray
        int64 channel id of each message (0 to 65535, as a walk yields them).

    Returns
    -------
    list of (int, numpy.ndarray)
        (channel id, indices of its messages in their order in ``cid``), by increasing id.
    """
    counts = np.bincount(cid)
    ids = np.flatnonzero(counts)
    if len(ids) <= 1:
        return [(int(c), np.arange(len(cid))) for c in ids]
    by = np.argsort(cid.astype(np.uint16), kind="stable")   # a stable sort of 16-bit keys is a radix sort
    return list(zip(ids.tolist(), np.split(by, np.cumsum(counts[ids[:-1]]))))


def _first_definitions(defined: dict, cid: np.ndarray) -> np.ndarray:
    """``defined.get(c, -1)`` for every channel id in ``cid`` (ids >= 0), by a table lookup."""
    if not len(cid):
        return np.zeros(0, dtype=np.int64)
    table = np.full(int(cid.max()) + 1, -1, dtype=np.int64)
    for c, o in defined.items():
        if c < len(table):
            table[c] = o
    return table[cid]


class ChunkStream:
    """Verified chunks of an MCAP file, one at a time (see :func:`iter_chunks`).

    Iterate once to get every :class:`Chunk` in file order; afterwards ``channels``,
    ``metadata`` and ``recovery`` hold what the whole walk found. The file is memory-mapped
    and the pages behind the walk are given back as it goes, so memory stays at about one
    chunk whatever the file's size. Use as a context manager (or call :meth:`close`).

    Parameters
    ----------
    path : str or Path
        The MCAP file.
    """

    def __init__(self, path, topics=None):
        import mmap  # the standard library's, only for streaming reads

        self.path = Path(path)
        self._topics = None if topics is None else frozenset(topics)
        self._mmap_mod = mmap
        self._fh = None
        self._map = None
        self._done = False
        self._scan = _Scan()
        self._n_msgs = 0
        self._t_lo: int | None = None
        self._t_hi: int | None = None
        with reading(self.path):
            self._fh = open(self.path, "rb")  # noqa: SIM115 - closed by close()
            size = self._fh.seek(0, 2)
            if size < 8:
                self.close()
                raise FormatError(f"{self.path}: not an MCAP file (bad magic bytes)")
            self._map = mmap.mmap(self._fh.fileno(), 0, access=mmap.ACCESS_READ)
        self._released = 0

    # -- memory ----------------------------------------------------------------------
    def _release(self, upto: int, force: bool = False) -> None:
        """Drop the mapped pages before ``upto`` (page cache keeps them; RSS does not)."""
        m = self._map
        if m is None or not hasattr(m, "madvise") or not hasattr(self._mmap_mod, "MADV_DONTNEED"):
            return
        page = self._mmap_mod.PAGESIZE
        start = self._released - self._released % page
        end = min(upto, len(m)) // page * page
        if end > start and (force or end - start >= _RELEASE_BYTES):
            m.madvise(self._mmap_mod.MADV_DONTNEED, start, end - start)
            self._released = end

    def _release_all(self) -> None:
        """Drop every mapped page (after a search or a check that ran over the file)."""
        m = self._map
        if m is not None and hasattr(m, "madvise") and hasattr(self._mmap_mod, "MADV_DONTNEED"):
            m.madvise(self._mmap_mod.MADV_DONTNEED, 0, len(m))
        self._released = 0

    # -- the walk ----------------------------------------------------------------------
    def __iter__(self):
        for records, at, t0, t1, cid, seq, t, ps, pe, _ordinal in self._batches():
            yield self._chunk(records, at, t0, t1, cid, seq, t, ps, pe)

    def _batches(self):
        """The walk: ``(records, at, t0, t1, cid, seq, t, ps, pe, ordinal)`` per batch of
        messages kept (``ordinal`` orders them in the file)."""
        if self._done or self._map is None:
            raise RuntimeError(f"{self.path}: a ChunkStream is read once")
        data, scan = self._map, self._scan
        _layout_windowed(scan, data, self._release_all)
        if data[:8] != MAGIC and not scan.footer:
            raise FormatError(f"{self.path}: not an MCAP file (bad magic bytes)")
        skip = _chunks_without(scan, self._topics)
        pending = []   # messages on a channel not (yet) defined: resolved at the end
        for records, msgs, at, t0, t1 in _walk(scan, data, self._release, _WINDOW_BYTES, skip):
            cid, seq, t, ps, pe, ordinal = msgs
            first = _first_definitions(scan.defined, cid)   # ordinal of each one's channel record, -1: none yet
            known = first >= 0
            if not known.all():
                later = ~known
                pending.append((np.array(records[:pe[later].max()]) if at >= 0 else records,
                                at, t0, t1, cid[later], seq[later], t[later], ps[later], pe[later], ordinal[later]))
            keep = known & (ordinal > first)
            if len(keep) and keep.all():   # the usual case: no copies
                yield records, at, t0, t1, cid, seq, t, ps, pe, ordinal
            elif keep.any():
                yield records, at, t0, t1, cid[keep], seq[keep], t[keep], ps[keep], pe[keep], ordinal[keep]
        _finish_windowed(scan, data, self._release_all)
        # messages met before their channel's record: kept when it never came (the summary has it)
        for records, at, t0, t1, cid, seq, t, ps, pe, ordinal in pending:
            keep = np.zeros(len(cid), dtype=bool)
            for c in np.unique(cid).tolist():
                sel = cid == c
                if c in scan.defined:
                    keep |= sel & (ordinal > scan.defined[c])
                elif c in scan.channels or _summary_channel(scan, c) is not None:
                    scan.channels.setdefault(c, _summary_channel(scan, c))
                    keep |= sel
                else:
                    scan.orphans[c] = scan.orphans.get(c, 0) + int(sel.sum())
            if keep.any():
                yield records, at, t0, t1, cid[keep], seq[keep], t[keep], ps[keep], pe[keep], ordinal[keep]
        if skip:   # the wanted channels a skipped chunk may have defined: the summary's copies
            for c in _chunks_wanted(scan, self._topics):
                scan.channels.setdefault(c, _summary_channel(scan, c))
        self._done = True

    def _chunk(self, records, at, t0, t1, cid, seq, t, ps, pe) -> Chunk:
        scan = self._scan
        name_enc = {sid: (name, enc) for sid, (name, enc, _data) in scan.schemas.items()}
        canon = []
        for c, ch in scan.channels.items():
            sname, senc = name_enc.get(ch.schema_id, ("", ""))
            if loadable(ch.encoding, senc, sname):
                canon.append(c)
        counted = np.isin(cid, canon)
        if counted.any():
            tc = t[counted]
            self._n_msgs += int(counted.sum())
            self._t_lo, self._t_hi = _widen(self._t_lo, self._t_hi, tc)
        return Chunk(at, t0, t1, records, cid, seq, t, ps, pe)

    # -- what the walk found -------------------------------------------------------------
    @property
    def channels(self) -> dict[int, ChannelInfo]:
        """Channel id -> :class:`ChannelInfo`, for the channels defined so far."""
        out = {}
        for cid, ch in self._scan.channels.items():
            name, enc, data = self._scan.schemas.get(ch.schema_id, ("", "", b""))
            out[cid] = ChannelInfo(ch.topic, ch.encoding, name, enc, bytes(data))
        return out

    @property
    def metadata(self) -> dict[str, dict[str, str]]:
        """Metadata records by name (complete after the iteration)."""
        return dict(self._scan.metadata)

    def recovery(self, skipped: dict[str, int] | None = None) -> RecoveryReport | None:
        """After the iteration: what was lost, as :func:`read_log` reports it, or None when intact.

        Parameters
        ----------
        skipped : dict, optional
            Topic -> messages a caller could not decode (counted as skipped).

        Returns
        -------
        RecoveryReport or None
            ``messages_recovered`` counts the messages of channels :func:`read_log` loads.
        """
        if not self._done:
            raise RuntimeError(f"{self.path}: iterate over the chunks first")
        scan, size = self._scan, len(self._map) if self._map is not None else self._scan.size
        skipped = dict(skipped or {})
        n = self._n_msgs - sum(skipped.values())
        return _report_if_lost(scan, size, n, self._t_lo, self._t_hi, skipped)

    def close(self) -> None:
        """Unmap and close the file."""
        if self._map is not None:
            try:
                self._map.close()
            except BufferError:   # a chunk still refers to the map; it goes with the last reference
                pass
            self._map = None
        if self._fh is not None:
            self._fh.close()
            self._fh = None

    def __enter__(self) -> ChunkStream:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def iter_chunks(path) -> ChunkStream:
    """Stream an MCAP file's verified chunks, one at a time, with memory bounded by a chunk.

    The walk is :func:`read_log`'s (every chunk's CRC checked, resynchronisation after
    damage, the same messages kept), without loading the file: it is memory-mapped and
    the pages behind the walk are released.

    Parameters
    ----------
    path : str or Path
        The MCAP file.

    Returns
    -------
    ChunkStream
        Iterate it for :class:`Chunk` objects (decompressed, verified, with their time
        range) in file order; then ``stream.recovery()`` is the
        :class:`~usvlog.log.fieldlog.RecoveryReport` (None when intact), ``stream.channels``
        and ``stream.metadata`` what the file defines.

    Examples
    --------
    >>> with iter_chunks("run.mcap") as stream:              # doctest: +SKIP
    ...     n = sum(len(c.log_time_ns) for c in stream)
    ...     report = stream.recovery()
    """
    return ChunkStream(path)


# -- the whole walk in one buffer ---------------------------------------------------

def _read_bytes(p: Path) -> bytes:
    with reading(p):
        data = p.read_bytes()
    if len(data) < 8 or (data[:8] != MAGIC and _find_footer(data) < 0):
        raise FormatError(f"{p}: not an MCAP file (bad magic bytes)")
    return data


def scan_file(path, *, scanner=None) -> tuple[_Scan, int]:
    """Walk an MCAP file's records: (scan, file size). ``scanner`` is ``_scan_fast``
    unless given (the tests pass :func:`.reference._scan_reference`)."""
    if scanner is not None:
        data = _read_bytes(Path(path))
        return scanner(data), len(data)
    # the fast scan reads a memory map, giving its pages back as it goes
    with ChunkStream(path) as stream:
        data = stream._map
        if data[:8] != MAGIC and _find_footer_windowed(data, stream._release_all) < 0:
            raise FormatError(f"{stream.path}: not an MCAP file (bad magic bytes)")
        return _scan_fast(data, stream._release, stream._release_all), len(data)


# -- the summary alone --------------------------------------------------------------

def _summary_of(path) -> _Summary | None:
    """The summary of an MCAP file (only the footer and the summary read, their CRC
    checked); None when it has none usable or is not MCAP."""
    try:
        with ChunkStream(path) as stream:
            data = stream._map
            at = _find_footer_windowed(data, stream._release_all)
            return _read_summary(data, at) if at >= 0 else None
    except (FormatError, OSError):
        return None


def chunk_spans(path) -> list[tuple[int, int, frozenset]] | None:
    """The chunks of an MCAP file from its summary's chunk index (only the footer and the
    summary are read, their CRC checked).

    Parameters
    ----------
    path : str or os.PathLike
        The file.

    Returns
    -------
    list of (int, int, frozenset of str) or None
        Per chunk: its first and last message log time (ns since the Unix epoch) and the
        topics it holds; None when the file has no usable summary (damaged, cut short,
        unchunked, not MCAP).
    """
    s = _summary_of(path)
    if s is None or not s.chunks:
        return None
    topic = {cid: ch[0] for cid, ch in s.channels.items()}
    return [(int(t0), int(t1), frozenset(topic.get(c, "") for c in cids))
            for _size, t0, t1, cids in (s.chunks[o] for o in s.chunk_offsets)]


def channel_ids(path) -> dict[str, int]:
    """Topic -> channel id of the channels an MCAP file's summary lists (a topic on more
    than one channel left out; empty without a usable summary).

    Parameters
    ----------
    path : str or os.PathLike
        The file.

    Returns
    -------
    dict
        Topic -> channel id (1 to 65535).
    """
    s = _summary_of(path)
    if s is None:
        return {}
    out: dict[str, int] = {}
    twice = set()
    for cid, (topic, _sid, _enc) in s.channels.items():
        if topic in out:
            twice.add(topic)
        out[topic] = cid
    return {t: c for t, c in out.items() if t not in twice}
