"""The MCAP file writer: :class:`McapWriter` writes a canonical file incrementally on an open file.

Schema and channel records as channels are registered, metadata records, each channel's
messages in chunks of its own (records built by compiled loops, :mod:`.kernels`), their
message indexes, and at the end the summary and
footer. The bytes are the mcap library's ``Writer``'s for the same messages. A whole log
is written through it by :func:`usvlog.io.mcap.writer.write_log`.
"""

from __future__ import annotations

import struct
import threading
from typing import TYPE_CHECKING

import numpy as np

from ..._version import __version__
from ...errors import InputError
from . import kernels as K
from .codec import Codec
from .format import (
    _REC,
    MAGIC,
    crc32,
)
from .schema_records import _codec_for, _compression, _schema_record

if TYPE_CHECKING:   # pandas is imported where a frame is made (inspect never needs it)
    import pandas as pd


ZSTD_LEVEL = 1
"""zstd level of the chunks :func:`write_log` writes: on canonical JSON logs level 1 is
2-2.5x faster than the library's level 3 and compresses better (ratio 4.3 vs 3.7 on a
replay log); see docs/performance.md, "Output encoding and compression"."""


_MSG_HEAD = 9 + 22   # a Message record's bytes before its payload: opcode, length, channel, sequence, times


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
    """(compressed bytes, compression name, CRC-32 of ``data``) of one chunk's records."""
    if comp == "zstd":
        packed, cname = _zstd(level).compress(data), "zstd"
    elif comp == "lz4":
        import lz4.frame  # only the compressor the file uses is loaded

        packed, cname = lz4.frame.compress(data), "lz4"
    else:
        packed, cname = data, ""
    return packed, cname, crc32(data)


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
    channel plus one batch: a chunk is a view of the batch's records, not a copy) are held.
    A chunk is compressed in the calling thread as it is closed and written at once.
    (Compressing on 1-4 worker threads while the caller encoded the next batch was
    measured in issue 32 under its 10 % bar, 1-hour estimate -5.5 to 11.5 %, replay 6.4 %,
    simulate 2.5 %, and taken out; docs/performance.md.) Each
    message's ``sequence`` is its row number in its channel over all batches, as
    :func:`read_log` expects; within a chunk messages are in (time, row) order.
    """

    def __init__(self, fh, *, chunk_size: int = 1 << 20, compression: str = "zstd", zstd_level: int = ZSTD_LEVEL):
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
                if cid in self._open_copy:   # its last copied chunk, followed by this one: closed now (it was lost)
                    closed.append(self._open_copy.pop(cid))
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

    def _submit(self, closed: list) -> None:
        """Compress the chunks ``closed`` ((kind, data, times, channel ids, offsets)) and write
        them, in order of their last message's time, then channel id (a copied chunk's
        record is written as it is)."""
        closed.sort(key=lambda c: (int(c[2].max()), int(c[3][0])))
        for kind, data, tc, cc, in_chunk in closed:
            if kind == "copy":
                self._emit(data, 0, tc, cc, in_chunk)
            else:
                self._emit(_pack_chunk(self._comp, self._zstd_level, data), len(data), tc, cc, in_chunk)

    def _emit(self, packed, size: int, tc: np.ndarray, cc: np.ndarray, in_chunk: np.ndarray) -> None:
        """Write one chunk record (``packed``: (bytes, compression, CRC) of ``size``
        uncompressed bytes, or a whole chunk record copied) and its message indexes."""
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
        """Nothing left to stop: kept for the callers that close a writer after
        :meth:`finish` or when they give up a file half written (chunks are written as they
        are closed, so nothing is pending)."""

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
