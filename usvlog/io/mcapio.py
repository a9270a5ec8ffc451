"""Canonical MCAP logs: write a FieldLog, read one back (recovering damaged files).

Layout written: header, metadata records (datum, vessel, provenance: first, so a
truncated file keeps them), then zstd chunks of JSON messages in log-time order,
then the usual summary (indexes, statistics). Each message's ``sequence`` is its
row number in the channel's frame so reading restores the frame's row order.

Reading walks the records itself (``_walk``) rather than through the mcap
library's per-record objects: it stops at the first incomplete record of a file
cut short, keeps every complete chunk, and reports what was lost.
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
from ..errors import FormatError, InputError, StorageError
from ..log import FieldLog, RecoveryReport
from .atomic import atomic_path

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

def _codec_for(log: FieldLog, topic: str) -> tuple[dict, Codec]:
    schema = schema_for_topic(topic) or log.schemas.get(topic)
    if schema is None:
        schema = auto_schema(topic, log.channels[topic])
    codec = codec_for_topic(topic) or codec_for_schema(schema)
    return schema, codec


def encode_log(log: FieldLog) -> list[tuple[str, dict, np.ndarray, list[bytes]]]:
    """[(topic, schema, t_ns, payloads)] for every channel, validated for writing."""
    out = []
    for topic in log.topics:
        frame = log.channels[topic]
        schema, codec = _codec_for(log, topic)
        t = np.asarray(frame.index, dtype=np.int64)
        if len(t) and t.min() < 0:
            raise InputError(f"channel {topic}: negative time stamp at row {int(np.argmin(t))}")
        out.append((topic, schema, t, codec.encode(frame, topic)))
    return out


def write_log(log: FieldLog, path, *, force: bool = False, chunk_size: int = 1 << 20,
              compression: str = "zstd") -> None:
    """Write ``log`` as a canonical MCAP file, atomically."""
    from mcap.writer import CompressionType, Writer

    comp = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}[compression]
    encoded = encode_log(log)
    with atomic_path(path, force=force) as tmp:
        with open(tmp, "wb") as fh:
            w = Writer(fh, chunk_size=chunk_size, compression=comp)
            w.start(profile="", library=f"usvlog {__version__}")
            for name in sorted(log.meta):
                w.add_metadata(name, {str(k): str(v) for k, v in log.meta[name].items()})
            schema_ids: dict[str, int] = {}
            chan_ids, times, rows, chans = [], [], [], []
            for ci, (topic, schema, t, payloads) in enumerate(encoded):
                sname = schema.get("title", topic)
                sdata = json.dumps(schema, sort_keys=False).encode()
                key = sname + "\0" + sdata.decode()
                if key not in schema_ids:
                    schema_ids[key] = w.register_schema(name=sname, encoding=SCHEMA_ENCODING, data=sdata)
                cid = w.register_channel(topic=topic, message_encoding=MESSAGE_ENCODING,
                                         schema_id=schema_ids[key])
                chan_ids.append(cid)
                times.append(t)
                rows.append(np.arange(len(t)))
                chans.append(np.full(len(t), ci))
            if times:
                t_all = np.concatenate(times)
                c_all = np.concatenate(chans)
                r_all = np.concatenate(rows)
                order = np.lexsort((r_all, c_all, t_all))
                add = w.add_message
                for t_i, c_i, r_i in zip(t_all[order].tolist(), c_all[order].tolist(), r_all[order].tolist()):
                    add(channel_id=chan_ids[c_i], log_time=t_i, data=encoded[c_i][3][r_i],
                        publish_time=t_i, sequence=r_i)
            w.finish()


# -----------------------------------------------------------------------------
# reading
# -----------------------------------------------------------------------------

@dataclass
class _Channel:
    topic: str
    schema_id: int
    encoding: str
    times: list = field(default_factory=list)
    seqs: list = field(default_factory=list)
    payloads: list = field(default_factory=list)


@dataclass
class _Scan:
    schemas: dict = field(default_factory=dict)     # id -> (name, encoding, data)
    channels: dict = field(default_factory=dict)    # id -> _Channel
    metadata: dict = field(default_factory=dict)
    end_offset: int = 8                             # end of the last complete top-level record
    complete: bool = False                          # footer reached
    reason: str = ""
    lost_chunk_range: tuple[int, int] | None = None


def _string(buf, off):
    n = _U32.unpack_from(buf, off)[0]
    off += 4
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


def _records(scan: _Scan, buf, start: int, end: int, in_chunk: bool):
    """Walk records in buf[start:end]; messages are appended to scan.channels."""
    off = start
    channels = scan.channels
    unpack_rec, unpack_msg = _REC.unpack_from, _MSG.unpack_from
    while off + 9 <= end:
        op, length = unpack_rec(buf, off)
        body = off + 9
        nxt = body + length
        if nxt > end:
            return off, False
        if op == OP_MESSAGE:
            cid, seq, log_time, _pub = unpack_msg(buf, body)
            ch = channels.get(cid)
            if ch is not None:
                ch.times.append(log_time)
                ch.seqs.append(seq)
                ch.payloads.append(buf[body + 22:nxt])
        elif op == OP_CHUNK:
            t0, t1, usize, _crc = _CHUNK.unpack_from(buf, body)
            comp, p = _string(buf, body + 28)
            rlen = _U64.unpack_from(buf, p)[0]
            raw = buf[p + 8:p + 8 + rlen]
            try:
                data = _decompress(comp, raw, usize)
            except Exception as err:  # corrupt chunk: keep what came before
                scan.reason = f"chunk at byte {off} is corrupt ({err})"
                scan.lost_chunk_range = (t0, t1)
                return off, False
            _records(scan, memoryview(data), 0, len(data), True)
        elif op == OP_SCHEMA:
            sid = _U16.unpack_from(buf, body)[0]
            name, p = _string(buf, body + 2)
            enc, p = _string(buf, p)
            n = _U32.unpack_from(buf, p)[0]
            scan.schemas[sid] = (name, enc, bytes(buf[p + 4:p + 4 + n]))
        elif op == OP_CHANNEL:
            cid, sid = struct.unpack_from("<HH", buf, body)
            topic, p = _string(buf, body + 4)
            enc, p = _string(buf, p)
            if cid not in channels:
                channels[cid] = _Channel(topic, sid, enc)
        elif op == OP_METADATA and not in_chunk:
            name, p = _string(buf, body)
            scan.metadata[name], _ = _map(buf, p)
        elif op in (OP_FOOTER,) and not in_chunk:
            scan.complete = True
            return nxt, True
        elif op == OP_DATA_END and not in_chunk:
            # the data section is complete; the summary is not needed for reading
            scan.complete = True
            return nxt, True
        off = nxt
        if not in_chunk:
            scan.end_offset = off
    return off, off == end


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


def scan_file(path) -> tuple[_Scan, int]:
    p = Path(path)
    try:
        data = p.read_bytes()
    except FileNotFoundError as err:
        raise StorageError(f"{p}: no such file") from err
    except OSError as err:
        raise StorageError(f"{p}: cannot read ({err.strerror})") from err
    if len(data) < 8 or data[:8] != MAGIC:
        raise FormatError(f"{p}: not an MCAP file (bad magic bytes)")
    scan = _Scan()
    buf = memoryview(data)
    try:
        _records(scan, buf, 8, len(data), False)
    except (struct.error, UnicodeDecodeError, IndexError) as err:
        scan.reason = f"malformed record after byte {scan.end_offset} ({err})"
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
    p = Path(path)
    scan, size = scan_file(p)
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
        except json.JSONDecodeError as err:
            raise InputError(f"{p} channel {ch.topic}: schema {sname} is not valid JSON") from err
        codec = codec_for_schema(schema)
        t = np.asarray(ch.times, dtype=np.int64)
        seq = np.asarray(ch.seqs, dtype=np.int64)
        order = np.argsort(seq, kind="stable")
        payloads = [ch.payloads[i] for i in order] if not np.all(order[:-1] < order[1:]) else ch.payloads
        try:
            cols = codec.decode(payloads, ch.topic)
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
