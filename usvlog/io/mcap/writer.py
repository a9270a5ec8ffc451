"""The one MCAP writer: :class:`McapWriter` (streaming) and :func:`write_log` (a whole log).

Message and index records are built with compiled loops (:mod:`.kernels`); the bytes are
the mcap library's ``Writer``'s for the same messages (:mod:`.reference` keeps that path).
"""

from __future__ import annotations

import json
import os
import struct
import zlib
from collections import deque

import numpy as np
import pandas as pd

from ..._version import __version__
from ...errors import InputError
from ...log.channels import (
    SCHEMA_ENCODING,
    auto_schema,
    schema_for_topic,
)
from ...log.fieldlog import FieldLog
from ..atomic import atomic_path
from . import kernels as K
from .codec import Codec, writer_codec
from .format import (
    _REC,
    MAGIC,
)


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

SLICE_MESSAGES = 1 << 17
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
    """
    _compression(compression)
    frames = {topic: log.channels[topic] for topic in log.topics}
    with atomic_path(path, force=force) as tmp:
        with open(tmp, "wb", buffering=1 << 20) as fh:
            w = McapWriter(fh, chunk_size=chunk_size, compression=compression, zstd_level=zstd_level)
            try:
                for name in sorted(log.meta):
                    w.add_metadata(name, log.meta[name])
                for topic in log.topics:
                    w.add_channel(topic, log.schemas.get(topic), log.channels[topic])
                for batch in time_slices(frames, slice_messages):
                    w.add_frames(batch, log.schemas)
                w.finish()
            finally:
                w.close()


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
    times = {t: np.asarray(f.index, dtype=np.int64) for t, f in frames.items() if len(f)}
    total = sum(len(v) for v in times.values())
    if total <= size or not all(len(v) < 2 or bool(np.all(v[1:] >= v[:-1])) for v in times.values()):
        yield frames
        return
    # boundaries at quantiles of every message's time (from a sample: boundaries need not be exact)
    step = max(1, total // (64 * (total // size + 1)))
    sample = np.sort(np.concatenate([v[::step] for v in times.values()]))
    cuts = np.unique(sample[np.linspace(0, len(sample), total // size + 1, endpoint=False).astype(np.int64)[1:]])
    edges = {t: np.concatenate(([0], np.searchsorted(v, cuts, side="left"), [len(v)])) for t, v in times.items()}
    for k in range(len(cuts) + 1):
        batch = {t: frames[t].iloc[int(e[k]):int(e[k + 1])] for t, e in edges.items() if e[k + 1] > e[k]}
        if batch:
            yield batch


def _pack_chunk(comp: str, level: int, data: bytes) -> tuple[bytes, str, int]:
    """(compressed bytes, compression name, CRC-32 of ``data``) of one chunk's records;
    runs on a worker thread (zstd, lz4 and zlib release the GIL)."""
    if comp == "zstd":
        import zstandard  # only the compressor the file uses is loaded

        packed, cname = zstandard.ZstdCompressor(level=level).compress(data), "zstd"
    elif comp == "lz4":
        import lz4.frame  # only the compressor the file uses is loaded

        packed, cname = lz4.frame.compress(data), "lz4"
    else:
        packed, cname = data, ""
    return packed, cname, zlib.crc32(data)


_WORKERS = max(1, min(4, (os.cpu_count() or 1) - 1))   # chunk compression threads


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
    plus one batch) and the chunks being compressed are held. Chunks are compressed
    on ``threads`` worker threads (default: one fewer than the CPUs, 1 to 4; 0
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
        import zlib

        self._pos = 0
        self._crc32 = zlib.crc32
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
        # the open chunk: its bytes, and its messages' times, channels, offsets in it
        self._open = bytearray()
        self._open_msgs: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        # chunks being compressed on worker threads, written in order as they are done
        self._threads = _WORKERS if threads is None else int(threads)
        self._pool = None
        self._pending: deque = deque()
        self._write(MAGIC)
        self._write(self._record(Header(profile="", library=f"usvlog {__version__}")))

    # -- low level -------------------------------------------------------------------
    def _write(self, b) -> int:
        at = self._pos
        self._fh.write(b)
        if self._data_crc is not None:
            self._data_crc = self._crc32(b, self._data_crc)
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
            self._open += self._record(self._schemas[-1])
        cid = len(self._channels) + 1
        self._channels.append(Channel(id=cid, topic=topic, message_encoding=codec.message_encoding, schema_id=sid,
                                      metadata={}))
        self._open += self._record(self._channels[-1])
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
    def add_frames(self, frames: dict[str, pd.DataFrame], schemas: dict[str, dict] | None = None) -> None:
        """Append one batch: every row of every frame (index: int64 log time ns) as a message."""
        bufs, ts, cids, seqs, starts, ends = [], [], [], [], [], []
        base = 0
        for topic, frame in frames.items():
            if not len(frame):
                continue
            cid = self.add_channel(topic, (schemas or {}).get(topic), frame)
            codec = self._topics[topic][1]
            t = np.asarray(frame.index, dtype=np.int64)
            if t.min() < 0:
                raise InputError(f"channel {topic}: negative time stamp at row {int(np.argmin(t))}")
            data, offs = codec.encode_packed(frame, topic)
            s0 = self._seq[cid]
            self._seq[cid] = s0 + len(t)
            bufs.append(data)
            ts.append(t)
            cids.append(np.full(len(t), cid, dtype=np.int64))
            seqs.append(np.arange(s0, s0 + len(t), dtype=np.int64))
            starts.append(offs[:-1] + base)
            ends.append(offs[1:] + base)
            base += len(data)
        if not ts:
            return
        t_all, c_all, s_all = np.concatenate(ts), np.concatenate(cids), np.concatenate(seqs)
        order = np.lexsort((s_all, c_all, t_all))
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
        bounds = K.chunk_bounds(rec_offs, self._chunk_size, len(self._open)).tolist()
        a = 0
        for k, b in enumerate(bounds):
            at = len(self._open)
            self._open += memoryview(recs)[rec_offs[a]:rec_offs[b]]
            self._open_msgs.append((t_all[a:b], c_all[a:b], rec_offs[a:b] - rec_offs[a] + at))
            if k < len(bounds) - 1 or len(self._open) > self._chunk_size:
                self._close_chunk()
            a = b

    def flush(self) -> None:
        """Close the open chunk now (if it holds messages): what was added so far is on ``fh``."""
        if self._open_msgs:
            self._close_chunk()
        while self._pending:
            self._emit(*self._pending.popleft())

    def _close_chunk(self) -> None:
        data = bytes(self._open)
        tc = np.concatenate([m[0] for m in self._open_msgs])
        cc = np.concatenate([m[1] for m in self._open_msgs])
        in_chunk = np.concatenate([m[2] for m in self._open_msgs])
        self._open = bytearray()
        self._open_msgs = []
        if self._threads <= 0 or self._comp == "none":
            self._emit(_pack_chunk(self._comp, self._zstd_level, data), data, tc, cc, in_chunk)
            return
        if self._pool is None:
            from concurrent.futures import ThreadPoolExecutor  # only when a chunk is compressed

            self._pool = ThreadPoolExecutor(self._threads, thread_name_prefix="usvlog-mcap-zstd")
        self._pending.append((self._pool.submit(_pack_chunk, self._comp, self._zstd_level, data),
                              data, tc, cc, in_chunk))
        # at most a few chunks in flight: memory stays bounded by them
        while len(self._pending) > 2 * self._threads or (self._pending and self._pending[0][0].done()):
            self._emit(*self._pending.popleft())

    def _emit(self, packed, data: bytes, tc: np.ndarray, cc: np.ndarray, in_chunk: np.ndarray) -> None:
        """Write one chunk record (``packed``: (bytes, compression, CRC) or its future) and
        its message indexes."""
        # start-up: the mcap library loads on first write, not on read
        from mcap.opcode import Opcode
        from mcap.records import Chunk, ChunkIndex

        packed, cname, crc = packed if isinstance(packed, tuple) else packed.result()
        t0, t1 = int(tc.min()), int(tc.max())
        rec = self._record(Chunk(compression=cname, data=packed, message_start_time=t0, message_end_time=t1,
                                 uncompressed_crc=crc, uncompressed_size=len(data)))
        chunk_at = self._write(rec)
        # one Message Index record per channel, in order of the channel's first message in the chunk
        uniq, first = np.unique(cc, return_index=True)
        index_at = self._pos
        offsets = {}
        for cid in uniq[np.argsort(first)].tolist():
            sel = cc == cid
            entries = np.empty((int(sel.sum()), 2), dtype="<u8")
            entries[:, 0] = tc[sel]
            entries[:, 1] = in_chunk[sel]
            offsets[cid] = self._write(_REC.pack(Opcode.MESSAGE_INDEX, 6 + entries.nbytes)
                                       + struct.pack("<HI", cid, entries.nbytes) + entries.tobytes())
        self._chunk_indexes.append(ChunkIndex(
            message_start_time=t0, message_end_time=t1, chunk_start_offset=chunk_at,
            chunk_length=len(rec), message_index_offsets=offsets,
            message_index_length=self._pos - index_at, compression=cname,
            compressed_size=len(packed), uncompressed_size=len(data)))

    def close(self) -> None:
        """Stop the compression threads (after :meth:`finish`, or to give up a file half
        written: chunks not yet written are dropped)."""
        self._pending.clear()
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
        crc = zlib.crc32(summary)
        crc = zlib.crc32(struct.pack("<BQQQ", Opcode.FOOTER, 20, summary_start, summary_offset_start), crc)
        self._write(summary)
        self._write(self._record(Footer(summary_start=summary_start, summary_offset_start=summary_offset_start,
                                        summary_crc=crc)))
        self._write(MAGIC)
