"""Some channels of a canonical file read a time window at a time (memory: a window, not the run).

:func:`iter_windows` walks the file's chunks (the walk of :func:`.reader.read_log`: CRC checked,
chunks without the channels skipped), decodes the wanted channels' messages chunk by chunk and
hands them on in time windows: every message before a time once no chunk still to come can hold
one earlier (each channel's messages rise in time; a channel is done once the summary's count of
its messages has been read). The frames of the windows, joined, are the frames :func:`read_log`
gives. Where that cannot be promised (no summary or statistics, messages outside chunks, a
message that does not decode, a channel's times or sequence numbers not rising, a damaged file)
it raises :class:`NotWindowed` and the caller reads the channels whole instead.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .codec import loadable
from .decode import _ChannelParts, _codec_of
from .stream import ChunkStream, by_channel


class NotWindowed(Exception):
    """The file cannot be read (or written) a window at a time; read it whole instead."""


def iter_windows(path, topics: list[str]):
    """Yield the channels ``topics`` of a canonical MCAP file in consecutive time windows.

    Parameters
    ----------
    path : str or os.PathLike
        The file (undamaged, with a summary and its statistics).
    topics : list of str
        The channels wanted (a topic the file lacks is left out).

    Yields
    ------
    dict
        Topic -> DataFrame of the channel's messages in the window (index: int64 log time
        ns), every wanted channel's messages before the window's end; windows in time order.

    Raises
    ------
    NotWindowed
        The file cannot be read so (see the module); nothing can be assumed of the windows
        already yielded.
    """
    p = Path(path)
    wanted = set(topics)
    with ChunkStream(p, topics=list(wanted)) as stream:
        scan = stream._scan
        parts: dict[int, tuple | None] = {}   # channel id -> (topic, schema, codec) or None (not wanted)
        counts: dict[int, int] | None = None  # wanted channel id -> its messages in the file
        seen: dict[int, int] = {}
        last: dict[int, tuple[int, int]] = {}  # channel id -> (time, sequence) of its last message
        held: dict[str, list] = {}             # topic -> frames not yet handed on

        def channel(c: int):
            if c not in parts:
                ch = scan.channels[c]
                sname, senc, sdata = scan.schemas.get(ch.schema_id, ("", "", b""))
                parts[c] = None
                if ch.topic in wanted and loadable(ch.encoding, senc, sname):
                    parts[c] = (ch.topic, *_codec_of(p, ch.topic, ch.encoding, senc, sname, sdata))
            return parts[c]

        def window(upto: int | None) -> dict:
            out = {}
            for topic, frames in held.items():
                if not frames:
                    continue
                f = frames[0] if len(frames) == 1 else _concat(frames)
                n = len(f) if upto is None else int(np.searchsorted(np.asarray(f.index, dtype=np.int64), upto))
                if n:
                    out[topic] = f.iloc[:n]
                held[topic] = [f.iloc[n:]] if n < len(f) else []
            return out

        sent = None
        for records, at, _t0, _t1, cid, seq, t, ps, pe, ordinal in stream._batches():
            if at < 0:
                raise NotWindowed("messages outside chunks")
            if counts is None:
                summ = scan.summary
                if summ is None or not summ.counts:
                    raise NotWindowed("no summary statistics")
                counts = {}
                by_topic: dict[str, int] = {}
                for c, (topic, _sid, _enc) in summ.channels.items():
                    if topic in wanted and summ.counts.get(c, 0) > 0:
                        if topic in by_topic:
                            raise NotWindowed(f"{topic} on more than one channel")
                        by_topic[topic] = c
                        counts[c] = summ.counts[c]
            buf = records if isinstance(records, np.ndarray) else np.frombuffer(records, dtype=np.uint8)
            for c, sel in by_channel(cid):
                info = channel(c)
                if info is None:
                    continue
                if c not in counts:
                    raise NotWindowed(f"{info[0]} not in the summary")
                part = _ChannelParts(*info)
                part.add(buf, sel, t, seq, ordinal, ps, pe)
                if part.first is not None or part.n_bad or part.mismatch:
                    raise NotWindowed(f"{info[0]}: a message does not decode")
                tc, sc = t[sel], seq[sel]
                prev = last.get(c)
                if (len(tc) > 1 and (np.any(tc[1:] < tc[:-1]) or np.any(sc[1:] <= sc[:-1]))) or \
                        (prev is not None and (int(tc[0]) < prev[0] or int(sc[0]) <= prev[1])):
                    raise NotWindowed(f"{info[0]}: messages not in time and sequence order")
                last[c] = (int(tc[-1]), int(sc[-1]))
                seen[c] = seen.get(c, 0) + len(sel)
                frame, _ = part.frame()
                held.setdefault(info[0], []).append(frame)
            # every message before the earliest last time of a channel not yet done has been read
            open_ = [last[c][0] if c in last else None for c in counts if seen.get(c, 0) < counts[c]]
            if any(x is None for x in open_):
                continue
            upto = min(open_) if open_ else None
            if upto is None:
                continue   # every channel done: the rest at the end
            if sent is None or upto > sent:
                out = window(upto)
                sent = upto
                if out:
                    yield out
        counts = counts or {}
        if stream.recovery() is not None or any(seen.get(c, 0) != n for c, n in counts.items()):
            raise NotWindowed("damaged file")
        out = window(None)
        if out:
            yield out


def _concat(frames):
    import pandas as pd  # the frames are pandas already

    return pd.concat(frames)


def topic_counts(path) -> dict[str, int]:
    """Topic -> messages in the file, from its summary's statistics (empty without them)."""
    from .stream import _summary_of  # (the summary alone: footer and summary read)

    s = _summary_of(path)
    if s is None or not s.counts:
        return {}
    out: dict[str, int] = {}
    for cid, (topic, _sid, _enc) in s.channels.items():
        out[topic] = out.get(topic, 0) + int(s.counts.get(cid, 0))
    return out
