"""Where imported frames go: into memory (a FieldLog) or streamed into an MCAP file.

:class:`McapSink` encodes and writes each batch as it comes, so importing a file 10x
larger does not need 10x the memory. Each message's ``sequence`` is its row number in
the channel, as :func:`usvlog.io.mcapio.read_log` expects; metadata records
(datum, vessel, provenance) are written once the import knows them, before the summary.
"""

from __future__ import annotations

import json

import numpy as np
import pandas as pd

from ... import __version__
from ...channels import MESSAGE_ENCODING, SCHEMA_ENCODING, codec_for_topic, schema_for_topic
from ...log import FieldLog


class MemorySink:
    def __init__(self):
        self._parts: dict[str, list[pd.DataFrame]] = {}

    def write(self, frames: dict[str, pd.DataFrame]) -> None:
        for topic, f in frames.items():
            self._parts.setdefault(topic, []).append(f)

    def finish(self, meta: dict[str, dict[str, str]]) -> FieldLog:
        log = FieldLog()
        for topic, parts in self._parts.items():
            log.set(topic, parts[0] if len(parts) == 1 else pd.concat(parts))
        log.meta.update(meta)
        return log


class McapSink:
    """Streams canonical frames into an MCAP file opened by the caller (binary, writable)."""

    def __init__(self, fh, *, chunk_size: int = 1 << 20):
        from mcap.writer import CompressionType, Writer

        self._w = Writer(fh, chunk_size=chunk_size, compression=CompressionType.ZSTD)
        self._w.start(profile="", library=f"usvlog {__version__}")
        self._channels: dict[str, int] = {}
        self._seq: dict[str, int] = {}

    def _channel(self, topic: str) -> int:
        cid = self._channels.get(topic)
        if cid is None:
            schema = schema_for_topic(topic)
            sid = self._w.register_schema(schema["title"], SCHEMA_ENCODING, json.dumps(schema).encode())
            cid = self._w.register_channel(topic, MESSAGE_ENCODING, sid)
            self._channels[topic] = cid
            self._seq[topic] = 0
        return cid

    def write(self, frames: dict[str, pd.DataFrame]) -> None:
        # interleave the topics of one batch in time order (readers like it, chunks index better)
        parts = []
        for topic, f in frames.items():
            cid = self._channel(topic)
            payloads = codec_for_topic(topic).encode(f, topic)
            t = np.asarray(f.index, dtype=np.int64)
            s0 = self._seq[topic]
            self._seq[topic] = s0 + len(t)
            parts.append((t, np.full(len(t), cid), np.arange(s0, s0 + len(t)), payloads))
        if not parts:
            return
        t = np.concatenate([p[0] for p in parts])
        cid = np.concatenate([p[1] for p in parts]).tolist()
        seq = np.concatenate([p[2] for p in parts]).tolist()
        payloads = [m for p in parts for m in p[3]]
        order = np.argsort(t, kind="stable").tolist()
        tl = t.tolist()
        add = self._w.add_message
        for i in order:
            add(cid[i], tl[i], payloads[i], tl[i], sequence=seq[i])

    def finish(self, meta: dict[str, dict[str, str]]) -> None:
        for name in sorted(meta):
            self._w.add_metadata(name, {str(k): str(v) for k, v in meta[name].items()})
        self._w.finish()
