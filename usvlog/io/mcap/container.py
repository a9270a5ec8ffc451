"""The MCAP container: its records, what a walk found, the summary and the file's layout.

The lowest layer of reading a canonical log (:mod:`.reader` is the front door). Here are
the pieces every walk of a file is made of: parsing one schema, channel or metadata record
(:func:`_parse`, kept in the walk's :class:`_Scan` by :func:`_apply`); checking one chunk
record (its header, decompression, size and CRC: :func:`_chunk_data`, which raises
:class:`_CorruptChunk`); and the file's layout, found before a walk starts: the footer, the
summary section (schemas, channels, the chunk and metadata indexes, its CRC checked) and so
where the data section ends (:func:`_layout`; :func:`_layout_windowed` on a memory map,
giving its pages back as it searches).

The walks that use them are :mod:`.walk` (compiled loops) and
:func:`.reference._scan_reference` (one record at a time); what to do about damage is
:mod:`.recovery`'s.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

import numpy as np

from .format import (
    _CHUNK,
    _FOOTER,
    _MSG,
    _REC,
    _U16,
    _U32,
    _U64,
    MAGIC,
    OP_CHANNEL,
    OP_CHUNK_INDEX,
    OP_FOOTER,
    OP_METADATA,
    OP_METADATA_INDEX,
    OP_SCHEMA,
    OP_STATISTICS,
)
from .format import (
    crc32 as _crc32,
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
class _Summary:
    """The summary section, when the footer and the summary CRC check out."""

    start: int                                      # summary start = end of the data section
    schemas: dict = field(default_factory=dict)     # id -> (name, encoding, data)
    channels: dict = field(default_factory=dict)    # id -> (topic, schema id, encoding)
    chunks: dict = field(default_factory=dict)      # offset -> (record length, t0, t1, channel ids)
    chunk_offsets: list = field(default_factory=list)
    metadata: dict = field(default_factory=dict)    # offset -> (record length, name)
    counts: dict | None = None                      # channel id -> messages (the Statistics record)


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


def _summary_channel(scan: _Scan, cid: int) -> _Channel | None:
    """A channel whose definition was lost with its chunk, from the summary's copy."""
    s = scan.summary
    if s is None or cid not in s.channels:
        return None
    topic, sid, enc = s.channels[cid]
    return _Channel(topic, sid, enc)


# -- one chunk record: checked, decompressed, its records --------------------------

_PAST_CHUNK = "a record runs past the end of the chunk"


_MAX_CHUNK = 1 << 32     # an uncompressed size above this is taken as a damaged header (bytes)


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
            elif op == OP_STATISTICS:   # the per-channel message counts (sizes for the decode)
                s.counts = _channel_counts(mv, body, nxt)
            off = nxt
    except (struct.error, UnicodeDecodeError, IndexError, TypeError):
        return None
    s.chunk_offsets = sorted(s.chunks)
    return s


def _channel_counts(mv, body: int, end: int) -> dict | None:
    """A Statistics record's channel message counts (channel id -> count); None when they
    do not parse (the counts are a hint: a reader decodes without them)."""
    at = body + 8 + 2 + 4 * 4 + 8 + 8   # message, schema, channel, attachment, metadata, chunk counts; times
    if at + 4 > end:
        return None
    n = _U32.unpack_from(mv, at)[0]
    at += 4
    if n % 10 or at + n > end:
        return None
    return {int(c): int(k) for c, k in struct.iter_unpack("<HQ", mv[at:at + n])}


def _layout(scan: _Scan, data: bytes, find_footer=_find_footer) -> None:
    """Find the footer (by ``find_footer(data)``) and summary; set where the data section ends."""
    scan.size = len(data)
    f = find_footer(data)
    if f >= 0:
        scan.footer, scan.mcap_end, scan.footer_at = True, f + 37, f
        scan.summary = _read_summary(data, f)
        scan.data_end = scan.summary.start if scan.summary is not None else f
    else:
        scan.mcap_end = scan.data_end = len(data)
    if data[:8] != MAGIC:
        scan.regions.append((0, 8, "bad magic bytes at the start"))


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
    """:func:`_layout` for a memory-mapped file (its pages released after the search)."""
    _layout(scan, data, lambda d: _find_footer_windowed(d, release))
    release()
