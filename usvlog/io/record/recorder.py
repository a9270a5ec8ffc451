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

The pieces: :mod:`.output` (part files, rotation), :mod:`.flusher` (the background
flush), :mod:`.dispatch` (NMEA and JSON lines), :mod:`.status` (counters, live status);
this module holds them together: the clock, the lock, the samples API, provenance and
the one sticky storage error.
"""

from __future__ import annotations

import contextlib
import json
import math
import threading
import time
import uuid

from ..._version import __version__
from ...errors import ConfigError, InputError, StorageError
from ...log.fieldlog import META_DATUM, META_PROVENANCE, META_VESSEL, format_time
from ...model.frames import Datum, ssa
from ...model.vessel import THRUST_UNITS
from ..mcap.codec import codec_for_topic
from .dispatch import LineInput
from .flusher import FlushThread
from .output import PartWriter, check_outputs, part_path, storage_error
from .status import RecorderStatus, SourceState, SourceStatus
from .topics import (
    META_RECORDING,
    TOPIC_EVENTS,
    TOPIC_FIX,
    TOPIC_HEADING,
    TOPIC_QUALITY,
    TOPIC_RAW_JSON,
    TOPIC_RAW_NMEA,
    TOPIC_STATUS,
    TOPIC_THRUST,
)

# a fix held for a better sentence of its epoch (see usvlog.io.nmea.FixSelector) is written
# by the next flush once it is this old: a receiver sends an epoch's sentences in one burst
_EPOCH_BURST_NS = 250_000_000
_UNKNOWN_COV = (0.0,) * 9  # LocationFix convention: zeros with covariance type 0 (unknown)
_COV_COLUMNS = ("cov_ee_m2", "cov_en_m2", "cov_eu_m2", "cov_ne_m2", "cov_nn_m2", "cov_nu_m2",
                "cov_ue_m2", "cov_un_m2", "cov_uu_m2")


class Recorder(LineInput):
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

    Parameters
    ----------
    path : path-like
        Output file (``run.mcap``; ``run_000.mcap``, ``run_001.mcap``, ... when rotating).
    vessel : usvlog.model.vessel.Vessel, optional
        Stored in every part.
    datum : usvlog.model.frames.Datum, optional
        Local NED origin; the first fix when None.
    flush_s : float
        Longest time a message waits in memory, s (0.01 to 60).
    rotate_mb, rotate_min : float, optional
        Start a new part after this many MB (1e6 bytes) / minutes.
    force : bool
        Overwrite existing outputs.
    sources : dict, optional
        Source name -> description, stored in the provenance.
    compression : str
        ``zstd``, ``lz4`` or ``none``.
    chunk_size : int
        Bytes after which mcap closes a chunk by itself.
    producer : str
        Provenance ``producer``.
    clock : tuple of int, optional
        ``(time.time_ns(), time.monotonic_ns())`` read together: where the receive clock
        starts (``usvlog record`` passes the moment its first source was opened, so data
        read before the recorder existed keeps its read time). Default: now.
    """

    def __init__(self, path, *, vessel=None, datum: Datum | None = None, flush_s: float = 1.0,
                 rotate_mb: float | None = None, rotate_min: float | None = None, force: bool = False,
                 sources: dict[str, str] | None = None, compression: str = "zstd",
                 chunk_size: int = 1 << 20, producer: str = "usvlog record",
                 clock: tuple[int, int] | None = None):
        if not (0.01 <= flush_s <= 60.0):
            raise ConfigError(f"flush_s {flush_s} out of range [0.01, 60]")
        if rotate_mb is not None and not rotate_mb > 0:
            raise ConfigError(f"rotate_mb {rotate_mb} must be > 0")
        if rotate_min is not None and not rotate_min > 0:
            raise ConfigError(f"rotate_min {rotate_min} must be > 0")
        rotating = rotate_mb is not None or rotate_min is not None
        self.flush_s = float(flush_s)
        self.rotate_bytes = None if rotate_mb is None else int(rotate_mb * 1e6)
        self.rotate_ns = None if rotate_min is None else int(rotate_min * 60e9)
        self._out = PartWriter(path, rotating=rotating, rotate_bytes=self.rotate_bytes, rotate_ns=self.rotate_ns,
                               compression=compression, chunk_size=chunk_size)
        self._base = self._out.base
        check_outputs(self._base, rotating=rotating, force=force)
        self._vessel = vessel
        self._datum = datum
        self._sources_desc = dict(sources or {})
        self._producer = producer
        self._settings = {"flush_s": flush_s, "rotate_mb": rotate_mb, "rotate_min": rotate_min,
                          "compression": compression}
        self.run_id = uuid.uuid4().hex
        self._lock = threading.RLock()
        self._utc0, self._mono0 = clock if clock is not None else (time.time_ns(), time.monotonic_ns())
        self._started_utc = format_time(self._utc0)
        self._codecs = {}
        self._seq: dict[str, int] = {}
        self._sources: dict[str, SourceState] = {}
        self._written = 0
        self._error: StorageError | None = None
        self._closed = False
        self._last_fix = None          # (lat, lon, t_ns)
        self._quality = None           # (fix_quality, satellites, hdop)
        self._last_status_ns = self.now_ns()
        self._last_prov_ns = 0
        self._prov_offsets = 0         # sources with a clock offset in the last provenance record
        self._subscribers: tuple = ()  # (callback, topics or None); replaced whole, read without the lock
        self.subscriber_errors: list[str] = []
        self._open_part()
        self._flusher = FlushThread(self.flush_s, self._lock, to_os=self._flush_to_os,
                                    after_sync=self._after_sync, fail=self._fail)
        self._flusher.start()

    # -- clock ---------------------------------------------------------------------
    def now_ns(self) -> int:
        """Receive time: the monotonic clock mapped to UTC at start (ns since the epoch)."""
        return self._utc0 + (time.monotonic_ns() - self._mono0)

    def receive_ns(self, monotonic_ns: int) -> int:
        """The receive time of a read made at ``monotonic_ns`` (a ``time.monotonic_ns()`` value).

        Parameters
        ----------
        monotonic_ns : int
            When the data was read, on the monotonic clock (ns).

        Returns
        -------
        int
            ns since the Unix epoch on the receive clock (:meth:`now_ns` at that moment).
        """
        return self._utc0 + (int(monotonic_ns) - self._mono0)

    # -- files ---------------------------------------------------------------------
    @property
    def path(self):
        """The file being written now."""
        return self._out.path

    @property
    def paths(self) -> list:
        """Every file of this recording so far, in order."""
        return self._out.paths

    def _open_part(self) -> None:
        out = self._out
        out.open(self.now_ns())   # StorageError when the file cannot be made
        with self._storage():
            out.start(f"usvlog {__version__}")
            if self._vessel is not None:
                out.add_metadata(META_VESSEL, self._vessel.to_dict())
            if self._datum is not None:
                out.add_metadata(META_DATUM, self._datum.to_dict())
            out.add_metadata(META_RECORDING, {"run_id": self.run_id, "part": str(out.part),
                                              "started_utc": self._started_utc,
                                              "part_started_ns": str(out.opened_ns)})
            self._write_provenance()
            out.sync()
            out.sync_directory()

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
                "run_id": self.run_id, "part": str(self._out.part), "started_utc": self._started_utc,
                "receive_clock": "monotonic mapped to UTC at start",
                "clock_offsets": json.dumps(offsets, sort_keys=True),
                "counts": json.dumps(counts, sort_keys=True),
                "closed": "false"}

    def _write_provenance(self, closed: bool = False) -> None:
        rec = self._provenance()
        rec["closed"] = "true" if closed else "false"
        self._out.add_metadata(f"{META_PROVENANCE}/0", rec)
        self._last_prov_ns = self.now_ns()

    def _fail(self, err: OSError) -> None:
        if self._error is None:
            self._error = storage_error(self.path, err, "recording stopped")
            self._error = StorageError(f"{self._error}; what was written before stays readable")
        self._out.abandon()

    @contextlib.contextmanager
    def _storage(self):
        """An OS error on the files stops the recording: the one sticky StorageError, raised from it."""
        try:
            yield
        except OSError as err:
            self._fail(err)
            raise self._error from err

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

    def write(self, topic: str, row: dict, t_ns: int | None = None) -> None:
        """Write one row of a registered canonical topic.

        Parameters
        ----------
        topic : str
            Canonical topic with a registered schema (``schemas/``).
        row : dict
            {column: value} in the schema's units.
        t_ns : int, optional
            Receive (log) time, ns since the Unix epoch (default: now).

        Raises
        ------
        InputError
            No schema for the topic, a row that does not fit it, or a negative time.
        StorageError
            The recording stopped on a storage failure.
        """
        data = self._codec(topic).encode_row(row, topic)
        t = self.now_ns() if t_ns is None else int(t_ns)
        if t < 0:
            raise InputError(f"channel {topic}: negative time {t}")
        with self._lock:
            self._check()
            seq = self._seq.get(topic, 0)
            with self._storage():
                self._out.add_message(topic, data, t, seq)
            self._seq[topic] = seq + 1
            self._written += 1
        if self._subscribers:
            self._notify(topic, row, t)

    # -- subscribers ---------------------------------------------------------------
    def subscribe(self, callback, topics=None) -> None:
        """Call ``callback(topic, row, t_ns)`` after each message written on ``topics``.

        The callback runs on the writing thread, after the message is in the file's open
        chunk, so it must return at once (hand the row to a bounded queue, never wait on
        I/O); ``row`` is the dict written (do not change it). An exception from it
        unsubscribes it and is kept in :attr:`subscriber_errors`: the recording goes on.

        Parameters
        ----------
        callback : callable
            ``callback(topic: str, row: dict, t_ns: int)``; ``t_ns`` is the receive time,
            ns since the Unix epoch.
        topics : iterable of str, optional
            Topics to pass on (default: every topic).
        """
        with self._lock:
            self._subscribers = (*self._subscribers, (callback, None if topics is None else frozenset(topics)))

    def unsubscribe(self, callback) -> None:
        """Stop calling ``callback`` (no error when it is not subscribed).

        Parameters
        ----------
        callback : callable
            A callback given to :meth:`subscribe`.
        """
        with self._lock:
            self._subscribers = tuple(s for s in self._subscribers if s[0] is not callback)

    def _notify(self, topic: str, row: dict, t: int) -> None:
        for callback, topics in self._subscribers:
            if topics is not None and topic not in topics:
                continue
            try:
                callback(topic, row, t)
            except Exception as err:  # a subscriber's fault never stops the recording
                self.unsubscribe(callback)
                self.subscriber_errors.append(f"{getattr(callback, '__name__', type(callback).__name__)}: {err}")

    def _source(self, name: str) -> SourceState:
        s = self._sources.get(name)
        if s is None:
            with self._lock:
                s = self._sources.setdefault(name, SourceState(name))
        return s

    def _count(self, source: str, garbage: bool = False) -> SourceState:
        s = self._source(source)
        s.count(garbage)
        return s

    def set_dropped(self, source: str, dropped: int) -> None:
        """Datagrams the OS dropped for a source so far (from the socket's counters).

        Parameters
        ----------
        source : str
            Source name.
        dropped : int
            Datagrams dropped since the start; -1 when unknown.
        """
        self._source(source).dropped = int(dropped)

    # -- samples -------------------------------------------------------------------
    def gnss(self, lat_deg: float, lon_deg: float, alt_m: float = math.nan, *, t_ns: int | None = None,
             stamp_ns: int | None = None, cov=None, frame_id: str = "gnss", source: str = "api",
             _counted: bool = False) -> None:
        """A position fix on ``/gnss/fix`` (the first one is the datum unless one was given).

        Parameters
        ----------
        lat_deg, lon_deg : float
            Position, degrees (WGS-84).
        alt_m : float
            Metres above the WGS-84 ellipsoid; NaN when unknown (stored as null). NMEA GGA gives
            it as sea level + geoid separation, see :mod:`usvlog.io.nmea`.
        t_ns : int, optional
            Receive time, ns since the Unix epoch (default: now).
        stamp_ns : int, optional
            The fix's own (GPS) time, ns since the Unix epoch (default: ``t_ns``).
        cov : array_like, optional
            None (unknown: zeros, type 0), 3 ENU variances in m^2 (diagonal known, type 2) or a
            full 3x3 / 9-element ENU covariance in m^2 (type 3).
        frame_id : str
            The fix's frame.
        source : str
            Source name (counters).

        Raises
        ------
        InputError
            A position out of range or a covariance of another size.
        """
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
        row = {"stamp_ns": t if stamp_ns is None else int(stamp_ns), "frame_id": frame_id,
               "lat_deg": float(lat_deg), "lon_deg": float(lon_deg), "alt_m": float(alt_m),
               "cov_type": ctype, **dict(zip(_COV_COLUMNS, c))}
        if not _counted:
            self._count(source)
        self.write(TOPIC_FIX, row, t)
        with self._lock:
            self._last_fix = (float(lat_deg), float(lon_deg), t)
            if self._datum is None:
                self.set_datum(Datum(lat_deg=float(lat_deg), lon_deg=float(lon_deg),
                                     alt_m=float(alt_m) if math.isfinite(alt_m) else 0.0))

    def set_datum(self, datum: Datum) -> None:
        """Store the datum now (metadata record, fsynced at once; later parts repeat it).

        Parameters
        ----------
        datum : Datum
            Local NED origin (latitude, longitude in degrees, altitude in m).
        """
        with self._lock:
            self._check()
            self._datum = datum
            with self._storage():
                self._out.add_metadata(META_DATUM, datum.to_dict())
                self._out.sync()

    def heading(self, heading_rad: float, reference: str = "true", *, t_ns: int | None = None,
                stamp_ns: int | None = None, std_rad: float | None = None, source: str = "api",
                _counted: bool = False) -> None:
        """A heading on ``/compass/heading``.

        Parameters
        ----------
        heading_rad : float
            Heading, rad clockwise from north (wrapped to [-pi, pi)).
        reference : str
            ``true`` or ``magnetic`` north.
        t_ns : int, optional
            Receive time, ns since the Unix epoch (default: now).
        stamp_ns : int, optional
            The sensor's own time, ns since the Unix epoch (default: ``t_ns``).
        std_rad : float, optional
            Standard deviation, rad.
        source : str
            Source name (counters).
        """
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
        """Thruster commands as sent, on ``/thrust/command``.

        Parameters
        ----------
        left, right : float
            The commands in ``unit``.
        unit : str
            ``newton``, ``normalized`` or ``pwm_us``.
        t_ns : int, optional
            Receive time, ns since the Unix epoch (default: now).
        stamp_ns : int, optional
            The sender's own time, ns since the Unix epoch (default: ``t_ns``).
        thrust_left_n, thrust_right_n : float, optional
            Forces, N, when known (the commands themselves with ``unit="newton"``).
        source : str
            Source name (counters).
        """
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
        """A free-text event (operator note, software event) on ``/events``.

        Parameters
        ----------
        text : str
            The note.
        t_ns : int, optional
            Receive time, ns since the Unix epoch (default: now).
        source : str
            Who noted it.
        """
        self.write(TOPIC_EVENTS, {"source": source, "text": str(text)}, t_ns)

    # -- flushing, rotation, status ------------------------------------------------
    def flush(self) -> None:
        """Write the open chunk and fsync now (the background thread does this every ``flush_s``)."""
        with self._lock:
            self._check()
            with self._storage():
                self._out.sync()

    def _tick(self, fsync: bool = True) -> None:
        """Status rows, provenance now and then, the open chunk to the OS (and to disk)."""
        now = self.now_ns()
        self._release_fixes(now - _EPOCH_BURST_NS)
        dt = max((now - self._last_status_ns) / 1e9, 1e-9)
        self._last_status_ns = now
        for s in list(self._sources.values()):
            s.update_rate(dt)
            est = s.offset.estimate()
            self.write(TOPIC_STATUS, {"source": s.name, "messages": s.messages, "garbage": s.garbage,
                                      "dropped": s.dropped, "rate_hz": s.rate_hz,
                                      "clock_offset_s": None if est is None else est.offset_ns / 1e9}, now)
        have = sum(s.offset.total > 0 for s in self._sources.values())
        if now - self._last_prov_ns >= 10e9 or have > self._prov_offsets:
            self._write_provenance()   # every 10 s, and as soon as a source's clock offset is first known
            self._prov_offsets = have
        if fsync:
            self._out.sync()
        else:
            self._out.flush_to_os()

    def _flush_to_os(self) -> int | None:
        """Flush thread, under the lock: status rows and the open chunk to the OS; the fd to fsync."""
        if self._closed or self._error is not None:
            return None
        self._tick(fsync=False)
        return self._out.fileno()

    def _after_sync(self) -> bool:
        """Flush thread, under the lock, after the fsync: rotate when due. False: stop."""
        if self._closed or self._error is not None:
            return False
        self._maybe_rotate()
        return True

    def _maybe_rotate(self) -> None:
        if self._out.rotation_due(self.now_ns()):
            size = self._out.size()
            self._finish_part()
            self._out.next_part(size)
            self._open_part()

    def _finish_part(self) -> None:
        self._write_provenance(closed=True)
        self._out.finish()

    @property
    def error(self) -> StorageError | None:
        """The storage error that stopped the recording, if any."""
        return self._error

    def status(self) -> RecorderStatus:
        """Counters, files, bytes, last fix and fix quality now."""
        with self._lock:
            now = self.now_ns()
            fix = self._last_fix
            q = self._quality or (None, None, None)
            return RecorderStatus(
                elapsed_s=(now - self._utc0) / 1e9, path=str(self.path), files=tuple(str(p) for p in self.paths),
                file_bytes=self._out.bytes_on_disk(), messages_written=self._written,
                sources=tuple(s.snapshot() for s in self._sources.values()),
                last_fix=None if fix is None else fix[:2], fix_age_s=None if fix is None else (now - fix[2]) / 1e9,
                satellites=q[1], hdop=q[2], fix_quality=q[0],
                error=None if self._error is None else str(self._error))

    # -- closing -------------------------------------------------------------------
    def close(self) -> None:
        """Finish the file (summary, footer) and fsync. Raises the storage error, if one happened."""
        self._flusher.stop()
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
        self._release_fixes(None)
        self._tick(fsync=False)
        self._finish_part()
        with contextlib.suppress(OSError):
            self._out.bytes_done += self.path.stat().st_size

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            with contextlib.suppress(StorageError):
                self.close()


__all__ = ["META_RECORDING", "TOPIC_EVENTS", "TOPIC_FIX", "TOPIC_HEADING", "TOPIC_QUALITY", "TOPIC_RAW_JSON",
           "TOPIC_RAW_NMEA", "TOPIC_STATUS", "TOPIC_THRUST", "Recorder", "RecorderStatus", "SourceStatus",
           "check_outputs", "part_path"]
