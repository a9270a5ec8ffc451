"""Canonical MCAP logs: write a FieldLog, read one back (recovering damaged files).

Layout written: header, metadata records (datum, vessel, provenance: first, so a
truncated file keeps them), then zstd chunks of JSON messages in log-time order,
then the usual summary (indexes, statistics). Each message's ``sequence`` is its
row number in the channel's frame so reading restores the frame's row order.
:class:`McapWriter` is the one writer: ``write_log`` writes a whole log through it,
the importer streams batches into it (its metadata then follows the chunks).

Writing builds the message and index records with compiled loops
(``usvlog._kernels``) and gives the same bytes as the mcap library's ``Writer``
(``_write_log_reference``, kept to test against).

Reading walks the records itself rather than through the mcap library's
per-record objects: it stops at the first incomplete record of a file cut short
(or the first corrupt chunk), keeps every complete chunk, and reports what was
lost. ``_scan_fast`` walks records and messages into arrays with compiled loops;
``_scan_reference`` is the plain one-record-at-a-time reading, kept as the
reference the tests compare it with.
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
from .. import __version__
from ..channels import (MESSAGE_ENCODING, SCHEMA_ENCODING, Codec, auto_schema, codec_for_schema,
                        codec_for_topic, frame_from_columns, schema_for_topic)
from ..errors import FormatError, InputError
from ..log import FieldLog, RecoveryReport
from .atomic import atomic_path, reading

MAGIC = b"\x89MCAP0\r\n"

OP_HEADER, OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK = 0x01, 0x02, 0x03, 0x04, 0x05, 0x06
OP_METADATA, OP_DATA_END = 0x0C, 0x0F

_U16 = struct.Struct("<H")
_U32 = struct.Struct("<I")
_U64 = struct.Struct("<Q")
_REC = struct.Struct("<BQ")
_MSG = struct.Struct("<HIQQ")
_CHUNK = struct.Struct("<QQQI")


# -----------------------------------------------------------------------------
# writing
# -----------------------------------------------------------------------------

def _codec_for(topic: str, schema: dict | None = None, frame: pd.DataFrame | None = None) -> tuple[dict, Codec]:
    """(schema, codec) of a channel: the registered schema, else ``schema`` (e.g. the one
    stored in the file read), else one generated from ``frame``'s dtypes."""
    schema = schema_for_topic(topic) or schema
    if schema is None:
        if frame is None:
            raise InputError(f"channel {topic}: no registered schema (see schemas/)")
        schema = auto_schema(topic, frame)
    return schema, codec_for_topic(topic) or codec_for_schema(schema)


def _compression(compression: str) -> str:
    if compression not in ("zstd", "lz4", "none"):
        raise InputError(f"unknown compression {compression!r} (zstd, lz4 or none)")
    return compression


def write_log(log: FieldLog, path, *, force: bool = False, chunk_size: int = 1 << 20,
              compression: str = "zstd") -> None:
    """Write ``log`` as a canonical MCAP file, atomically, through :class:`McapWriter`.

    The file is the one the mcap library's ``Writer`` writes for the same messages
    (byte for byte; ``_write_log_reference`` does it that way and the tests compare).
    Metadata records come first (a truncated file keeps them), then every channel,
    then the messages of all channels in (time, channel, row) order.
    """
    _compression(compression)
    with atomic_path(path, force=force) as tmp:
        with open(tmp, "wb", buffering=1 << 20) as fh:
            w = McapWriter(fh, chunk_size=chunk_size, compression=compression)
            for name in sorted(log.meta):
                w.add_metadata(name, log.meta[name])
            for topic in log.topics:
                w.add_channel(topic, log.schemas.get(topic), log.channels[topic])
            w.add_frames({topic: log.channels[topic] for topic in log.topics}, log.schemas)
            w.finish()


class McapWriter:
    """Canonical MCAP file written incrementally on an open binary file ``fh``.

    The one MCAP writing path of usvlog: :func:`write_log` writes a whole log through
    it, the importer streams batches of frames into it. Records and chunks are those
    the mcap library's ``Writer`` writes for the same calls (byte for byte:
    ``_write_log_reference`` does it that way and the tests compare): schema and
    channel records open the chunk that follows their registration; a chunk is
    closed after the message that takes it past ``chunk_size``; then message
    indexes, and at :meth:`finish` the summary (schemas, channels, statistics, chunk
    and metadata indexes). Message records are built by compiled loops from the
    packed output of :meth:`usvlog.channels.Codec.encode_packed`.

    Memory stays flat when streaming: only the open chunk (at most ``chunk_size``
    plus one batch) is held. Each message's ``sequence`` is its row number in its
    channel over all batches, as :func:`read_log` expects; within a batch messages
    are ordered by (time, channel, row).
    """

    def __init__(self, fh, *, chunk_size: int = 1 << 20, compression: str = "zstd", zstd_level: int = 3):
        from mcap.records import Header

        self._fh = fh
        self._chunk_size = int(chunk_size)
        self._comp = _compression(compression)
        self._zstd_level = int(zstd_level)
        self._pos = 0
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
        self._write(MAGIC)
        self._write(self._record(Header(profile="", library=f"usvlog {__version__}")))

    # -- low level -------------------------------------------------------------------
    def _write(self, b) -> int:
        at = self._pos
        self._fh.write(b)
        self._pos += len(b)
        return at

    @staticmethod
    def _record(rec) -> bytes:
        from mcap.data_stream import RecordBuilder

        rb = RecordBuilder()
        rec.write(rb)
        return rb.end()

    # -- channels and metadata -----------------------------------------------------------
    def add_channel(self, topic: str, schema: dict | None = None, frame: pd.DataFrame | None = None) -> int:
        """Register ``topic`` (once; its schema: the registered one, else ``schema``, else one
        generated from ``frame``); returns the channel id."""
        from mcap.records import Channel, Schema

        known = self._topics.get(topic)
        if known is not None:
            return known[0]
        schema, codec = _codec_for(topic, schema, frame)
        sname = schema.get("title", topic)
        sdata = json.dumps(schema, sort_keys=False).encode()
        sid = self._schema_ids.get((sname, sdata))
        if sid is None:
            sid = self._schema_ids[(sname, sdata)] = len(self._schemas) + 1
            self._schemas.append(Schema(id=sid, name=sname, encoding=SCHEMA_ENCODING, data=sdata))
            self._open += self._record(self._schemas[-1])
        cid = len(self._channels) + 1
        self._channels.append(Channel(id=cid, topic=topic, message_encoding=MESSAGE_ENCODING, schema_id=sid,
                                      metadata={}))
        self._open += self._record(self._channels[-1])
        self._topics[topic] = (cid, codec)
        self._seq[cid] = 0
        return cid

    def add_metadata(self, name: str, record: dict) -> None:
        """A metadata record (values stored as strings), after the messages written so far."""
        from mcap.records import Metadata, MetadataIndex

        self.flush()
        b = self._record(Metadata(name=name, metadata={str(k): str(v) for k, v in record.items()}))
        self._meta_index.append(MetadataIndex(offset=self._write(b), length=len(b), name=name))

    # -- messages ------------------------------------------------------------------------
    def add_frames(self, frames: dict[str, pd.DataFrame], schemas: dict[str, dict] | None = None) -> None:
        """Append one batch: every row of every frame (index: int64 log time ns) as a message."""
        from .. import _kernels as K

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

    def _close_chunk(self) -> None:
        import zlib

        from mcap.opcode import Opcode
        from mcap.records import Chunk, ChunkIndex

        data = bytes(self._open)
        tc = np.concatenate([m[0] for m in self._open_msgs])
        cc = np.concatenate([m[1] for m in self._open_msgs])
        in_chunk = np.concatenate([m[2] for m in self._open_msgs])
        self._open = bytearray()
        self._open_msgs = []
        if self._comp == "zstd":
            import zstandard

            packed, cname = zstandard.ZstdCompressor(level=self._zstd_level).compress(data), "zstd"
        elif self._comp == "lz4":
            import lz4.frame

            packed, cname = lz4.frame.compress(data), "lz4"
        else:
            packed, cname = data, ""
        t0, t1 = int(tc.min()), int(tc.max())
        rec = self._record(Chunk(compression=cname, data=packed, message_start_time=t0, message_end_time=t1,
                                 uncompressed_crc=zlib.crc32(data), uncompressed_size=len(data)))
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

    # -- the end ------------------------------------------------------------------------
    def finish(self) -> None:
        """Close the open chunk, write the summary and the footer (the file stays open)."""
        import zlib

        from mcap.data_stream import RecordBuilder
        from mcap.opcode import Opcode
        from mcap.records import DataEnd, Footer, Statistics, SummaryOffset

        self.flush()
        self._write(self._record(DataEnd(0)))
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


def _schema_records(log: FieldLog) -> tuple[list, list, list, list[tuple[str, dict, Codec]]]:
    """(mcap Schema records, Channel records, both in registration order, and
    [(topic, schema, codec)] in channel-id order) -- for the reference writer."""
    from mcap.records import Channel, Schema

    schemas, channels, both, out, ids = [], [], [], [], {}
    for topic in log.topics:
        schema, codec = _codec_for(topic, log.schemas.get(topic), log.channels[topic])
        sname = schema.get("title", topic)
        sdata = json.dumps(schema, sort_keys=False).encode()
        key = (sname, sdata)
        if key not in ids:
            ids[key] = len(schemas) + 1
            schemas.append(Schema(id=ids[key], name=sname, encoding=SCHEMA_ENCODING, data=sdata))
            both.append(schemas[-1])
        channels.append(Channel(id=len(channels) + 1, topic=topic, message_encoding=MESSAGE_ENCODING,
                                schema_id=ids[key], metadata={}))
        both.append(channels[-1])
        out.append((topic, schema, codec))
    return schemas, channels, both, out


def _write_log_reference(log: FieldLog, path, *, force: bool = False, chunk_size: int = 1 << 20,
                         compression: str = "zstd") -> None:
    """Write ``log`` through the mcap library's Writer, one ``add_message`` per message
    (the reference :func:`write_log` is tested against)."""
    from mcap.writer import CompressionType, Writer

    comp = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4,
            "none": CompressionType.NONE}[_compression(compression)]
    _schemas, _channels, registered, encs = _schema_records(log)
    encoded = []
    for topic, _schema, codec in encs:
        frame = log.channels[topic]
        t = np.asarray(frame.index, dtype=np.int64)
        if len(t) and t.min() < 0:
            raise InputError(f"channel {topic}: negative time stamp at row {int(np.argmin(t))}")
        encoded.append((t, codec.encode_reference(frame, topic)))
    with atomic_path(path, force=force) as tmp:
        with open(tmp, "wb") as fh:
            w = Writer(fh, chunk_size=chunk_size, compression=comp)
            w.start(profile="", library=f"usvlog {__version__}")
            for name in sorted(log.meta):
                w.add_metadata(name, {str(k): str(v) for k, v in log.meta[name].items()})
            for r in registered:
                if hasattr(r, "topic"):
                    w.register_channel(topic=r.topic, message_encoding=r.message_encoding, schema_id=r.schema_id)
                else:
                    w.register_schema(name=r.name, encoding=r.encoding, data=r.data)
            if encoded:
                t_all = np.concatenate([t for t, _ in encoded])
                c_all = np.concatenate([np.full(len(t), i) for i, (t, _) in enumerate(encoded)])
                r_all = np.concatenate([np.arange(len(t)) for t, _ in encoded])
                order = np.lexsort((r_all, c_all, t_all))
                for t_i, c_i, r_i in zip(t_all[order].tolist(), c_all[order].tolist(), r_all[order].tolist()):
                    w.add_message(channel_id=c_i + 1, log_time=t_i, data=encoded[c_i][1][r_i],
                                  publish_time=t_i, sequence=r_i)
            w.finish()


# -----------------------------------------------------------------------------
# reading
# -----------------------------------------------------------------------------

class _CorruptChunk(Exception):
    pass


@dataclass
class _Channel:
    topic: str
    schema_id: int
    encoding: str
    times: list = field(default_factory=list)
    seqs: list = field(default_factory=list)
    payloads: list = field(default_factory=list)
    # fast scan: message arrays instead of the lists above
    t: np.ndarray | None = None
    seq: np.ndarray | None = None
    starts: np.ndarray | None = None
    ends: np.ndarray | None = None


@dataclass
class _Scan:
    schemas: dict = field(default_factory=dict)     # id -> (name, encoding, data)
    channels: dict = field(default_factory=dict)    # id -> _Channel
    metadata: dict = field(default_factory=dict)
    end_offset: int = 8                             # end of the last complete top-level record
    complete: bool = False                          # Data End or Footer reached
    reason: str = ""
    lost_chunk_range: tuple[int, int] | None = None
    arena: np.ndarray | None = None                 # fast scan: every message's bytes


def _string(buf, off):
    n = _U32.unpack_from(buf, off)[0]
    off += 4
    if off + n > len(buf):
        raise struct.error("string runs past the end of its record")
    return bytes(buf[off:off + n]).decode("utf-8"), off + n


def _map(buf, off):
    total = _U32.unpack_from(buf, off)[0]
    off += 4
    end = off + total
    out = {}
    while off < end:
        k, off = _string(buf, off)
        v, off = _string(buf, off)
        out[k] = v
    return out, end


def _parse(op: int, rec) -> tuple | None:
    """A schema, channel or metadata record's fields (rec = the record's body), else None.

    Raises struct.error / UnicodeDecodeError on a malformed record."""
    if op == OP_SCHEMA:
        sid = _U16.unpack_from(rec, 0)[0]
        name, p = _string(rec, 2)
        enc, p = _string(rec, p)
        n = _U32.unpack_from(rec, p)[0]
        if p + 4 + n > len(rec):
            raise struct.error("schema data runs past the end of its record")
        return (op, sid, name, enc, bytes(rec[p + 4:p + 4 + n]))
    if op == OP_CHANNEL:
        cid, sid = struct.unpack_from("<HH", rec, 0)
        topic, p = _string(rec, 4)
        enc, p = _string(rec, p)
        return (op, cid, sid, topic, enc)
    if op == OP_METADATA:
        name, p = _string(rec, 0)
        return (op, name, _map(rec, p)[0])
    return None


def _apply(scan: _Scan, parsed: tuple, in_chunk: bool) -> None:
    op = parsed[0]
    if op == OP_SCHEMA:
        scan.schemas[parsed[1]] = parsed[2:]
    elif op == OP_CHANNEL:
        if parsed[1] not in scan.channels:
            scan.channels[parsed[1]] = _Channel(parsed[3], parsed[2], parsed[4])
    elif op == OP_METADATA and not in_chunk:
        scan.metadata[parsed[1]] = parsed[2]


def _chunk_header(buf, body: int, end: int):
    t0, t1, usize, _crc = _CHUNK.unpack_from(buf, body)
    comp, p = _string(buf, body + 28)
    rlen = _U64.unpack_from(buf, p)[0]
    if p + 8 + rlen > end:
        raise struct.error("chunk data runs past the end of its record")
    return t0, t1, usize, comp, buf[p + 8:p + 8 + rlen]


_PAST_CHUNK = "a record runs past the end of the chunk"
_BAD_MESSAGE = "a message record is too short or its log time past int64"


def _chunk_records(data) -> list[tuple[int, int, int]]:
    """(op, body start, body end) of every record in a decompressed chunk; a chunk
    whose records do not fit it exactly, or holds a bad message record, is corrupt."""
    out, off, end = [], 0, len(data)
    while off < end:
        if off + 9 > end:
            raise _CorruptChunk(_PAST_CHUNK)
        op, length = _REC.unpack_from(data, off)
        nxt = off + 9 + length
        if nxt > end:
            raise _CorruptChunk(_PAST_CHUNK)
        out.append((op, off + 9, nxt))
        off = nxt
    for op, b, e in out:
        if op == OP_MESSAGE and (e - b < 22 or _U64.unpack_from(data, b + 6)[0] >= 1 << 63):
            raise _CorruptChunk(_BAD_MESSAGE)
    return out


def _scan_reference(data: bytes) -> _Scan:
    """The plain reading of the records (one Python step per record), kept as the
    reference the fast scan is tested against."""
    scan = _Scan()
    buf = memoryview(data)
    end, off = len(data), 8
    while off + 9 <= end:
        op, length = _REC.unpack_from(buf, off)
        body, nxt = off + 9, off + 9 + length
        if nxt > end:
            break
        try:
            if op == OP_MESSAGE:
                if length < 22 or _U64.unpack_from(buf, body + 6)[0] >= 1 << 63:
                    raise struct.error("bad message record")
                _add_message(scan, buf, body, nxt)
            elif op == OP_CHUNK:
                t0, t1, usize, comp, raw = _chunk_header(buf, body, nxt)
                try:
                    chunk = memoryview(_decompress(comp, raw, usize))
                    recs = _chunk_records(chunk)
                    parsed = [(o, b, e, _parse(o, chunk[b:e])) for o, b, e in recs]
                except Exception as err:  # corrupt chunk: keep what came before
                    raise _CorruptChunk(err) from err
                for o, b, e, pr in parsed:
                    if o == OP_MESSAGE:
                        _add_message(scan, chunk, b, e)
                    elif pr is not None:
                        _apply(scan, pr, True)
            else:
                pr = _parse(op, buf[body:nxt])
                if pr is not None:
                    _apply(scan, pr, False)
        except _CorruptChunk as err:
            scan.reason = f"chunk at byte {off} is corrupt ({err})"
            scan.lost_chunk_range = (t0, t1)
            return scan
        except (struct.error, UnicodeDecodeError, IndexError) as err:
            scan.reason = f"malformed record after byte {off} ({err})"
            return scan
        if op in (OP_FOOTER, OP_DATA_END):
            # the data section is complete; the summary is not needed for reading
            scan.complete = True
            return scan
        off = scan.end_offset = nxt
    return scan


def _add_message(scan: _Scan, buf, body: int, nxt: int) -> None:
    cid, seq, log_time, _pub = _MSG.unpack_from(buf, body)
    if log_time >= 1 << 63:
        raise struct.error("message log time past int64")
    ch = scan.channels.get(cid)
    if ch is not None:
        ch.times.append(log_time)
        ch.seqs.append(seq)
        ch.payloads.append(bytes(buf[body + 22:nxt]))


def _scan_fast(data: bytes) -> _Scan:
    """The same reading as :func:`_scan_reference`, with the per-message work done by
    compiled loops: records are walked into arrays, and a message is kept when its
    channel was defined before it (compared by record ordinals)."""
    from .. import _kernels as K

    scan = _Scan()
    buf = np.frombuffer(data, dtype=np.uint8)
    mv = memoryview(data)
    ops, offs, lens, stop, complete = K.walk_records(buf, 8, len(buf), True)
    n_top = len(ops)
    defined: dict[int, int] = {}     # channel id -> ordinal of its record
    parts = []                       # (arena offset, cid, seq, t, start, end, ordinal)

    top_msgs = np.flatnonzero(ops == OP_MESSAGE)
    chunk_ops = np.flatnonzero(ops == OP_CHUNK)
    usizes = [_U64.unpack_from(data, int(offs[i]) + 9 + 16)[0] for i in chunk_ops.tolist()
              if lens[i] >= 24]
    arena = _Arena(min(sum(usizes), 64 * len(data)) + (len(data) if len(top_msgs) else 0))
    if len(top_msgs):
        cid, seq, t, ps, pe, ok = K.message_fields(buf, offs[top_msgs], lens[top_msgs])
        if not ok:  # a too-short message record: the file is read up to it
            first_bad = int(top_msgs[np.flatnonzero(cid < 0)[0]])
            n_top, complete = first_bad, False
            scan.reason = f"malformed record after byte {int(offs[first_bad])} (bad message record)"
            keep = top_msgs < first_bad
            cid, seq, t, ps, pe, top_msgs = cid[keep], seq[keep], t[keep], ps[keep], pe[keep], top_msgs[keep]
        parts.append((arena.put(buf), cid, seq, t, ps, pe, top_msgs.astype(np.int64) << 32))

    for i in np.flatnonzero(ops[:n_top] != OP_MESSAGE).tolist():
        op, off, ln = int(ops[i]), int(offs[i]), int(lens[i])
        body, nxt = off + 9, off + 9 + ln
        try:
            if op == OP_CHUNK:
                t0, t1, usize, comp, raw = _chunk_header(mv, body, nxt)
                try:
                    chunk = np.frombuffer(_decompress(comp, raw, usize), dtype=np.uint8)
                    cops, coffs, clens, _cstop, ccomplete = K.walk_records(chunk, 0, len(chunk), False)
                    if not ccomplete:
                        raise _CorruptChunk(_PAST_CHUNK)
                    m = np.flatnonzero(cops == OP_MESSAGE)
                    cid, seq, t, ps, pe, ok = K.message_fields(chunk, coffs[m], clens[m])
                    if not ok:
                        raise _CorruptChunk(_BAD_MESSAGE)
                    cmv = memoryview(chunk)
                    other = np.flatnonzero(cops != OP_MESSAGE).tolist()
                    parsed = [(j, _parse(int(cops[j]), cmv[coffs[j] + 9:coffs[j] + 9 + clens[j]])) for j in other]
                except _CorruptChunk:
                    raise
                except Exception as err:  # corrupt chunk: keep what came before
                    raise _CorruptChunk(err) from err
                for j, pr in parsed:
                    if pr is not None:
                        if pr[0] == OP_CHANNEL and pr[1] not in scan.channels:
                            defined[pr[1]] = (i << 32) + j + 1
                        _apply(scan, pr, True)
                if len(m):
                    parts.append((arena.put(chunk), cid, seq, t, ps, pe, (np.int64(i) << 32) + m + 1))
            else:
                pr = _parse(op, mv[body:nxt])
                if pr is not None:
                    if pr[0] == OP_CHANNEL and pr[1] not in scan.channels:
                        defined[pr[1]] = i << 32
                    _apply(scan, pr, False)
        except _CorruptChunk as err:
            scan.reason = f"chunk at byte {off} is corrupt ({err})"
            scan.lost_chunk_range = (t0, t1)
            n_top, complete = i, False
            break
        except (struct.error, UnicodeDecodeError, IndexError) as err:
            scan.reason = f"malformed record after byte {off} ({err})"
            n_top, complete = i, False
            break

    scan.complete = bool(complete)
    if not complete:
        scan.end_offset = int(offs[n_top]) if n_top < len(ops) else int(stop)

    # messages -> per-channel arrays into one arena of bytes
    if parts:
        scan.arena = arena.buf[:arena.used]
        cid = np.concatenate([p[1] for p in parts])
        seq = np.concatenate([p[2] for p in parts])
        t = np.concatenate([p[3] for p in parts])
        shift = np.concatenate([np.full(len(p[1]), p[0], dtype=np.int64) for p in parts])
        ps = np.concatenate([p[4] for p in parts]) + shift
        pe = np.concatenate([p[5] for p in parts]) + shift
        ordinal = np.concatenate([p[6] for p in parts])
        limit = np.int64(n_top) << 32   # messages after the point where reading stopped are lost
        for c, ch in scan.channels.items():
            sel = np.flatnonzero((cid == c) & (ordinal > defined.get(c, -1)) & (ordinal < limit))
            ch.t, ch.seq, ch.starts, ch.ends = t[sel], seq[sel], ps[sel], pe[sel]
    else:
        scan.arena = np.zeros(0, dtype=np.uint8)
        for ch in scan.channels.values():
            ch.t = ch.seq = ch.starts = ch.ends = np.zeros(0, dtype=np.int64)
    return scan


class _Arena:
    """One growing byte buffer holding every message's bytes (decompressed chunks)."""

    def __init__(self, capacity: int):
        self.buf = np.empty(max(capacity, 0), dtype=np.uint8)
        self.used = 0

    def put(self, data: np.ndarray) -> int:
        n, at = len(data), self.used
        if at + n > len(self.buf):
            grown = np.empty(max(2 * len(self.buf), at + n), dtype=np.uint8)
            grown[:at] = self.buf[:at]
            self.buf = grown
        self.buf[at:at + n] = data
        self.used = at + n
        return at


def _decompress(comp: str, raw, usize: int) -> bytes:
    if comp == "":
        return bytes(raw)
    if comp == "zstd":
        import zstandard

        return zstandard.ZstdDecompressor().decompress(bytes(raw), max_output_size=usize)
    if comp == "lz4":
        import lz4.frame

        return lz4.frame.decompress(bytes(raw))
    raise ValueError(f"unsupported compression {comp!r}")


def _read_bytes(p: Path) -> bytes:
    with reading(p):
        data = p.read_bytes()
    if len(data) < 8 or data[:8] != MAGIC:
        raise FormatError(f"{p}: not an MCAP file (bad magic bytes)")
    return data


def scan_file(path, *, fast: bool = True) -> tuple[_Scan, int]:
    data = _read_bytes(Path(path))
    scan = _scan_fast(data) if fast else _scan_reference(data)
    if not scan.complete and not scan.reason:
        scan.reason = "file ends inside a record (cut short)"
        off = scan.end_offset
        # if the truncated record is a chunk whose header survived, name its time range
        if off + 9 + 16 <= len(data) and data[off] == OP_CHUNK:
            scan.lost_chunk_range = struct.unpack_from("<QQ", data, off + 9)
    return scan, len(data)


def read_log(path, *, topics: list[str] | None = None, strict: bool = False) -> FieldLog:
    """Load a canonical MCAP log into a :class:`FieldLog`.

    A file cut short loads with every complete chunk; ``log.recovery`` says what was
    lost. ``strict=True`` raises instead.
    """
    return _read_log(path, topics=topics, strict=strict, fast=True)


def _read_log(path, *, topics=None, strict=False, fast=True) -> FieldLog:
    p = Path(path)
    scan, size = scan_file(p, fast=fast)
    log = FieldLog(source=str(p))
    log.meta = dict(scan.metadata)
    n_msgs = 0
    t_max = None
    for cid in sorted(scan.channels):
        ch = scan.channels[cid]
        if topics is not None and ch.topic not in topics:
            continue
        sname, senc, sdata = scan.schemas.get(ch.schema_id, ("", "", b""))
        if ch.encoding != MESSAGE_ENCODING or senc != SCHEMA_ENCODING:
            continue  # not a canonical channel: left alone
        try:
            schema = json.loads(sdata) if sdata else {"title": sname, "properties": {}}
            if not isinstance(schema, dict):
                raise TypeError("not an object")
            codec = codec_for_schema(schema)
        except (ValueError, TypeError, AttributeError) as err:
            raise InputError(f"{p} channel {ch.topic}: schema {sname} is not a usable JSON Schema ({err})") from err
        if scan.arena is None:
            t = np.asarray(ch.times, dtype=np.int64)
            seq = np.asarray(ch.seqs, dtype=np.int64)
        else:
            t, seq = ch.t, ch.seq
        order = np.argsort(seq, kind="stable")
        try:
            if scan.arena is None:
                cols = codec.decode_reference([ch.payloads[i] for i in order.tolist()], ch.topic)
            else:
                cols = codec.decode_spans(scan.arena, ch.starts[order], ch.ends[order], ch.topic)
        except InputError as err:
            raise InputError(f"{p} {err}") from err
        log.channels[ch.topic] = frame_from_columns(cols, t[order], codec)
        log.schemas[ch.topic] = schema
        n_msgs += len(t)
        if len(t):
            t_max = int(t.max()) if t_max is None else max(t_max, int(t.max()))
    if not scan.complete:
        if strict:
            raise InputError(f"{p}: damaged file: {scan.reason}")
        lost = scan.lost_chunk_range
        log.recovery = RecoveryReport(
            file_size=size, bytes_recovered=scan.end_offset, bytes_lost=size - scan.end_offset,
            messages_recovered=n_msgs, lost_from_ns=t_max,
            lost_to_ns=int(lost[1]) if lost else None, reason=scan.reason)
    return log


def read_logs(paths, *, topics: list[str] | None = None) -> FieldLog:
    """Load consecutive files of one run (e.g. a rotated recording) as one :class:`FieldLog`.

    Files written by the recorder carry a ``usvlog.recording`` record (run id, part
    number): they are put in part order and must be one run with no part missing.
    Other files are taken in the order given. Channels are concatenated; metadata
    comes from the first file, with the datum from the first file that has one.
    A damaged file is recovered as :func:`read_log` does; its report is kept.
    """
    paths = [Path(p) for p in paths]
    if not paths:
        raise InputError("read_logs: no files given")
    logs = [read_log(p, topics=topics) for p in paths]
    rec = [lg.meta.get("usvlog.recording") for lg in logs]
    if all(r is not None for r in rec):
        runs = {r.get("run_id") for r in rec}
        if len(runs) != 1:
            raise InputError(f"{paths[0]}: files belong to different recordings (run ids {', '.join(sorted(map(str, runs)))})")
        order = sorted(range(len(logs)), key=lambda i: int(rec[i].get("part", 0)))
        parts = [int(rec[i].get("part", 0)) for i in order]
        for a, b, i in zip(parts, parts[1:], order[1:]):
            if b != a + 1:
                raise InputError(f"{paths[i]}: part {b} follows part {a}; part(s) missing between them")
        logs = [logs[i] for i in order]
    elif any(r is not None for r in rec):
        raise InputError(f"{paths[0]}: mixes recorder files with other files")
    out = FieldLog(source=", ".join(str(lg.source) for lg in logs))
    out.meta = {k: dict(v) for k, v in logs[0].meta.items()}
    for lg in logs:
        if lg.datum is not None:
            out.datum = lg.datum
            break
    topics_all = []
    for lg in logs:
        topics_all += [t for t in lg.channels if t not in topics_all]
        out.schemas.update({t: s for t, s in lg.schemas.items() if t not in out.schemas})
    for t in topics_all:
        frames = [lg.channels[t] for lg in logs if t in lg.channels]
        out.channels[t] = frames[0] if len(frames) == 1 else pd.concat(frames)
    damaged = [lg for lg in logs if lg.recovery is not None]
    if damaged:
        out.recovery = damaged[-1].recovery
    return out
