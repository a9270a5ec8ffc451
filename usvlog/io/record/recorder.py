"""Recorder: live samples -> a canonical MCAP log that survives a killed process.

Every message goes into the mcap Writer's open chunk (in memory); a background
thread closes the chunk, writes it and fsyncs the file at a fixed rate (every
0.8 ``flush_s``), so no message waits in memory longer than ``flush_s`` and a
SIGKILL or a power cut loses at most the last ``flush_s`` (1 s by default). Metadata records
(vessel, provenance, and the datum as soon as the first fix gives it) are written
between chunks and fsynced at once; ``usvlog.io.mcap.read_log`` reads metadata
found anywhere before the cut and every complete chunk. ``close()`` finishes the
file with the usual summary.

Receive times (``t_ns``, the MCAP log time) come from the monotonic clock mapped
to UTC once at start, so they never jump when the system clock is stepped. The
sensor's own time goes into ``stamp_ns``; the offset between the two (receive
minus sensor, robust median) is stored per source in the provenance record and in
``/recorder/status``.
"""

from __future__ import annotations

import contextlib
import errno
import json
import math
import os
import re
import threading
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path

import orjson

from ..._version import __version__
from ...errors import ConfigError, InputError, OutputExistsError, StorageError
from ...log.channels import (
    MESSAGE_ENCODING,
    SCHEMA_ENCODING,
    registered_topics,
    schema_for_topic,
)
from ...log.fieldlog import META_DATUM, META_PROVENANCE, META_VESSEL, format_time
from ...model.frames import Datum, ssa
from ..mcap.codec import codec_for_topic
from ..nmea import NmeaError, parse_sentence, resolve_time_of_day
from .timesync import OffsetEstimator

TOPIC_FIX = "/gnss/fix"
TOPIC_QUALITY = "/gnss/quality"
TOPIC_HEADING = "/compass/heading"
TOPIC_THRUST = "/thrust/command"
TOPIC_RAW_NMEA = "/raw/nmea"
TOPIC_RAW_JSON = "/raw/json"
TOPIC_EVENTS = "/events"
TOPIC_STATUS = "/recorder/status"
META_RECORDING = "usvlog.recording"   # {run_id, part, started_utc}: lets read_logs check consecutive files

THRUST_UNITS = ("newton", "normalized", "pwm_us")
_POSITION_PRIORITY = {"GGA": 0, "RMC": 1, "GLL": 2}  # one fix per epoch, from the best sentence a source sends
_PREFER_WINDOW_NS = 2_000_000_000
_UNKNOWN_COV = (0.0,) * 9  # LocationFix convention: zeros with covariance type 0 (unknown)


# -----------------------------------------------------------------------------
# status
# -----------------------------------------------------------------------------

@dataclass(frozen=True)
class SourceStatus:
    name: str
    messages: int         # lines / calls received
    garbage: int          # malformed (kept raw)
    dropped: int          # dropped by the OS before reading (UDP); -1 unknown
    rate_hz: float        # over the last status interval
    clock_offset_s: float | None


@dataclass(frozen=True)
class RecorderStatus:
    elapsed_s: float
    path: str             # file being written
    files: tuple[str, ...]
    file_bytes: int       # bytes on disk, all parts
    messages_written: int
    sources: tuple[SourceStatus, ...]
    last_fix: tuple[float, float] | None   # lat, lon
    fix_age_s: float | None
    satellites: int | None
    hdop: float | None
    fix_quality: int | None
    error: str | None
    source_errors: tuple[str, ...] = ()    # e.g. "compass: cannot connect to ..." (filled by the session)

    def line(self) -> str:
        """The one-line live status."""
        parts = [f"{self.elapsed_s:6.0f} s"]
        for s in self.sources:
            p = f"{s.name} {s.rate_hz:5.1f}/s"
            if s.garbage:
                p += f" bad {s.garbage}"
            if s.dropped > 0:
                p += f" drop {s.dropped}"
            parts.append(p)
        if self.last_fix is not None:
            fix = f"fix {self.last_fix[0]:.6f},{self.last_fix[1]:.6f}"
            if self.fix_age_s is not None and self.fix_age_s > 2.0:
                fix += f" ({self.fix_age_s:.0f} s old)"
            parts.append(fix)
        else:
            parts.append("no fix")
        if self.satellites is not None and self.satellites >= 0:
            parts.append(f"sats {self.satellites}")
        if self.hdop is not None and math.isfinite(self.hdop):
            parts.append(f"hdop {self.hdop:.1f}")
        parts.append(f"{self.file_bytes / 1e6:.2f} MB")
        parts.extend(self.source_errors)
        if self.error:
            parts.append(f"ERROR {self.error}")
        return " | ".join(parts)

    def to_dict(self) -> dict:
        d = {k: getattr(self, k) for k in ("elapsed_s", "path", "file_bytes", "messages_written", "fix_age_s",
                                          "satellites", "hdop", "fix_quality", "error")}
        d["files"] = list(self.files)
        d["source_errors"] = list(self.source_errors)
        d["last_fix"] = list(self.last_fix) if self.last_fix else None
        d["sources"] = [s.__dict__ for s in self.sources]
        return d


@dataclass
class _Source:
    """Counters and NMEA state of one source (mutated under the recorder's lock)."""

    name: str
    messages: int = 0
    garbage: int = 0
    dropped: int = -1
    rate_hz: float = 0.0
    _last_messages: int = 0
    offset: OffsetEstimator = field(default_factory=OffsetEstimator)
    position_seen: dict = field(default_factory=dict)  # sentence kind -> last receive time


def part_path(path, part: int | None) -> Path:
    """``run.mcap`` -> ``run_000.mcap``, ``run_001.mcap``, ... (``part=None``: the path itself)."""
    p = Path(path)
    if part is None:
        return p
    return p.with_name(f"{p.stem}_{part:03d}{p.suffix or '.mcap'}")


def check_outputs(path, *, rotating: bool, force: bool) -> None:
    """Fail before recording when the output (or, rotating, any part of it) exists or cannot be made."""
    p = Path(path)
    if p.exists() and p.is_dir():
        raise StorageError(f"{p}: output is a directory")
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        raise StorageError(f"{p}: directory {parent} does not exist")
    if force:
        return
    first = part_path(p, 0 if rotating else None)
    if first.exists():
        raise OutputExistsError(f"{first}: output exists (use --force to overwrite)")
    if rotating:
        pat = re.compile(re.escape(p.stem) + r"_\d{3,}" + re.escape(p.suffix or ".mcap") + "$")
        for q in parent.iterdir():
            if pat.match(q.name):
                raise OutputExistsError(f"{q}: output exists (use --force to overwrite)")


def _storage_error(path, err: OSError, what: str) -> StorageError:
    reason = {errno.ENOSPC: "disk full", errno.EFBIG: "file too large for the file system or limit",
              errno.EDQUOT: "disk quota exceeded"}.get(err.errno, err.strerror or str(err))
    return StorageError(f"{path}: {what} ({reason})")


# -----------------------------------------------------------------------------
# the recorder
# -----------------------------------------------------------------------------

class Recorder:
    """Log live samples from this process into a power-loss-safe canonical MCAP file.

    >>> with Recorder("run.mcap", vessel=v) as rec:          # doctest: +SKIP
    ...     rec.gnss(59.91, 10.75, alt_m=2.0)
    ...     rec.heading(0.3)
    ...     rec.thrust(12.0, 10.5)
    ...     rec.event("start of the zig-zag")

    Thread-safe: sources on other threads may call it concurrently. Times default to
    :meth:`now_ns` (receive time); ``stamp_ns`` is the sample's own time when it has one.
    After a storage failure (disk full, device gone) every call raises the same
    :class:`StorageError`; what was flushed before stays readable.
    """

    def __init__(self, path, *, vessel=None, datum: Datum | None = None, flush_s: float = 1.0,
                 rotate_mb: float | None = None, rotate_min: float | None = None, force: bool = False,
                 sources: dict[str, str] | None = None, compression: str = "zstd",
                 chunk_size: int = 1 << 20, producer: str = "usvlog record"):
        from mcap.writer import CompressionType

        if not (0.01 <= flush_s <= 60.0):
            raise ConfigError(f"flush_s {flush_s} out of range [0.01, 60]")
        if rotate_mb is not None and not rotate_mb > 0:
            raise ConfigError(f"rotate_mb {rotate_mb} must be > 0")
        if rotate_min is not None and not rotate_min > 0:
            raise ConfigError(f"rotate_min {rotate_min} must be > 0")
        try:
            self._compression = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4,
                                 "none": CompressionType.NONE}[compression]
        except KeyError:
            raise ConfigError(f"compression {compression!r}: use zstd, lz4 or none") from None
        self._base = Path(path)
        self._rotating = rotate_mb is not None or rotate_min is not None
        check_outputs(self._base, rotating=self._rotating, force=force)
        self.flush_s = float(flush_s)
        self.rotate_bytes = None if rotate_mb is None else int(rotate_mb * 1e6)
        self.rotate_ns = None if rotate_min is None else int(rotate_min * 60e9)
        self._chunk_size = int(chunk_size)
        self._vessel = vessel
        self._datum = datum
        self._sources_desc = dict(sources or {})
        self._producer = producer
        self._settings = {"flush_s": flush_s, "rotate_mb": rotate_mb, "rotate_min": rotate_min,
                          "compression": compression}
        self.run_id = uuid.uuid4().hex
        self._lock = threading.RLock()
        self._utc0 = time.time_ns()
        self._mono0 = time.monotonic_ns()
        self._started_utc = format_time(self._utc0)
        self._codecs = {}
        self._seq: dict[str, int] = {}
        self._sources: dict[str, _Source] = {}
        self._written = 0
        self._error: StorageError | None = None
        self._closed = False
        self._last_fix = None          # (lat, lon, t_ns)
        self._quality = None           # (fix_quality, satellites, hdop)
        self._last_status_ns = self.now_ns()
        self._last_prov_ns = 0
        self._prov_offsets = 0         # sources with a clock offset in the last provenance record
        self._bytes_done = 0           # bytes of finished parts
        self.paths: list[Path] = []
        self._part = 0
        self._fh = None
        self._open_part()
        self._stop = threading.Event()
        self._flusher = threading.Thread(target=self._flush_loop, name="usvlog-record-flush", daemon=True)
        self._flusher.start()

    # -- clock ---------------------------------------------------------------------
    def now_ns(self) -> int:
        """Receive time: the monotonic clock mapped to UTC at start (ns since the epoch)."""
        return self._utc0 + (time.monotonic_ns() - self._mono0)

    # -- files ---------------------------------------------------------------------
    @property
    def path(self) -> Path:
        """The file being written now."""
        return self.paths[-1]

    def _open_part(self) -> None:
        from mcap.writer import Writer

        p = part_path(self._base, self._part if self._rotating else None)
        try:
            fh = open(p, "wb")
        except OSError as err:
            raise _storage_error(p, err, "cannot create output") from err
        self._fh = fh
        self.paths.append(p)
        self._opened_ns = self.now_ns()
        self._w = Writer(fh, chunk_size=self._chunk_size, compression=self._compression)
        self._chan: dict[str, int] = {}
        self._schema_ids: dict[str, int] = {}
        try:
            self._w.start(profile="", library=f"usvlog {__version__}")
            if self._vessel is not None:
                self._w.add_metadata(META_VESSEL, self._vessel.to_dict())
            if self._datum is not None:
                self._w.add_metadata(META_DATUM, self._datum.to_dict())
            self._w.add_metadata(META_RECORDING, {"run_id": self.run_id, "part": str(self._part),
                                                  "started_utc": self._started_utc,
                                                  "part_started_ns": str(self._opened_ns)})
            self._write_provenance()
            self._sync()
            with contextlib.suppress(OSError):  # make the new directory entry durable too
                dfd = os.open(p.parent if str(p.parent) else ".", os.O_RDONLY)
                try:
                    os.fsync(dfd)
                finally:
                    os.close(dfd)
        except OSError as err:
            self._fail(err)
            raise self._error from err

    def _provenance(self) -> dict[str, str]:
        offsets = {}
        for s in self._sources.values():
            est = s.offset.estimate()
            if est is not None:
                offsets[s.name] = {"offset_ns": est.offset_ns, "mad_ns": est.mad_ns, "samples": est.samples}
        counts = {s.name: {"messages": s.messages, "garbage": s.garbage, "dropped": s.dropped}
                  for s in self._sources.values()}
        return {"producer": self._producer, "usvlog_version": __version__,
                "source": json.dumps(self._sources_desc, sort_keys=True),
                "settings": json.dumps(self._settings, sort_keys=True),
                "run_id": self.run_id, "part": str(self._part), "started_utc": self._started_utc,
                "receive_clock": "monotonic mapped to UTC at start",
                "clock_offsets": json.dumps(offsets, sort_keys=True),
                "counts": json.dumps(counts, sort_keys=True),
                "closed": "false"}

    def _write_provenance(self, closed: bool = False) -> None:
        rec = self._provenance()
        rec["closed"] = "true" if closed else "false"
        self._w.add_metadata(f"{META_PROVENANCE}/0", rec)
        self._last_prov_ns = self.now_ns()

    def _sync(self) -> None:
        self._w.flush()
        self._fh.flush()
        os.fsync(self._fh.fileno())

    def _fail(self, err: OSError) -> None:
        if self._error is None:
            self._error = _storage_error(self.path, err, "recording stopped")
            self._error = StorageError(f"{self._error}; what was written before stays readable")
        fh, self._fh = self._fh, None
        if fh is not None:
            with contextlib.suppress(Exception):
                fh.close()

    def _check(self) -> None:
        if self._error is not None:
            raise self._error
        if self._closed:
            raise StorageError(f"{self._base}: the recorder is closed")

    # -- writing -------------------------------------------------------------------
    def _codec(self, topic: str):
        c = self._codecs.get(topic)
        if c is None:
            c = codec_for_topic(topic)
            if c is None:
                raise InputError(f"channel {topic}: no registered schema (see schemas/)")
            self._codecs[topic] = c
        return c

    def _channel(self, topic: str) -> int:
        cid = self._chan.get(topic)
        if cid is None:
            schema = schema_for_topic(topic)
            name = schema.get("title", topic)
            sid = self._schema_ids.get(name)
            if sid is None:
                sid = self._w.register_schema(name=name, encoding=SCHEMA_ENCODING, data=json.dumps(schema).encode())
                self._schema_ids[name] = sid
            cid = self._w.register_channel(topic=topic, message_encoding=MESSAGE_ENCODING, schema_id=sid)
            self._chan[topic] = cid
        return cid

    def write(self, topic: str, row: dict, t_ns: int | None = None) -> None:
        """Write one row ``{column: value}`` of a registered canonical topic at receive time ``t_ns``."""
        data = self._codec(topic).encode_row(row, topic)
        t = self.now_ns() if t_ns is None else int(t_ns)
        if t < 0:
            raise InputError(f"channel {topic}: negative time {t}")
        with self._lock:
            self._check()
            try:
                seq = self._seq.get(topic, 0)
                self._w.add_message(channel_id=self._channel(topic), log_time=t, data=data, publish_time=t,
                                    sequence=seq & 0xFFFFFFFF)
            except OSError as err:
                self._fail(err)
                raise self._error from err
            self._seq[topic] = seq + 1
            self._written += 1

    def _source(self, name: str) -> _Source:
        s = self._sources.get(name)
        if s is None:
            with self._lock:
                s = self._sources.setdefault(name, _Source(name))
        return s

    def _count(self, source: str, garbage: bool = False) -> _Source:
        s = self._source(source)
        s.messages += 1
        if garbage:
            s.garbage += 1
        return s

    def set_dropped(self, source: str, dropped: int) -> None:
        """Datagrams the OS dropped for ``source`` so far (from the socket's counters)."""
        self._source(source).dropped = int(dropped)

    # -- samples -------------------------------------------------------------------
    def gnss(self, lat_deg: float, lon_deg: float, alt_m: float = math.nan, *, t_ns: int | None = None,
             stamp_ns: int | None = None, cov=None, frame_id: str = "gnss", source: str = "api",
             _counted: bool = False) -> None:
        """A position fix (degrees; ``alt_m`` metres above the WGS-84 ellipsoid, NaN when unknown,
        stored as null; NMEA GGA gives it as sea level + geoid separation, see ``usvlog.nmea``). ``cov``:
        None (unknown: zeros, type 0), 3 ENU variances in m^2 (diagonal known, type 2) or a full
        3x3 / 9-element ENU covariance (type 3)."""
        if not (-90.0 <= lat_deg <= 90.0 and -180.0 <= lon_deg <= 180.0):
            raise InputError(f"channel {TOPIC_FIX}: position {lat_deg},{lon_deg} out of range")
        t = self.now_ns() if t_ns is None else int(t_ns)
        if cov is None:
            c, ctype = _UNKNOWN_COV, 0
        else:
            flat = [float(x) for row in (cov if hasattr(cov, "__len__") else [cov]) for x in
                    (row if hasattr(row, "__len__") else [row])]
            if len(flat) == 3:
                c, ctype = (flat[0], 0.0, 0.0, 0.0, flat[1], 0.0, 0.0, 0.0, flat[2]), 2
            elif len(flat) == 9:
                c, ctype = tuple(flat), 3
            else:
                raise InputError(f"channel {TOPIC_FIX}: cov must have 3 (diagonal) or 9 elements, not {len(flat)}")
        cols = ("cov_ee_m2", "cov_en_m2", "cov_eu_m2", "cov_ne_m2", "cov_nn_m2", "cov_nu_m2",
                "cov_ue_m2", "cov_un_m2", "cov_uu_m2")
        row = {"stamp_ns": t if stamp_ns is None else int(stamp_ns), "frame_id": frame_id,
               "lat_deg": float(lat_deg), "lon_deg": float(lon_deg), "alt_m": float(alt_m),
               "cov_type": ctype, **dict(zip(cols, c))}
        if not _counted:
            self._count(source)
        self.write(TOPIC_FIX, row, t)
        with self._lock:
            self._last_fix = (float(lat_deg), float(lon_deg), t)
            if self._datum is None:
                self.set_datum(Datum(lat_deg=float(lat_deg), lon_deg=float(lon_deg),
                                     alt_m=float(alt_m) if math.isfinite(alt_m) else 0.0))

    def set_datum(self, datum: Datum) -> None:
        """Store the datum now (metadata record, fsynced at once; later parts repeat it)."""
        with self._lock:
            self._check()
            self._datum = datum
            try:
                self._w.add_metadata(META_DATUM, datum.to_dict())
                self._sync()
            except OSError as err:
                self._fail(err)
                raise self._error from err

    def heading(self, heading_rad: float, reference: str = "true", *, t_ns: int | None = None,
                stamp_ns: int | None = None, std_rad: float | None = None, source: str = "api",
                _counted: bool = False) -> None:
        """Heading, rad clockwise from north (wrapped to [-pi, pi))."""
        if reference not in ("true", "magnetic"):
            raise InputError(f"channel {TOPIC_HEADING}: reference {reference!r} is not 'true' or 'magnetic'")
        if not math.isfinite(heading_rad):
            raise InputError(f"channel {TOPIC_HEADING}: heading {heading_rad} is not finite")
        t = self.now_ns() if t_ns is None else int(t_ns)
        if not _counted:
            self._count(source)
        self.write(TOPIC_HEADING, {"stamp_ns": t if stamp_ns is None else int(stamp_ns),
                                   "heading_rad": float(ssa(heading_rad)), "reference": reference,
                                   "std_rad": std_rad}, t)

    def thrust(self, left: float, right: float, unit: str = "newton", *, t_ns: int | None = None,
               stamp_ns: int | None = None, thrust_left_n: float | None = None,
               thrust_right_n: float | None = None, source: str = "api", _counted: bool = False) -> None:
        """Thruster commands as sent (``unit``: newton, normalized, pwm_us), with forces when known."""
        if unit not in THRUST_UNITS:
            raise InputError(f"channel {TOPIC_THRUST}: unit {unit!r} is not one of {', '.join(THRUST_UNITS)}")
        if unit == "newton":
            thrust_left_n = left if thrust_left_n is None else thrust_left_n
            thrust_right_n = right if thrust_right_n is None else thrust_right_n
        t = self.now_ns() if t_ns is None else int(t_ns)
        if not _counted:
            self._count(source)
        self.write(TOPIC_THRUST, {"stamp_ns": t if stamp_ns is None else int(stamp_ns), "left": float(left),
                                  "right": float(right), "unit": unit, "thrust_left_n": thrust_left_n,
                                  "thrust_right_n": thrust_right_n}, t)

    def event(self, text: str, *, t_ns: int | None = None, source: str = "api") -> None:
        """A free-text event (operator note, software event) on ``/events``."""
        self.write(TOPIC_EVENTS, {"source": source, "text": str(text)}, t_ns)

    # -- raw lines -----------------------------------------------------------------
    def nmea(self, text: str, *, source: str = "nmea", t_ns: int | None = None):
        """One NMEA 0183 sentence as received: kept in ``/raw/nmea``; positions, headings,
        fix quality and GPS time go to their canonical channels. Parsed by
        :func:`usvlog.io.nmea.parse_sentence` (as the file importer does), checksum required;
        a time of day without a date is placed nearest the receive time minus the source's
        clock offset. Returns the parsed sample (None when malformed, whatever the reason:
        counted as garbage, still kept raw)."""
        t = self.now_ns() if t_ns is None else int(t_ns)
        try:
            s = parse_sentence(text)
            err = ""
        except NmeaError as e:
            s, err = None, str(e)
        with self._lock:
            return self._nmea_locked(text, s, err, source, t)

    def _nmea_locked(self, text, s, err, source, t):
        src = self._count(source, garbage=s is None)
        kind = s.kind if s is not None else _guess_kind(text)
        self.write(TOPIC_RAW_NMEA, {"source": source, "text": text, "valid": s is not None, "kind": kind,
                                    "error": err}, t)
        if s is None:
            return None
        stamp = None
        if s.gps_time_ns is not None:
            stamp = s.gps_time_ns
        elif s.time_of_day_ns is not None:
            est = src.offset.estimate()
            stamp = resolve_time_of_day(s.time_of_day_ns, t - (est.offset_ns if est else 0))
        if stamp is not None:
            src.offset.add(t, stamp)
        if s.kind == "GGA":
            self.write(TOPIC_QUALITY, {"stamp_ns": t if stamp is None else stamp,
                                       "fix_quality": -1 if s.fix_quality is None else s.fix_quality,
                                       "satellites": -1 if s.satellites is None else s.satellites,
                                       "hdop": s.hdop}, t)
            self._quality = (s.fix_quality, s.satellites, s.hdop)
        if s.has_fix:
            src.position_seen[s.kind] = t
            prio = _POSITION_PRIORITY.get(s.kind, 9)
            better = any(_POSITION_PRIORITY.get(k, 9) < prio and t - seen < _PREFER_WINDOW_NS
                         for k, seen in src.position_seen.items())
            if not better:
                self.gnss(s.lat_deg, s.lon_deg, math.nan if s.alt_m is None else s.alt_m, t_ns=t,
                          stamp_ns=stamp, source=source, _counted=True)
        if s.heading_rad is not None:
            self.heading(s.heading_rad, s.reference, t_ns=t, source=source, _counted=True)
        return s

    def json_line(self, text: str, *, source: str = "json", t_ns: int | None = None) -> bool:
        """One JSON line (see the README for the message forms). Returns True when used;
        a line that cannot be used is counted as garbage and kept in ``/raw/json``."""
        t = self.now_ns() if t_ns is None else int(t_ns)
        kind, err = "", ""
        try:
            obj = orjson.loads(text)
            if not isinstance(obj, dict):
                raise InputError("not a JSON object")
            stamp = obj.get("stamp_ns")
            if stamp is None and obj.get("t") is not None:
                stamp = int(round(float(obj["t"]) * 1e6)) * 1000  # float seconds: µs resolution
            if stamp is not None:
                stamp = int(stamp)
                if stamp < 0:
                    raise InputError(f"negative time {stamp}")
                with self._lock:
                    self._source(source).offset.add(t, stamp)
            if "topic" in obj:
                kind = str(obj["topic"])
                if kind not in registered_topics() or kind in (TOPIC_RAW_JSON, TOPIC_RAW_NMEA, TOPIC_STATUS):
                    raise InputError(f"topic {kind} is not a canonical topic a source may write")
                row = {k: v for k, v in obj.items() if k not in ("topic", "t")}
                if "stamp_ns" in self._codec(kind).columns:
                    row["stamp_ns"] = t if stamp is None else stamp
                self.write(kind, row, t)
                self._count(source)
            elif "event" in obj:
                kind = "event"
                self._count(source)
                self.event(str(obj["event"]), t_ns=t, source=source)
            elif "left" in obj and "right" in obj:
                kind = "thrust"
                self.thrust(float(obj["left"]), float(obj["right"]), str(obj.get("unit", "newton")), t_ns=t,
                            stamp_ns=stamp, thrust_left_n=obj.get("thrust_left_n"),
                            thrust_right_n=obj.get("thrust_right_n"), source=source)
            else:
                raise InputError("no 'left'/'right', 'event' or 'topic' key")
            return True
        except StorageError:
            raise
        except (orjson.JSONDecodeError, InputError, TypeError, ValueError) as e:
            err = str(e)
        self._count(source, garbage=True)
        self.write(TOPIC_RAW_JSON, {"source": source, "text": text, "valid": False, "kind": kind, "error": err}, t)
        return False

    # -- flushing, rotation, status ------------------------------------------------
    def flush(self) -> None:
        """Write the open chunk and fsync now (the background thread does this every ``flush_s``)."""
        with self._lock:
            self._check()
            try:
                self._sync()
            except OSError as err:
                self._fail(err)
                raise self._error from err

    def _tick(self, fsync: bool = True) -> None:
        """Status rows, provenance now and then, the open chunk to the OS (and to disk)."""
        now = self.now_ns()
        dt = max((now - self._last_status_ns) / 1e9, 1e-9)
        self._last_status_ns = now
        for s in list(self._sources.values()):
            s.rate_hz = (s.messages - s._last_messages) / dt
            s._last_messages = s.messages
            est = s.offset.estimate()
            self.write(TOPIC_STATUS, {"source": s.name, "messages": s.messages, "garbage": s.garbage,
                                      "dropped": s.dropped, "rate_hz": s.rate_hz,
                                      "clock_offset_s": None if est is None else est.offset_ns / 1e9}, now)
        have = sum(s.offset.total > 0 for s in self._sources.values())
        if now - self._last_prov_ns >= 10e9 or have > self._prov_offsets:
            self._write_provenance()   # every 10 s, and as soon as a source's clock offset is first known
            self._prov_offsets = have
        if fsync:
            self._sync()
        else:
            self._w.flush()
            self._fh.flush()

    def _maybe_rotate(self) -> None:
        size = self._fh.tell()
        if ((self.rotate_bytes is not None and size >= self.rotate_bytes) or
                (self.rotate_ns is not None and self.now_ns() - self._opened_ns >= self.rotate_ns)):
            self._finish_part()
            self._bytes_done += size
            self._part += 1
            self._open_part()

    def _flush_loop(self) -> None:
        # flush_s bounds how long a message waits in memory: flushing at a fixed rate of
        # 0.8 flush_s leaves a fifth of it for a late wake-up on a busy machine
        period = 0.8 * self.flush_s
        nxt = time.monotonic() + period
        while not self._stop.wait(max(0.0, nxt - time.monotonic())):
            nxt = max(nxt + period, time.monotonic() + 0.1 * period)
            try:
                with self._lock:
                    if self._closed or self._error is not None:
                        return
                    self._tick(fsync=False)        # in the page cache now: a killed process loses nothing more
                    fd = self._fh.fileno()
                os.fsync(fd)                       # to disk, without holding up the sources
                with self._lock:
                    if self._closed or self._error is not None:
                        return
                    self._maybe_rotate()
            except OSError as err:
                with self._lock:
                    self._fail(err)
                return
            except StorageError:
                return

    def _finish_part(self) -> None:
        self._write_provenance(closed=True)
        self._w.finish()
        self._fh.flush()
        os.fsync(self._fh.fileno())
        self._fh.close()
        self._fh = None

    @property
    def error(self) -> StorageError | None:
        return self._error

    def status(self) -> RecorderStatus:
        with self._lock:
            now = self.now_ns()
            try:
                cur = self._fh.tell() if self._fh is not None else self.path.stat().st_size
            except (OSError, ValueError):
                cur = 0
            fix = self._last_fix
            q = self._quality or (None, None, None)
            srcs = []
            for s in self._sources.values():
                est = s.offset.estimate()
                srcs.append(SourceStatus(s.name, s.messages, s.garbage, s.dropped, s.rate_hz,
                                         None if est is None else est.offset_ns / 1e9))
            return RecorderStatus(
                elapsed_s=(now - self._utc0) / 1e9, path=str(self.path), files=tuple(str(p) for p in self.paths),
                file_bytes=self._bytes_done + cur, messages_written=self._written, sources=tuple(srcs),
                last_fix=None if fix is None else fix[:2], fix_age_s=None if fix is None else (now - fix[2]) / 1e9,
                satellites=q[1], hdop=q[2], fix_quality=q[0],
                error=None if self._error is None else str(self._error))

    # -- closing -------------------------------------------------------------------
    def close(self) -> None:
        """Finish the file (summary, footer) and fsync. Raises the storage error, if one happened."""
        self._stop.set()
        if self._flusher.is_alive() and threading.current_thread() is not self._flusher:
            self._flusher.join()
        with self._lock:
            if self._closed:
                return
            if self._error is None:
                try:
                    self._tick_final()
                except OSError as err:
                    self._fail(err)
            self._closed = True
            if self._error is not None:
                raise self._error

    def _tick_final(self) -> None:
        self._last_prov_ns = self.now_ns()  # _tick must not write it: the closing record follows
        self._tick(fsync=False)
        self._finish_part()
        with contextlib.suppress(OSError):
            self._bytes_done += self.path.stat().st_size

    def __enter__(self) -> "Recorder":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            with contextlib.suppress(StorageError):
                self.close()


def _guess_kind(text: str) -> str:
    head = text.strip()[1:].split(",", 1)[0] if text.strip().startswith(("$", "!")) else ""
    return head[2:] if len(head) == 5 and head.isalnum() else ""

