"""Logs in and out: load, save, import a field log, inspect, export, check (``usvlog import``,
``inspect``, ``export``, ``check``).

The verbs that take a log as it comes (a canonical MCAP file, a FieldLog or a foreign source) and
either turn it into a canonical log, describe it, write it out, or judge it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from ..errors import StorageError
from ._common import PathLike, Progress, _check_paths, _is_path, _read, _say, _vessel_file

if TYPE_CHECKING:  # annotations and docstring links only: importing these at run time pulls numpy and pandas
    import os  # noqa: F401  (named in the docstrings: the API reference links it)

    from ..check import CheckResult
    from ..io.importers import ImportResult
    from ..io.importers.catalog import Catalog
    from ..log.fieldlog import FieldLog
    from ..log.summary import LogSummary
    from ..model.vessel import Vessel  # noqa: F401  (named in the docstrings: the API reference links it)


def load(path, **kwargs) -> FieldLog:
    """Load a canonical MCAP log, recovering what it can from a damaged file.

    Parameters
    ----------
    path : str, os.PathLike or list of them
        The MCAP file. A list of paths loads consecutive files of one run (a rotated
        recording, ``run_000.mcap``, ``run_001.mcap``, ...) as one log.
    **kwargs
        ``topics`` (list of str): load only these channels. ``strict`` (bool, single file
        only): raise instead of recovering a file cut short. ``defer`` (bool, single file
        only, with ``topics``): keep the other channels in the file, decoded when touched
        and copied undecoded by :func:`save` (see :func:`usvlog.io.mcap.read_log`).

    Returns
    -------
    FieldLog
        One DataFrame per channel indexed by ``t_ns`` (int64 ns since the Unix epoch);
        ``log.recovery`` says what was lost from a damaged file (None when nothing was).
    """
    from ..io.mcap import read_log, read_logs  # heavy: the compiled MCAP reader (numpy, numba)

    if isinstance(path, (list, tuple)):
        return read_logs(path, **kwargs)
    return read_log(path, **kwargs)


def save(log: FieldLog, path: PathLike, force: bool = False, **kw) -> Path:
    """Write ``log`` as a canonical MCAP file, atomically.

    Parameters
    ----------
    log : FieldLog
        The run to write.
    path : str or os.PathLike
        Output file; its directory must exist.
    force : bool
        Replace an existing file (else :class:`~usvlog.errors.OutputExistsError`).
    **kw
        ``chunk_size`` (bytes of messages per zstd chunk, default 1 MiB) and ``compression``
        (``"zstd"``, default, or ``""`` for none).

    Returns
    -------
    pathlib.Path
        The path written.
    """
    from ..io.mcap import write_log  # heavy: the compiled MCAP writer

    write_log(log, path, force=force, **kw)
    return Path(path)


def import_log(src: PathLike, out: PathLike | None = None, *, fmt: str = "auto", vessel=None,
               columns: dict[str, str] | None = None, topics: dict[str, str] | None = None,
               thrust_unit: str | None = None, start_utc: str | int | None = None, force: bool = False,
               on_mapping: Callable | None = None, prefix_time: str | None = None,
               thrust_range: str | tuple | None = None, keep_dead: bool = False,
               msg_dirs: Sequence[PathLike] = (), datum: str | tuple | None = None) -> ImportResult:
    """Import a field log (CSV, NMEA 0183, ROS 1/2 bag, ArduPilot .bin, PX4 .ulg): ``usvlog import``.

    Parameters
    ----------
    src : str or os.PathLike
        The field log file (or ROS 2 bag directory).
    out : str or os.PathLike, optional
        Stream the canonical log into this MCAP file (then ``result.log`` is None); without it
        the log is returned in memory.
    fmt : str
        ``"auto"`` (detected from the content, not the name) or one of
        :data:`usvlog.choices.IMPORT_FORMATS` (``--format``).
    vessel : Vessel or path, optional
        Vessel (or vessel TOML) whose thruster map turns non-newton commands into forces.
    columns : dict, optional
        CSV: role -> column header (roles: ``time_s``, ``lat_deg``, ``heading_deg``,
        ``thrust_left``, ...); what is not given is guessed.
    topics : dict, optional
        role -> ``SOURCE[.field.path[i]]`` as ``usvlog inspect SOURCE`` lists them (roles:
        ``gnss``, ``heading``, ``yaw_rate``, ``thrust``, ``thrust_left``, ``thrust_right``,
        ``velocity``, ``speed_mps``, ``course``); what is not given is chosen by structure.
    thrust_unit : str, optional
        Unit of the recorded thruster commands (:data:`usvlog.choices.THRUST_UNITS`);
        None guesses it from the values.
    start_utc : str or int, optional
        Time of the first sample of a log with relative times: ISO 8601 text or ns since the
        Unix epoch.
    force : bool
        Replace an existing ``out``.
    on_mapping : callable, optional
        Called with the import report once the column/topic mapping is known, before the bulk
        of the work.
    prefix_time : str, optional
        NMEA/text logs: ``"auto"`` or a ``strptime`` format to use the time stamps a logger
        wrote before each sentence, ``"none"`` never; None uses only stamps that say their
        zone (``--prefix-time``).
    thrust_range : str or tuple, optional
        ``"LO:HI"`` or ``(lo, hi)``: range of integer ``counts`` commands (``--thrust-range``);
        guessed from the values when None.
    keep_dead : bool
        Write channels the sensor health audit judges dead as data (``--keep-dead``); by
        default they go to ``/raw/...`` and are flagged.
    msg_dirs : sequence of str or os.PathLike
        ROS bags: directories whose ``.msg`` files (``<pkg>/msg/<Name>.msg``) define the
        message types the bag does not store (``--msg-dir``, repeatable).
    datum : str or tuple, optional
        ``"LAT,LON"`` or ``(lat, lon)`` in degrees (``--datum``): the origin of the local
        frame; positions in metres (``/local/position``) are then geo-referenced. None: the
        first fix (and local positions stay local).

    Returns
    -------
    ImportResult
        ``log`` (None when streamed to ``out``), ``report`` (mapping, guesses, counts, skipped
        records) and ``out``.
    """
    _check_paths([src], out, force, parent=False)   # the importer's own checks, before its imports
    from ..io.importers import import_file  # heavy: the importers (numpy, pandas)

    return import_file(src, fmt, vessel=_vessel_file(vessel), columns=columns, topics=topics,
                       thrust_unit=thrust_unit, start_utc=start_utc, out=out, force=force,
                       on_mapping=on_mapping, prefix_time=prefix_time, thrust_range=thrust_range,
                       keep_dead=keep_dead, msg_dirs=msg_dirs, datum=datum)


def inspect(log, *, fmt: str = "auto", topics: dict[str, str] | None = None,
            msg_dirs: Sequence[PathLike] = ()) -> LogSummary | Catalog:
    """What is in a log or a foreign source (``usvlog inspect``).

    A canonical MCAP log gives its summary: the file is read a chunk at a time
    (:func:`usvlog.io.mcap.reader.iter_chunks`: every chunk's CRC checked, recovery past damage
    as :func:`load` does) and only its time stamps are looked at, so memory stays bounded
    (about 200 MB) whatever the file's size; payloads are not decoded (a message that does not
    fit its schema is reported by :func:`load`). Any other source (ROS 1/2 bag, ULog,
    DataFlash, NMEA, CSV) gives its catalog: every topic/message with type, count, time span
    and field paths, the role mapping ``usvlog import`` would use and why.

    Parameters
    ----------
    log : FieldLog or path
        The log, its MCAP file, or a foreign source file (a directory for a ROS 2 bag).
    fmt : str
        Format of a foreign source: ``"auto"`` (from the content) or one of
        :data:`usvlog.choices.IMPORT_FORMATS`.
    topics : dict, optional
        role -> ``SOURCE.field.path[i]`` for a foreign source, checked and honoured as
        ``usvlog import --topic`` would.
    msg_dirs : sequence of str or os.PathLike
        ROS bags: directories of ``.msg`` files for the types the bag does not store
        (``--msg-dir``).

    Returns
    -------
    LogSummary or Catalog
        LogSummary (canonical log): per channel count, nominal rate (Hz), first/last time (ns),
        duration (s), gaps longer than 3 periods, backwards and repeated time stamps; plus
        metadata, recovery and skipped-record counts. ``format_summary`` of
        :mod:`usvlog.log.summary` prints it, ``to_dict()`` gives the JSON form;
        ``recovery["nothing_recovered"]`` marks a damaged file with nothing in it
        (``usvlog inspect`` exits 1). Catalog (foreign source):
        :class:`usvlog.io.importers.catalog.Catalog`, printed by ``format_catalog``.
    """
    if _is_path(log):
        path = Path(log)
        if _is_canonical_candidate(path):
            return _inspect_file(path)
        from ..io.importers import catalog_file  # heavy: the importers (numpy, pandas)

        return catalog_file(path, fmt, topics=topics, msg_dirs=msg_dirs)
    from ..log.summary import summarize  # heavy: numpy, pandas

    return summarize(log)


def _is_canonical_candidate(path: Path) -> bool:
    """An MCAP file that is not a ROS 2 bag, a missing path, or a non-MCAP file named ``*.mcap``."""
    if not path.exists():
        return True
    if path.is_dir():
        return False
    try:
        with open(path, "rb") as fh:
            head = fh.read(64)
    except OSError as err:
        raise StorageError(f"{path}: cannot be read ({err.strerror or err})") from err
    if head.startswith(b"\x89MCAP0\r\n"):
        return b"ros2" not in head[8:64]  # the header record's profile names a ROS 2 bag
    return path.suffix.lower() == ".mcap"


def _inspect_file(path: Path) -> LogSummary:
    """:func:`inspect` of an MCAP file, streamed: the same summary as ``summarize(load(path))``."""
    # heavy: numpy, the MCAP reader
    from ..io.mcap.reader import by_channel as split_channels
    from ..io.mcap.reader import codec_of_channel, iter_chunks
    from ..log.channels import schema_for_topic
    from ..log.fieldlog import META_PROVENANCE
    from ..log.summary import LogSummary, TimeStats, skipped_from_provenance

    def by_channel(chunk):
        """(channel id, its times, its sequence numbers) in the chunk, in file order."""
        groups = split_channels(chunk.channel_id)
        if len(groups) == 1:
            yield groups[0][0], chunk.log_time_ns, chunk.sequence
            return
        for c, ix in groups:
            yield c, chunk.log_time_ns[ix], chunk.sequence[ix]

    stats: dict[int, TimeStats] = {}
    with iter_chunks(path) as stream:
        for chunk in stream:
            for c, t, seq in by_channel(chunk):
                stats.setdefault(c, TimeStats()).add(t, seq)
        channels, meta, recovery = stream.channels, stream.metadata, stream.recovery()
    again = {c for c, st in stats.items() if st.needs_pass()}
    if again:   # a median from a histogram, or stamps out of order: read the stamps once more
        for c in again:
            stats[c].start_pass()
        with iter_chunks(path) as stream:
            for chunk in stream:
                for c, t, seq in by_channel(chunk):
                    if c in again:
                        stats[c].refine(t, seq)
    by_topic = {}
    for cid in sorted(channels):
        ch = channels[cid]
        if not ch.canonical:
            continue  # not a canonical channel: load leaves it alone too
        schema, _codec = codec_of_channel(path, ch)
        title = schema.get("title", "") or (schema_for_topic(ch.topic) or {}).get("title", "")
        by_topic[ch.topic] = stats.get(cid, TimeStats()).summary(ch.topic, title)
    chans = tuple(by_topic[t] for t in sorted(by_topic))
    firsts = [c.first_ns for c in chans if c.first_ns is not None]
    lasts = [c.last_ns for c in chans if c.last_ns is not None]
    first = min(firsts) if firsts else None
    last = max(lasts) if lasts else None
    prov_keys = sorted((k for k in meta if k.startswith(META_PROVENANCE + "/")), key=lambda k: int(k.rsplit("/", 1)[1]))
    return LogSummary(str(path), chans, first, last, (last - first) / 1e9 if first is not None else 0.0,
                      {k: dict(v) for k, v in meta.items()}, recovery.to_dict() if recovery else None,
                      skipped_from_provenance([meta[k] for k in prov_keys]))


def export(log, out: PathLike, *, fmt: str = "csv", force: bool = False,
           progress: Progress = None) -> list[Path]:
    """Write each channel of a log to ``out/<topic>.csv`` or ``.parquet`` (``usvlog export``).

    Parameters
    ----------
    log : FieldLog or path
        The log, or its MCAP file.
    out : str or os.PathLike
        Output directory (created when missing).
    fmt : str
        ``"csv"`` (default) or ``"parquet"`` (``--format``).
    force : bool
        Replace existing files (every output is checked before the first is written).
    progress : callable, optional
        Receives the one-line damage report of a damaged input file.

    Returns
    -------
    list of pathlib.Path
        The files written, one per channel; the index ``t_ns`` (ns since the Unix epoch) is
        the first column.
    """
    from ..io.export import export_log  # heavy: pandas

    return export_log(_read(log, progress), out, fmt=fmt, force=force)


# -----------------------------------------------------------------------------
# check
# -----------------------------------------------------------------------------

def check(log, *, vessel=None, fmt: str = "auto", msg_dirs: Sequence[PathLike] = (),
          progress: Progress = None) -> CheckResult:
    """Is this log sound, and what is wrong with the boat's sensors (``usvlog check``)?

    Parameters
    ----------
    log : FieldLog or path
        A log, its canonical MCAP file, or any field log ``usvlog import`` reads: that one is
        imported in memory first with the import's own guesses (an import that keeps too
        little is checked all the same, its reason an error finding).
    vessel : Vessel or path, optional
        The boat (thruster map and limits, heading offset); default the log's own.
    fmt : str
        Format of a field log (``"auto"``: from the content).
    msg_dirs : sequence of str or os.PathLike
        ROS bags: directories of ``.msg`` files for types the bag does not store.
    progress : callable, optional
        Receives a line per stage.

    Returns
    -------
    usvlog.check.CheckResult
        The findings (severity, channel, time range from the log's start, evidence, action)
        and the checks that ran; ``exit_code`` is 1 when any finding is an error.
    """
    from ..log.findings import Finding, findings_from_health  # light: standard library only

    extra: list = []
    if _is_path(log) and not _is_canonical_candidate(Path(log)):
        _say(progress, f"importing {log} in memory")
        res = import_log(log, fmt=fmt, vessel=vessel, force=True, msg_dirs=msg_dirs)
        rep = res.report
        if rep.unusable:
            extra.append(Finding(severity="error", code="import.unusable", evidence=str(rep.unusable),
                                 action="fix the mapping or the time column at import"))
        topic = {"gnss": "/gnss/fix", "heading": "/compass/heading", "yaw_rate": "/imu/yaw_rate",
                 "velocity": "/gnss/velocity", "local": "/local/position"}
        held = {topic.get(k[:-len("_held_repeat")], k): int(n) for k, n in rep.skipped.items()
                if k.endswith("_held_repeat")}
        extra += findings_from_health(None, held)
        log = res.log
    else:
        if _is_path(log):
            _check_paths([log], None, False)
        log = _read(log, progress)
    from ..check import check_log  # heavy: numpy, scipy and the identification's smoother

    _say(progress, "checking")
    return check_log(log, _vessel_file(vessel), extra=extra)
