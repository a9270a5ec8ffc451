"""Import field logs (CSV, NMEA 0183, ROS 1/2 bags, ArduPilot .bin, PX4 .ulg) into canonical logs.

``import_file(src)`` detects the format from the file's content, reads it in chunks,
maps its columns/topics/messages to the canonical channels (``/gnss/fix``,
``/compass/heading``, ``/thrust/command``, ``/imu/yaw_rate``, ``/gnss/velocity``),
skips and counts bad records, and either returns a :class:`usvlog.FieldLog` or (with
``out=``) streams it into an MCAP file written atomically. Every import records its
provenance (source name, size, sha256, format, settings, skipped counts, guesses).

One module per format; each has ``read(path, options, report) -> iterator of batches``
(see :mod:`usvlog.io.importers.core` for the batch layout).
"""

from __future__ import annotations

import gzip
import hashlib
import importlib
import math
import re
import zlib
from dataclasses import dataclass, field
from pathlib import Path

from ...choices import IMPORT_FORMATS
from ...errors import ConfigError, FormatError, InputError, UnusableResultError
from ...log.fieldlog import FieldLog, parse_time
from ...model.frames import Datum
from ...model.vessel import THRUST_UNITS, Vessel
from ..atomic import atomic_path, check_input, check_output
from .catalog import Catalog
from .core import Assembler, ImportReport
from .csvlog import looks_like_csv
from .mapping import ROLES as MAPPING_ROLES
from .mapping import apply as mapping_apply
from .mapping import propulsion_outside_model, split_path
from .nmea import looks_like_nmea
from .sink import McapSink, MemorySink
from .sniff import (
    DATAFLASH_MAGIC,
    GZIP_MAGIC,
    MCAP_MAGIC,
    ROS1_MAGIC,
    SQLITE_MAGIC,
    ULOG_MAGIC,
    file_head,
)

FORMATS = IMPORT_FORMATS
_MODULES = {"csv": "csvlog", "nmea": "nmea", "ros1": "rosbag", "ros2": "rosbag",
            "dataflash": "dataflash", "ulog": "ulog"}
CSV_ROLES = ("time_s", "time_ms", "time_us", "time_ns", "time_iso", "lat_deg", "lon_deg", "alt_m", "heading_deg",
             "heading_rad",
             "thrust_left", "thrust_right", "yaw_rate_degps", "yaw_rate_radps", "speed_mps", "course_deg",
             "thrust_left_dir", "thrust_right_dir", "local_n", "local_e")
TOPIC_ROLES = MAPPING_ROLES  # gnss, heading, yaw_rate, thrust, thrust_left, thrust_right, velocity, speed_mps, course



def _check_topic_spec(role: str, spec) -> None:
    """``--topic ROLE=SOURCE.field.path[i]``: a name, then dotted fields with optional ``[i]`` indices."""
    text = str(spec)
    bad = (not text.strip() or any(c.isspace() or not c.isprintable() for c in text)
           or text.count("[") != text.count("]"))
    if not bad and "[" in text:
        bad = not all((tok.startswith("[") and tok[1:-1].isdigit()) or ("[" not in tok and "]" not in tok)
                      for tok in re.findall(r"\[[^\]]*\]|[^\[]+", text))
    if bad or not split_path(text):
        shown = "".join(c if c.isprintable() else "?" for c in text)[:80]
        raise ConfigError(f"--topic {role}={shown!r} is not SOURCE[.field.path[i]] "
                          "(e.g. /fix, /motors.left, /cmd.data[1], actuator_outputs.1.output[0])")


def _check_msg_dirs(dirs) -> None:
    """Every ``--msg-dir`` is a directory with a ``.msg`` file under it (ConfigError, one line, if not)."""
    for d in dirs:
        p = Path(d)
        if not p.is_dir():
            raise ConfigError(f"--msg-dir {d}: not a directory")
        if next((f for f in p.rglob("*.msg") if f.is_file()), None) is None:
            raise ConfigError(f"--msg-dir {d}: no .msg file under it")


@dataclass(frozen=True, kw_only=True)
class ImportOptions:
    """Settings of one import (recorded in the log's provenance)."""

    columns: dict = field(default_factory=dict)   # CSV role -> header
    topics: dict = field(default_factory=dict)    # bag role -> "/topic[.field.path]"
    thrust_unit: str | None = None                # None: guessed from the values
    start_utc_ns: int | None = None               # for relative time columns
    chunk_rows: int = 50_000
    prefix_time: str | None = None                # text logs: None, "auto", "none" or a strptime format
    thrust_range: tuple | None = None             # (lo, hi) of counts commands (--thrust-range)
    keep_dead: bool = False                       # write channels judged dead as data (--keep-dead)
    msg_dirs: tuple = ()                          # ROS bags: directories of .msg files (--msg-dir)

    def __post_init__(self):
        if self.prefix_time is not None and self.prefix_time not in ("auto", "none") and "%" not in self.prefix_time:
            raise ConfigError(f"--prefix-time {self.prefix_time!r} is not auto, none or a strptime format "
                              "such as '%Y-%m-%d %H:%M:%S.%f'")
        if self.thrust_unit is not None and self.thrust_unit not in THRUST_UNITS:
            raise ConfigError(f"thrust unit {self.thrust_unit!r} is not one of {', '.join(THRUST_UNITS)}")
        for role in self.columns:
            if role not in CSV_ROLES:
                raise ConfigError(f"unknown column role {role!r} (roles: {', '.join(CSV_ROLES)})")
        for role, spec in self.topics.items():
            if role not in TOPIC_ROLES:
                raise ConfigError(f"unknown topic role {role!r} (roles: {', '.join(TOPIC_ROLES)})")
            _check_topic_spec(role, spec)
        if self.chunk_rows < 1:
            raise ConfigError("chunk_rows must be >= 1")
        _check_msg_dirs(self.msg_dirs)
        if self.thrust_range is not None:
            lo, hi = self.thrust_range
            if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi and max(abs(lo), abs(hi)) > 0):
                raise ConfigError(f"thrust range {lo:g}:{hi:g} is not LO:HI with LO < HI")
            if self.thrust_unit not in (None, "counts"):
                raise ConfigError(f"--thrust-range is for counts commands, not {self.thrust_unit}")

    def to_dict(self) -> dict:
        """The settings as recorded in the log's provenance.

        Returns
        -------
        dict
            ``columns`` and ``topics`` (role -> source name), ``thrust_unit`` (None when
            guessed) and ``start_utc_ns`` (ns since the Unix epoch, or None); ``thrust_range``
            and ``keep_dead`` only when set; ``chunk_rows`` is not recorded.
        """
        d = {"columns": dict(self.columns), "topics": dict(self.topics), "thrust_unit": self.thrust_unit,
             "start_utc_ns": self.start_utc_ns}
        if self.prefix_time is not None:
            d["prefix_time"] = self.prefix_time
        if self.thrust_range is not None:
            d["thrust_range"] = list(self.thrust_range)
        if self.keep_dead:
            d["keep_dead"] = True
        if self.msg_dirs:
            d["msg_dirs"] = [str(x) for x in self.msg_dirs]
        return d


@dataclass(frozen=True)
class ImportResult:
    """The imported log (None when streamed to ``out``), the report, the output path."""

    log: FieldLog | None
    report: ImportReport
    out: Path | None = None

    def to_dict(self) -> dict:
        """The import report as a JSON-ready dict, plus the output path.

        Returns
        -------
        dict
            :meth:`ImportReport.to_dict` with ``out`` added: the MCAP file written (str),
            or None when the log was kept in memory.
        """
        d = self.report.to_dict()
        d["out"] = str(self.out) if self.out else None
        return d


def parse_thrust_range(text: str | None) -> tuple[float, float] | None:
    """``--thrust-range`` text ``LO:HI`` (e.g. ``-255:255``, ``0:200``) -> (lo, hi) in counts.

    Parameters
    ----------
    text : str or None
        Two numbers separated by ``:``, or None.

    Returns
    -------
    tuple of float or None
        ``(lo, hi)``; None when ``text`` is None.

    Raises
    ------
    ConfigError
        Not two finite numbers with LO < HI.
    """
    if text is None:
        return None
    lo, sep, hi = str(text).partition(":")
    try:
        rng = (float(lo), float(hi))
    except ValueError:
        rng = None
    if not sep or rng is None or not all(math.isfinite(x) for x in rng) or rng[0] >= rng[1]:
        raise ConfigError(f"thrust range {text!r} is not LO:HI with LO < HI (e.g. -255:255 or 0:200)")
    return rng


def parse_datum(value) -> Datum | None:
    """``--datum`` ``"LAT,LON"`` (degrees), a ``(lat, lon)`` pair or a Datum -> Datum (None stays None).

    Raises
    ------
    ConfigError
        Not two numbers, or latitude/longitude out of range.
    """
    if value is None or isinstance(value, Datum):
        return value
    parts = value.replace(";", ",").split(",") if isinstance(value, str) else list(value)
    try:
        lat, lon = (float(x) for x in parts)
    except (TypeError, ValueError):
        raise ConfigError(f"--datum {value!r} is not LAT,LON in degrees (e.g. 25.6514,-100.2895)") from None
    if not (math.isfinite(lat) and math.isfinite(lon) and abs(lat) <= 90 and abs(lon) <= 180):
        raise ConfigError(f"--datum {value!r}: latitude must be within +-90 and longitude within +-180 degrees")
    return Datum(lat_deg=lat, lon_deg=lon)


def parse_start_utc(text: str | None) -> int | None:
    """``--start-utc`` text -> ns since the Unix epoch.

    Parameters
    ----------
    text : str or None
        An ISO 8601 time, UTC when it has no zone (:func:`usvlog.log.fieldlog.parse_time`),
        or None.

    Returns
    -------
    int or None
        The time in ns since the Unix epoch (UTC); None when ``text`` is None.

    Raises
    ------
    ConfigError
        ``text`` is not an ISO 8601 time.
    """
    if text is None:
        return None
    try:
        return parse_time(text)
    except ValueError as err:
        raise ConfigError(f"start time {text!r} is not an ISO 8601 time") from err


_TIME_REASONS = ("_time_backwards", "_time_duplicate", "_time_negative")


def _check_usable(p, asm: Assembler, report: ImportReport, force: bool) -> None:
    """Raise :class:`UnusableResultError` when a stream kept less than half of its samples
    (:meth:`Assembler.shortfalls`); with ``force`` flag the report (and the log's provenance)
    and go on."""
    short = asm.shortfalls()
    if not short:
        return
    s = short[0]
    why = f"{s['reason']} {s['count']}" if s["reason"] else "reason unknown"
    if s["first"]:
        why += "; first: " + " ".join(str(s["first"]).split())
    fix = ("give the right time column (e.g. --column time_ms=HEADER)" if s["reason"] and
           s["reason"].endswith(_TIME_REASONS) else "check the column/topic mapping")
    more = f" (and {', '.join(x['topic'] for x in short[1:])})" if len(short) > 1 else ""
    msg = (f"{p}: {s['topic']}{more}: kept {s['kept']} of {s['of']} samples ({why}); {fix}, "
           "or --force writes it anyway, flagged")
    if not force:
        raise UnusableResultError(msg)
    report.unusable = msg
    report.note(f"UNUSABLE, written with --force: {msg}")


def detect_format(path) -> str:
    """Format of ``path`` from its content (magic bytes, first lines), not its name."""
    p = Path(path)
    if p.is_dir():
        if (p / "metadata.yaml").exists() or any(p.glob("*.db3")) or any(p.glob("*.mcap")):
            return "ros2"
        raise FormatError(f"{p}: a directory that is not a ROS 2 bag (no metadata.yaml)")
    head = file_head(p, 65536)
    if not head:
        raise InputError(f"{p}: empty file")
    if head.startswith(ROS1_MAGIC):
        return "ros1"
    if head.startswith(SQLITE_MAGIC):
        return "ros2"
    if head.startswith(MCAP_MAGIC):
        if b"usvlog" in head[:256]:
            raise FormatError(f"{p}: already a usvlog canonical log (nothing to import)")
        return "ros2"
    if head.startswith(ULOG_MAGIC):
        return "ulog"
    if head.startswith(DATAFLASH_MAGIC):
        return "dataflash"
    if head.startswith(GZIP_MAGIC):
        return _detect_gzip(p)
    text = head.decode("utf-8", errors="replace")
    if looks_like_nmea(text):   # before the binary check: a receiver's capture may mix binary messages in
        return "nmea"
    if looks_binary(text):
        raise FormatError(f"{p}: unknown format (binary content that is not a ROS bag, DataFlash or ULog; "
                          "CSV and NMEA are text); give --format if it is one of them")
    if looks_like_csv(text):
        return "csv"
    raise FormatError(f"{p}: unknown format (not CSV, NMEA, ROS bag, DataFlash or ULog); "
                      "give --format if it is one of them")


def _detect_gzip(p: Path) -> str:
    """Format of a gzip-compressed file: CSV (read through pandas) or NMEA, from its first lines."""
    try:
        with gzip.open(p, "rb") as fh:
            text = fh.read(65536).decode("utf-8", errors="replace")
    except (OSError, EOFError, zlib.error) as err:
        raise FormatError(f"{p}: damaged gzip file ({type(err).__name__}: {err})") from err
    if looks_like_nmea(text):
        return "nmea"
    if looks_like_csv(text) and not looks_binary(text):
        return "csv"
    raise FormatError(f"{p}: gzip-compressed content that is not CSV or NMEA (decompress it and give "
                      "--format if it is another format)")


def looks_binary(text: str) -> bool:
    """Whether the start of a file, decoded as UTF-8 with replacement characters, is binary
    rather than text: a NUL, or more than 5 % of its characters undecodable or control
    characters other than tab, CR, LF and form feed.

    Parameters
    ----------
    text : str
        The file's first bytes, decoded.
    """
    if not text:
        return False
    if "\0" in text:
        return True
    bad = sum(1 for c in text if c == "\ufffd" or (c < " " and c not in "\t\r\n\f"))
    return bad > 0.05 * len(text)


def file_identity(path) -> dict:
    """Size and sha256 of a file (or of every file of a bag directory, in name order)."""
    p = Path(path)
    files = sorted(x for x in p.rglob("*") if x.is_file()) if p.is_dir() else [p]
    h = hashlib.sha256()
    size = 0
    for f in files:
        with open(f, "rb") as fh:
            while buf := fh.read(1 << 20):
                h.update(buf)
                size += len(buf)
    return {"size": size, "sha256": h.hexdigest()}


def catalog_file(src, fmt: str = "auto", *, topics: dict | None = None, msg_dirs=()) -> Catalog:
    """What a foreign source holds and how it would be mapped: ``usvlog inspect SOURCE``.

    Parameters
    ----------
    src : path-like
        The source file (a directory for a ROS 2 bag).
    fmt : str
        ``auto`` (detected from the content) or one of :data:`FORMATS`.
    topics : dict, optional
        role -> ``SOURCE.field.path[i]`` to check and honour, as ``--topic`` of ``import``.
    msg_dirs : sequence of path-like
        ROS bags: directories whose ``.msg`` files define the message types the bag does
        not store (``--msg-dir``).

    Returns
    -------
    Catalog
        Every topic/message with type, count, time span (ns) and field paths, and the role
        mapping with its reasons (:func:`usvlog.io.importers.mapping.map_roles`, unless the
        format's reader fills it itself).

    Raises
    ------
    UsvlogError
        One line: the file does not exist or is empty (``StorageError``/``InputError``),
        cannot be read (``FormatError``), a ``--topic`` mapping names what does not exist
        (``InputError``), or the format has no listing yet (``FormatError``).
    """
    p = check_input(src)
    if fmt not in ("auto",) + FORMATS:
        raise ConfigError(f"format {fmt!r} is not auto or one of {', '.join(FORMATS)}")
    opts = ImportOptions(topics=dict(topics or {}), msg_dirs=tuple(str(d) for d in msg_dirs or ()))
    if p.is_file() and p.stat().st_size == 0:
        raise InputError(f"{p}: empty file")
    if fmt == "auto":
        fmt = detect_format(p)
    module = importlib.import_module(f".{_MODULES[fmt]}", __name__)
    lister = getattr(module, "catalog", None)
    if lister is None:
        raise FormatError(f"{p}: listing the topics of a {fmt} source is not yet supported "
                          f"(usvlog import {p} --out LOG.mcap, then usvlog inspect LOG.mcap)")
    cat = lister(p, opts, fmt=fmt) if fmt in ("ros1", "ros2") else lister(p, opts)
    if not cat.mapping:
        mapping_apply(cat, opts.topics)
    cat.propulsion = propulsion_outside_model(cat, cat.mapping)
    if cat.propulsion:
        cat.notes.append(cat.propulsion["why"])
    return cat


def import_file(src, fmt: str = "auto", *, vessel: Vessel | None = None, columns: dict | None = None,
                topics: dict | None = None, thrust_unit: str | None = None, start_utc: str | int | None = None,
                datum: Datum | str | tuple | None = None, out=None, force: bool = False, chunk_rows: int = 50_000,
                on_mapping=None, prefix_time: str | None = None, thrust_range=None,
                keep_dead: bool = False, msg_dirs=()) -> ImportResult:
    """Import one field log.

    Parameters
    ----------
    src : path-like
        The source file (a directory for a ROS 2 bag).
    fmt : str
        ``auto`` (detected from the content) or one of :data:`FORMATS`.
    vessel : usvlog.model.vessel.Vessel, optional
        Its thruster map turns commands that are not newtons into forces (N).
    columns : dict, optional
        CSV role -> header (roles: :data:`CSV_ROLES`); what is not given is guessed.
    topics : dict, optional
        role -> ``SOURCE[.field.path[i]]`` (roles: :data:`TOPIC_ROLES`); chosen by structure otherwise.
    thrust_unit : str, optional
        ``newton``, ``normalized`` or ``pwm_us``; guessed from the values when None.
    start_utc : str or int, optional
        Time of the first sample of a log with relative times (ISO 8601 text or ns since the
        Unix epoch); for NMEA without RMC/ZDA also the date.
    datum : usvlog.model.frames.Datum or str, optional
        Origin of the local NED frame (or ``"LAT,LON"``, :func:`parse_datum`); the first kept
        fix when None. Local positions in metres are geo-referenced to it.
    out : path-like, optional
        Stream the log into this MCAP file (written atomically) instead of memory.
    force : bool
        Overwrite ``out`` if it exists.
    chunk_rows : int
        Source records per batch (memory stays flat).
    on_mapping : callable, optional
        ``on_mapping(report)`` once the mapping is known, before the bulk of the work.
    prefix_time : str, optional
        NMEA/text logs: use the time stamps before the sentences (``"auto"``: ISO 8601 or
        seconds; or a ``strptime`` format); ``"none"``: never; None: only stamps that say
        their zone or are epoch seconds (see :mod:`usvlog.io.importers.nmea`).
    thrust_range : tuple of float or str, optional
        ``(lo, hi)`` or ``"LO:HI"``: the range of ``counts`` commands (full scale: the larger
        magnitude); implies ``thrust_unit="counts"``. Guessed from the values when None.
    keep_dead : bool
        Write channels the health audit judges dead as data (flagged) instead of under
        ``/raw/...`` (:mod:`usvlog.io.importers.audit`).
    msg_dirs : sequence of path-like
        ROS bags: directories whose ``.msg`` files (``<pkg>/msg/<Name>.msg``) define the
        message types the bag does not store (``--msg-dir``).

    Returns
    -------
    ImportResult
        The log (None with ``out``), the :class:`ImportReport` (records read, kept,
        skipped by reason, guesses) and the output path.

    Raises
    ------
    UsvlogError
        One line naming the file: :class:`~usvlog.errors.InputError` for unusable content,
        :class:`~usvlog.errors.FormatError` for a file the format's parser cannot read
        (chained ``from`` the parser's exception), ``StorageError`` / ``OutputExistsError``
        / ``ConfigError`` for paths and settings. Any other exception is a bug in usvlog
        and propagates as it is.
    """
    p = check_input(src)
    if fmt not in ("auto",) + FORMATS:
        raise ConfigError(f"format {fmt!r} is not auto or one of {', '.join(FORMATS)}")
    start_ns = start_utc if isinstance(start_utc, int) or start_utc is None else parse_start_utc(start_utc)
    datum = parse_datum(datum)
    if isinstance(thrust_range, str):
        thrust_range = parse_thrust_range(thrust_range)
    opts = ImportOptions(columns=dict(columns or {}), topics=dict(topics or {}), thrust_unit=thrust_unit,
                         start_utc_ns=start_ns, chunk_rows=chunk_rows, prefix_time=prefix_time,
                         thrust_range=None if thrust_range is None else tuple(float(x) for x in thrust_range),
                         keep_dead=bool(keep_dead), msg_dirs=tuple(str(d) for d in msg_dirs or ()))
    if out is not None:
        check_output(out, force)
    if p.is_file() and p.stat().st_size == 0:
        raise InputError(f"{p}: empty file")
    if fmt == "auto":
        fmt = detect_format(p)
    report = ImportReport(source=p.name, format=fmt)
    ident = file_identity(p)
    asm = Assembler(report, vessel=vessel, datum=datum, thrust_unit=opts.thrust_unit,
                    thrust_range=opts.thrust_range, keep_dead=opts.keep_dead)
    module = importlib.import_module(f".{_MODULES[fmt]}", __name__)

    def run(sink):
        # no catch-all here: each reader wraps its third-party parser's exceptions where it
        # calls it (FormatError from the library's error); anything else is a bug in usvlog
        for batch in module.read(p, opts, report, fmt=fmt, on_mapping=on_mapping):
            sink.write(asm.process(batch))
        sink.write(asm.finish())
        if sum(report.counts.values()) == 0:
            sk = ", ".join(f"{k} {v}" for k, v in sorted(report.skipped.items())) or "none"
            first = "; first: " + " ".join(next(iter(report.first_bad.values())).split()) if report.first_bad else ""
            raise InputError(f"{p}: nothing imported as {fmt} ({report.records} records read, skipped: {sk}{first})")
        _check_usable(p, asm, report, force)
        meta = FieldLog()
        if asm.datum is not None:
            meta.datum = asm.datum
        if vessel is not None:
            meta.vessel = vessel
        meta.add_provenance(producer="usvlog import", source=p.name, settings=opts.to_dict(), format=fmt,
                            size=str(ident["size"]), sha256=ident["sha256"],
                            skipped=dict(sorted(report.skipped.items())), guesses=report.guesses,
                            mapping=report.mapping, records=str(report.records), health=asm.health,
                            **({"unusable": report.unusable} if report.unusable else {}),
                            **({"force_scale": asm.health["thrust"]["force_scale"]}
                               if asm.health and asm.health.get("thrust") else {}),
                            **({"propulsion": report.propulsion} if report.propulsion else {}))
        return meta.meta

    if out is None:
        sink = MemorySink()
        meta = run(sink)
        log = sink.finish(meta)
        log.source = str(p)
        return ImportResult(log, report, None)
    with atomic_path(out, force=force) as tmp:
        with open(tmp, "wb") as fh:
            sink = McapSink(fh)
            sink.finish(run(sink))
    return ImportResult(None, report, Path(out))


__all__ = ["FORMATS", "Catalog", "catalog_file", "CSV_ROLES", "TOPIC_ROLES", "ImportOptions", "ImportReport",
           "ImportResult", "detect_format", "file_identity", "import_file", "parse_start_utc",
           "parse_thrust_range"]
