"""The one MCAP writer: :class:`McapWriter` (streaming) and :func:`write_log` (a whole log).

A whole log is written by :func:`write_log`: atomically, in time slices (memory bounded by
a slice), through the streaming :class:`McapWriter` (:mod:`.file_writer`), with channels
still deferred copied from the log's source file as they are stored (:mod:`.raw_copy`).
Message and index records are built with compiled loops (:mod:`.kernels`); the bytes are
the mcap library's ``Writer``'s for the same messages (:mod:`.reference` keeps that path).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ...errors import InputError
from ...log.fieldlog import Channels, DeferredSource, FieldLog
from ..atomic import atomic_path
from .file_writer import ZSTD_LEVEL, McapWriter
from .raw_copy import _OutOfOrder, _RawFeed
from .reader import read_log
from .schema_records import _codec_for, _compression, _schema_record
from .stream import ChunkStream, by_channel, channel_ids
from .windows import NotWindowed
from .windows import topic_counts as topic_counts_of

if TYPE_CHECKING:   # pandas is imported where a frame is made (inspect never needs it)
    import pandas as pd

__all__ = ["SLICE_MESSAGES", "ZSTD_LEVEL", "McapWriter", "time_slices", "merged_ids", "write_log", "write_log_merged"]


SLICE_MESSAGES = 1 << 16
"""Messages :func:`write_log` encodes at a time (one time slice of the whole log)."""


def write_log(log: FieldLog, path, *, force: bool = False, chunk_size: int = 1 << 20,
              compression: str = "zstd", zstd_level: int = ZSTD_LEVEL,
              slice_messages: int = SLICE_MESSAGES) -> None:
    """Write ``log`` as a canonical MCAP file, atomically, through :class:`McapWriter`.

    The log goes through the writer in time slices of about ``slice_messages``
    messages, so the encoding's memory is bounded by a slice, not by the log.
    Metadata records come first (a truncated file keeps them), then every channel's
    schema and channel records, then chunks each holding one channel's messages in
    (time, row) order (:class:`McapWriter`); the message records are the mcap library's
    ``Writer``'s for the same messages (``_write_log_reference``, the tests compare).

    A channel still deferred (``log.deferred``: read from a file and never touched) is
    copied from that file without decoding it when the file stores it with the schema
    record and message encoding this writer uses for it, keeping its channel id: a chunk
    of the file holding that channel alone, in the order and with the sequence numbers a
    usvlog file has and the writer's compression, is copied whole (its compressed bytes
    and CRC as they are, after its CRC was checked), other messages payload by payload;
    the same messages as after decoding it. It is decoded instead when the file stores it
    otherwise, when the log was read with damage recovered, or when its messages are not
    in the time and sequence order a usvlog file has; a file changed or damaged since it
    was read (size or modification time, a chunk's CRC) is refused (:class:`InputError`).
    """
    _compression(compression)
    ids = _channel_ids(log, log.deferred)
    copy = _copied_channels(log)
    with atomic_path(path, force=force) as tmp:
        if copy:
            try:
                _write(log, tmp, chunk_size, compression, zstd_level, slice_messages, copy, ids)
                return
            except _OutOfOrder:   # the source's messages are not in time/row order: decode them
                assert isinstance(log.channels, Channels)
                log.channels.load_deferred(copy)
        _write(log, tmp, chunk_size, compression, zstd_level, slice_messages, [], ids)


def _write(log: FieldLog, tmp, chunk_size: int, compression: str, zstd_level: int, slice_messages: int,
           copy: list[str], ids: dict[str, int]) -> None:
    """:func:`write_log` to ``tmp``, the channels ``copy`` from the log's source file, the
    channels under the ids ``ids`` (:func:`_channel_ids`)."""
    decoded = log.channels.decoded() if isinstance(log.channels, Channels) else log.channels
    frames = {topic: decoded[topic] for topic in log.topics if topic not in copy}
    with open(tmp, "wb", buffering=1 << 20) as fh:
        w = McapWriter(fh, chunk_size=chunk_size, compression=compression, zstd_level=zstd_level)
        feed = None
        try:
            for name in sorted(log.meta):
                w.add_metadata(name, log.meta[name])
            src = log.deferred
            for topic, cid in sorted(ids.items(), key=lambda kv: kv[1]):   # records in id order
                w.add_channel(topic, log.schemas.get(topic), frames.get(topic), channel_id=cid)
            if not copy:
                for batch in time_slices(frames, slice_messages):
                    w.add_frames(batch, log.schemas)
            else:
                assert src is not None
                feed = _RawFeed(src, copy, {t: w.add_channel(t) for t in copy})
                cuts = _slice_cuts(_times(frames), slice_messages)
                # frames whose times do not rise: one slice
                cuts = np.zeros(0, dtype=np.int64) if cuts is None else cuts
                feed.start()
                for k, batch in enumerate(_cut(frames, cuts)):
                    # the slice encoded, then the source's chunks ending in it read, both into chunks
                    per = w._encode_frames(batch, log.schemas)
                    w._add_encoded(per, *feed.take(int(cuts[k]) if k < len(cuts) else None))
                feed.finish()
            w.finish()
        finally:
            w.close()
            if feed is not None:
                feed.close()


def _channel_ids(log: FieldLog, src: DeferredSource | None) -> dict[str, int]:
    """Topic -> channel id in the file written: the channels of ``src`` (the file the log's
    deferred channels are in) keep their ids there (its chunks are copied whole), the others
    take the lowest ids left in the log's channel order (a log read from a file lists its
    channels in their order there, so a log read and written again keeps the file's ids)."""
    ids = {t: c for t, c in channel_ids(src.path).items() if t in log.channels} if src is not None else {}
    free = (c for c in range(1, 1 << 16) if c not in ids.values())
    for topic in log.channels:
        if topic not in ids:
            ids[topic] = next(free)
    return ids


def _copied_channels(log: FieldLog) -> list[str]:
    """The deferred channels :func:`write_log` copies from the source file (the others it
    must write are decoded now)."""
    ch = log.channels
    src = log.deferred
    if src is None or not isinstance(ch, Channels):
        return []
    why = src.changed()
    if why is not None:
        raise InputError(f"{src.path} {why}: cannot write channel(s) {', '.join(ch.deferred_topics())} "
                         "from it (load the log again)")
    todo = ch.deferred_topics()
    if log.recovery is not None:
        ch.load_deferred()
        return []
    copy, decode = [], []
    for topic in todo:
        schema, codec = _codec_for(topic, log.schemas.get(topic))
        mine = (codec.message_encoding, *_schema_record(topic, schema, codec))
        (copy if mine == tuple(src.topics[topic]) else decode).append(topic)
    ch.load_deferred(decode)
    return copy



def _times(frames: dict[str, pd.DataFrame]) -> dict[str, np.ndarray]:
    return {t: np.asarray(f.index, dtype=np.int64) for t, f in frames.items() if len(f)}


def _slice_cuts(times: dict[str, np.ndarray], size: int) -> np.ndarray | None:
    """The times that cut ``times`` (topic -> rising int64 ns) into slices of about ``size``
    messages (a slice is [cut k-1, cut k)); None when a channel's times do not rise (then
    the frames are one slice)."""
    total = sum(len(v) for v in times.values())
    if not all(len(v) < 2 or bool(np.all(v[1:] >= v[:-1])) for v in times.values()):
        return None
    if total <= size:
        return np.zeros(0, dtype=np.int64)
    # boundaries at quantiles of every message's time (from a sample: boundaries need not be exact)
    step = _sample_step(total, size)
    return _cuts_from_sample(np.sort(np.concatenate([v[::step] for v in times.values()])), total, size)


def _sample_step(total: int, size: int) -> int:
    """Every how many messages :func:`_slice_cuts` samples a channel's times."""
    return max(1, total // (64 * (total // size + 1)))


def _cuts_from_sample(sample: np.ndarray, total: int, size: int) -> np.ndarray:
    """The cuts of :func:`_slice_cuts` from its sorted sample of ``total`` messages' times."""
    return np.unique(sample[np.linspace(0, len(sample), total // size + 1, endpoint=False).astype(np.int64)[1:]])


def _cut(frames: dict[str, pd.DataFrame], cuts: np.ndarray):
    """The slices of ``frames`` at ``cuts`` (one per cut and the last: len(cuts) + 1, some
    may be empty dicts)."""
    times = _times(frames)
    edges = {t: np.concatenate(([0], np.searchsorted(v, cuts, side="left"), [len(v)])) for t, v in times.items()}
    for k in range(len(cuts) + 1):
        yield {t: frames[t].iloc[int(e[k]):int(e[k + 1])] for t, e in edges.items() if e[k + 1] > e[k]}


def time_slices(frames: dict[str, pd.DataFrame], size: int):
    """Split frames (index: int64 log time ns) into consecutive time slices of about
    ``size`` messages in all, for :meth:`McapWriter.add_frames` one slice at a time.

    A boundary is a time: every message of a time falls into one slice, so the slices
    written in turn give the (time, channel, row) order of the whole. A frame whose
    times do not rise (rare: an unsorted import) cannot be cut so: then the frames
    are one slice.

    Parameters
    ----------
    frames : dict
        Topic -> DataFrame indexed by log time (int64 ns).
    size : int
        Messages per slice (about; a slice holds every message of its times).

    Yields
    ------
    dict
        Topic -> the rows of its frame in the slice (views, not copies).
    """
    cuts = _slice_cuts(_times(frames), size)
    if cuts is None or not len(cuts):
        yield frames
        return
    for batch in _cut(frames, cuts):
        if batch:
            yield batch



def merged_ids(log: FieldLog, topics: list[str]) -> dict[str, int]:
    """Topic -> channel id in the file :func:`write_log_merged` writes for ``log`` plus the new
    channels ``topics``: the ids :func:`write_log` gives the log with those channels set (the
    source file's ids kept, the lowest free ones taken in the log's channel order)."""
    src = log.deferred
    known = {t: c for t, c in channel_ids(src.path).items() if t in log.channels or t in topics} \
        if src is not None else {}
    free = (c for c in range(1, 1 << 16) if c not in known.values())
    return {t: known[t] if t in known else next(free)
            for t in [*log.channels, *(t for t in topics if t not in log.channels)]}


def write_log_merged(log: FieldLog, path, spools: list[FieldLog], topics: list[str], *, force: bool = False,
                     chunk_size: int = 1 << 20, compression: str = "zstd", zstd_level: int = ZSTD_LEVEL,
                     slice_messages: int = SLICE_MESSAGES) -> None:
    """Write ``log`` plus the channels of other canonical files, all copied undecoded, atomically.

    ``log`` is a log read with every channel deferred (:func:`read_log` with ``defer``), or a
    log without channels (its metadata alone: a producer's spools hold every channel);
    ``spools`` are logs read so from files :class:`McapWriter` wrote with the ids of
    :func:`merged_ids` (of ``topics``: the spools' channels in the order they take new ids)
    and this writer's chunk size and compression (a producer writes its new channels there
    as it makes them, in time order). A channel of a spool replaces the log's of that topic.
    The file is the one :func:`write_log` writes for ``log`` with the spools' channels set
    in it, byte for byte (metadata records first: ``log.meta``; the same time slices: cut from
    the spools' message times as :func:`write_log` cuts the frames it encodes), but no channel
    is decoded: every file is walked once, a slice at a time (memory: a slice and the spools'
    message times' sample, not the log).

    Raises
    ------
    NotWindowed
        A channel cannot be copied as it is stored (decoded, another schema, messages out of
        order, a damaged or changed source): nothing is written; write the log whole instead.
    """
    _compression(compression)
    new = list(topics)
    if sorted(new) != sorted(t for sp in spools for t in sp.topics):
        raise ValueError("topics must list the spools' channels")
    srcs = [(log, [t for t in log.topics if t not in new])] if log.topics else []   # (no channels: metadata)
    srcs += [(sp, sp.topics) for sp in spools]
    for lg, tops in srcs:
        src, ch = lg.deferred, lg.channels
        if src is None or not isinstance(ch, Channels) or lg.recovery is not None \
                or set(ch.deferred_topics()) != set(lg.topics):
            raise NotWindowed("not a log read with its channels deferred")
        if src.changed() is not None:
            raise NotWindowed(f"{src.path} changed")
        for topic in tops:
            schema, codec = _codec_for(topic, lg.schemas.get(topic))
            if (codec.message_encoding, *_schema_record(topic, schema, codec)) != tuple(src.topics[topic]):
                raise NotWindowed(f"{topic} stored otherwise")
    ids = merged_ids(log, new)
    cuts = _spool_cuts(spools, slice_messages)
    cuts = np.zeros(0, dtype=np.int64) if cuts is None else cuts
    with atomic_path(path, force=force) as tmp, open(tmp, "wb", buffering=1 << 20) as fh:
        w = McapWriter(fh, chunk_size=chunk_size, compression=compression, zstd_level=zstd_level)
        feeds: list[_RawFeed] = []
        try:
            for name in sorted(log.meta):
                w.add_metadata(name, log.meta[name])
            for topic, cid in sorted(ids.items(), key=lambda kv: kv[1]):   # records in id order
                sp = next((sp for sp in spools if topic in sp.topics), log)
                w.add_channel(topic, sp.schemas.get(topic), channel_id=cid)
            feeds = [_RawFeed(lg.deferred, tops, {t: ids[t] for t in tops}) for lg, tops in srcs]
            for f in feeds:
                f.start()
            for upto in [*cuts.tolist(), None]:
                raw: dict[str, list] = {}
                chunks: list[tuple] = []
                for f in feeds:
                    r, c = f.take(upto)
                    raw.update(r)
                    chunks.extend(c)
                w._add_encoded({}, raw, chunks)
            for f in feeds:
                f.finish()
            w.finish()
        except _OutOfOrder as err:
            raise NotWindowed("a channel's messages out of order") from err
        finally:
            w.close()
            for f in feeds:
                f.close()


def _spool_cuts(spools: list[FieldLog], size: int) -> np.ndarray:
    """:func:`_slice_cuts` of the spools' messages, from their times' sample alone (the walk
    keeps every ``step``-th time of a channel, as :func:`_slice_cuts` samples them)."""
    counts = [n for sp in spools for n in topic_counts_of(sp.deferred.path).values()]
    total = sum(counts)
    if total <= size:
        return np.zeros(0, dtype=np.int64)
    step = _sample_step(total, size)
    sample: list[np.ndarray] = []
    for sp in spools:
        pos: dict[int, int] = {}
        last: dict[int, int] = {}
        with ChunkStream(sp.deferred.path) as stream:
            for _records, _at, _t0, _t1, cid, _seq, t, _ps, _pe, _ordinal in stream._batches():
                for c, sel in by_channel(cid):
                    tc = t[sel]
                    if (len(tc) > 1 and np.any(tc[1:] < tc[:-1])) or tc[0] < last.get(c, tc[0]):
                        return np.zeros(0, dtype=np.int64)   # times that do not rise: one slice
                    last[c] = int(tc[-1])
                    at = pos.get(c, 0)
                    sample.append(tc[(-at) % step::step])
                    pos[c] = at + len(tc)
    return _cuts_from_sample(np.sort(np.concatenate(sample)), total, size)


class Spool:
    """New channels written to a file of their own as a producer makes them, for
    :func:`write_log_merged` to copy into the file it writes (chunks copied whole).

    ``ids`` (:func:`merged_ids`) gives each channel its id in that file; :meth:`add` appends a
    batch of frames (each channel's rows in time order over the batches); :meth:`close`
    finishes the file and returns it read with its channels deferred (None after an error).
    The file is the caller's to remove.
    """

    def __init__(self, path, topics: list[str], ids: dict[str, int], *, chunk_size: int = 1 << 20,
                 compression: str = "zstd", zstd_level: int = ZSTD_LEVEL):
        self.path = path
        self._fh = open(path, "wb", buffering=1 << 20)  # noqa: SIM115 - closed by close()
        self._w = McapWriter(self._fh, chunk_size=chunk_size, compression=compression, zstd_level=zstd_level)
        for t in sorted(topics, key=ids.__getitem__):
            self._w.add_channel(t, channel_id=ids[t])

    def add(self, frames: dict[str, pd.DataFrame]) -> None:
        """Append one batch: topic -> frame (index: int64 log time ns), rows after the last batch's."""
        self._w.add_frames(frames)

    def close(self) -> FieldLog:
        """Finish the file (summary and footer) and return it read with its channels deferred."""
        try:
            self._w.finish()
        finally:
            self._w.close()
            self._fh.close()
        return read_log(self.path, topics=[], defer=True)
