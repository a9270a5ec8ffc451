"""Reading canonical MCAP logs, recovering what a damaged file still holds.

Records are walked here rather than through the mcap library's per-record objects.
Every chunk's CRC is checked (and the data section CRC in the Data End record, when
set); a chunk that fails, does not decompress or whose records do not parse is never
loaded. After any damaged record the walk resumes at the next chunk that checks out
(the summary's chunk index gives every chunk's offset when the footer and summary
survive; else the bytes are searched for a chunk header whose fields agree and whose
CRC checks out), so every intact chunk is kept wherever the damage is. A message that
does not decode costs that message only. What was lost is reported
(:class:`usvlog.log.fieldlog.RecoveryReport`). Records and messages are walked into
arrays with compiled loops (:mod:`.kernels`); :func:`read_log` decodes the messages a group
of chunks at a time as the walk goes (:class:`ChunkStream`), so its memory is the decoded
frames plus a bounded buffer whatever the file's size, and with ``topics`` it skips the
chunks the summary's chunk index shows hold none of them. ``_scan_fast`` is the same walk
into one buffer of every message (``scan_file``); :func:`.reference._scan_reference` is the
plain reading the tests compare them with.
"""

from __future__ import annotations

import bisect
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ...errors import FormatError, InputError
from ...log.channels import concat_columns, frame_from_columns
from ...log.fieldlog import Channels, DeferredSource, FieldLog, LostChunk, RecoveryReport
from ..atomic import reading
from . import kernels as K
from .codec import channel_codec, loadable
from .format import (
    _CHUNK,
    _FOOTER,
    _MSG,
    _REC,
    _U16,
    _U32,
    _U64,
    COMPRESSIONS,
    MAGIC,
    OP_CHANNEL,
    OP_CHUNK,
    OP_CHUNK_INDEX,
    OP_DATA_END,
    OP_FOOTER,
    OP_MESSAGE,
    OP_MESSAGE_INDEX,
    OP_METADATA,
    OP_METADATA_INDEX,
    OP_SCHEMA,
)
from .format import (
    crc32 as _crc32,
)

if TYPE_CHECKING:   # pandas is imported where a frame is made (inspect never needs it)
    import pandas as pd



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
class _Summary:
    """The summary section, when the footer and the summary CRC check out."""

    start: int                                      # summary start = end of the data section
    schemas: dict = field(default_factory=dict)     # id -> (name, encoding, data)
    channels: dict = field(default_factory=dict)    # id -> (topic, schema id, encoding)
    chunks: dict = field(default_factory=dict)      # offset -> (record length, t0, t1, channel ids)
    chunk_offsets: list = field(default_factory=list)
    metadata: dict = field(default_factory=dict)    # offset -> (record length, name)


@dataclass
class _Scan:
    schemas: dict = field(default_factory=dict)     # id -> (name, encoding, data)
    channels: dict = field(default_factory=dict)    # id -> _Channel
    metadata: dict = field(default_factory=dict)
    arena: np.ndarray | None = None                 # fast scan: every message's bytes
    size: int = 0                                   # file size (bytes)
    data_end: int = 0                               # end of the data section (or of the file)
    mcap_end: int = 0                               # end of the closing magic (or of the file)
    footer: bool = False                            # a footer and closing magic were found
    footer_at: int = -1
    summary: _Summary | None = None
    data_end_at: int = -1                           # offset of the Data End record, if read
    regions: list = field(default_factory=list)     # damaged byte ranges: (start, end, reason)
    lost_chunks: list = field(default_factory=list)  # (offset, size, t0, t1, channel ids, trusted, why)
    bad_messages: dict = field(default_factory=dict)  # channel id (-1 unknown) -> malformed records
    orphans: dict = field(default_factory=dict)     # channel id -> messages on a channel never defined
    notes: list = field(default_factory=list)       # other damage (e.g. data section CRC mismatch)
    metadata_lost: list = field(default_factory=list)
    defined: dict = field(default_factory=dict)     # channel id -> ordinal of its (first) record
    walked: tuple | None = None                     # the last run of top-level records walked

    @property
    def complete(self) -> bool:
        """Nothing damaged or missing in the data section."""
        return not self.regions and not self.notes and not self.bad_messages

    @property
    def reason(self) -> str:
        why = [r[2] for r in self.regions] + self.notes
        if not why:
            return ""
        return why[0] + (f" (and {len(why) - 1} more damaged region(s))" if len(why) > 1 else "")


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


_PAST_CHUNK = "a record runs past the end of the chunk"
_MAX_CHUNK = 1 << 32     # an uncompressed size above this is taken as a damaged header (bytes)
_DAY_NS = 86_400 * 10**9


_DECOMPRESSED = [0]   # chunks this process has decompressed (see chunks_decompressed)


def chunks_decompressed() -> int:
    """How many chunk records this process's reads have decompressed so far (every chunk
    a read does not skip is decompressed and its CRC checked, by any thread).

    Returns
    -------
    int
        The count since the module was loaded (compare two calls around a read).
    """
    return _DECOMPRESSED[0]


def _chunk_data(buf, body: int, nxt: int) -> tuple[int, int, bytes]:
    """A chunk record's (start time, end time, uncompressed records), checked.

    Raises _CorruptChunk when the header does not parse, the data do not fill the
    record, cannot be decompressed, have another size than the header says, or fail
    the CRC (a CRC of 0 means "not set" in MCAP and is not checked)."""
    try:
        t0, t1, usize, crc = _CHUNK.unpack_from(buf, body)
        comp, p = _string(buf, body + 28)
        rlen = _U64.unpack_from(buf, p)[0]
    except (struct.error, UnicodeDecodeError) as err:
        raise _CorruptChunk(f"bad header: {err}") from err
    if p + 8 + rlen != nxt:
        raise _CorruptChunk("its data length disagrees with its record length")
    if usize > _MAX_CHUNK:
        raise _CorruptChunk(f"implausible uncompressed size {usize}")
    _DECOMPRESSED[0] += 1
    try:
        out = _decompress(comp, buf[p + 8:nxt], usize)
    except Exception as err:  # any decompressor failure: the chunk is damaged
        raise _CorruptChunk(f"cannot decompress: {err}") from err
    if len(out) != usize:
        raise _CorruptChunk(f"{len(out)} bytes uncompressed, header says {usize}")
    if crc and _crc32(out) != crc:
        raise _CorruptChunk("CRC mismatch")
    return t0, t1, out


def _chunk_records(data) -> list[tuple[int, int, int]]:
    """(op, body start, body end) of every record in a decompressed chunk; a chunk
    whose records do not fit it exactly is corrupt."""
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
    return out


def _check_message_index(buf, body: int, length: int) -> None:
    """A Message Index record must be its channel id, a byte count and 16-byte entries."""
    if length < 6 or _U32.unpack_from(buf, body + 2)[0] != length - 6 or (length - 6) % 16:
        raise struct.error("bad message index record")


def _add_message(scan: _Scan, buf, body: int, nxt: int) -> None:
    """The reference reading of one message record (a malformed one is counted, not kept;
    one on a channel not defined yet waits in ``scan.orphans``)."""
    if nxt - body < 22 or _U64.unpack_from(buf, body + 6)[0] >= 1 << 63:
        scan.bad_messages[-1] = scan.bad_messages.get(-1, 0) + 1
        return
    cid, seq, log_time, _pub = _MSG.unpack_from(buf, body)
    ch = scan.channels.get(cid)
    if ch is not None:
        ch.times.append(log_time)
        ch.seqs.append(seq)
        ch.payloads.append(bytes(buf[body + 22:nxt]))
    else:
        scan.orphans.setdefault(cid, []).append((log_time, seq, bytes(buf[body + 22:nxt])))


# -- the file's layout: footer, summary, where the data section ends --------------------

def _find_footer(data: bytes) -> int:
    """Offset of the last Footer record followed by the closing magic, or -1."""
    end = len(data)
    while True:
        m = data.rfind(MAGIC, 8, end)
        if m < 0:
            return -1
        f = m - 29
        if f >= 8 and data[f] == OP_FOOTER and _U64.unpack_from(data, f + 1)[0] == 20:
            return f
        end = m + len(MAGIC) - 1


def _read_summary(data: bytes, footer_at: int) -> _Summary | None:
    """The summary section named by the footer at ``footer_at``; None when there is none,
    its CRC fails, or a record in it does not parse."""
    _op, _len, start, offsets_at, crc = _FOOTER.unpack_from(data, footer_at)
    if start == 0 or not 8 <= start <= footer_at:
        return None
    mv = memoryview(data)
    if crc and _crc32(mv[start:footer_at + 25]) != crc:
        return None
    stop = offsets_at if start <= offsets_at <= footer_at and offsets_at else footer_at
    s = _Summary(start=start)
    off = start
    try:
        while off < stop:
            op, length = _REC.unpack_from(mv, off)
            body, nxt = off + 9, off + 9 + length
            if nxt > stop:
                return None
            if op in (OP_SCHEMA, OP_CHANNEL):
                pr = _parse(op, mv[body:nxt])
                assert pr is not None
                if op == OP_SCHEMA:
                    s.schemas[pr[1]] = pr[2:]
                else:
                    s.channels[pr[1]] = (pr[3], pr[2], pr[4])
            elif op == OP_CHUNK_INDEX:
                t0, t1, at, size = struct.unpack_from("<QQQQ", mv, body)
                n = _U32.unpack_from(mv, body + 32)[0]
                if n % 10 or body + 36 + n > nxt:
                    return None
                cids = tuple(_U16.unpack_from(mv, body + 36 + k)[0] for k in range(0, n, 10))
                s.chunks[at] = (size, t0, t1, cids)
            elif op == OP_METADATA_INDEX:
                at, size = struct.unpack_from("<QQ", mv, body)
                s.metadata[at] = (size, _string(mv, body + 16)[0])
            off = nxt
    except (struct.error, UnicodeDecodeError, IndexError, TypeError):
        return None
    s.chunk_offsets = sorted(s.chunks)
    return s


def _layout(scan: _Scan, data: bytes) -> None:
    """Find the footer and summary; set where the data section ends."""
    scan.size = len(data)
    f = _find_footer(data)
    if f >= 0:
        scan.footer, scan.mcap_end, scan.footer_at = True, f + 37, f
        scan.summary = _read_summary(data, f)
        scan.data_end = scan.summary.start if scan.summary is not None else f
    else:
        scan.mcap_end = scan.data_end = len(data)
    if data[:8] != MAGIC:
        scan.regions.append((0, 8, "bad magic bytes at the start"))


def _unexpected(scan: _Scan, op: int, off: int, length: int) -> str | None:
    """With a summary, a chunk or metadata record must be one its indexes list, and no
    record may run over the start of a chunk the chunk index lists (damaged bytes read as a
    record must not swallow an intact chunk)."""
    s = scan.summary
    if s is None:
        return None
    if op == OP_CHUNK and s.chunks and s.chunks.get(off, (-1,))[0] != length + 9:
        return f"chunk record at byte {off} is not in the chunk index"
    if op == OP_METADATA and s.metadata and s.metadata.get(off, (-1,))[0] != length + 9:
        return f"metadata record at byte {off} is not in the metadata index"
    j = bisect.bisect_right(s.chunk_offsets, off)
    if j < len(s.chunk_offsets) and s.chunk_offsets[j] < off + 9 + length:
        return _over_chunk(off, s.chunk_offsets[j])
    return None


def _over_chunk(off: int, chunk_at: int) -> str:
    return f"record at byte {off} runs over the chunk at byte {chunk_at}"


def _first_over_chunk(scan: _Scan, ops, offs, lens) -> tuple[int, str | None]:
    """(index, reason) of the first message record among ``ops`` that runs over the start
    of a listed chunk (:func:`_unexpected`'s rule, for the records the compiled walk reads
    as messages), else (len(ops), None)."""
    s = scan.summary
    if s is None or not s.chunk_offsets or not len(ops):
        return len(ops), None
    co = np.asarray(s.chunk_offsets, dtype=np.int64)
    j = np.searchsorted(co, offs, side="right")
    nxt = co[np.minimum(j, len(co) - 1)]
    over = (ops == OP_MESSAGE) & (j < len(co)) & (nxt < offs + 9 + lens)
    if not over.any():
        return len(ops), None
    i = int(np.argmax(over))
    return i, _over_chunk(int(offs[i]), int(nxt[i]))


def _chunk_shape(data: bytes, p: int, end: int) -> int:
    """Length of the chunk record at p if its header is consistent (see
    :func:`.kernels.find_chunk`, which this is the reference of), else -1."""
    if p + 49 > end or data[p] != OP_CHUNK:
        return -1
    length = _U64.unpack_from(data, p + 1)[0]
    if not 40 <= length <= end - p - 9:
        return -1
    t0, t1, usize, _crc = _CHUNK.unpack_from(data, p + 9)
    clen = _U32.unpack_from(data, p + 37)[0]
    if t0 > t1 or t1 >= 1 << 63 or 40 + clen > length or data[p + 41:p + 41 + clen] not in COMPRESSIONS:
        return -1
    rlen = _U64.unpack_from(data, p + 41 + clen)[0]
    if rlen != length - 40 - clen or (clen == 0 and usize != rlen):
        return -1
    return length


def _next_chunk_reference(data: bytes, start: int, end: int) -> int:
    """First offset >= start where a chunk record with a consistent header begins, or -1."""
    p = data.find(b"\x06", start, end)
    while p >= 0:
        if _chunk_shape(data, p, end) >= 0:
            return p
        p = data.find(b"\x06", p + 1, end)
    return -1


def _resync(scan: _Scan, start: int, verify, find_next) -> int | None:
    """Offset of the first chunk after ``start`` that passes ``verify`` (the chunk
    index's offsets when the summary survived, else chunk headers found by
    ``find_next``), or None."""
    s = scan.summary
    if s is not None and s.chunks:
        for off in s.chunk_offsets[bisect.bisect_right(s.chunk_offsets, start):]:
            if off >= scan.data_end:
                break
            if verify(off) is None:
                return off
        return None
    p = start + 1
    while True:
        c = find_next(p)
        if c < 0:
            return None
        if verify(c) is None:
            return c
        p = c + 1


def _index_channels(data: bytes, p: int, end: int) -> tuple | None:
    """Channel ids of the Message Index records that follow a chunk ending at p."""
    cids = []
    while p + 15 <= end and data[p] == OP_MESSAGE_INDEX:
        length = _U64.unpack_from(data, p + 1)[0]
        if length < 6 or p + 9 + length > end:
            break
        cid, n = struct.unpack_from("<HI", data, p + 9)
        if n != length - 6 or n % 16:
            break
        cids.append(cid)
        p += 9 + length
    return tuple(cids) or None


def _note_region(scan: _Scan, data: bytes, start: int, end: int, reason: str, verify) -> None:
    """Record the damaged range [start, end) and the chunks lost in it: the chunk
    index's when the summary survived (time range and channels exact), else the
    chunk headers found in the range (times as written, channels from the message
    indexes that follow, when they survive)."""
    scan.regions.append((start, end, reason))
    s = scan.summary
    if s is not None and s.chunks:
        for off in s.chunk_offsets[bisect.bisect_left(s.chunk_offsets, start):]:
            if off >= end:
                break
            size, t0, t1, cids = s.chunks[off]
            why = reason if off == start else (verify(off) or "damaged")
            scan.lost_chunks.append((off, size, t0, t1, cids, True, why))
        return
    p = start + 1
    if start + 9 <= len(data) and data[start] == OP_CHUNK:
        length = _U64.unpack_from(data, start + 1)[0]
        t0, t1 = struct.unpack_from("<QQ", data, start + 9) if start + 25 <= len(data) else (None, None)
        if 40 <= length <= end - start - 9:
            size, p = 9 + length, start + 9 + length
            cids = _index_channels(data, p, scan.data_end)
        else:
            size, p, cids = end - start, end, None
        scan.lost_chunks.append((start, size, t0, t1, cids, False, reason))
    while p < end:
        c = _next_chunk_reference(data, p, end)
        if c < 0:
            break
        length = _U64.unpack_from(data, c + 1)[0]
        t0, t1 = struct.unpack_from("<QQ", data, c + 9)
        cids = _index_channels(data, c + 9 + length, scan.data_end)
        scan.lost_chunks.append((c, 9 + length, t0, t1, cids, False, verify(c) or "damaged"))
        p = c + 9 + length


def _region_reason(scan: _Scan, off: int, resumed: bool) -> str:
    if not scan.footer and not resumed:
        return "file ends inside a record (cut short)"
    return f"malformed record at byte {off} (runs past the end of the data section)"


def _finish(scan: _Scan, data: bytes, crc_upto=None) -> None:
    """After the walk: metadata and schemas the summary still has, the data section CRC
    (``crc_upto(n)``, when given, is the CRC-32 of ``data[:n]``)."""
    s = scan.summary
    mv = memoryview(data)
    if s is not None:
        for sid, rec in s.schemas.items():
            scan.schemas.setdefault(sid, rec)
        for off, (size, name) in s.metadata.items():
            if name in scan.metadata:
                continue
            try:
                op, length = _REC.unpack_from(mv, off)
                pr = _parse(op, mv[off + 9:off + 9 + length]) if op == OP_METADATA and length + 9 == size else None
            except (struct.error, UnicodeDecodeError, IndexError):
                pr = None
            if pr is not None and pr[1] == name and off + size <= scan.data_end:
                scan.metadata[name] = pr[2]
            else:
                scan.metadata_lost.append(name)
    if scan.data_end_at >= 0:
        # the footer that closes this data section (not one in bytes appended after it)
        off, found = scan.data_end_at + 13, -1
        try:
            while off + 9 <= len(data):
                op, length = _REC.unpack_from(mv, off)
                if op == OP_FOOTER and length == 20 and data[off + 29:off + 37] == MAGIC:
                    found = off
                    break
                off += 9 + length
        except struct.error:
            pass
        if found < 0:
            scan.notes.append("the summary or footer after the data is damaged or missing"
                              " (the data section was read in full)")
        else:
            scan.footer, scan.mcap_end = True, found + 37
            if (scan.summary is None if found == scan.footer_at else _read_summary(data, found) is None) \
                    and _FOOTER.unpack_from(data, found)[2] != 0:
                scan.notes.append("the summary section is damaged (its CRC fails; the data section was read in full)")
    if not scan.regions and scan.data_end_at >= 0:
        crc = _U32.unpack_from(mv, scan.data_end_at + 9)[0]
        if crc and (crc_upto(scan.data_end_at) if crc_upto else _crc32(mv[:scan.data_end_at])) != crc:
            scan.notes.append("data section CRC mismatch: a record outside the chunks (header, metadata or"
                              " an index) is damaged, the metadata may be wrong")


def _summary_channel(scan: _Scan, cid: int) -> _Channel | None:
    """A channel whose definition was lost with its chunk, from the summary's copy."""
    s = scan.summary
    if s is None or cid not in s.channels:
        return None
    topic, sid, enc = s.channels[cid]
    return _Channel(topic, sid, enc)


# -- the compiled scan ----------------------------------------------------------------

def _fast_chunk(mv, K, off: int, nxt: int):
    """A chunk record at ``off`` read with compiled loops: (records as bytes, message
    record indices, their fields, the parsed schema/channel/metadata records)."""
    _t0, _t1, raw = _chunk_data(mv, off + 9, nxt)
    chunk = np.frombuffer(raw, dtype=np.uint8)
    cops, coffs, clens, _cstop, ccomplete = K.walk_records(chunk, 0, len(chunk), False)
    if not ccomplete:
        raise _CorruptChunk(_PAST_CHUNK)
    m = np.flatnonzero(cops == OP_MESSAGE)
    cid, seq, t, ps, pe, _ok = K.message_fields(chunk, coffs[m], clens[m])
    cmv = memoryview(chunk)
    try:
        parsed = [(j, _parse(int(cops[j]), cmv[coffs[j] + 9:coffs[j] + 9 + clens[j]]))
                  for j in np.flatnonzero(cops != OP_MESSAGE).tolist()]
    except (struct.error, UnicodeDecodeError, IndexError) as err:
        raise _CorruptChunk(f"a record in it does not parse: {err}") from err
    return chunk, m, cid, seq, t, ps, pe, parsed


def _walk(scan: _Scan, data, release=None, window: int | None = None, skip: frozenset = frozenset()):
    """Walk an MCAP file's records, checking every chunk: yields one batch of messages per
    chunk that checks out (and per run of messages outside chunks), in file order.

    A batch is ``(records, msgs, at, t0, t1)``: ``records`` the bytes the messages lie in
    (a chunk's decompressed records as a uint8 array, or the file's buffer),
    ``msgs = (channel id, sequence, log time, payload start, payload end, ordinal)``
    arrays (malformed message records left out and counted in ``scan.bad_messages``;
    ``ordinal`` orders records in the file, ``scan.defined`` holds each channel's),
    ``at`` the chunk record's offset (-1 outside chunks) and ``t0``/``t1`` its time range.
    Schemas, channels and metadata go into ``scan`` as they are met; after a damaged
    record the walk goes on at the next chunk that checks out (:func:`_resync`) and the
    damaged range is recorded (:func:`_note_region`). Chunks at the offsets in ``skip``
    (see :func:`_chunks_without`) are passed over unread. ``_layout`` must have run;
    ``_finish`` runs after. ``release(offset)``, when given, is called as the walk passes
    an offset it will not read again (a memory map drops its pages there); ``window``
    (bytes), when given, walks the top-level records that many bytes at a time (or one
    record, when it is longer), so the record arrays stay small whatever the file's size."""
    buf = np.frombuffer(data, dtype=np.uint8)
    mv = memoryview(data)
    defined = scan.defined           # channel id -> ordinal of its record
    checked: dict[int, str | None] = {}

    def verify(off: int) -> str | None:
        if off not in checked:
            why = None
            ln = _chunk_shape(data, off, scan.data_end)
            if ln < 0:
                why = "no consistent chunk header"
            else:
                try:
                    _fast_chunk(mv, K, off, off + 9 + ln)
                except _CorruptChunk as err:
                    why = str(err)
            checked[off] = why
        return checked[off]

    def find_next(p: int) -> int:
        return int(K.find_chunk(buf, p, scan.data_end))

    def good(cid, seq, t, ps, pe, ordinal):
        bad = cid < 0
        if bad.any():
            scan.bad_messages[-1] = scan.bad_messages.get(-1, 0) + int(bad.sum())
            ok = ~bad
            return cid[ok], seq[ok], t[ok], ps[ok], pe[ok], ordinal[ok]
        return cid, seq, t, ps, pe, ordinal

    pos, base = 8, 0
    while True:
        end = scan.data_end
        if window is not None and pos + 9 <= end:
            end = min(end, max(pos + window, pos + 9 + _U64.unpack_from(data, pos + 1)[0]))
        ops, offs, lens, stop, complete = K.walk_records(buf, pos, end, True)
        n = len(ops)
        scan.walked = (ops, offs, lens)
        bad_i, why = n, None
        over_i, over_why = _first_over_chunk(scan, ops, offs, lens)
        for i in np.flatnonzero(ops[:over_i] != OP_MESSAGE).tolist():
            op, off, ln = int(ops[i]), int(offs[i]), int(lens[i])
            body, nxt = off + 9, off + 9 + ln
            why = _unexpected(scan, op, off, ln)
            batch = None
            if why is None:
                try:
                    if op == OP_CHUNK and off in skip:
                        pass
                    elif op == OP_CHUNK:
                        chunk, m, cid, seq, t, ps, pe, parsed = _fast_chunk(mv, K, off, nxt)
                        for j, pr in parsed:
                            if pr is not None:
                                if pr[0] == OP_CHANNEL and pr[1] not in scan.channels:
                                    defined[pr[1]] = ((base + i) << 32) + j + 1
                                _apply(scan, pr, True)
                        msgs = good(cid, seq, t, ps, pe, (np.int64(base + i) << 32) + m + 1)
                        t0, t1 = _CHUNK.unpack_from(mv, body)[:2]
                        batch = (chunk, msgs, off, t0, t1)
                    elif op == OP_MESSAGE_INDEX:
                        _check_message_index(mv, body, ln)
                    elif op == OP_DATA_END:
                        scan.data_end_at = off
                    else:
                        pr = _parse(op, mv[body:nxt])
                        if pr is not None:
                            if pr[0] == OP_CHANNEL and pr[1] not in scan.channels:
                                defined[pr[1]] = (base + i) << 32
                            _apply(scan, pr, False)
                except _CorruptChunk as err:
                    why = f"chunk at byte {off} is corrupt ({err})"
                except (struct.error, UnicodeDecodeError, IndexError) as err:
                    why = f"malformed record at byte {off} ({err})"
            if why is not None:
                bad_i = i
                break
            if op == OP_CHUNK:
                if batch is not None and len(batch[1][0]):
                    yield batch
                if release is not None:
                    release(nxt)
        if why is None and over_i < n:
            bad_i, why = over_i, over_why
        top = np.flatnonzero(ops[:bad_i] == OP_MESSAGE)
        if len(top):
            cid, seq, t, ps, pe, _ok = K.message_fields(buf, offs[top], lens[top])
            msgs = good(cid, seq, t, ps, pe, (top.astype(np.int64) + base) << 32)
            if len(msgs[0]):
                yield buf, msgs, -1, None, None
        if why is None:
            if complete or (scan.footer and stop == scan.data_end):
                break
            if end < scan.data_end:   # the window ends here, not the data: walk on
                if release is not None:
                    release(int(stop))
                pos, base = int(stop), base + n
                continue
            bad_at = int(stop)
        else:
            bad_at = int(offs[bad_i])
        resume = _resync(scan, bad_at, verify, find_next)
        _note_region(scan, data, bad_at, scan.data_end if resume is None else resume,
                     why or _region_reason(scan, bad_at, resume is not None), verify)
        if resume is None:
            break
        if release is not None:
            release(resume)
        pos, base = resume, base + n + 1


def _chunks_wanted(scan: _Scan, topics) -> set[int]:
    """Ids of the summary's channels on ``topics``."""
    assert scan.summary is not None
    return {cid for cid, (topic, _sid, _enc) in scan.summary.channels.items() if topic in topics}


def _chunks_without(scan: _Scan, topics) -> frozenset:
    """Offsets of the chunks that hold no message of ``topics`` by the summary's chunk
    index (its CRC checked); none without a summary or when ``topics`` is None.

    Such a chunk is not read: it is neither decompressed nor checked, and a channel or
    schema record in it is taken from the summary's copy."""
    s = scan.summary
    if topics is None or s is None or not s.chunks:
        return frozenset()
    wanted = _chunks_wanted(scan, topics)
    return frozenset(off for off, (_size, _t0, _t1, cids) in s.chunks.items() if wanted.isdisjoint(cids))


def _scan_fast(data, release=None, release_all=None) -> _Scan:
    """The same reading as :func:`.reference._scan_reference`, with the per-message work
    done by compiled loops (:func:`_walk`): a message is kept when its channel was defined
    before it (compared by record ordinals), or, when its definition was lost, the summary
    still defines the channel. Every message's bytes go into one arena.

    ``data`` is the file's bytes or a memory map of it; with a map, ``release(offset)``
    and ``release_all()`` drop its pages behind the walk (see :class:`ChunkStream`), so
    the file is not held in memory next to the arena."""
    scan = _Scan()
    if release_all is None:
        _layout(scan, data)
    else:
        _layout_windowed(scan, data, release_all)
    parts = []                       # (arena offset, cid, seq, t, start, end, ordinal)
    arena = _Arena(0)
    walked = None
    for records, (cid, seq, t, ps, pe, ordinal), _at, _t0, _t1 in _walk(scan, data, release):
        if scan.walked is not walked:   # a new run of records: room for its chunks at once
            walked = scan.walked
            ops, offs, lens = walked
            chunk_ops = np.flatnonzero(ops == OP_CHUNK)
            arena.reserve(min(sum(_U64.unpack_from(data, int(offs[i]) + 9 + 16)[0] for i in chunk_ops.tolist()
                                  if lens[i] >= 24), 64 * len(data)))
        parts.append((arena.put(records), cid, seq, t, ps, pe, ordinal))
    if release_all is None:
        _finish(scan, data)
    else:
        _finish_windowed(scan, data, release_all)
    defined = scan.defined
    # messages -> per-channel arrays into one arena of bytes
    scan.arena = arena.buf[:arena.used]
    if parts:
        cid = np.concatenate([p[1] for p in parts])
        seq = np.concatenate([p[2] for p in parts])
        t = np.concatenate([p[3] for p in parts])
        shift = np.concatenate([np.full(len(p[1]), p[0], dtype=np.int64) for p in parts])
        ps = np.concatenate([p[4] for p in parts]) + shift
        pe = np.concatenate([p[5] for p in parts]) + shift
        ordinal = np.concatenate([p[6] for p in parts])
        ids, counts = np.unique(cid, return_counts=True)
        for c, k in zip(ids.tolist(), counts.tolist()):
            if c not in scan.channels:
                ch = _summary_channel(scan, c)
                if ch is None:
                    scan.orphans[c] = k
                else:
                    scan.channels[c] = ch
        for c, ch in scan.channels.items():
            sel = np.flatnonzero((cid == c) & (ordinal > defined.get(c, -1)))
            ch.t, ch.seq, ch.starts, ch.ends = t[sel], seq[sel], ps[sel], pe[sel]
    else:
        for ch in scan.channels.values():
            ch.t = ch.seq = ch.starts = ch.ends = np.zeros(0, dtype=np.int64)
    return scan


class _Arena:
    """One growing byte buffer holding every message's bytes (decompressed chunks)."""

    def __init__(self, capacity: int):
        self.buf = np.empty(max(capacity, 0), dtype=np.uint8)
        self.used = 0

    def reserve(self, n: int) -> None:
        """Make room for ``n`` more bytes."""
        if self.used + n > len(self.buf):
            grown = np.empty(self.used + n, dtype=np.uint8)
            grown[:self.used] = self.buf[:self.used]
            self.buf = grown

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

        return zstandard.ZstdDecompressor().decompress(raw, max_output_size=usize)   # from the map, no copy
    if comp == "lz4":
        import lz4.frame  # only the decompressor the file uses is loaded

        return lz4.frame.decompress(bytes(raw))
    raise ValueError(f"unsupported compression {comp!r}")


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


def read_log(path, *, topics: list[str] | None = None, strict: bool = False, defer: bool = False) -> FieldLog:
    """Load a canonical MCAP log into a :class:`FieldLog`, checking every chunk's CRC.

    Parameters
    ----------
    path : str or Path
        The MCAP file.
    topics : list of str, optional
        Load only these channels.
    strict : bool
        Raise :class:`InputError` on any damage instead of recovering.
    defer : bool
        With ``topics``: decode only those now and keep the file's other canonical
        channels deferred (``log.channels`` is a :class:`~usvlog.log.fieldlog.Channels`:
        they are listed, their schemas are in ``log.schemas``, and each is decoded when first
        touched; :func:`.writer.write_log` copies one still deferred without decoding it).
        A damaged file is read whole instead (its recovery report is then the full one).

    Returns
    -------
    FieldLog
        ``log.recovery`` is None for an undamaged file. A damaged one loads with every
        chunk that checks out (CRC, decompression, records) wherever the damage is, and
        every message that decodes; ``log.recovery`` (:class:`RecoveryReport`) lists the
        damaged byte ranges, the chunks lost (time range and channels where known), the
        messages skipped and bytes after the footer. A chunk that fails is never loaded.
    """
    if defer and topics is not None:
        log = _read_deferred(Path(path), list(topics), strict)
    else:
        log = _read_log(path, topics=topics, strict=strict)
    _return_freed_memory()
    return log


def _load_channels(path: str, topics: list[str]) -> dict[str, pd.DataFrame]:
    """The frames of ``topics`` of the file (the loader of deferred channels)."""
    log = _read_log(path, topics=topics)
    if log.recovery is not None:   # it read intact before: it changed under the same size and time
        raise InputError(f"{path}: damaged since it was read ({log.recovery.reason}); load it again")
    frames = {t: log.channels[t] for t in topics if t in log.channels}
    _return_freed_memory()
    return frames


def _read_deferred(p: Path, topics: list[str], strict: bool) -> FieldLog:
    """:func:`read_log` of ``topics``, the file's other canonical channels deferred."""
    import os  # stdlib: the file's size and time when read

    with reading(p):   # a missing or unreadable file: the one-line error of any read
        st = os.stat(p)
    log = _read_log(p, topics=topics, strict=strict)
    if log.recovery is not None:   # damaged: read whole, as without deferral
        return _read_log(p, strict=strict)
    stored = _stored_channels(p)
    if stored is None:   # no summary, or a topic on two channels: read whole
        return _read_log(p, strict=strict)
    rest = {t: v for t, v in stored.items() if t not in log.channels and t not in topics}
    for t, (enc, sname, senc, sdata) in rest.items():
        log.schemas[t] = _codec_of(p, t, enc, senc, sname, sdata)[0]
    log.channels = Channels(log.channels, DeferredSource(str(p), st.st_size, st.st_mtime_ns, stored, _load_channels),
                            rest)
    return log


def _stored_channels(p: Path) -> dict[str, tuple[str, str, str, bytes]] | None:
    """Topic -> (message encoding, schema name, schema encoding, schema bytes) of every
    canonical channel the file's summary lists (read from the summary alone); None when
    there is no summary or a topic is on more than one channel."""
    with ChunkStream(p) as stream:
        scan = stream._scan
        _layout_windowed(scan, stream._map, stream._release_all)
        s = scan.summary
        if s is None:
            return None
        out = {}
        for _cid, (topic, sid, enc) in sorted(s.channels.items()):
            sname, senc, sdata = s.schemas.get(sid, ("", "", b""))
            if loadable(enc, senc, sname):
                if topic in out:
                    return None
                out[topic] = (enc, sname, senc, bytes(sdata))
        return out


def _return_freed_memory() -> None:
    """Hand the heap that decoding freed back to the system (glibc keeps it otherwise:
    ~300 MB of a 3-hour log's read stayed in the process); a no-op elsewhere."""
    global _MALLOC_TRIM
    if _MALLOC_TRIM is None:
        try:
            import ctypes  # stdlib; only here

            _MALLOC_TRIM = ctypes.CDLL("libc.so.6").malloc_trim
        except (OSError, AttributeError):
            _MALLOC_TRIM = False
    if _MALLOC_TRIM:
        _MALLOC_TRIM(0)


_MALLOC_TRIM = None


def _decode_bad(decode, n: int) -> tuple[dict | None, np.ndarray, InputError | None]:
    """``decode(idx)`` of the n messages that decode: (columns, indices of the messages
    that do not, the error of decoding them all or None). The bad ones are found by
    halving; columns is None when the whole fails but no message fails alone."""
    idx = np.arange(n)
    try:
        return decode(idx), idx[:0], None
    except InputError as err:
        first = err
    bad: list[np.ndarray] = []

    def find(ix: np.ndarray) -> None:
        try:
            decode(ix)
        except InputError:
            if len(ix) == 1:
                bad.append(ix)
            else:
                find(ix[:len(ix) // 2])
                find(ix[len(ix) // 2:])

    find(idx[:n // 2])
    find(idx[n // 2:])
    bad_idx = np.concatenate(bad) if bad else idx[:0]
    if not len(bad_idx):
        return None, bad_idx, first
    return decode(np.setdiff1d(idx, bad_idx)), bad_idx, first


def _decode_tolerant(decode, n: int) -> tuple[dict, np.ndarray]:
    """``decode(idx)`` of all n messages, or of those that decode when some do not:
    (columns, indices of the messages skipped). The error is raised when every message
    fails (a mismatch, not damage) or none fails alone."""
    cols, bad, first = _decode_bad(decode, n)
    if first is not None and (cols is None or len(bad) == n > 1):
        raise first
    return cols, bad


def _plausible(t0, t1, lo, hi) -> bool:
    """A lost chunk's header times are shown when ordered and near the data recovered."""
    if t0 is None or t1 is None or t0 > t1:
        return False
    return lo is None or (t0 >= lo - _DAY_NS and t1 <= hi + _DAY_NS)


def _report(scan: _Scan, size: int, n_msgs: int, t_lo, t_hi, skipped: dict) -> RecoveryReport:
    def topic_of(cid: int) -> str:
        if cid in scan.channels:
            return scan.channels[cid].topic
        if scan.summary is not None and cid in scan.summary.channels:
            return scan.summary.channels[cid][0]
        return f"channel {cid}"

    lost = []
    for off, sz, t0, t1, cids, trusted, why in scan.lost_chunks:
        if not trusted and not _plausible(t0, t1, t_lo, t_hi):
            t0 = t1 = None
        lost.append(LostChunk(offset=off, size=sz, start_ns=t0, end_ns=t1, reason=why,
                              topics=None if cids is None else tuple(sorted({topic_of(c) for c in cids}))))
    bytes_lost = sum(e - s for s, e, _ in scan.regions)
    trailing = size - scan.mcap_end if scan.footer else 0
    for cid, k in scan.bad_messages.items():
        key = "unknown channel" if cid < 0 else topic_of(cid)
        skipped[key] = skipped.get(key, 0) + k
    if scan.regions or scan.notes:
        for cid, k in scan.orphans.items():  # their channel's definition was lost
            key = topic_of(cid)
            skipped[key] = skipped.get(key, 0) + (k if isinstance(k, int) else len(k))
    cut = bool(scan.regions) and not scan.footer and scan.regions[-1][1] >= scan.data_end
    if cut:  # the end of the file is missing: data after the last recovered message
        tail = [c for c in lost if c.offset >= scan.regions[-1][0]]
        lost_from, lost_to = t_hi, (tail[-1].end_ns if tail else None)
    else:
        starts = [c.start_ns for c in lost if c.start_ns is not None]
        ends = [c.end_ns for c in lost if c.end_ns is not None]
        lost_from, lost_to = (min(starts) if starts else None), (max(ends) if ends else None)
    reason = scan.reason
    if not reason and skipped:
        reason = f"{sum(skipped.values())} message(s) could not be read"
    if not reason and scan.metadata_lost:
        reason = "metadata record(s) damaged"
    if not reason and trailing:
        reason = f"{trailing} bytes after the footer"
    return RecoveryReport(
        file_size=size, bytes_recovered=size - bytes_lost - trailing, bytes_lost=bytes_lost,
        messages_recovered=n_msgs, lost_from_ns=lost_from, lost_to_ns=lost_to, reason=reason,
        lost_chunks=tuple(lost), damaged_ranges=tuple((s, e - s) for s, e, _ in scan.regions),
        messages_skipped=sum(skipped.values()), skipped_by_topic=dict(sorted(skipped.items())),
        trailing_bytes=trailing, metadata_lost=tuple(scan.metadata_lost))


_DECODE_BYTES = 16 << 20   # decompressed chunk bytes decoded at a time by read_log


class _ChannelParts:
    """One channel's messages decoded part by part as :func:`read_log` walks the file."""

    def __init__(self, topic: str, schema: dict, codec):
        self.topic, self.schema, self.codec = topic, schema, codec
        self.t: list = []
        self.seq: list = []
        self.ordinal: list = []
        self.cols: list = []
        self.n = self.n_bad = 0
        self.first: InputError | None = None   # the first decoding error met
        self.mismatch = False                  # a part failed with no message failing alone

    def add(self, buf: np.ndarray, sel: np.ndarray, t, seq, ordinal, ps, pe) -> None:
        """Decode the messages ``sel`` (payloads ``buf[ps:pe]``), leaving out those that do not decode."""
        codec, topic = self.codec, self.topic
        starts, ends = ps[sel], pe[sel]

        def decode(ix):   # string columns coded (StrCodes): the frame gathers them from the distinct values
            return codec.decode_spans(buf, starts[ix], ends[ix], topic, coded=True)
        cols, bad, err = _decode_bad(decode, len(sel))
        self.first = self.first or err
        if cols is None:
            self.mismatch = True
            return
        keep = sel if not len(bad) else np.delete(sel, bad)
        self.n += len(sel)
        self.n_bad += len(bad)
        self.t.append(t[keep])
        self.seq.append(seq[keep])
        self.ordinal.append(ordinal[keep])
        self.cols.append(cols)

    def frame(self) -> tuple[pd.DataFrame, int]:
        """(the channel's frame in sequence order, messages skipped); the rules of
        :func:`_decode_tolerant` applied to the whole channel."""
        if self.first is not None and (self.mismatch or self.n_bad == self.n > 1):
            raise self.first
        if not self.t:
            return frame_from_columns(self.codec.empty_columns(), np.zeros(0, dtype=np.int64), self.codec.spec), 0

        def cat(a: list) -> np.ndarray:
            return a[0] if len(a) == 1 else np.concatenate(a)
        t, seq, ordinal = cat(self.t), cat(self.seq), cat(self.ordinal)
        self.t = self.seq = self.ordinal = []
        order = None
        if len(seq) > 1 and not np.all(seq[1:] > seq[:-1]):
            order = np.lexsort((ordinal, seq))   # by sequence, file order among equal ones
        cols = {}
        for c in self.codec.spec.columns:
            a = concat_columns([p[c] for p in self.cols])
            cols[c] = a if order is None else a[order]
        self.cols = []
        own = len({id(a) for a in cols.values()}) == len(cols)   # fresh arrays, one per column
        return frame_from_columns(cols, t if order is None else t[order], self.codec.spec, copy=not own), self.n_bad


def _read_streamed(p: Path, topics, strict: bool) -> FieldLog:
    """:func:`read_log` a group of chunks at a time: memory bounded by the decoded frames."""
    log = FieldLog(source=str(p))
    parts: dict[int, _ChannelParts | None] = {}
    errors: dict[int, InputError] = {}
    with ChunkStream(p, topics=topics) as stream:
        scan = stream._scan

        def channel(c: int) -> _ChannelParts | None:
            if c not in parts:
                ch = scan.channels[c]
                part = None
                sname, senc, sdata = scan.schemas.get(ch.schema_id, ("", "", b""))
                if (topics is None or ch.topic in topics) and loadable(ch.encoding, senc, sname):
                    try:
                        part = _ChannelParts(ch.topic, *_codec_of(p, ch.topic, ch.encoding, senc, sname, sdata))
                    except InputError as err:
                        errors[c] = err
                parts[c] = part
            return parts[c]

        group: list = []
        held = 0

        def decode_group() -> None:
            if len(group) == 1:
                buf, (cid, seq, t, ps, pe, ordinal) = group[0]
            else:
                bufs = [g[0] for g in group]
                shift = np.cumsum([0] + [len(b) for b in bufs[:-1]])
                buf = np.concatenate(bufs)
                cid, seq, t, ps, pe, ordinal = (np.concatenate([g[1][k] + shift[i] if k in (3, 4) else g[1][k]
                                                                for i, g in enumerate(group)]) for k in range(6))
            group.clear()
            for c, sel in by_channel(cid):
                part = channel(c)
                if part is not None and not part.mismatch:
                    part.add(buf, sel, t, seq, ordinal, ps, pe)

        for records, at, _t0, _t1, cid, seq, t, ps, pe, ordinal in stream._batches():
            if at < 0 and group:   # messages outside chunks: their spans in the file's bytes, alone
                decode_group()
                held = 0
            group.append((records, (cid, seq, t, ps, pe, ordinal)))
            held += len(records)
            if at < 0 or held >= _DECODE_BYTES:
                decode_group()
                held = 0
        if group:
            decode_group()
        size = len(stream._map)
    log.meta = dict(scan.metadata)
    n_msgs = 0
    t_lo = t_hi = None
    skipped: dict[str, int] = {}
    for cid in sorted(scan.channels):
        if cid in errors:
            raise errors[cid]
        if cid not in parts:
            channel(cid)
            if cid in errors:
                raise errors[cid]
        part = parts[cid]
        if part is None:
            continue
        try:
            frame, bad = part.frame()
        except InputError as err:
            raise InputError(f"{p} {err}") from err
        if bad:
            skipped[part.topic] = bad
        log.channels[part.topic] = frame
        log.schemas[part.topic] = part.schema
        n_msgs += len(frame)
        if len(frame):
            t = frame.index.to_numpy()
            t_lo = int(t.min()) if t_lo is None else min(t_lo, int(t.min()))
            t_hi = int(t.max()) if t_hi is None else max(t_hi, int(t.max()))
    trailing = scan.footer and scan.mcap_end < size
    if not scan.complete or skipped or trailing or scan.metadata_lost:
        log.recovery = _report(scan, size, n_msgs, t_lo, t_hi, skipped)
        if strict:
            raise InputError(f"{p}: damaged file: {log.recovery.reason}")
    return log


def _codec_of(p: Path, topic: str, enc: str, senc: str, sname: str, sdata: bytes):
    """(schema, codec) of a channel's schema as stored in the file (InputError when unusable):
    :func:`.codec.channel_codec`, whose codecs (and so their message layouts) are cached per schema."""
    try:
        return channel_codec(topic, enc, senc, sname, sdata)
    except (ValueError, TypeError, AttributeError) as err:
        what = "JSON Schema" if enc != "cdr" else "ros2msg schema"
        raise InputError(f"{p} channel {topic}: schema {sname} is not a usable {what} ({err})") from err


def codec_of_channel(path, ch: ChannelInfo):
    """(JSON Schema, codec) :func:`read_log` decodes a channel with (``ch.canonical`` must hold).

    Parameters
    ----------
    path : str or Path
        The file (for the error message).
    ch : ChannelInfo
        The channel, e.g. from :attr:`ChunkStream.channels`.

    Raises
    ------
    InputError
        Its stored schema is not usable.
    """
    return _codec_of(Path(path), ch.topic, ch.message_encoding, ch.schema_encoding, ch.schema_name, ch.schema_data)


def _read_log(path, *, topics=None, strict=False, scanner=None) -> FieldLog:
    p = Path(path)
    if scanner is None:
        return _read_streamed(p, topics, strict)
    scan, size = scan_file(p, scanner=scanner)
    log = FieldLog(source=str(p))
    log.meta = dict(scan.metadata)
    n_msgs = 0
    t_lo = t_hi = None
    skipped: dict[str, int] = {}
    for cid in sorted(scan.channels):
        ch = scan.channels[cid]
        if topics is not None and ch.topic not in topics:
            continue
        sname, senc, sdata = scan.schemas.get(ch.schema_id, ("", "", b""))
        if not loadable(ch.encoding, senc, sname):
            continue  # not a canonical channel: left alone
        schema, codec = _codec_of(p, ch.topic, ch.encoding, senc, sname, sdata)
        if scan.arena is None:
            t = np.asarray(ch.times, dtype=np.int64)
            seq = np.asarray(ch.seqs, dtype=np.int64)
        else:
            t, seq = ch.t, ch.seq
        order = np.argsort(seq, kind="stable")
        payloads = [ch.payloads[i] for i in order.tolist()] if scan.arena is None else None
        starts, ends = (ch.starts[order], ch.ends[order]) if scan.arena is not None else (None, None)

        def decode(ix, payloads=payloads, starts=starts, ends=ends, codec=codec, topic=ch.topic):
            if payloads is not None:
                return codec.decode_reference([payloads[i] for i in ix.tolist()], topic)
            return codec.decode_spans(scan.arena, starts[ix], ends[ix], topic)
        try:
            cols, bad = _decode_tolerant(decode, len(order))
        except InputError as err:
            raise InputError(f"{p} {err}") from err
        if len(bad):
            skipped[ch.topic] = len(bad)
            order = np.delete(order, bad)
        t = t[order]
        log.channels[ch.topic] = frame_from_columns(cols, t, codec.spec)
        log.schemas[ch.topic] = schema
        n_msgs += len(t)
        if len(t):
            t_lo = int(t.min()) if t_lo is None else min(t_lo, int(t.min()))
            t_hi = int(t.max()) if t_hi is None else max(t_hi, int(t.max()))
    trailing = scan.footer and scan.mcap_end < size
    if not scan.complete or skipped or trailing or scan.metadata_lost:
        log.recovery = _report(scan, size, n_msgs, t_lo, t_hi, skipped)
        if strict:
            raise InputError(f"{p}: damaged file: {log.recovery.reason}")
    return log


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
            lo, hi = int(tc.min()), int(tc.max())
            self._t_lo = lo if self._t_lo is None else min(self._t_lo, lo)
            self._t_hi = hi if self._t_hi is None else max(self._t_hi, hi)
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
        trailing = scan.footer and scan.mcap_end < size
        if not scan.complete or skipped or trailing or scan.metadata_lost:
            return _report(scan, size, n, self._t_lo, self._t_hi, skipped)
        return None

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


def _find_footer_windowed(data, release, window: int = 8 << 20) -> int:
    """:func:`_find_footer` searching back from the end a window at a time (each window's
    pages released after), so a file with no footer is not mapped in whole."""
    end = len(data)
    lo = end
    while lo > 8:
        lo = max(8, end - window)
        m = data.rfind(MAGIC, lo, end)
        while m >= 0:
            f = m - 29
            if f >= 8 and data[f] == OP_FOOTER and _U64.unpack_from(data, f + 1)[0] == 20:
                return f
            m = data.rfind(MAGIC, lo, m + len(MAGIC) - 1)
        release()
        end = lo + len(MAGIC) - 1
    return -1


def _layout_windowed(scan: _Scan, data, release) -> None:
    """:func:`_layout` for a memory-mapped file."""
    scan.size = len(data)
    f = _find_footer_windowed(data, release)
    if f >= 0:
        scan.footer, scan.mcap_end, scan.footer_at = True, f + 37, f
        scan.summary = _read_summary(data, f)
        scan.data_end = scan.summary.start if scan.summary is not None else f
    else:
        scan.mcap_end = scan.data_end = len(data)
    if data[:8] != MAGIC:
        scan.regions.append((0, 8, "bad magic bytes at the start"))
    release()


def _finish_windowed(scan: _Scan, data, release, window: int = 8 << 20) -> None:
    """:func:`_finish` for a memory-mapped file: the data section CRC a window at a time."""
    def crc_upto(n: int) -> int:
        mv = memoryview(data)
        crc, off = 0, 0
        try:
            while off < n:
                crc = _crc32(mv[off:min(n, off + window)], crc)
                off += window
                release()
        finally:
            mv.release()
        return crc

    _finish(scan, data, crc_upto)
    release()


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
        if len(frames) == 1:
            out.channels[t] = frames[0]
        else:
            import pandas as pd
            out.channels[t] = pd.concat(frames)
    damaged = [lg for lg in logs if lg.recovery is not None]
    if damaged:
        out.recovery = damaged[-1].recovery
    return out


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
