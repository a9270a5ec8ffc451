"""The compiled walk of an MCAP file: verified chunks' messages as arrays, in file order.

:func:`_walk` walks the top-level records with compiled loops (:mod:`.kernels`),
decompresses and checks every chunk (:func:`.container._chunk_data`) and yields each
one's messages as arrays (channel id, sequence, log time, payload span, ordinal), going on
past damage as :mod:`.recovery` says. With ``topics``, :func:`_chunks_without` names the
chunks it may pass over unread (by the summary's chunk index). :func:`_scan_fast` is the
walk gathered into one arena of every message (what :func:`.stream.scan_file` returns);
:class:`.stream.ChunkStream` streams the same walk a chunk at a time.
"""

from __future__ import annotations

import struct

import numpy as np

from . import kernels as K
from .container import (
    _PAST_CHUNK,
    _apply,
    _check_message_index,
    _chunk_data,
    _CorruptChunk,
    _layout,
    _layout_windowed,
    _parse,
    _Scan,
    _summary_channel,
)
from .format import (
    _CHUNK,
    _U64,
    OP_CHANNEL,
    OP_CHUNK,
    OP_DATA_END,
    OP_MESSAGE,
    OP_MESSAGE_INDEX,
)
from .recovery import (
    _chunk_shape,
    _finish,
    _finish_windowed,
    _first_over_chunk,
    _note_region,
    _region_reason,
    _resync,
    _unexpected,
)


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
