"""Reading canonical MCAP logs, recovering what a damaged file still holds: the front door.

Records are walked here rather than through the mcap library's per-record objects.
Every chunk's CRC is checked (and the data section CRC in the Data End record, when
set); a chunk that fails, does not decompress or whose records do not parse is never
loaded. After any damaged record the walk resumes at the next chunk that checks out
(the summary's chunk index gives every chunk's offset when the footer and summary
survive; else the bytes are searched for a chunk header whose fields agree and whose
CRC checks out), so every intact chunk is kept wherever the damage is. A message that
does not decode costs that message only. What was lost is reported
(:class:`usvlog.log.fieldlog.RecoveryReport`). Records and messages are walked into
arrays with compiled loops (:mod:`.kernels`); :func:`read_log` decodes the messages a group
of chunks at a time as the walk goes (:class:`ChunkStream`), so its memory is the decoded
frames plus a bounded buffer whatever the file's size, and with ``topics`` it skips the
chunks the summary's chunk index shows hold none of them. ``_scan_fast`` is the same walk
into one buffer of every message (``scan_file``); :func:`.reference._scan_reference` is the
plain reading the tests compare them with.

This module holds :func:`read_log` and :func:`read_logs` and names the rest of the reading
API, which lives in the modules of its parts, lowest first:

- :mod:`.container`: records, the summary, the file's layout, one chunk checked;
- :mod:`.recovery`: damage spotted, the walk resumed past it, the recovery report;
- :mod:`.walk`: the compiled walk of verified chunks into message arrays;
- :mod:`.stream`: :func:`iter_chunks` / :class:`ChunkStream`, :func:`scan_file`, the
  summary-only reads :func:`chunk_spans` and :func:`channel_ids`;
- :mod:`.decode`: channels decoded into frames (:func:`codec_of_channel`);
- :mod:`.deferred`: channels decoded when first touched (``read_log(..., defer=True)``).
"""

from __future__ import annotations

from pathlib import Path

from ...errors import InputError
from ...log.fieldlog import FieldLog
from .container import chunks_decompressed
from .decode import _read_log, _return_freed_memory, codec_of_channel
from .deferred import _read_deferred
from .stream import ChannelInfo, Chunk, ChunkStream, by_channel, channel_ids, chunk_spans, iter_chunks, scan_file

__all__ = ["ChannelInfo", "Chunk", "ChunkStream", "by_channel", "channel_ids", "chunk_spans", "chunks_decompressed",
           "codec_of_channel", "iter_chunks", "read_log", "read_logs", "scan_file"]


def read_log(path, *, topics: list[str] | None = None, strict: bool = False, defer: bool = False) -> FieldLog:
    """Load a canonical MCAP log into a :class:`FieldLog`, checking every chunk's CRC.

    Parameters
    ----------
    path : str or Path
        The MCAP file.
    topics : list of str, optional
        Load only these channels.
    strict : bool
        Raise :class:`InputError` on any damage instead of recovering.
    defer : bool
        With ``topics``: decode only those now and keep the file's other canonical
        channels deferred (``log.channels`` is a :class:`~usvlog.log.fieldlog.Channels`:
        they are listed, their schemas are in ``log.schemas``, and each is decoded when first
        touched; :func:`.writer.write_log` copies one still deferred without decoding it).
        A damaged file is read whole instead (its recovery report is then the full one).

    Returns
    -------
    FieldLog
        ``log.recovery`` is None for an undamaged file. A damaged one loads with every
        chunk that checks out (CRC, decompression, records) wherever the damage is, and
        every message that decodes; ``log.recovery`` (:class:`RecoveryReport`) lists the
        damaged byte ranges, the chunks lost (time range and channels where known), the
        messages skipped and bytes after the footer. A chunk that fails is never loaded.
    """
    if defer and topics is not None:
        log = _read_deferred(Path(path), list(topics), strict)
    else:
        log = _read_log(path, topics=topics, strict=strict)
    _return_freed_memory()
    return log


def read_logs(paths, *, topics: list[str] | None = None) -> FieldLog:
    """Load consecutive files of one run (e.g. a rotated recording) as one :class:`FieldLog`.

    Files written by the recorder carry a ``usvlog.recording`` record (run id, part
    number): they are put in part order and must be one run with no part missing.
    Other files are taken in the order given. Channels are concatenated; metadata
    comes from the first file, with the datum from the first file that has one.
    A damaged file is recovered as :func:`read_log` does; its report is kept.
    """
    paths = [Path(p) for p in paths]
    if not paths:
        raise InputError("read_logs: no files given")
    logs = [read_log(p, topics=topics) for p in paths]
    rec = [lg.meta.get("usvlog.recording") for lg in logs]
    if all(r is not None for r in rec):
        runs = {r.get("run_id") for r in rec}
        if len(runs) != 1:
            ids = ", ".join(sorted(map(str, runs)))
            raise InputError(f"{paths[0]}: files belong to different recordings (run ids {ids})")
        order = sorted(range(len(logs)), key=lambda i: int(rec[i].get("part", 0)))
        parts = [int(rec[i].get("part", 0)) for i in order]
        for a, b, i in zip(parts, parts[1:], order[1:]):
            if b != a + 1:
                raise InputError(f"{paths[i]}: part {b} follows part {a}; part(s) missing between them")
        logs = [logs[i] for i in order]
    elif any(r is not None for r in rec):
        raise InputError(f"{paths[0]}: mixes recorder files with other files")
    out = FieldLog(source=", ".join(str(lg.source) for lg in logs))
    out.meta = {k: dict(v) for k, v in logs[0].meta.items()}
    for lg in logs:
        if lg.datum is not None:
            out.datum = lg.datum
            break
    topics_all = []
    for lg in logs:
        topics_all += [t for t in lg.channels if t not in topics_all]
        out.schemas.update({t: s for t, s in lg.schemas.items() if t not in out.schemas})
    for t in topics_all:
        frames = [lg.channels[t] for lg in logs if t in lg.channels]
        if len(frames) == 1:
            out.channels[t] = frames[0]
        else:
            import pandas as pd
            out.channels[t] = pd.concat(frames)
    damaged = [lg for lg in logs if lg.recovery is not None]
    if damaged:
        out.recovery = damaged[-1].recovery
    return out
