"""Reading canonical MCAP logs, recovering what a damaged file still holds.

Records are walked here rather than through the mcap library's per-record objects: a
file cut short keeps every complete chunk and the loss is reported. ``_scan_fast`` walks
records and messages into arrays with compiled loops (:mod:`.kernels`);
:func:`.reference._scan_reference` is the plain reading the tests compare it with.
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from ...errors import FormatError, InputError
from ...log.channels import MESSAGE_ENCODING, SCHEMA_ENCODING, frame_from_columns
from ...log.fieldlog import FieldLog, RecoveryReport
from ..atomic import reading
from . import kernels as K
from .codec import codec_for_schema
from .format import (
    _CHUNK,
    _MSG,
    _REC,
    _U16,
    _U32,
    _U64,
    MAGIC,
    OP_CHANNEL,
    OP_CHUNK,
    OP_MESSAGE,
    OP_METADATA,
    OP_SCHEMA,
)


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
        import zstandard  # only the decompressor the file uses is loaded

        return zstandard.ZstdDecompressor().decompress(bytes(raw), max_output_size=usize)
    if comp == "lz4":
        import lz4.frame  # only the decompressor the file uses is loaded

        return lz4.frame.decompress(bytes(raw))
    raise ValueError(f"unsupported compression {comp!r}")


def _read_bytes(p: Path) -> bytes:
    with reading(p):
        data = p.read_bytes()
    if len(data) < 8 or data[:8] != MAGIC:
        raise FormatError(f"{p}: not an MCAP file (bad magic bytes)")
    return data


def scan_file(path, *, scanner=None) -> tuple[_Scan, int]:
    """Walk an MCAP file's records: (scan, file size). ``scanner`` is ``_scan_fast``
    unless given (the tests pass :func:`.reference._scan_reference`)."""
    data = _read_bytes(Path(path))
    scan = (scanner or _scan_fast)(data)
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
    return _read_log(path, topics=topics, strict=strict)


def _read_log(path, *, topics=None, strict=False, scanner=None) -> FieldLog:
    p = Path(path)
    scan, size = scan_file(p, scanner=scanner)
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
        log.channels[ch.topic] = frame_from_columns(cols, t[order], codec.spec)
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
            ids = ", ".join(sorted(map(str, runs)))
            raise InputError(f"{paths[0]}: files belong to different recordings (run ids {ids})")
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
