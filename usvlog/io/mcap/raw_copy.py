"""Channels copied from the log's source file without decoding them, for :func:`~usvlog.io.mcap.writer.write_log`.

:class:`_RawFeed` walks the canonical file a log's deferred channels were read from and
hands their messages as they are stored to the :class:`~usvlog.io.mcap.file_writer.McapWriter`:
chunks holding one copied channel whole, other messages payload by payload. The walk runs
in the calling thread (a read-ahead thread saved nothing on a 1-hour replay; docs/performance.md).
A channel whose messages are not in (time, row) order raises :class:`_OutOfOrder` (the caller decodes it instead).
"""

from __future__ import annotations

import numpy as np

from ...errors import InputError
from ...log.fieldlog import DeferredSource
from . import kernels as K
from .format import _REC, _U64
from .stream import ChunkStream


class _OutOfOrder(Exception):
    """The source's messages of a copied channel are not in (time, row) order."""


def _only_messages(records: np.ndarray, ps: np.ndarray, pe: np.ndarray) -> bool:
    """Whether a chunk's records are exactly these message records, back to back, each with
    its publish time equal to its log time (as this writer writes them)."""
    return bool(K.bare_messages(records, ps, pe))


class _RawFeed:
    """The messages of channels of a canonical file, as they are stored, handed to a
    :class:`McapWriter` for :func:`write_log` to copy without decoding.

    The file is walked in its order (every chunk decompressed and its CRC checked; chunks
    holding none of the channels skipped). A chunk holding
    messages of one copied channel only, nothing else, in the order and with the
    sequence numbers the writer gives them, under the same channel id, is copied whole:
    its record's bytes as they are (compressed data, CRC), its message index rebuilt
    (:meth:`McapWriter.add_chunk`). Other messages of the channels (chunks holding
    several channels, messages outside chunks) are copied payload by payload into the
    writer's own chunks. Memory: the chunk being copied.
    """

    def __init__(self, src: DeferredSource, topics: list[str], ids: dict[str, int]):
        self._src = src
        # the reader's walk: CRC checks, chunks without these channels skipped (chunk index)
        self._stream = ChunkStream(src.path, topics=topics)
        self._topics = set(topics)
        self._ids = ids          # topic -> its channel id in the file written
        self._it = None
        self._next = None        # the batch read and not yet handed on
        self._done = False
        self._last: dict[str, tuple[int, int]] = {}  # topic -> (time, sequence) of its last message read

    def _batches(self):
        """The walk's batches, each with the bytes of its chunk record when it may be copied
        whole (one channel)."""
        m = self._stream._map
        for b in self._stream._batches():
            at, cid = b[1], b[4]
            rec = None
            if at >= 0 and cid[0] == cid[-1] and np.all(cid == cid[0]):
                rec = bytes(m[at:at + _REC.size + _U64.unpack_from(m, at + 1)[0]])
            yield b, rec

    def start(self) -> None:
        """Start the walk (else the first :meth:`take` does)."""
        if self._it is None:
            self._it = self._batches()

    def _peek(self):
        if self._next is None and not self._done:
            self.start()
            try:
                self._next = next(self._it)
            except StopIteration:
                self._done = True
        return self._next

    def take(self, upto: int | None) -> tuple[dict[str, list], list[tuple]]:
        """The batches of the file, in its order, up to the first whose last message is at
        ``upto`` (ns) or later (None: all the rest), for :meth:`McapWriter.add_frames`:
        (topic -> payload pieces, chunks to copy whole). Raises :class:`_OutOfOrder` when a
        channel's messages are not in time and sequence order."""
        raw: dict[str, list] = {}
        chunks: list[tuple] = []
        while True:
            item = self._peek()
            if item is None:
                break
            b, rec = item
            t = b[6]
            if upto is not None and len(t) and int(t.max()) >= upto:
                break
            self._next = None
            self._hand(b, rec, raw, chunks)
        return raw, chunks

    def _hand(self, b, rec, raw: dict[str, list], chunks: list[tuple]) -> None:
        records, at, _t0, _t1, cid, seq, t, ps, pe, _ordinal = b
        chans = self._stream._scan.channels
        one = rec is not None   # a chunk of one channel (_batches checked): its messages as they are
        for c in [int(cid[0])] if one else np.unique(cid).tolist():
            topic = chans[c].topic
            if topic not in self._topics:
                continue
            sel = slice(None) if one else np.flatnonzero(cid == c)
            tc, sc = t[sel], seq[sel]
            prev = self._last.get(topic)
            if (len(tc) > 1 and (np.any(tc[1:] < tc[:-1]) or np.any(sc[1:] < sc[:-1]))) or \
                    (prev is not None and (int(tc[0]) < prev[0] or int(sc[0]) < prev[1])):
                raise _OutOfOrder
            self._last[topic] = (int(tc[-1]), int(sc[-1]))
            if at < 0:   # messages outside chunks: spans in the file's bytes, copied out
                lo, hi = int(ps[sel].min()), int(pe[sel].max())
                buf = np.frombuffer(bytes(records[lo:hi]), dtype=np.uint8)
                raw.setdefault(topic, []).append((tc, buf, ps[sel] - lo, pe[sel] - lo))
                continue
            buf = np.frombuffer(records, dtype=np.uint8) if not isinstance(records, np.ndarray) else records
            if rec is not None and c == self._ids.get(topic) and _only_messages(buf, ps, pe):
                chunks.append((topic, rec, tc, sc, buf, ps, pe))
            elif chunks and any(ch[0] == topic for ch in chunks):   # keep the channel's order
                chunks.append((topic, None, tc, sc, buf, ps[sel], pe[sel]))
            else:
                raw.setdefault(topic, []).append((tc, buf, ps[sel], pe[sel]))

    def finish(self) -> None:
        """After the last batch: the file must have read intact and be unchanged."""
        assert self._done and self._next is None
        rep = self._stream.recovery()
        why = self._src.changed()
        if rep is not None or why is not None:
            raise InputError(f"{self._src.path} {why or 'is damaged: ' + rep.reason} since it was read; "
                             "load the log again")

    def close(self) -> None:
        if self._it is not None:
            self._it.close()   # the walk's generator ends before the file it reads is closed
        self._stream.close()
