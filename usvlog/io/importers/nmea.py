"""NMEA 0183 text logs, raw or with a time stamp before each sentence, read line by line.

Sentences are parsed by :func:`usvlog.io.nmea.parse_sentence`, the parser the live
recorder uses too (talker IDs, HDG deviation/variation, GGA altitude as WGS-84
ellipsoidal height, checksum rules: see that module). GGA, RMC, GLL ->
``/gnss/fix``; HDT, HDG, HDM -> ``/compass/heading``; VTG -> ``/gnss/velocity``.
What is particular to a file is done here: the date comes from RMC (or
``--start-utc``); a time of day without a date is placed on the day nearest the
previous sentence's time (:func:`usvlog.io.nmea.resolve_time_of_day`), so the time
rolling past midnight moves to the next day. One fix per epoch, from its best valid
sentence (GGA, else RMC, else GLL: :class:`usvlog.io.nmea.FixSelector`, the rule the
recorder follows too). Sentences without a checksum are accepted (some loggers strip it);
lines with a bad checksum, garbage, unreadable fields and sentences that say
"no fix" are skipped and counted.

Times: a line's prefix (ISO 8601 or seconds, epoch or relative to ``--start-utc``) is
the record time; the sentence's own UTC time is ``stamp_ns``. Without a prefix,
sentences with no time of their own (headings, VTG) are spread evenly between the
timed sentences around them.
"""

from __future__ import annotations

import datetime as _dt
import math
import re
from collections.abc import Iterator

import numpy as np

from ...errors import InputError
from ...log.fieldlog import parse_time
from ..atomic import reading
from ..nmea import (
    FixSelector,
    NmeaChecksumError,
    NmeaError,
    NmeaFieldError,
    NmeaSample,
    date_ns,
    parse_sentence,
    resolve_time_of_day,
)

_SENTENCE = re.compile(r"[$!][A-Z][A-Z0-9]{2,5},")
_DAY_NS = 86_400 * 1_000_000_000
_POSITION = {"GGA", "RMC", "GLL"}
_HEADING = {"HDT", "HDG", "HDM"}
_USED = _POSITION | _HEADING | {"VTG"}


def looks_like_nmea(text: str) -> bool:
    """Whether the start of a file reads as an NMEA 0183 log.

    True when at least half of the first 40 non-blank lines hold a sentence start
    (``$`` or ``!``, talker and type, a comma), with or without a time stamp before it.

    Parameters
    ----------
    text : str
        The file's first bytes, decoded.
    """
    lines = [ln for ln in text.splitlines()[:40] if ln.strip()]
    if not lines:
        return False
    hits = sum(1 for ln in lines if _SENTENCE.search(ln))
    return hits >= max(1, len(lines) // 2)


class _Clock:
    """Calendar time of sentence times of day: RMC dates, midnight roll-over."""

    def __init__(self, day_ns: int | None):
        self.day = day_ns or 0
        self.last: int | None = None

    def stamp(self, tod: int, date: _dt.date | None) -> int:
        if date is not None:
            t = date_ns(date) + tod
        elif self.last is None:
            t = self.day + tod
        else:
            t = resolve_time_of_day(tod, self.last)
        self.last = t
        return t


def _prefix_ns(prefix: str, start_ns: int | None, report, state: dict) -> int | None:
    s = prefix.strip().strip(",;|:").strip()
    if not s:
        return None
    try:
        v = float(s)
    except ValueError:
        v = None
    if v is not None:
        if not math.isfinite(v):
            return -1
        if v >= 1e8:
            return int(round(v * 1e9))
        if start_ns is None and "start_utc" not in report.guesses:
            report.guesses["start_utc"] = "1970-01-01T00:00:00Z"
            report.note("line time stamps are relative and no --start-utc was given: times start at the Unix epoch")
        return int(round(v * 1e9)) + (start_ns or 0)
    try:
        return parse_time(s)
    except ValueError:
        return -1


def _first_date(path, limit: int = 20000) -> int | None:
    """Date of the first RMC sentence near the start of the file (for sentences before it)."""
    for i, line in enumerate(_lines(path)):
        if i >= limit:
            break
        m = _SENTENCE.search(line) if "RMC," in line else None
        if m is not None:
            try:
                s = parse_sentence(line[m.start():], require_checksum=False)
            except NmeaError:
                continue
            if s.date is not None:
                return date_ns(s.date)
    return None


def _lines(path) -> Iterator[str]:
    """The file's lines (undecodable bytes replaced); OS errors -> one-line StorageError.

    A generator, so the ``try`` of :func:`usvlog.io.atomic.reading` covers the file
    reads only, not what the caller does with each line.
    """
    with reading(path), open(path, encoding="ascii", errors="replace", newline=None) as fh:
        yield from fh


class _Buf:
    def __init__(self):
        self.gnss = {k: [] for k in ("t_ns", "stamp_ns", "lat_deg", "lon_deg", "alt_m")}
        self.heading = {k: [] for k in ("t_ns", "stamp_ns", "heading_rad", "reference")}
        self.velocity = {k: [] for k in ("t_ns", "stamp_ns", "sog_mps", "cog_rad")}

    def batch(self) -> dict:
        out = {}
        for name in ("gnss", "heading", "velocity"):
            d = getattr(self, name)
            if d["t_ns"]:
                out[name] = {k: np.asarray(v, dtype=object if k == "reference" else
                                           (np.int64 if k.endswith("_ns") else float)) for k, v in d.items()}
        self.__init__()
        return out


def read(path, opts, report, *, fmt="nmea", on_mapping=None) -> Iterator[dict]:
    """Batches of role streams (``gnss``, ``heading``, ``velocity``) from an NMEA 0183 log.

    See :mod:`usvlog.io.importers.core` for the batch layout and this module's docstring
    for the sentences used and how times are placed: ``t_ns`` is the line's time stamp
    prefix, else the sentence's own UTC time; ``stamp_ns`` the sentence's own time. Both
    are ns since the Unix epoch. Headings and courses are in rad, speeds in m/s,
    altitudes in m.

    Parameters
    ----------
    path : pathlib.Path
        The log file (ASCII; undecodable bytes are replaced).
    opts : usvlog.io.importers.ImportOptions
        ``start_utc_ns`` (ns since the Unix epoch) for relative prefixes and for the date
        when the file has no RMC; ``chunk_rows`` samples per batch.
    report : usvlog.io.importers.core.ImportReport
        Filled with lines read, lines skipped by reason (garbage, bad checksum, bad
        field, bad time, no fix, untimed, unsupported sentence), the mapping and guesses.
    fmt : str
        Unused (one signature for every reader).
    on_mapping : callable, optional
        Called with ``report`` before the sentences are read.

    Raises
    ------
    InputError
        The file has no lines.
    StorageError
        The file cannot be read.
    """
    p = path
    start_ns = opts.start_utc_ns
    day0 = _first_date(p)
    if day0 is None and start_ns is not None:
        day0 = (start_ns // _DAY_NS) * _DAY_NS
    if day0 is None:
        report.guesses["date"] = "1970-01-01"
        report.note("no RMC date in the file and no --start-utc: sentence times are on 1970-01-01")
    clock = _Clock(day0)
    report.mapping.update({"gnss": "GGA/RMC/GLL", "heading": "HDT/HDG/HDM", "velocity": "VTG"})
    if on_mapping is not None:
        on_mapping(report)
    buf = _Buf()
    pending: list[tuple[str, tuple]] = []   # untimed samples waiting for the next timed sentence
    last_t: int | None = None
    last_dt = 100_000_000
    fixes = FixSelector()
    state: dict = {}
    n_lines = 0

    def emit_pending(t_next: int | None):
        nonlocal pending
        if not pending:
            return
        if last_t is None and t_next is None:
            report.skip("nmea_untimed", len(pending))
            pending = []
            return
        if last_t is None:
            step = last_dt / (len(pending) + 1)
            base = max(0, t_next - last_dt)
        else:
            span = (t_next - last_t) if t_next is not None else last_dt
            base, step = last_t, span / (len(pending) + 1)
        for k, (kind, vals) in enumerate(pending):
            t = int(base + (k + 1) * step)
            _put(buf, kind, t, t, vals)
        pending = []

    for lineno, line in enumerate(_lines(p), 1):
        n_lines += 1
        report.records += 1
        line = line.strip()
        if not line:
            report.records -= 1
            continue
        m = _SENTENCE.search(line)
        if m is None:
            report.skip("nmea_garbage", 1, where=f"line {lineno}: {line[:40]!r}")
            continue
        prefix = line[:m.start()]
        body = line[m.start():]
        t_prefix = _prefix_ns(prefix, start_ns, report, state) if prefix else None
        if t_prefix is not None and t_prefix < 0:
            report.skip("nmea_bad_time", 1, where=f"line {lineno}: time {prefix.strip()[:40]!r}")
            continue
        try:
            smp = parse_sentence(body, require_checksum=False)
        except NmeaChecksumError:
            report.skip("nmea_bad_checksum", 1, where=f"line {lineno}: {body[:40]!r}")
            continue
        except NmeaFieldError:
            report.skip("nmea_bad_field", 1, where=f"line {lineno}: {body[:60]!r}")
            continue
        except NmeaError:
            report.skip("nmea_garbage", 1, where=f"line {lineno}: {body[:40]!r}")
            continue
        typ = smp.kind
        if typ not in _USED:
            report.skip("nmea_unsupported", 1)
            continue
        kind, vals, stamp = _values(smp, clock)
        if kind == "nofix":
            report.skip("gnss_no_fix", 1, where=f"line {lineno}: {typ} without a fix")
            continue
        t = t_prefix if t_prefix is not None else stamp
        if t is None:
            pending.append((kind, vals))
            continue
        if not (kind == "gnss" and fixes.same_epoch(smp)):   # the epoch's 2nd fix sentence: same time
            emit_pending(t)
            if last_t is not None and t > last_t:
                last_dt = t - last_t
            last_t = t
        if kind == "gnss":
            # one fix per epoch, from its best valid sentence (GGA, else RMC, else GLL)
            for item in fixes.offer(smp, t, (t, stamp if stamp is not None else t, vals)):
                _put(buf, "gnss", *item)
        else:
            _put(buf, kind, t, stamp if stamp is not None else t, vals)
        if len(buf.gnss["t_ns"]) + len(buf.heading["t_ns"]) + len(buf.velocity["t_ns"]) >= opts.chunk_rows:
            yield buf.batch()
    for item in fixes.flush():
        _put(buf, "gnss", *item)
    emit_pending(None)
    if n_lines == 0:
        raise InputError(f"{p}: empty file")
    yield buf.batch()


def _values(s: NmeaSample, clock: _Clock):
    """(kind, values, own stamp ns or None) of one parsed sentence."""
    stamp = clock.stamp(s.time_of_day_ns, s.date) if s.time_of_day_ns is not None else None
    if s.kind in _POSITION:
        if not s.has_fix:
            return "nofix", None, None
        return "gnss", (s.lat_deg, s.lon_deg, math.nan if s.alt_m is None else s.alt_m), stamp
    if s.kind in _HEADING:
        return "heading", (s.heading_rad, s.reference), None
    return "velocity", (math.nan if s.sog_mps is None else s.sog_mps,
                        math.nan if s.cog_rad is None else s.cog_rad), None


def _put(buf: _Buf, kind: str, t: int, stamp: int, vals: tuple) -> None:
    d = getattr(buf, kind)
    d["t_ns"].append(t)
    d["stamp_ns"].append(stamp)
    if kind == "gnss":
        d["lat_deg"].append(vals[0])
        d["lon_deg"].append(vals[1])
        d["alt_m"].append(vals[2])
    elif kind == "heading":
        d["heading_rad"].append(vals[0])
        d["reference"].append(vals[1])
    else:
        d["sog_mps"].append(vals[0])
        d["cog_rad"].append(vals[1])
