"""Where imported frames go: into memory (a FieldLog) or streamed into an MCAP file.

:class:`McapSink` encodes and writes each batch as it comes (the one MCAP writer,
:class:`usvlog.io.mcap.McapWriter`), so importing a file 10x larger does not need
10x the memory; metadata records (datum, vessel, provenance) are written once the
import knows them, before the summary.
"""

from __future__ import annotations

import pandas as pd

from ...log.fieldlog import FieldLog
from ..mcap import McapWriter


class MemorySink:
    """Collects imported frames in memory and makes a :class:`~usvlog.log.fieldlog.FieldLog` of them.

    The counterpart of :class:`McapSink` for imports without an output file; memory grows
    with the log.
    """

    def __init__(self):
        self._parts: dict[str, list[pd.DataFrame]] = {}

    def write(self, frames: dict[str, pd.DataFrame]) -> None:
        """Keep one batch of canonical frames.

        Parameters
        ----------
        frames : dict
            Topic -> DataFrame indexed by ``t_ns`` (ns since the Unix epoch), as
            :meth:`usvlog.io.importers.core.Assembler.process` returns.
        """
        for topic, f in frames.items():
            self._parts.setdefault(topic, []).append(f)

    def finish(self, meta: dict[str, dict[str, str]]) -> FieldLog:
        """The log of every batch written, each channel's parts joined in write order.

        Parameters
        ----------
        meta : dict
            Metadata records ``{name: {key: str}}`` (datum, vessel, provenance).

        Returns
        -------
        FieldLog
            The channels and ``meta``.
        """
        log = FieldLog()
        for topic, parts in self._parts.items():
            log.set(topic, parts[0] if len(parts) == 1 else pd.concat(parts))
        log.meta.update(meta)
        return log


class McapSink:
    """Streams canonical frames into an MCAP file opened by the caller (binary, writable),
    through :class:`usvlog.io.mcap.McapWriter` (zstd level 1: imports are large), one
    chunk (or more) per batch: each batch is on the file before the next is read."""

    def __init__(self, fh, *, chunk_size: int = 1 << 20):
        self._w = McapWriter(fh, chunk_size=chunk_size, zstd_level=1)

    def write(self, frames: dict[str, pd.DataFrame]) -> None:
        """Encode one batch of canonical frames and write it to the file now.

        Parameters
        ----------
        frames : dict
            Topic -> DataFrame indexed by ``t_ns`` (ns since the Unix epoch), as
            :meth:`usvlog.io.importers.core.Assembler.process` returns; the chunks are
            flushed before returning, so nothing of the batch stays in memory.
        """
        self._w.add_frames(frames)
        self._w.flush()

    def finish(self, meta: dict[str, dict[str, str]]) -> None:
        """Write the metadata records (in name order), the summary and the footer.

        Parameters
        ----------
        meta : dict
            Metadata records ``{name: {key: str}}`` (datum, vessel, provenance). The
            caller closes the file.
        """
        for name in sorted(meta):
            self._w.add_metadata(name, meta[name])
        self._w.finish()
