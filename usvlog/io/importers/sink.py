"""Where imported frames go: into memory (a FieldLog) or streamed into an MCAP file.

:class:`McapSink` encodes and writes each batch as it comes, so importing a file 10x
larger does not need 10x the memory. Each message's ``sequence`` is its row number in
the channel, as :func:`usvlog.io.mcapio.read_log` expects; metadata records
(datum, vessel, provenance) are written once the import knows them, before the summary.
"""

from __future__ import annotations

import json
import struct
from itertools import chain, repeat

import numpy as np
import pandas as pd

from ... import __version__
from ...channels import MESSAGE_ENCODING, SCHEMA_ENCODING, codec_for_topic, schema_for_topic
from ...log import FieldLog


def encode_messages(codec, frame: pd.DataFrame, topic: str = "") -> list[bytes]:
    """The same bytes as ``codec.encode(frame)``, built column by column.

    Each column is serialized by orjson in one call and split into its values
    (numbers and null never contain a comma); strings are serialized once per
    distinct value. Rows are then joined with the property names in C
    (``map(b"".join, zip(...))``) instead of building a dict per row.
    """
    import orjson

    if not codec.fields or not len(frame):
        return codec.encode(frame, topic)
    missing = [c for c in codec.columns if c not in frame.columns]
    if missing:
        return codec.encode(frame, topic)  # raises the usual error
    n = len(frame)
    pieces = []
    for i, f in enumerate(codec.fields):
        key = orjson.dumps(f.prop) + b":"
        pieces.append((b"{" if i == 0 else b",") + key)
        col = frame[f.columns[0]]
        if f.kind == "time":
            t = np.asarray(col.to_numpy(), dtype=np.int64)
            sec, nsec = np.divmod(t, 1_000_000_000)
            pieces.append(list(map(b"".join, zip(repeat(b'{"sec":'), _split(orjson.dumps(sec.tolist()), n),
                                                  repeat(b',"nsec":'), _split(orjson.dumps(nsec.tolist()), n),
                                                  repeat(b"}")))))
        elif f.kind == "array":
            parts: list = [b"["]
            for j, c in enumerate(f.columns):
                v = np.asarray(frame[c].to_numpy(), dtype=float).tolist()
                parts += ([b","] if j else []) + [_split(orjson.dumps(v), n)]
            parts.append(b"]")
            pieces.append(_rows(parts, n))
        elif f.kind == "float":
            pieces.append(_split(orjson.dumps(np.asarray(col.to_numpy(), dtype=float).tolist()), n))
        elif f.kind == "int":
            pieces.append(_split(orjson.dumps(np.asarray(col.to_numpy(), dtype=np.int64).tolist()), n))
        elif f.kind == "bool":
            pieces.append(_split(orjson.dumps(np.asarray(col.to_numpy(), dtype=bool).tolist()), n))
        else:
            codes, uniques = pd.factorize(pd.Series([str(x) for x in col.tolist()]) if col.dtype == object
                                          else col.astype("str"), use_na_sentinel=False)
            enc = [orjson.dumps(str(u)) for u in uniques]
            pieces.append([enc[c] for c in codes.tolist()])
    pieces.append(b"}")
    return _rows(pieces, n)


def _rows(pieces: list, n: int) -> list[bytes]:
    """Join constant bytes and per-row lists of bytes into n rows (in C)."""
    if all(isinstance(p, bytes) for p in pieces):
        return [b"".join(pieces)] * n
    return list(map(b"".join, zip(*[repeat(p) if isinstance(p, bytes) else p for p in pieces])))


def _split(text: bytes, n: int) -> list[bytes]:
    vals = text[1:-1].split(b",")
    if len(vals) != n:  # cannot happen for numbers; keep the invariant loud
        raise ValueError(f"column split into {len(vals)} values, expected {n}")
    return vals


class MemorySink:
    def __init__(self):
        self._parts: dict[str, list[pd.DataFrame]] = {}

    def write(self, frames: dict[str, pd.DataFrame]) -> None:
        for topic, f in frames.items():
            self._parts.setdefault(topic, []).append(f)

    def finish(self, meta: dict[str, dict[str, str]]) -> FieldLog:
        log = FieldLog()
        for topic, parts in self._parts.items():
            log.set(topic, parts[0] if len(parts) == 1 else pd.concat(parts))
        log.meta.update(meta)
        return log


_MSG_HDR = np.dtype([("op", "u1"), ("len", "<u8"), ("cid", "<u2"), ("seq", "<u4"), ("lt", "<u8"),
                     ("pt", "<u8")])  # packed: 31 bytes, the MCAP Message record header
_IDX = np.dtype([("t", "<u8"), ("off", "<u8")])


class McapSink:
    """Streams canonical frames into an MCAP file opened by the caller (binary, writable).

    Message records are packed with numpy (one structured array per chunk) rather
    than one Python call per message, which is what makes a 100 Hz CSV import run
    at several hundred thousand rows/s; every other record (header, schemas,
    channels, chunks, indexes, statistics, summary) is written with the mcap
    library's own record classes. CRCs are left 0 ("not computed", as the spec allows).
    """

    def __init__(self, fh, *, chunk_size: int = 1 << 20):
        from mcap.data_stream import RecordBuilder
        from mcap.records import Header

        self._fh = fh
        self._chunk_size = chunk_size
        self._channels: dict[str, int] = {}
        self._schemas: list = []
        self._channel_recs: list = []
        self._seq: dict[str, int] = {}
        self._counts: dict[int, int] = {}
        self._chunk_indexes: list = []
        self._t_min: int | None = None
        self._t_max: int | None = None
        self._n = 0
        fh.write(b"\x89MCAP0\r\n")
        rb = RecordBuilder()
        Header(profile="", library=f"usvlog {__version__}").write(rb)
        fh.write(rb.end())

    def _channel(self, topic: str) -> int:
        from mcap.data_stream import RecordBuilder
        from mcap.records import Channel, Schema

        cid = self._channels.get(topic)
        if cid is None:
            schema = schema_for_topic(topic)
            sid = len(self._schemas) + 1
            cid = len(self._channel_recs) + 1
            srec = Schema(id=sid, name=schema["title"], encoding=SCHEMA_ENCODING,
                          data=json.dumps(schema).encode())
            crec = Channel(id=cid, topic=topic, message_encoding=MESSAGE_ENCODING, schema_id=sid, metadata={})
            rb = RecordBuilder()
            srec.write(rb)
            crec.write(rb)
            self._fh.write(rb.end())
            self._schemas.append(srec)
            self._channel_recs.append(crec)
            self._channels[topic] = cid
            self._seq[topic] = 0
            self._counts[cid] = 0
        return cid

    def write(self, frames: dict[str, pd.DataFrame]) -> None:
        parts = []
        for topic, f in frames.items():
            if not len(f):
                continue
            cid = self._channel(topic)
            payloads = encode_messages(codec_for_topic(topic), f, topic)
            t = np.asarray(f.index, dtype=np.int64)
            s0 = self._seq[topic]
            self._seq[topic] = s0 + len(t)
            self._counts[cid] += len(t)
            parts.append((t, np.full(len(t), cid, np.uint16), np.arange(s0, s0 + len(t), dtype=np.uint32), payloads))
        if not parts:
            return
        t = np.concatenate([p[0] for p in parts])
        order = np.argsort(t, kind="stable")  # one batch's topics interleaved in time
        t = t[order]
        cid = np.concatenate([p[1] for p in parts])[order]
        seq = np.concatenate([p[2] for p in parts])[order]
        allp = [m for p in parts for m in p[3]]
        payloads = [allp[i] for i in order.tolist()]
        sizes = np.fromiter(map(len, payloads), dtype=np.int64, count=len(payloads))
        rec = sizes + 31
        ends = np.cumsum(rec)
        # chunk boundaries every ~chunk_size bytes of records
        cuts = np.searchsorted(ends, np.arange(self._chunk_size, int(ends[-1]), self._chunk_size), side="left")
        bounds = [0] + sorted(set((cuts + 1).tolist()) - {0, len(t)}) + [len(t)]
        for a, b in zip(bounds[:-1], bounds[1:]):
            self._write_chunk(t[a:b], cid[a:b], seq[a:b], payloads[a:b], sizes[a:b])

    def _write_chunk(self, t, cid, seq, payloads, sizes) -> None:
        import zstandard
        from mcap.data_stream import RecordBuilder
        from mcap.records import Chunk, ChunkIndex

        n = len(t)
        hdr = np.empty(n, _MSG_HDR)
        hdr["op"] = 0x05
        hdr["len"] = sizes + 22
        hdr["cid"] = cid
        hdr["seq"] = seq
        hdr["lt"] = t
        hdr["pt"] = t
        hb = hdr.tobytes()
        heads = map(hb.__getitem__, map(slice, range(0, 31 * n, 31), range(31, 31 * n + 31, 31)))
        body = b"".join(chain.from_iterable(zip(heads, payloads)))
        offsets = np.concatenate([[0], np.cumsum(sizes + 31)[:-1]]).astype(np.uint64)
        data = zstandard.ZstdCompressor(level=1).compress(body)
        t0, t1 = int(t.min()), int(t.max())
        start = self._fh.tell()
        rb = RecordBuilder()
        Chunk(compression="zstd", data=data, message_start_time=t0, message_end_time=t1,
              uncompressed_crc=0, uncompressed_size=len(body)).write(rb)
        chunk_bytes = rb.end()
        self._fh.write(chunk_bytes)
        # message indexes, one per channel in the chunk
        idx_start = start + len(chunk_bytes)
        offs = {}
        pieces = []
        pos = idx_start
        for c in np.unique(cid).tolist():
            m = cid == c
            arr = np.empty(int(m.sum()), _IDX)
            arr["t"] = t[m]
            arr["off"] = offsets[m]
            raw = arr.tobytes()
            rec = struct.pack("<BQHI", 0x07, 2 + 4 + len(raw), c, len(raw)) + raw
            offs[c] = pos
            pos += len(rec)
            pieces.append(rec)
        idx_bytes = b"".join(pieces)
        self._fh.write(idx_bytes)
        self._chunk_indexes.append(ChunkIndex(
            message_start_time=t0, message_end_time=t1, chunk_start_offset=start, chunk_length=len(chunk_bytes),
            message_index_offsets=offs, message_index_length=len(idx_bytes), compression="zstd",
            compressed_size=len(data), uncompressed_size=len(body)))
        self._t_min = t0 if self._t_min is None else min(self._t_min, t0)
        self._t_max = t1 if self._t_max is None else max(self._t_max, t1)
        self._n += n

    def finish(self, meta: dict[str, dict[str, str]]) -> None:
        from mcap.data_stream import RecordBuilder
        from mcap.opcode import Opcode
        from mcap.records import DataEnd, Footer, Metadata, MetadataIndex, Statistics, SummaryOffset

        fh = self._fh
        meta_index = []
        for name in sorted(meta):
            rb = RecordBuilder()
            Metadata(name=name, metadata={str(k): str(v) for k, v in meta[name].items()}).write(rb)
            b = rb.end()
            meta_index.append(MetadataIndex(offset=fh.tell(), length=len(b), name=name))
            fh.write(b)
        rb = RecordBuilder()
        DataEnd(data_section_crc=0).write(rb)
        fh.write(rb.end())
        summary_start = fh.tell()
        sb = RecordBuilder()
        offsets = []

        def group(op, recs):
            g0 = sb.count
            for r in recs:
                r.write(sb)
            if recs:
                offsets.append(SummaryOffset(group_opcode=op, group_start=summary_start + g0,
                                             group_length=sb.count - g0))

        group(Opcode.SCHEMA, self._schemas)
        group(Opcode.CHANNEL, self._channel_recs)
        group(Opcode.STATISTICS, [Statistics(
            message_count=self._n, schema_count=len(self._schemas), channel_count=len(self._channel_recs),
            attachment_count=0, metadata_count=len(meta_index), chunk_count=len(self._chunk_indexes),
            message_start_time=self._t_min or 0, message_end_time=self._t_max or 0,
            channel_message_counts=dict(self._counts))])
        group(Opcode.CHUNK_INDEX, self._chunk_indexes)
        group(Opcode.METADATA_INDEX, meta_index)
        offset_start = summary_start + sb.count
        for o in offsets:
            o.write(sb)
        fh.write(sb.end())
        rb = RecordBuilder()
        Footer(summary_start=summary_start, summary_offset_start=offset_start, summary_crc=0).write(rb)
        fh.write(rb.end())
        fh.write(b"\x89MCAP0\r\n")
