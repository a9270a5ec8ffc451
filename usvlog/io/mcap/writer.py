"""The one MCAP writer: :class:`McapWriter` (streaming) and :func:`write_log` (a whole log).

Message and index records are built with compiled loops (:mod:`.kernels`); the bytes are
the mcap library's ``Writer``'s for the same messages (:mod:`.reference` keeps that path).
"""

from __future__ import annotations

import json
import os
import struct
import threading
from collections import deque
from typing import TYPE_CHECKING

import numpy as np

from ..._cpu import spare_cpu
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
    _U64,
    MAGIC,
    crc32,
)
from .stream import ChunkStream, channel_ids

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
    messages, so the encoding's memory is bounded by a slice, not by the log.
    Metadata records come first (a truncated file keeps them), then every channel's
    schema and channel records, then chunks each holding one channel's messages in
    (time, row) order (:class:`McapWriter`); the message records are the mcap library's
    ``Writer``'s for the same messages (``_write_log_reference``, the tests compare).

    A channel still deferred (``log.deferred``: read from a file and never touched) is
    copied from that file without decoding it when the file stores it with the schema
    record and message encoding this writer uses for it, keeping its channel id: a chunk
    of the file holding that channel alone, in the order and with the sequence numbers a
    usvlog file has and the writer's compression, is copied whole (its compressed bytes
    and CRC as they are, after its CRC was checked), other messages payload by payload;
    the same messages as after decoding it. It is decoded instead when the file stores it
    otherwise, when the log was read with damage recovered, or when its messages are not
    in the time and sequence order a usvlog file has; a file changed or damaged since it
    was read (size or modification time, a chunk's CRC) is refused (:class:`InputError`).
    """
    _compression(compression)
    ids = _channel_ids(log, log.deferred)
    copy = _copied_channels(log)
    with atomic_path(path, force=force) as tmp:
        if copy:
            try:
                _write(log, tmp, chunk_size, compression, zstd_level, slice_messages, copy, ids)
                return
            except _OutOfOrder:   # the source's messages are not in time/row order: decode them
                assert isinstance(log.channels, Channels)
                log.channels.load_deferred(copy)
        _write(log, tmp, chunk_size, compression, zstd_level, slice_messages, [], ids)


def _write(log: FieldLog, tmp, chunk_size: int, compression: str, zstd_level: int, slice_messages: int,
           copy: list[str], ids: dict[str, int]) -> None:
    """:func:`write_log` to ``tmp``, the channels ``copy`` from the log's source file, the
    channels under the ids ``ids`` (:func:`_channel_ids`)."""
    decoded = log.channels.decoded() if isinstance(log.channels, Channels) else log.channels
    frames = {topic: decoded[topic] for topic in log.topics if topic not in copy}
    with open(tmp, "wb", buffering=1 << 20) as fh:
        w = McapWriter(fh, chunk_size=chunk_size, compression=compression, zstd_level=zstd_level)
        feed = None
        try:
            for name in sorted(log.meta):
                w.add_metadata(name, log.meta[name])
            src = log.deferred
            for topic, cid in sorted(ids.items(), key=lambda kv: kv[1]):   # records in id order
                w.add_channel(topic, log.schemas.get(topic), frames.get(topic), channel_id=cid)
            if not copy:
                for batch in time_slices(frames, slice_messages):
                    w.add_frames(batch, log.schemas)
            else:
                assert src is not None
                feed = _RawFeed(src, copy, {t: w.add_channel(t) for t in copy})
                cuts = _slice_cuts(_times(frames), slice_messages)
                # frames whose times do not rise: one slice
                cuts = np.zeros(0, dtype=np.int64) if cuts is None else cuts
                feed.start()
                for k, batch in enumerate(_cut(frames, cuts)):
                    # the slice encoded while the read-ahead thread reads the source's chunks
                    # ending in it, then both into chunks
                    per = w._encode_frames(batch, log.schemas)
                    w._add_encoded(per, *feed.take(int(cuts[k]) if k < len(cuts) else None))
                feed.finish()
            w.finish()
        finally:
            w.close()
            if feed is not None:
                feed.close()


def _channel_ids(log: FieldLog, src: DeferredSource | None) -> dict[str, int]:
    """Topic -> channel id in the file written: the channels of ``src`` (the file the log's
    deferred channels are in) keep their ids there (its chunks are copied whole), the others
    take the lowest ids left in the log's channel order (a log read from a file lists its
    channels in their order there, so a log read and written again keeps the file's ids)."""
    ids = {t: c for t, c in channel_ids(src.path).items() if t in log.channels} if src is not None else {}
    free = (c for c in range(1, 1 << 16) if c not in ids.values())
    for topic in log.channels:
        if topic not in ids:
            ids[topic] = next(free)
    return ids


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


_READ_AHEAD = 16    # batches (chunks) of a copied file read (decompressed, CRC-checked) ahead by a thread:
                    # a slice's worth (~1.5 MB each), read while the slice is encoded


class _ReadAhead:
    """The items of iterator ``it``, produced by a thread up to ``depth`` ahead of the
    caller (zstd decompression and the CRC release the GIL: the copied file's chunks are
    unpacked on another core while the caller encodes). An exception of ``it`` is raised
    by the :func:`next` that would have returned its item; :meth:`close` stops the thread
    (it must be called before the source ``it`` reads is closed)."""

    _END = object()

    def __init__(self, it, depth: int = _READ_AHEAD):
        import queue

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


_MSG_HEAD = 9 + 22   # a Message record's bytes before its payload: opcode, length, channel, sequence, times


def _only_messages(records: np.ndarray, ps: np.ndarray, pe: np.ndarray) -> bool:
    """Whether a chunk's records are exactly these message records, back to back, each with
    its publish time equal to its log time (as this writer writes them)."""
    return bool(K.bare_messages(records, ps, pe))


class _RawFeed:
    """The messages of channels of a canonical file, as they are stored, handed to a
    :class:`McapWriter` for :func:`write_log` to copy without decoding.

    The file is walked in its order (every chunk decompressed and its CRC checked, on a
    read-ahead thread; chunks holding none of the channels skipped). A chunk holding
    messages of one copied channel only, nothing else, in the order and with the
    sequence numbers the writer gives them, under the same channel id, is copied whole:
    its record's bytes as they are (compressed data, CRC), its message index rebuilt
    (:meth:`McapWriter.add_chunk`). Other messages of the channels (chunks holding
    several channels, messages outside chunks) are copied payload by payload into the
    writer's own chunks. Memory: the chunks read ahead.
    """

    def __init__(self, src: DeferredSource, topics: list[str], ids: dict[str, int]):
        self._src = src
        # the reader's walk: CRC checks, chunks without these channels skipped (chunk index)
        self._stream = ChunkStream(src.path, topics=topics)
        self._topics = set(topics)
        self._ids = ids          # topic -> its channel id in the file written
        self._it = None
        self._next = None        # the batch read and not yet handed on
        self._done = False
        self._last: dict[str, tuple[int, int]] = {}  # topic -> (time, sequence) of its last message read

    def _batches(self):
        """The walk's batches, each with the bytes of its chunk record when it may be copied
        whole (one channel; runs on the read-ahead thread)."""
        m = self._stream._map
        for b in self._stream._batches():
            at, cid = b[1], b[4]
            rec = None
            if at >= 0 and cid[0] == cid[-1] and np.all(cid == cid[0]):
                rec = bytes(m[at:at + _REC.size + _U64.unpack_from(m, at + 1)[0]])
            yield b, rec

    def start(self) -> None:
        """Start reading ahead (else the first :meth:`take` does)."""
        if self._it is None:   # on a second thread when a CPU is spare, else here as it is taken
            self._it = _ReadAhead(self._batches()) if spare_cpu() else self._batches()

    def _peek(self):
        if self._next is None and not self._done:
            self.start()
            try:
                self._next = next(self._it)
            except StopIteration:
                self._done = True
        return self._next

    def take(self, upto: int | None) -> tuple[dict[str, list], list[tuple]]:
        """The batches of the file, in its order, up to the first whose last message is at
        ``upto`` (ns) or later (None: all the rest), for :meth:`McapWriter.add_frames`:
        (topic -> payload pieces, chunks to copy whole). Raises :class:`_OutOfOrder` when a
        channel's messages are not in time and sequence order."""
        raw: dict[str, list] = {}
        chunks: list[tuple] = []
        while True:
            item = self._peek()
            if item is None:
                break
            b, rec = item
            t = b[6]
            if upto is not None and len(t) and int(t.max()) >= upto:
                break
            self._next = None
            self._hand(b, rec, raw, chunks)
        return raw, chunks

    def _hand(self, b, rec, raw: dict[str, list], chunks: list[tuple]) -> None:
        records, at, _t0, _t1, cid, seq, t, ps, pe, _ordinal = b
        chans = self._stream._scan.channels
        one = rec is not None   # a chunk of one channel (_batches checked): its messages as they are
        for c in [int(cid[0])] if one else np.unique(cid).tolist():
            topic = chans[c].topic
            if topic not in self._topics:
                continue
            sel = slice(None) if one else np.flatnonzero(cid == c)
            tc, sc = t[sel], seq[sel]
            prev = self._last.get(topic)
            if (len(tc) > 1 and (np.any(tc[1:] < tc[:-1]) or np.any(sc[1:] < sc[:-1]))) or \
                    (prev is not None and (int(tc[0]) < prev[0] or int(sc[0]) < prev[1])):
                raise _OutOfOrder
            self._last[topic] = (int(tc[-1]), int(sc[-1]))
            if at < 0:   # messages outside chunks: spans in the file's bytes, copied out
                lo, hi = int(ps[sel].min()), int(pe[sel].max())
                buf = np.frombuffer(bytes(records[lo:hi]), dtype=np.uint8)
                raw.setdefault(topic, []).append((tc, buf, ps[sel] - lo, pe[sel] - lo))
                continue
            buf = np.frombuffer(records, dtype=np.uint8) if not isinstance(records, np.ndarray) else records
            if rec is not None and c == self._ids.get(topic) and _only_messages(buf, ps, pe):
                chunks.append((topic, rec, tc, sc, buf, ps, pe))
            elif chunks and any(ch[0] == topic for ch in chunks):   # keep the channel's order
                chunks.append((topic, None, tc, sc, buf, ps[sel], pe[sel]))
            else:
                raw.setdefault(topic, []).append((tc, buf, ps[sel], pe[sel]))

    def finish(self) -> None:
        """After the last batch: the file must have read intact and be unchanged."""
        assert self._done and self._next is None
        rep = self._stream.recovery()
        why = self._src.changed()
        if rep is not None or why is not None:
            raise InputError(f"{self._src.path} {why or 'is damaged: ' + rep.reason} since it was read; "
                             "load the log again")

    def close(self) -> None:
        if self._it is not None:
            self._it.close()   # the thread stops before the file it reads is closed
        self._stream.close()


_TLS = threading.local()


def _zstd(level: int):
    """This thread's zstd compressor of ``level``, made once (a compressor's context is
    reused chunk after chunk: the same bytes, without allocating it again each time)."""
    zs = getattr(_TLS, "zstd", None)
    if zs is None:
        zs = _TLS.zstd = {}
    z = zs.get(level)
    if z is None:
        import zstandard  # only the compressor the file uses is loaded

        z = zs[level] = zstandard.ZstdCompressor(level=level)
    return z


def _pack_chunk(comp: str, level: int, data: bytes) -> tuple[bytes, str, int]:
    """(compressed bytes, compression name, CRC-32 of ``data``) of one chunk's records;
    runs on a worker thread (zstd and lz4 release the GIL; the CRC is ~0.1 ms a megabyte)."""
    if comp == "zstd":
        packed, cname = _zstd(level).compress(data), "zstd"
    elif comp == "lz4":
        import lz4.frame  # only the compressor the file uses is loaded

        packed, cname = lz4.frame.compress(data), "lz4"
    else:
        packed, cname = data, ""
    return packed, cname, crc32(data)


def _workers() -> int:
    """Chunk compression threads: as many as the CPUs this process may use (1 to 4), since
    compression is the write's largest work and when the caller waits for it (chunks pending,
    or the last ones) every core compresses; none (compression in the calling thread) without a
    spare CPU (``USVLOG_THREADS=1``, a process pinned to one CPU)."""
    if not spare_cpu():
        return 0
    try:
        n = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):   # no affinity mask on this system
        n = os.cpu_count() or 1
    return max(1, min(4, n))


_PENDING_BYTES = 16 << 20   # uncompressed bytes of chunks waiting for (or in) compression at most
_CHUNK_HEAD = struct.Struct("<QQQII")   # Chunk record: start, end time, size, CRC, compression name length


class McapWriter:
    """Canonical MCAP file written incrementally on an open binary file ``fh``.

    The one MCAP writing path of usvlog: :func:`write_log` writes a whole log through
    it, the importer streams batches of frames into it. Schema and channel records are
    written (outside chunks) when a channel is registered. Each channel's messages go
    into chunks of their own (a reader wanting some channels skips the others' chunks
    by the chunk index, and a copy takes a chunk whole): a channel's chunk is closed
    after the message that takes it past ``chunk_size`` (as the mcap library's
    ``Writer`` closes its one chunk), then its message index follows it; chunks closed
    by one batch are written in order of their last message's time (then channel id),
    so the file is in about time order and its bytes do not depend on how the messages
    were cut into batches. At :meth:`finish` come the Data End record with the data
    section's CRC (metadata records have no CRC of their own: this one lets a reader
    tell that one was damaged) and the summary (schemas, channels, statistics, chunk and
    metadata indexes). Message records are built by compiled loops from the packed
    output of :meth:`usvlog.io.mcap.codec.Codec.encode_packed`; their bytes are the
    mcap library's for the same messages.

    Memory stays flat when streaming: only the open chunks (at most ``chunk_size`` per
    channel plus one batch: a chunk is a view of the batch's records, not a copy) and
    the chunks being compressed (at most ``_PENDING_BYTES`` uncompressed) are held.
    Chunks are compressed on ``threads`` worker threads (default: one per CPU this process
    may use, 1 to 4, none without a spare CPU (``USVLOG_THREADS=1``); 0 compresses in the
    calling thread) while the caller encodes the next
    batch, and written in order; :meth:`flush` and :meth:`finish` wait for them. Each
    message's ``sequence`` is its row number in its channel over all batches, as
    :func:`read_log` expects; within a chunk messages are in (time, row) order.
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
        self._counts: dict[int, int] = {}         # channel id -> messages
        self._order: dict[int, None] = {}         # channel ids in order of their first chunk in the file
        self._chunk_indexes: list = []
        self._meta_index: list = []
        self._t_min: int | None = None
        self._t_max: int | None = None
        self._n = 0
        # the open chunk of each channel: its bytes (pieces: views of a batch's records),
        # their total length, and its messages' times and offsets in it
        self._open: dict[int, list] = {}
        self._open_len: dict[int, int] = {}
        self._open_msgs: dict[int, list[tuple[np.ndarray, np.ndarray]]] = {}
        self._open_copy: dict[int, tuple] = {}   # channel id -> its last chunk, copied, not yet written
        self._mine: set[int] = set()   # ids of the buffers of the batch being added this writer encoded
        # chunks being compressed on worker threads, written in order as they are done
        self._threads = _workers() if threads is None else int(threads)
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
    def add_channel(self, topic: str, schema: dict | None = None, frame: pd.DataFrame | None = None,
                    channel_id: int | None = None) -> int:
        """Register ``topic`` (once; its schema: the registered one, else ``schema``, else one
        generated from ``frame``) and write its schema and channel records; returns the
        channel id: ``channel_id`` when given (it must be free), else the lowest free one."""
        # start-up: the mcap library loads on first write, not on read
        from mcap.records import Channel, Schema

        known = self._topics.get(topic)
        if known is not None:
            return known[0]
        used = {c.id for c in self._channels}
        if channel_id is not None and (channel_id in used or not 0 < channel_id < 1 << 16):
            raise ValueError(f"channel {topic}: id {channel_id} is taken or out of range")
        cid = channel_id if channel_id is not None else min(set(range(1, len(used) + 2)) - used)
        schema, codec = _codec_for(topic, schema, frame)
        sname, senc, sdata = _schema_record(topic, schema, codec)
        sid = self._schema_ids.get((sname, sdata))
        if sid is None:
            sid = self._schema_ids[(sname, sdata)] = len(self._schemas) + 1
            self._schemas.append(Schema(id=sid, name=sname, encoding=senc, data=sdata))
            self._write(self._record(self._schemas[-1]))
        self._channels.append(Channel(id=cid, topic=topic, message_encoding=codec.message_encoding, schema_id=sid,
                                      metadata={}))
        self._write(self._record(self._channels[-1]))
        self._topics[topic] = (cid, codec)
        self._seq[cid] = 0
        return cid

    def add_metadata(self, name: str, record: dict) -> None:
        """A metadata record (values stored as strings), after the messages written so far."""
        # start-up: the mcap library loads on first write, not on read
        from mcap.records import Metadata, MetadataIndex

        self.flush()
        b = self._record(Metadata(name=name, metadata={str(k): str(v) for k, v in record.items()}))
        self._meta_index.append(MetadataIndex(offset=self._write(b), length=len(b), name=name))

    # -- messages ------------------------------------------------------------------------
    def add_frames(self, frames: dict[str, pd.DataFrame], schemas: dict[str, dict] | None = None,
                   raw: dict[str, list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]] | None = None,
                   chunks: list[tuple] | None = None) -> None:
        """Append one batch: every row of every frame (index: int64 log time ns) as a message.

        ``raw`` adds messages already encoded, topic -> pieces (int64 log times in ns, a
        uint8 buffer, int64 starts and ends of the payloads in it), in the channel's row
        order (pieces may share a buffer): their channel must be registered
        (:meth:`add_channel`) and the payloads be what its codec writes (e.g. copied from
        a file whose channel has the same schema record).

        ``chunks`` adds chunk records of another file to copy as they are (their compressed
        bytes and CRC), ``(topic, record, times, sequences, buffer, starts, ends)``: the
        whole Chunk record (opcode and length included), holding message records of
        ``topic`` only, back to back, under this file's channel id for it, with publish
        time = log time (the caller checks, e.g. from the walk that verified the chunk's
        CRC), and its messages' int64 log times (ns), sequence numbers and payload spans in
        ``buffer`` (the decompressed records). A chunk is copied when its compression is
        this writer's, its times rise and its sequence numbers are the next rows of the
        channel (those this writer gives them); else its payloads are added as ``raw``
        ones. A channel's raw pieces come before its chunks in the batch.
        """
        self._add_encoded(self._encode_frames(frames, schemas), raw, chunks)

    def _encode_frames(self, frames: dict[str, pd.DataFrame], schemas: dict[str, dict] | None) -> dict[int, list]:
        """The first half of :meth:`add_frames`: the frames' channels registered and their rows
        encoded, channel id -> [(topic, times, buffer, starts, ends)] (pure: nothing written, so
        a caller may encode a batch while another thread reads what goes with it)."""
        per: dict[int, list] = {}
        for topic, frame in frames.items():
            if not len(frame):
                continue
            cid = self.add_channel(topic, (schemas or {}).get(topic), frame)
            # room for the Message records' headers before the payloads (JSON and CDR codecs
            # leave it: the records are then made in place, not copied)
            data, starts, ends = self._topics[topic][1].encode_spans(frame, topic, _MSG_HEAD)
            self._mine.add(id(data))
            per.setdefault(cid, []).append((topic, np.asarray(frame.index, dtype=np.int64), data, starts, ends))
        return per

    def _add_encoded(self, per: dict[int, list], raw: dict[str, list] | None, chunks: list[tuple] | None) -> None:
        """The second half of :meth:`add_frames`: the encoded rows ``per``
        (:meth:`_encode_frames`), then ``raw`` and ``chunks``, into chunks."""
        try:
            self._add_all(per, raw, chunks)
        finally:
            self._mine.clear()

    def _add_all(self, per: dict[int, list], raw: dict[str, list] | None, chunks: list[tuple] | None) -> None:
        for topic, parts in (raw or {}).items():
            per.setdefault(self._topics[topic][0], []).extend((topic, *p) for p in parts if len(p[0]))
        for c in chunks or ():
            per.setdefault(self._topics[c[0]][0], []).append(c)
        closed: list = []
        for cid in sorted(per):
            pieces: list = []
            for item in per[cid]:
                if len(item) == 5:
                    pieces.append(item)
                    continue
                topic, record, t, seq, buf, ps, pe = item
                if record is None or not self._copyable(cid, record, t, seq):
                    pieces.append((topic, t, buf, ps, pe))
                    continue
                self._add_messages(cid, pieces, closed)
                pieces = []
                if cid in self._open_msgs:   # the channel's earlier messages first
                    closed.append(self._take_open(cid))
                self._seq[cid] += len(t)
                self._count(cid, len(t), int(t[0]), int(t[-1]))
                done = ("copy", record, t, np.full(len(t), cid, dtype=np.int64), ps - _MSG_HEAD)
                if _CHUNK_HEAD.unpack_from(record, _REC.size)[2] > self._chunk_size:
                    closed.append(done)           # closed after the message taking it past the size
                else:
                    self._open_copy[cid] = done   # the channel's last chunk: closed by flush()
            self._add_messages(cid, pieces, closed)
        self._submit(closed)

    def _copyable(self, cid: int, record: bytes, t: np.ndarray, seq: np.ndarray) -> bool:
        """Whether a chunk record of another file can be copied whole (see :meth:`add_frames`)."""
        n = len(t)
        if not n or not np.array_equal(seq, np.arange(self._seq[cid], self._seq[cid] + n)) or \
                (n > 1 and not bool(np.all(t[1:] >= t[:-1]))):
            return False
        p = _REC.size + _CHUNK_HEAD.size
        cn_len = _CHUNK_HEAD.unpack_from(record, _REC.size)[4]
        return bytes(record[p:p + cn_len]).decode("ascii", "replace") == {"none": ""}.get(self._comp, self._comp)

    def _add_messages(self, cid: int, pieces: list, closed: list) -> None:
        """One channel's messages of a batch into its open chunk; the chunks they fill go to
        ``closed``."""
        bufs, ts, starts, ends = [], [], [], []
        bases: dict[int, int] = {}   # id of a buffer -> where it starts in the batch's bytes
        base = 0
        for topic, t, data, ps, pe in pieces:
            if t.min() < 0:
                raise InputError(f"channel {topic}: negative time stamp at row {int(np.argmin(t))}")
            at = bases.get(id(data))
            if at is None:
                at = bases[id(data)] = base
                bufs.append(data)
                base += len(data)
            ts.append(t)
            starts.append(ps + at)
            ends.append(pe + at)
        if not ts:
            return
        if cid in self._open_copy:   # a copied chunk the channel's messages follow: closed now
            closed.append(self._open_copy.pop(cid))
        t_all = np.concatenate(ts) if len(ts) > 1 else ts[0]
        n = len(t_all)
        s0 = self._seq[cid]
        self._seq[cid] = s0 + n
        s_all = np.arange(s0, s0 + n, dtype=np.int64)   # row numbers
        ps_all = np.concatenate(starts) if len(starts) > 1 else starts[0]
        pe_all = np.concatenate(ends) if len(ends) > 1 else ends[0]
        if n > 1 and not bool(np.all(t_all[1:] >= t_all[:-1])):   # rows out of time order: by (time, row)
            order = np.argsort(t_all, kind="stable")
            t_all, s_all, ps_all, pe_all = t_all[order], s_all[order], ps_all[order], pe_all[order]
        cids = np.full(n, cid, dtype=np.int64)
        recs = np.concatenate(bufs) if len(bufs) > 1 else bufs[0]
        done = False
        if len(bufs) == 1 and id(recs) in self._mine:   # the records written around the payloads
            done, rec_offs = K.message_headers(recs, ps_all, pe_all, cids, s_all, t_all)
        if not done:
            recs, rec_offs = K.message_records(recs, ps_all, pe_all, cids, s_all, t_all)
        self._count(cid, n, int(t_all.min()), int(t_all.max()))
        open_len = self._open_len.get(cid, 0)
        bounds = K.chunk_bounds(rec_offs, self._chunk_size, open_len).tolist()
        view = memoryview(recs)   # the chunks hold views of the batch's records (no copy)
        a = 0
        for k, b in enumerate(bounds):
            at = self._open_len.get(cid, 0)
            self._open.setdefault(cid, []).append(view[rec_offs[a]:rec_offs[b]])
            self._open_len[cid] = at + int(rec_offs[b] - rec_offs[a])
            self._open_msgs.setdefault(cid, []).append((t_all[a:b], rec_offs[a:b] - rec_offs[a] + at))
            if k < len(bounds) - 1 or self._open_len[cid] > self._chunk_size:
                closed.append(self._take_open(cid))
            a = b

    def _count(self, cid: int, n: int, t0: int, t1: int) -> None:
        self._counts[cid] = self._counts.get(cid, 0) + n
        self._n += n
        self._t_min = t0 if self._t_min is None else min(self._t_min, t0)
        self._t_max = t1 if self._t_max is None else max(self._t_max, t1)

    def _take_open(self, cid: int) -> tuple:
        """The open chunk of channel ``cid``, closed: ("new", its records, times, channel ids,
        offsets)."""
        pieces, msgs = self._open.pop(cid), self._open_msgs.pop(cid)
        del self._open_len[cid]
        data = pieces[0] if len(pieces) == 1 else b"".join(pieces)   # one piece: compressed as it is
        tc = msgs[0][0] if len(msgs) == 1 else np.concatenate([m[0] for m in msgs])
        in_chunk = msgs[0][1] if len(msgs) == 1 else np.concatenate([m[1] for m in msgs])
        return "new", data, tc, np.full(len(tc), cid, dtype=np.int64), in_chunk

    def flush(self) -> None:
        """Close the open chunks now: what was added so far is on ``fh``."""
        closed = [self._take_open(cid) for cid in list(self._open_msgs)] + list(self._open_copy.values())
        self._open_copy = {}
        self._submit(closed)
        while self._pending:
            self._emit(*self._pending.popleft())

    def _submit(self, closed: list) -> None:
        """Compress the chunks ``closed`` ((kind, data, times, channel ids, offsets)) and write
        them, in order of their last message's time, then channel id (a copied chunk's
        record is written as it is)."""
        closed.sort(key=lambda c: (int(c[2].max()), int(c[3][0])))
        for kind, data, tc, cc, in_chunk in closed:
            if kind == "copy":
                self._pending.append((data, 0, tc, cc, in_chunk))
            elif self._threads <= 0 or self._comp == "none":
                self._pending.append((_pack_chunk(self._comp, self._zstd_level, data), len(data), tc, cc, in_chunk))
            else:
                if self._pool is None:
                    from concurrent.futures import ThreadPoolExecutor  # only when a chunk is compressed

                    self._pool = ThreadPoolExecutor(self._threads, thread_name_prefix="usvlog-mcap-zstd")
                self._pending.append((self._pool.submit(_pack_chunk, self._comp, self._zstd_level, data),
                                      len(data), tc, cc, in_chunk))
                self._pending_bytes += len(data)
            # at most _PENDING_BYTES in flight (the threads compress while the caller encodes the
            # next batch): memory stays bounded by them
            while self._pending and (self._pending_bytes > _PENDING_BYTES or not hasattr(self._pending[0][0], "done")
                                     or self._pending[0][0].done()):
                self._emit(*self._pending.popleft())

    def _emit(self, packed, size: int, tc: np.ndarray, cc: np.ndarray, in_chunk: np.ndarray) -> None:
        """Write one chunk record (``packed``: (bytes, compression, CRC) of ``size``
        uncompressed bytes, or its future, or a whole chunk record copied) and its
        message indexes."""
        # start-up: the mcap library loads on first write, not on read
        from mcap.opcode import Opcode
        from mcap.records import ChunkIndex

        if isinstance(packed, (bytes, bytearray, memoryview)):   # a chunk record copied as it is
            t0, t1, size, _crc, cn_len = _CHUNK_HEAD.unpack_from(packed, _REC.size)
            p = _REC.size + _CHUNK_HEAD.size
            cname = bytes(packed[p:p + cn_len]).decode()
            csize = struct.unpack_from("<Q", packed, p + cn_len)[0]
            chunk_at = self._write(packed)
            rec_len = len(packed)
        else:
            if not isinstance(packed, tuple):
                packed = packed.result()
                self._pending_bytes -= size
            packed, cname, crc = packed
            t0, t1 = int(tc.min()), int(tc.max())
            # the Chunk record (mcap.records.Chunk's bytes), its compressed records written as they are
            cn = cname.encode()
            head = _CHUNK_HEAD.pack(t0, t1, size, crc, len(cn)) + cn + struct.pack("<Q", len(packed))
            chunk_at = self._write(_REC.pack(Opcode.CHUNK, len(head) + len(packed)) + head)
            self._write(packed)
            rec_len = _REC.size + len(head) + len(packed)
            csize = len(packed)
        # one Message Index record per channel, in order of the channel's first message in the chunk
        ids, counts, entries = K.message_index(cc, tc, in_chunk)
        for cid in ids.tolist():
            self._order.setdefault(cid)
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
            compressed_size=csize, uncompressed_size=size))

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

        counts = {c: self._counts[c] for c in self._order}   # in order of their first chunk, as the library
        stats = Statistics(attachment_count=0, channel_count=len(self._channels),
                           channel_message_counts=counts, chunk_count=len(self._chunk_indexes),
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
