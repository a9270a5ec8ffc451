"""Decoding an MCAP file's channels into frames: the body of :func:`.reader.read_log`.

:func:`_read_streamed` reads a :class:`.stream.ChunkStream` and decodes each canonical
channel's messages a group of chunks at a time (:class:`_ChannelParts`), with the codec of
the schema stored in the file (:func:`_codec_of`), so memory is the decoded frames plus a
bounded buffer: each column is allocated once from the summary's message count of its channel
and filled group by group, and the frame takes the arrays without a copy (without the
summary's statistics, the groups' arrays are joined at the end instead). A message that does
not decode costs that message only: the bad ones are found by halving (:func:`_decode_bad`)
and counted in the recovery report. :func:`_read_log` with a ``scanner`` decodes a whole
scan at once instead (the tests' reference path, see :func:`.reference._scan_reference`).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ...errors import InputError
from ...log.channels import concat_columns, frame_from_columns
from ...log.fieldlog import FieldLog
from .codec import channel_codec, loadable
from .recovery import _report_if_lost, _widen
from .stream import ChannelInfo, ChunkStream, by_channel, scan_file

if TYPE_CHECKING:   # pandas is imported where a frame is made (inspect never needs it)
    import pandas as pd


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


_DECODE_BYTES = 16 << 20   # decompressed chunk bytes decoded at a time by read_log


class _Column:
    """One column of a channel as :func:`read_log` decodes it: allocated once (``size``
    values, from the summary's message count) and filled part by part, or, without a size,
    or when a part does not fit (another dtype, coded strings, more values than the
    summary said), its parts kept and joined at the end (:func:`concat_columns`)."""

    __slots__ = ("buf", "parts", "size")

    def __init__(self, size: int | None):
        self.size = size
        self.buf: np.ndarray | None = None
        self.parts: list = []

    def put(self, a, pos: int) -> None:
        """Add the part ``a``, whose rows start at row ``pos`` of the channel."""
        k = len(a)
        b = self.buf
        if b is None and self.size is not None and not self.parts:
            if isinstance(a, np.ndarray) and a.ndim == 1 and a.dtype != object and pos + k <= self.size:
                self.buf = b = np.empty(self.size, dtype=a.dtype)
            else:
                self.size = None   # kept as parts from here on
        if b is not None:
            if isinstance(a, np.ndarray) and a.ndim == 1 and a.dtype == b.dtype and pos + k <= len(b):
                b[pos:pos + k] = a
                return
            self.parts, self.buf, self.size = [b[:pos]], None, None   # what was filled, as a part
        self.parts.append(a)

    def take(self, n: int):
        """The whole column (``n`` rows), its parts dropped: the allocated array trimmed to
        ``n`` (a damaged file can hold fewer messages than its summary says)."""
        b, self.buf = self.buf, None
        if b is None:
            parts, self.parts = self.parts, []
            return concat_columns(parts)
        if len(b) != n:
            try:
                b.resize(n, refcheck=True)   # in place (realloc), no copy of the rows kept
            except ValueError:
                b = b[:n].copy()
        return b


class _ChannelParts:
    """One channel's messages decoded part by part as :func:`read_log` walks the file.

    With ``size`` (the summary's message count of the channel), each column is allocated
    once and filled part by part (:class:`_Column`), and the frame takes the arrays as they
    are: memory is the frame, not its parts plus their concatenation plus the frame."""

    def __init__(self, topic: str, schema: dict, codec, size: int | None = None):
        self.topic, self.schema, self.codec = topic, schema, codec
        size = size if size is not None and size > 0 else None
        self.t, self.seq, self.ordinal = _Column(size), _Column(size), _Column(size)
        self.cols = {c: _Column(size) for c in codec.spec.columns}
        self.rows = 0                          # rows kept so far
        self.added = False                     # a part was added
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
        pos = self.rows
        self.t.put(t[keep], pos)
        self.seq.put(seq[keep], pos)
        self.ordinal.put(ordinal[keep], pos)
        for c, col in self.cols.items():
            col.put(cols[c], pos)
        self.rows += len(keep)
        self.added = True

    def frame(self) -> tuple[pd.DataFrame, int]:
        """(the channel's frame in sequence order, messages skipped); the rules of
        :func:`_decode_tolerant` applied to the whole channel."""
        if self.first is not None and (self.mismatch or self.n_bad == self.n > 1):
            raise self.first
        if not self.added:
            return frame_from_columns(self.codec.empty_columns(), np.zeros(0, dtype=np.int64), self.codec.spec), 0
        n = self.rows
        t, seq, ordinal = self.t.take(n), self.seq.take(n), self.ordinal.take(n)
        order = None
        if len(seq) > 1 and not np.all(seq[1:] > seq[:-1]):
            order = np.lexsort((ordinal, seq))   # by sequence, file order among equal ones
        del seq, ordinal
        cols = {}
        for c in self.codec.spec.columns:
            a = self.cols[c].take(n)
            cols[c] = a if order is None else a[order]
        own = len({id(a) for a in cols.values()}) == len(cols)   # fresh arrays, one per column
        return frame_from_columns(cols, t if order is None else t[order], self.codec.spec, copy=not own), self.n_bad


def _read_streamed(p: Path, topics, strict: bool) -> FieldLog:
    """:func:`read_log` a group of chunks at a time: memory bounded by the decoded frames."""
    log = FieldLog(source=str(p))
    parts: dict[int, _ChannelParts | None] = {}
    errors: dict[int, InputError] = {}
    with ChunkStream(p, topics=topics) as stream:
        scan = stream._scan
        counts = None   # messages per channel (the summary's statistics), known once the walk has begun

        def channel(c: int) -> _ChannelParts | None:
            if c not in parts:
                ch = scan.channels[c]
                part = None
                sname, senc, sdata = scan.schemas.get(ch.schema_id, ("", "", b""))
                if (topics is None or ch.topic in topics) and loadable(ch.encoding, senc, sname):
                    try:
                        part = _ChannelParts(ch.topic, *_codec_of(p, ch.topic, ch.encoding, senc, sname, sdata),
                                             size=counts.get(c) if counts else None)
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
            if counts is None:
                counts = scan.summary.counts if scan.summary is not None and scan.summary.counts else {}
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
        t_lo, t_hi = _widen(t_lo, t_hi, frame.index.to_numpy())
    return _with_recovery(log, p, scan, size, n_msgs, t_lo, t_hi, skipped, strict)


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
        t_lo, t_hi = _widen(t_lo, t_hi, t)
    return _with_recovery(log, p, scan, size, n_msgs, t_lo, t_hi, skipped, strict)


def _with_recovery(log: FieldLog, p: Path, scan, size: int, n_msgs: int, t_lo, t_hi, skipped: dict,
                   strict: bool) -> FieldLog:
    """``log`` with its recovery report when anything was lost (:func:`.recovery._report_if_lost`);
    with ``strict``, InputError instead."""
    log.recovery = _report_if_lost(scan, size, n_msgs, t_lo, t_hi, skipped)
    if log.recovery is not None and strict:
        raise InputError(f"{p}: damaged file: {log.recovery.reason}")
    return log


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
