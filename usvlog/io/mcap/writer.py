"""The one MCAP writer: :class:`McapWriter` (streaming) and :func:`write_log` (a whole log).

Message and index records are built with compiled loops (:mod:`.kernels`); the bytes are
the mcap library's ``Writer``'s for the same messages (:mod:`.reference` keeps that path).
"""

from __future__ import annotations

import json
import os
import struct
from collections import deque
from typing import TYPE_CHECKING

import numpy as np

from ..._version import __version__
from ...errors import InputError
from ...log.channels import (
    SCHEMA_ENCODING,
    auto_schema,
    schema_for_topic,
)
from ...log.fieldlog import Channels, DeferredSource, FieldLog
from ..atomic import atomic_path
from . import kernels as K
from .codec import Codec, writer_codec
from .format import (
    _REC,
    MAGIC,
    crc32,
)
from .reader import ChunkStream, chunk_spans

if TYPE_CHECKING:   # pandas is imported where a frame is made (inspect never needs it)
    import pandas as pd


def _codec_for(topic: str, schema: dict | None = None, frame: pd.DataFrame | None = None) -> tuple[dict, Codec]:
    """(schema, codec) of a channel: the registered schema, else ``schema`` (e.g. the one
    stored in the file read), else one generated from ``frame``'s dtypes; the codec is
    CDR for the bulk derived channels, else JSON (:func:`.codec.writer_codec`)."""
    schema = schema_for_topic(topic) or schema
    if schema is None:
        if frame is None:
            raise InputError(f"channel {topic}: no registered schema (see schemas/)")
        schema = auto_schema(topic, frame)
    return schema, writer_codec(topic, schema)


def _schema_record(topic: str, schema: dict, codec: Codec) -> tuple[str, str, bytes]:
    """(name, encoding, data) of a channel's Schema record: the JSON Schema (named by its
    title), or the ros2msg definition of a CDR channel."""
    if codec.schema_encoding == SCHEMA_ENCODING:
        return schema.get("title", topic), SCHEMA_ENCODING, json.dumps(schema, sort_keys=False).encode()
    return codec.schema_name, codec.schema_encoding, codec.schema_data


def _compression(compression: str) -> str:
    if compression not in ("zstd", "lz4", "none"):
        raise InputError(f"unknown compression {compression!r} (zstd, lz4 or none)")
    return compression


ZSTD_LEVEL = 1
"""zstd level of the chunks :func:`write_log` writes: on canonical JSON logs level 1 is
2-2.5x faster than the library's level 3 and compresses better (ratio 4.3 vs 3.7 on a
replay log); see the README's "Output encoding and compression"."""

SLICE_MESSAGES = 1 << 16
"""Messages :func:`write_log` encodes at a time (one time slice of the whole log)."""


def write_log(log: FieldLog, path, *, force: bool = False, chunk_size: int = 1 << 20,
              compression: str = "zstd", zstd_level: int = ZSTD_LEVEL,
              slice_messages: int = SLICE_MESSAGES) -> None:
    """Write ``log`` as a canonical MCAP file, atomically, through :class:`McapWriter`.

    The log goes through the writer in time slices of about ``slice_messages``
    messages, so the encoding's memory is bounded by a slice, not by the log. The file
    is the one the mcap library's ``Writer`` writes for the same messages (byte for
    byte at the library's ``zstd_level=3``; ``_write_log_reference`` does it that way
    and the tests compare). Metadata records come first (a truncated file keeps them),
    then every channel, then the messages of all channels in (time, channel, row) order.

    A channel still deferred (``log.deferred``: read from a file and never touched) is
    copied from that file's message payloads without decoding them when the file
    stores it with the schema record and message encoding this writer uses for it: the
    same file as after decoding it, byte for byte. It is decoded instead when the file
    stores it otherwise, when the log was read with damage recovered, or when its messages
    are not in the time and sequence order a usvlog file has; a file changed since it was
    read (size or modification time) is refused (:class:`InputError`).
    """
    _compression(compression)
    copy = _copied_channels(log)
    with atomic_path(path, force=force) as tmp:
        if copy:
            try:
                _write(log, tmp, chunk_size, compression, zstd_level, slice_messages, copy)
                return
            except _OutOfOrder:   # the source's messages are not in time/row order: decode them
                assert isinstance(log.channels, Channels)
                log.channels.load_deferred(copy)
        _write(log, tmp, chunk_size, compression, zstd_level, slice_messages, [])


def _write(log: FieldLog, tmp, chunk_size: int, compression: str, zstd_level: int, slice_messages: int,
           copy: list[str]) -> None:
    """:func:`write_log` to ``tmp``, the channels ``copy`` from the log's source file."""
    decoded = log.channels.decoded() if isinstance(log.channels, Channels) else log.channels
    frames = {topic: decoded[topic] for topic in log.topics if topic not in copy}
    with open(tmp, "wb", buffering=1 << 20) as fh:
        w = McapWriter(fh, chunk_size=chunk_size, compression=compression, zstd_level=zstd_level)
        feed = None
        try:
            for name in sorted(log.meta):
                w.add_metadata(name, log.meta[name])
            for topic in log.topics:
                w.add_channel(topic, log.schemas.get(topic), frames.get(topic))
            if not copy:
                for batch in time_slices(frames, slice_messages):
                    w.add_frames(batch, log.schemas)
            else:
                src = log.deferred
                assert src is not None
                feed = _RawFeed(src, copy)
                cuts = _slice_cuts(_times(frames), slice_messages)
                # frames whose times do not rise: one slice (the copied payloads held whole)
                cuts = np.zeros(0, dtype=np.int64) if cuts is None else feed.cuts(cuts)
                for k, batch in enumerate(_cut(frames, cuts)):
                    w.add_frames(batch, log.schemas, feed.take(int(cuts[k]) if k < len(cuts) else None))
                feed.finish()
            w.finish()
        finally:
            w.close()
            if feed is not None:
                feed.close()


def _copied_channels(log: FieldLog) -> list[str]:
    """The deferred channels :func:`write_log` copies from the source file (the others it
    must write are decoded now)."""
    ch = log.channels
    src = log.deferred
    if src is None or not isinstance(ch, Channels):
        return []
    why = src.changed()
    if why is not None:
        raise InputError(f"{src.path} {why}: cannot write channel(s) {', '.join(ch.deferred_topics())} "
                         "from it (load the log again)")
    todo = ch.deferred_topics()
    if log.recovery is not None:
        ch.load_deferred()
        return []
    copy, decode = [], []
    for topic in todo:
        schema, codec = _codec_for(topic, log.schemas.get(topic))
        mine = (codec.message_encoding, *_schema_record(topic, schema, codec))
        (copy if mine == tuple(src.topics[topic]) else decode).append(topic)
    ch.load_deferred(decode)
    return copy


class _OutOfOrder(Exception):
    """The source's messages of a copied channel are not in (time, row) order."""


def _times(frames: dict[str, pd.DataFrame]) -> dict[str, np.ndarray]:
    return {t: np.asarray(f.index, dtype=np.int64) for t, f in frames.items() if len(f)}


def _slice_cuts(times: dict[str, np.ndarray], size: int) -> np.ndarray | None:
    """The times that cut ``times`` (topic -> rising int64 ns) into slices of about ``size``
    messages (a slice is [cut k-1, cut k)); None when a channel's times do not rise (then
    the frames are one slice)."""
    total = sum(len(v) for v in times.values())
    if not all(len(v) < 2 or bool(np.all(v[1:] >= v[:-1])) for v in times.values()):
        return None
    if total <= size:
        return np.zeros(0, dtype=np.int64)
    # boundaries at quantiles of every message's time (from a sample: boundaries need not be exact)
    step = max(1, total // (64 * (total // size + 1)))
    sample = np.sort(np.concatenate([v[::step] for v in times.values()]))
    return np.unique(sample[np.linspace(0, len(sample), total // size + 1, endpoint=False).astype(np.int64)[1:]])


def _cut(frames: dict[str, pd.DataFrame], cuts: np.ndarray):
    """The slices of ``frames`` at ``cuts`` (one per cut and the last: len(cuts) + 1, some
    may be empty dicts)."""
    times = _times(frames)
    edges = {t: np.concatenate(([0], np.searchsorted(v, cuts, side="left"), [len(v)])) for t, v in times.items()}
    for k in range(len(cuts) + 1):
        yield {t: frames[t].iloc[int(e[k]):int(e[k + 1])] for t, e in edges.items() if e[k + 1] > e[k]}


def time_slices(frames: dict[str, pd.DataFrame], size: int):
    """Split frames (index: int64 log time ns) into consecutive time slices of about
    ``size`` messages in all, for :meth:`McapWriter.add_frames` one slice at a time.

    A boundary is a time: every message of a time falls into one slice, so the slices
    written in turn give the (time, channel, row) order of the whole. A frame whose
    times do not rise (rare: an unsorted import) cannot be cut so: then the frames
    are one slice.

    Parameters
    ----------
    frames : dict
        Topic -> DataFrame indexed by log time (int64 ns).
    size : int
        Messages per slice (about; a slice holds every message of its times).

    Yields
    ------
    dict
        Topic -> the rows of its frame in the slice (views, not copies).
    """
    cuts = _slice_cuts(_times(frames), size)
    if cuts is None or not len(cuts):
        yield frames
        return
    for batch in _cut(frames, cuts):
        if batch:
            yield batch


_FEED_CHUNKS = 16   # a copied file's chunks per extra slice boundary
_READ_AHEAD = 2     # batches of a copied file read (decompressed, CRC-checked) ahead by a thread


class _ReadAhead:
    """The items of iterator ``it``, produced by a thread up to ``depth`` ahead of the
    caller (zstd decompression and the CRC release the GIL: the copied file's chunks are
    unpacked on another core while the caller encodes). An exception of ``it`` is raised
    by the :func:`next` that would have returned its item; :meth:`close` stops the thread
    (it must be called before the source ``it`` reads is closed)."""

    _END = object()

    def __init__(self, it, depth: int = _READ_AHEAD):
        import queue
        import threading

        self._q: queue.Queue = queue.Queue(depth)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(it,), name="usvlog-mcap-read", daemon=True)
        self._thread.start()

    def _run(self, it) -> None:
        try:
            for item in it:
                self._q.put((item, None))
                if self._stop.is_set():
                    return
            self._q.put((self._END, None))
        except BaseException as err:  # noqa: BLE001 - handed to the caller's next()
            self._q.put((None, err))

    def __iter__(self):
        return self

    def __next__(self):
        item, err = self._q.get()
        if err is not None:
            self._stop.set()
            raise err
        if item is self._END:
            self._stop.set()
            raise StopIteration
        return item

    def close(self) -> None:
        """Stop the thread (waits for the item it is producing) and drop what it read."""
        import queue

        self._stop.set()
        while self._thread.is_alive():
            try:   # make room: the thread may be waiting to put an item
                self._q.get(timeout=0.05)
            except queue.Empty:
                pass
        self._thread.join()


class _RawFeed:
    """The message payloads of channels of a canonical file, by time slice, as they are
    stored (for :func:`write_log` to copy without decoding).

    Memory: the decompressed chunks read ahead of the slice being written, whose payloads
    are copied straight into the message records (a file usvlog wrote is in time order, so
    about one slice plus one chunk; one slice holding everything when the log's frames do
    not rise in time).
    """

    def __init__(self, src: DeferredSource, topics: list[str]):
        self._src = src
        # the reader's walk: CRC checks, chunks without these channels skipped (chunk index)
        self._stream = ChunkStream(src.path, topics=topics)
        self._topics = set(topics)
        self._it = None
        self._done = False
        self._seen = np.iinfo(np.int64).min        # latest time read so far (ns)
        self._emitted = np.iinfo(np.int64).min     # every message before this time was handed out
        self._last: dict[str, tuple[int, int]] = {}  # topic -> (time, sequence) of its last message read
        self._held: list = []   # per batch read: (its bytes, {topic: (times, payload starts, ends)})

    def cuts(self, cuts: np.ndarray) -> np.ndarray:
        """``cuts`` plus the start time of every :data:`_FEED_CHUNKS`-th chunk of the file
        (so the copied payloads are sliced too)."""
        spans = chunk_spans(self._src.path)
        if spans is None:
            return cuts
        t0 = sorted(a for a, _b, _topics in spans)[::_FEED_CHUNKS][1:]
        return np.union1d(cuts, np.asarray(t0, dtype=np.int64))

    def _pull(self) -> bool:
        """Read the next batch of messages; False at the end of the file."""
        if self._it is None:
            self._it = _ReadAhead(self._stream._batches())
        try:
            records, at, _t0, _t1, cid, seq, t, ps, pe, _ordinal = next(self._it)
        except StopIteration:
            self._done = True
            return False
        if len(t):
            if int(t.min()) < self._emitted:
                raise _OutOfOrder
            self._seen = max(self._seen, int(t.max()))
        chans = self._stream._scan.channels
        held = {}
        for c in np.unique(cid).tolist():
            topic = chans[c].topic
            if topic not in self._topics:
                continue
            sel = np.flatnonzero(cid == c)
            tc, sc = t[sel], seq[sel]
            prev = self._last.get(topic)
            if (len(tc) > 1 and (np.any(tc[1:] < tc[:-1]) or np.any(sc[1:] < sc[:-1]))) or \
                    (prev is not None and (int(tc[0]) < prev[0] or int(sc[0]) < prev[1])):
                raise _OutOfOrder
            self._last[topic] = (int(tc[-1]), int(sc[-1]))
            held[topic] = (tc, ps[sel], pe[sel])
        if held:
            if at < 0:   # messages outside chunks: spans in the file's bytes, copied out
                lo = min(int(v[1].min()) for v in held.values())
                hi = max(int(v[2].max()) for v in held.values())
                buf = np.frombuffer(bytes(records[lo:hi]), dtype=np.uint8)
                held = {k: (v[0], v[1] - lo, v[2] - lo) for k, v in held.items()}
            else:        # a chunk's records: the payloads are copied from it when written
                buf = np.frombuffer(records, dtype=np.uint8) if not isinstance(records, np.ndarray) else records
            self._held.append((buf, held))
        return True

    def take(self, upto: int | None) -> dict[str, list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]]:
        """The payloads of every message before ``upto`` (ns; None: all the rest), topic ->
        pieces (times, buffer, payload starts, payload ends), in row order."""
        while not self._done and (upto is None or self._seen < upto):
            self._pull()
        out: dict[str, list] = {}
        keep = []
        for buf, held in self._held:
            rest = {}
            for topic, (t, ps, pe) in held.items():
                n = len(t) if upto is None else int(np.searchsorted(t, upto, side="left"))
                if n:
                    out.setdefault(topic, []).append((t[:n], buf, ps[:n], pe[:n]))
                if n < len(t):
                    rest[topic] = (t[n:], ps[n:], pe[n:])
            if rest:
                keep.append((buf, rest))
        self._held = keep
        if upto is not None:
            self._emitted = max(self._emitted, upto)
        return out

    def finish(self) -> None:
        """After the last slice: the file must have read intact and be unchanged."""
        assert self._done and not self._held
        rep = self._stream.recovery()
        why = self._src.changed()
        if rep is not None or why is not None:
            raise InputError(f"{self._src.path} {why or 'is damaged: ' + rep.reason} since it was read; "
                             "load the log again")

    def close(self) -> None:
        if self._it is not None:
            self._it.close()   # the thread stops before the file it reads is closed
        self._stream.close()


def _pack_chunk(comp: str, level: int, data: bytes) -> tuple[bytes, str, int]:
    """(compressed bytes, compression name, CRC-32 of ``data``) of one chunk's records;
    runs on a worker thread (zstd and lz4 release the GIL; the CRC is ~0.1 ms a megabyte)."""
    if comp == "zstd":
        import zstandard  # only the compressor the file uses is loaded

        packed, cname = zstandard.ZstdCompressor(level=level).compress(data), "zstd"
    elif comp == "lz4":
        import lz4.frame  # only the compressor the file uses is loaded

        packed, cname = lz4.frame.compress(data), "lz4"
    else:
        packed, cname = data, ""
    return packed, cname, crc32(data)


_WORKERS = max(1, min(4, (os.cpu_count() or 1) - 1))   # chunk compression threads
_PENDING_BYTES = 16 << 20   # uncompressed bytes of chunks waiting for (or in) compression at most
_CHUNK_HEAD = struct.Struct("<QQQII")   # Chunk record: start, end time, size, CRC, compression name length


class McapWriter:
    """Canonical MCAP file written incrementally on an open binary file ``fh``.

    The one MCAP writing path of usvlog: :func:`write_log` writes a whole log through
    it, the importer streams batches of frames into it. Records and chunks are those
    the mcap library's ``Writer`` writes for the same calls (byte for byte:
    ``_write_log_reference`` does it that way and the tests compare): schema and
    channel records open the chunk that follows their registration; a chunk is
    closed after the message that takes it past ``chunk_size``; then message
    indexes, and at :meth:`finish` the Data End record with the data section's CRC
    (metadata records have no CRC of their own: this one lets a reader tell that one
    was damaged) and the summary (schemas, channels, statistics, chunk and metadata
    indexes). Message records are built by compiled loops from the
    packed output of :meth:`usvlog.io.mcap.codec.Codec.encode_packed`.

    Memory stays flat when streaming: only the open chunk (at most ``chunk_size``
    plus one batch: a chunk is a view of the batch's records, not a copy) and the chunks
    being compressed (at most ``_PENDING_BYTES`` uncompressed) are held. Chunks are
    compressed on ``threads`` worker threads (default: one fewer than the CPUs, 1 to 4; 0
    compresses in the calling thread) while the caller encodes the next batch, and
    written in order; :meth:`flush` and :meth:`finish` wait for them. Each message's
    ``sequence`` is its row number in its channel over all batches, as :func:`read_log` expects; within a batch messages
    are ordered by (time, channel, row).
    """

    def __init__(self, fh, *, chunk_size: int = 1 << 20, compression: str = "zstd", zstd_level: int = ZSTD_LEVEL,
                 threads: int | None = None):
        # start-up: the mcap library loads on first write, not on read
        from mcap.records import Header

        self._fh = fh
        self._chunk_size = int(chunk_size)
        self._comp = _compression(compression)
        self._zstd_level = int(zstd_level)
        self._pos = 0
        self._data_crc: int | None = 0   # CRC of the data section so far (None once it is closed)
        self._schemas: list = []
        self._schema_ids: dict[tuple[str, bytes], int] = {}
        self._channels: list = []
        self._topics: dict[str, tuple[int, Codec]] = {}
        self._seq: dict[int, int] = {}
        self._counts: dict[int, int] = {}         # channel id -> messages, in order of the first message
        self._chunk_indexes: list = []
        self._meta_index: list = []
        self._t_min: int | None = None
        self._t_max: int | None = None
        self._n = 0
        # the open chunk: its bytes (pieces: records, views of a batch's records), their
        # total length, and its messages' times, channels, offsets in it
        self._open: list = []
        self._open_len = 0
        self._open_msgs: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        # chunks being compressed on worker threads, written in order as they are done
        self._threads = _WORKERS if threads is None else int(threads)
        self._pool = None
        self._pending: deque = deque()
        self._pending_bytes = 0   # uncompressed bytes of the chunks in self._pending
        self._write(MAGIC)
        self._write(self._record(Header(profile="", library=f"usvlog {__version__}")))

    # -- low level -------------------------------------------------------------------
    def _write(self, b) -> int:
        at = self._pos
        self._fh.write(b)
        if self._data_crc is not None:
            self._data_crc = crc32(b, self._data_crc)
        self._pos += len(b)
        return at

    @staticmethod
    def _record(rec) -> bytes:
        # start-up: the mcap library loads on first write, not on read
        from mcap.data_stream import RecordBuilder

        rb = RecordBuilder()
        rec.write(rb)
        return rb.end()

    # -- channels and metadata -----------------------------------------------------------
    def add_channel(self, topic: str, schema: dict | None = None, frame: pd.DataFrame | None = None) -> int:
        """Register ``topic`` (once; its schema: the registered one, else ``schema``, else one
        generated from ``frame``); returns the channel id."""
        # start-up: the mcap library loads on first write, not on read
        from mcap.records import Channel, Schema

        known = self._topics.get(topic)
        if known is not None:
            return known[0]
        schema, codec = _codec_for(topic, schema, frame)
        sname, senc, sdata = _schema_record(topic, schema, codec)
        sid = self._schema_ids.get((sname, sdata))
        if sid is None:
            sid = self._schema_ids[(sname, sdata)] = len(self._schemas) + 1
            self._schemas.append(Schema(id=sid, name=sname, encoding=senc, data=sdata))
            self._add_open(self._record(self._schemas[-1]))
        cid = len(self._channels) + 1
        self._channels.append(Channel(id=cid, topic=topic, message_encoding=codec.message_encoding, schema_id=sid,
                                      metadata={}))
        self._add_open(self._record(self._channels[-1]))
        self._topics[topic] = (cid, codec)
        self._seq[cid] = 0
        return cid

    def _add_open(self, b) -> None:
        self._open.append(b)
        self._open_len += len(b)

    def add_metadata(self, name: str, record: dict) -> None:
        """A metadata record (values stored as strings), after the messages written so far."""
        # start-up: the mcap library loads on first write, not on read
        from mcap.records import Metadata, MetadataIndex

        self.flush()
        b = self._record(Metadata(name=name, metadata={str(k): str(v) for k, v in record.items()}))
        self._meta_index.append(MetadataIndex(offset=self._write(b), length=len(b), name=name))

    # -- messages ------------------------------------------------------------------------
    def add_frames(self, frames: dict[str, pd.DataFrame], schemas: dict[str, dict] | None = None,
                   raw: dict[str, list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]] | None = None) -> None:
        """Append one batch: every row of every frame (index: int64 log time ns) as a message.

        ``raw`` adds messages already encoded, topic -> pieces (int64 log times in ns, a
        uint8 buffer, int64 starts and ends of the payloads in it), in the channel's row
        order (pieces may share a buffer): their channel must be registered
        (:meth:`add_channel`) and the payloads be what its codec writes (e.g. copied from
        a file whose channel has the same schema record).
        """
        pieces: list[tuple[str, int, np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
        for topic, frame in frames.items():
            if not len(frame):
                continue
            cid = self.add_channel(topic, (schemas or {}).get(topic), frame)
            data, offs = self._topics[topic][1].encode_packed(frame, topic)
            pieces.append((topic, cid, np.asarray(frame.index, dtype=np.int64), data, offs[:-1], offs[1:]))
        for topic, parts in (raw or {}).items():
            pieces += [(topic, self._topics[topic][0], *p) for p in parts if len(p[0])]
        # by channel id (stable: a channel's pieces stay in row order), so that the messages
        # in (time, channel, row) order are a stable sort by time of the concatenation
        pieces.sort(key=lambda p: p[1])
        bufs, ts, cids, seqs, starts, ends = [], [], [], [], [], []
        bases: dict[int, int] = {}   # id of a buffer -> where it starts in the batch's bytes
        base = 0
        for topic, cid, t, data, ps, pe in pieces:
            if t.min() < 0:
                raise InputError(f"channel {topic}: negative time stamp at row {int(np.argmin(t))}")
            s0 = self._seq[cid]
            self._seq[cid] = s0 + len(t)
            at = bases.get(id(data))
            if at is None:
                at = bases[id(data)] = base
                bufs.append(data)
                base += len(data)
            ts.append(t)
            cids.append(np.full(len(t), cid, dtype=np.int64))
            seqs.append(np.arange(s0, s0 + len(t), dtype=np.int64))
            starts.append(ps + at)
            ends.append(pe + at)
        if not ts:
            return
        t_all, c_all, s_all = np.concatenate(ts), np.concatenate(cids), np.concatenate(seqs)
        order = np.argsort(t_all, kind="stable")   # = np.lexsort((s_all, c_all, t_all)): see above
        t_all, c_all, s_all = t_all[order], c_all[order], s_all[order]
        recs, rec_offs = K.message_records(np.concatenate(bufs), np.concatenate(starts)[order],
                                           np.concatenate(ends)[order], c_all, s_all, t_all)
        _, first = np.unique(c_all, return_index=True)
        for cid in c_all[np.sort(first)].tolist():
            self._counts.setdefault(cid, 0)
        counts = np.bincount(c_all)
        for cid in self._counts:
            if cid < len(counts):
                self._counts[cid] += int(counts[cid])
        self._n += len(t_all)
        self._t_min = int(t_all[0]) if self._t_min is None else min(self._t_min, int(t_all[0]))
        self._t_max = int(t_all[-1]) if self._t_max is None else max(self._t_max, int(t_all[-1]))
        bounds = K.chunk_bounds(rec_offs, self._chunk_size, self._open_len).tolist()
        view = memoryview(recs)   # the chunks hold views of the batch's records (no copy)
        a = 0
        for k, b in enumerate(bounds):
            at = self._open_len
            self._add_open(view[rec_offs[a]:rec_offs[b]])
            self._open_msgs.append((t_all[a:b], c_all[a:b], rec_offs[a:b] - rec_offs[a] + at))
            if k < len(bounds) - 1 or self._open_len > self._chunk_size:
                self._close_chunk()
            a = b

    def flush(self) -> None:
        """Close the open chunk now (if it holds messages): what was added so far is on ``fh``."""
        if self._open_msgs:
            self._close_chunk()
        while self._pending:
            self._emit(*self._pending.popleft())

    def _close_chunk(self) -> None:
        # one piece (most chunks: a run of one batch's records) is compressed as it is
        data = self._open[0] if len(self._open) == 1 else b"".join(self._open)
        tc = np.concatenate([m[0] for m in self._open_msgs])
        cc = np.concatenate([m[1] for m in self._open_msgs])
        in_chunk = np.concatenate([m[2] for m in self._open_msgs])
        self._open = []
        self._open_len = 0
        self._open_msgs = []
        if self._threads <= 0 or self._comp == "none":
            self._emit(_pack_chunk(self._comp, self._zstd_level, data), data, tc, cc, in_chunk)
            return
        if self._pool is None:
            from concurrent.futures import ThreadPoolExecutor  # only when a chunk is compressed

            self._pool = ThreadPoolExecutor(self._threads, thread_name_prefix="usvlog-mcap-zstd")
        self._pending.append((self._pool.submit(_pack_chunk, self._comp, self._zstd_level, data),
                              data, tc, cc, in_chunk))
        self._pending_bytes += len(data)
        # at most _PENDING_BYTES in flight (the threads compress while the caller encodes the
        # next batch): memory stays bounded by them
        while self._pending_bytes > _PENDING_BYTES or (self._pending and self._pending[0][0].done()):
            self._emit(*self._pending.popleft())

    def _emit(self, packed, data: bytes, tc: np.ndarray, cc: np.ndarray, in_chunk: np.ndarray) -> None:
        """Write one chunk record (``packed``: (bytes, compression, CRC) or its future) and
        its message indexes."""
        # start-up: the mcap library loads on first write, not on read
        from mcap.opcode import Opcode
        from mcap.records import ChunkIndex

        if not isinstance(packed, tuple):
            packed = packed.result()
            self._pending_bytes -= len(data)
        packed, cname, crc = packed
        t0, t1 = int(tc.min()), int(tc.max())
        # the Chunk record (mcap.records.Chunk's bytes), its compressed records written as they are
        cn = cname.encode()
        head = _CHUNK_HEAD.pack(t0, t1, len(data), crc, len(cn)) + cn + struct.pack("<Q", len(packed))
        chunk_at = self._write(_REC.pack(Opcode.CHUNK, len(head) + len(packed)) + head)
        self._write(packed)
        rec_len = _REC.size + len(head) + len(packed)
        # one Message Index record per channel, in order of the channel's first message in the chunk
        ids, counts, entries = K.message_index(cc, tc, in_chunk)
        index_at = self._pos
        offsets = {}
        parts = []
        at, e0 = index_at, 0
        for cid, m in zip(ids.tolist(), counts.tolist()):
            nb = 16 * m
            parts.append(_REC.pack(Opcode.MESSAGE_INDEX, 6 + nb) + struct.pack("<HI", cid, nb))
            parts.append(entries[e0:e0 + m].tobytes())
            offsets[cid] = at
            at += _REC.size + 6 + nb
            e0 += m
        self._write(b"".join(parts))
        self._chunk_indexes.append(ChunkIndex(
            message_start_time=t0, message_end_time=t1, chunk_start_offset=chunk_at,
            chunk_length=rec_len, message_index_offsets=offsets,
            message_index_length=self._pos - index_at, compression=cname,
            compressed_size=len(packed), uncompressed_size=len(data)))

    def close(self) -> None:
        """Stop the compression threads (after :meth:`finish`, or to give up a file half
        written: chunks not yet written are dropped)."""
        self._pending.clear()
        self._pending_bytes = 0
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None

    # -- the end ------------------------------------------------------------------------
    def finish(self) -> None:
        """Close the open chunk, write the summary and the footer (the file stays open)."""
        # start-up: the mcap library loads on first write, not on read
        from mcap.data_stream import RecordBuilder
        from mcap.opcode import Opcode
        from mcap.records import DataEnd, Footer, Statistics, SummaryOffset

        self.flush()
        self.close()
        crc, self._data_crc = self._data_crc, None
        self._write(self._record(DataEnd(crc)))
        # summary: the same groups, in the same order, as the mcap Writer
        summary_start = self._pos
        sb = RecordBuilder()
        groups = []

        def group(opcode, records) -> None:
            g0 = sb.count
            for r in records:
                r.write(sb)
            groups.append(SummaryOffset(group_opcode=opcode, group_start=summary_start + g0,
                                        group_length=sb.count - g0))

        stats = Statistics(attachment_count=0, channel_count=len(self._channels),
                           channel_message_counts=dict(self._counts), chunk_count=len(self._chunk_indexes),
                           message_count=self._n, metadata_count=len(self._meta_index),
                           message_start_time=self._t_min or 0, message_end_time=self._t_max or 0,
                           schema_count=len(self._schemas))
        group(Opcode.SCHEMA, self._schemas)
        group(Opcode.CHANNEL, self._channels)
        group(Opcode.STATISTICS, [stats])
        group(Opcode.CHUNK_INDEX, self._chunk_indexes)
        group(Opcode.ATTACHMENT_INDEX, [])
        group(Opcode.METADATA_INDEX, self._meta_index)
        summary_offset_start = summary_start + sb.count
        for g in groups:
            g.write(sb)
        summary = sb.end()
        crc = crc32(summary)
        crc = crc32(struct.pack("<BQQQ", Opcode.FOOTER, 20, summary_start, summary_offset_start), crc)
        self._write(summary)
        self._write(self._record(Footer(summary_start=summary_start, summary_offset_start=summary_offset_start,
                                        summary_crc=crc)))
        self._write(MAGIC)
