"""Recovery of damaged MCAP files: spotting damage, resuming past it, reporting what was lost.

A walk (:mod:`.walk`, :func:`.reference._scan_reference`) asks this module three things.
Whether a record it met is damaged though it parses (:func:`_unexpected`,
:func:`_first_over_chunk`: with a summary, a chunk or metadata record must be one its
indexes list and no record may run over a listed chunk). Where to go on after a damaged
record (:func:`_resync`: the next chunk that checks out, from the summary's chunk index,
else by looking for a consistent chunk header, :func:`_chunk_shape`), and which chunks the
damaged range held (:func:`_note_region`). And, after the walk, what the summary still
gives and whether the data section's CRC holds (:func:`_finish`). :func:`_report` turns
all that into the :class:`~usvlog.log.fieldlog.RecoveryReport` a read returns.
"""

from __future__ import annotations

import bisect
import struct

import numpy as np

from ...log.fieldlog import LostChunk, RecoveryReport
from .container import _parse, _read_summary, _Scan
from .format import (
    _CHUNK,
    _FOOTER,
    _REC,
    _U32,
    _U64,
    COMPRESSIONS,
    MAGIC,
    OP_CHUNK,
    OP_FOOTER,
    OP_MESSAGE,
    OP_MESSAGE_INDEX,
    OP_METADATA,
)
from .format import (
    crc32 as _crc32,
)

# -- damage met during a walk, and where to resume -------------------------------------

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


# -- after the walk: what the summary still gives, the data section's CRC ---------------

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


# -- the recovery report ------------------------------------------------------------

_DAY_NS = 86_400 * 10**9


def _plausible(t0, t1, lo, hi) -> bool:
    """A lost chunk's header times are shown when ordered and near the data recovered."""
    if t0 is None or t1 is None or t0 > t1:
        return False
    return lo is None or (t0 >= lo - _DAY_NS and t1 <= hi + _DAY_NS)


def _widen(lo: int | None, hi: int | None, t: np.ndarray) -> tuple[int | None, int | None]:
    """The time range (lo, hi) of the data recovered so far widened to the times ``t``
    (int64 ns; none: unchanged)."""
    if not len(t):
        return lo, hi
    a, b = int(t.min()), int(t.max())
    return (a if lo is None else min(lo, a)), (b if hi is None else max(hi, b))


def _report_if_lost(scan: _Scan, size: int, n_msgs: int, t_lo, t_hi, skipped: dict) -> RecoveryReport | None:
    """:func:`_report` when anything was lost (damage, messages skipped, bytes after the
    footer, metadata), else None."""
    trailing = scan.footer and scan.mcap_end < size
    if not scan.complete or skipped or trailing or scan.metadata_lost:
        return _report(scan, size, n_msgs, t_lo, t_hi, skipped)
    return None


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
