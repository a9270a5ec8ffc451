"""Deferred channels: a log read with some channels decoded and the rest decoded when touched.

``read_log(path, topics=..., defer=True)`` decodes ``topics`` now and lists the file's other
canonical channels (from its summary alone, :func:`_stored_channels`) in a
:class:`~usvlog.log.fieldlog.Channels` whose :class:`~usvlog.log.fieldlog.DeferredSource`
decodes one when it is first touched (:func:`_load_channels`, refusing a file changed since).
A damaged file, or one without a summary, is read whole instead.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from ...errors import InputError
from ...log.fieldlog import Channels, DeferredSource, FieldLog
from ..atomic import reading
from .codec import loadable
from .container import _layout_windowed
from .decode import _codec_of, _read_log, _return_freed_memory
from .stream import ChunkStream

if TYPE_CHECKING:   # pandas is imported where a frame is made (inspect never needs it)
    import pandas as pd


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


def _load_channels(path: str, topics: list[str]) -> dict[str, pd.DataFrame]:
    """The frames of ``topics`` of the file (the loader of deferred channels)."""
    log = _read_log(path, topics=topics)
    if log.recovery is not None:   # it read intact before: it changed under the same size and time
        raise InputError(f"{path}: damaged since it was read ({log.recovery.reason}); load it again")
    frames = {t: log.channels[t] for t in topics if t in log.channels}
    _return_freed_memory()
    return frames
