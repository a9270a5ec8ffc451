"""NMEA 0183 text logs, raw or captured by a logger that writes something before each sentence.

Sentences are found anywhere in a line (after any logger prefix: a time stamp, a log
level, a module name) and parsed by :func:`usvlog.io.nmea.parse_sentence`, the parser
the live recorder uses too (talker IDs, HDG deviation/variation, GGA altitude as WGS-84
ellipsoidal height, checksum rules: see that module). GGA, RMC, GLL -> ``/gnss/fix``
(one fix per epoch, from its best valid sentence: GGA, else RMC, else GLL,
:class:`usvlog.io.nmea.FixSelector`); HDT, HDG, HDM -> ``/compass/heading``; VTG, or RMC
when the file has no VTG -> ``/gnss/velocity``. RMC-only fixes have no altitude: it is
written as unknown (NaN / null), never 0.

What is skipped and counted (one bad line never costs more than its own samples): lines
with no sentence, bad checksums, a sentence without its checksum in a file whose sentences
carry one (a truncated ``$HEHDT,2`` is not read as 2 deg), unreadable or out-of-range
fields, empty headings (``$GPHDT,,*4F``), sentences that say "no fix", prefix times that
cannot be a time (``1e300``).

Times: the sentence's own UTC (RMC/ZDA give the date; a time of day alone is placed on
the day nearest the previous sentence, so a midnight roll-over moves to the next day) is
``stamp_ns``, and the record time ``t_ns`` unless a line prefix time is used. A prefix
time (ISO 8601, epoch or relative seconds, or ``--prefix-time FORMAT``) is used:

* without ``--prefix-time``: only when it says its zone (``...Z``, ``+02:00``) or is epoch
  seconds; a zone-less prefix (a logger's local clock) is not used and is reported with its
  offset from the sentences' UTC; relative seconds only when the file has no RMC/ZDA date;
* ``--prefix-time auto`` or ``FORMAT`` (``strptime``): always; a zone-less or relative
  prefix is put on UTC by ``--start-utc`` (the time of the first stamped line), else by
  its offset from the sentences' UTC (rounded to the time zone it is when within a minute
  of one), else taken as UTC (zone-less) or counted from the Unix epoch (relative), with
  a note each time;
* ``--prefix-time none``: never.

Without a usable prefix, sentences with no time of their own (headings, VTG) are spread
evenly between the timed sentences around them.
"""

from __future__ import annotations

import datetime as _dt
import gzip
import math
import re
import statistics
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np

from ..._jit import readonly
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
from .catalog import Catalog
from .sniff import check_gzip

_SENTENCE = re.compile(r"[$!][A-Z][A-Z0-9]{2,5},")
_DAY_NS = 86_400 * 1_000_000_000
_POSITION = {"GGA", "RMC", "GLL"}
_HEADING = {"HDT", "HDG", "HDM"}
_USED = _POSITION | _HEADING | {"VTG"}
_SCAN_LINES = 20_000
_ISO = re.compile(r"(\d{4}-\d{2}-\d{2})[T ](\d{2}:\d{2}:\d{2}(?:[.,]\d+)?)[ ]?(Z|UTC|GMT|[+-]\d{2}:?\d{2})?(?![\d:])")
_NUM = re.compile(r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?(?![\w.:-])")
_EPOCH_MIN_S, _EPOCH_MAX_S = 1e8, 4e9    # epoch seconds: 1973 .. 2096 (beyond: no time stamp, e.g. 1e300)
_ZONE_STEP_NS = 15 * 60 * 1_000_000_000  # time zones are whole quarter hours


def looks_like_nmea(text: str) -> bool:
    """Whether the start of a file reads as an NMEA 0183 log.

    True when at least a quarter of the first 40 non-blank lines (and two of them, in a file
    of two lines or more) hold a sentence start (``$`` or ``!``, talker and type, a comma)
    anywhere in the line, after any prefix: a logger's capture may interleave its own lines.

    Parameters
    ----------
    text : str
        The file's first bytes, decoded.
    """
    lines = [ln for ln in text.splitlines()[:40] if ln.strip()]
    if not lines:
        return False
    hits = sum(1 for ln in lines if _SENTENCE.search(ln))
    return hits >= max(min(2, len(lines)), len(lines) // 4)


class PrefixTimeError(ValueError):
    """A line prefix that holds something like a time stamp which cannot be one."""


def prefix_time(prefix: str, fmt: str | None = None) -> tuple[int, str] | None:
    """The time stamp at the start of a line's prefix.

    Parameters
    ----------
    prefix : str
        The text before the sentence (``"2023-09-01 15:56:44.626 | DEBUG | ... - "``).
    fmt : str, optional
        A ``strptime`` format for the stamp (as many words as it has are read), or
        None / ``"auto"``: ISO 8601 date and time (``T`` or a space between, zone optional)
        or a number of seconds.

    Returns
    -------
    (int, str) or None
        The time in ns and its kind: ``"utc"`` (a zone was given, or epoch seconds: ns since
        the Unix epoch), ``"local"`` (a date and time without zone, read as if UTC) or
        ``"relative"`` (seconds < 1e8: ns since some start); None when the prefix starts
        with no time stamp.

    Raises
    ------
    PrefixTimeError
        A stamp that cannot be a time: a number that is not finite, negative or beyond
        2096 as epoch seconds (``1e300``), a date that does not exist, text that does not
        fit ``fmt``.
    """
    s = prefix.strip().lstrip("[(")
    if not s:
        return None
    if fmt not in (None, "auto", "none"):
        words = len(str(fmt).split())
        text = " ".join(s.split()[:words]).rstrip(",;|])")
        try:
            t = _dt.datetime.strptime(text, str(fmt))
        except ValueError:
            raise PrefixTimeError(f"{text[:40]!r} does not fit --prefix-time {fmt!r}") from None
        kind = "local" if t.tzinfo is None else "utc"
        t = t.replace(tzinfo=_dt.UTC) if t.tzinfo is None else t
        d = t - _dt.datetime(1970, 1, 1, tzinfo=_dt.UTC)
        return (d.days * 86_400 + d.seconds) * 1_000_000_000 + d.microseconds * 1000, kind
    m = _ISO.match(s)
    if m is not None:
        date, tod, zone = m.groups()
        z = "" if zone is None else ("+00:00" if zone in ("Z", "UTC", "GMT") else
                                     zone if ":" in zone else zone[:3] + ":" + zone[3:])
        try:
            return parse_time(f"{date}T{tod.replace(',', '.')}{z}"), ("local" if zone is None else "utc")
        except ValueError:
            raise PrefixTimeError(f"{m.group(0)!r} is not a time") from None
    m = _NUM.match(s)
    if m is None:
        return None
    try:
        v = float(m.group(0))
    except (ValueError, OverflowError):   # pragma: no cover - the pattern is a float literal
        raise PrefixTimeError(f"{m.group(0)[:40]!r} is not a time") from None
    if not (math.isfinite(v) and 0.0 <= v < _EPOCH_MAX_S):
        raise PrefixTimeError(f"{m.group(0)[:40]!r} is not a time")
    return int(round(v * 1e9)), ("utc" if v >= _EPOCH_MIN_S else "relative")


@dataclass
class _Scan:
    """What the first lines of a file say: date, checksums, prefix kind, prefix-to-UTC offsets."""

    day0: int | None = None                 # ns of the UTC midnight of the first RMC/ZDA date
    with_cs: int = 0
    without_cs: int = 0
    vtg: int = 0
    kind: str | None = None                 # the first prefix time's kind
    first_prefix: int | None = None         # the first prefix time, ns
    example: str = ""                       # the first prefix time as written
    offsets: list = field(default_factory=list)   # sentence UTC - prefix time, ns (RMC/ZDA lines)

    @property
    def checksummed(self) -> bool:
        """The file's sentences carry checksums (most of them do)."""
        return self.with_cs > self.without_cs

    def offset(self) -> int | None:
        """Median of sentence UTC - prefix time (ns), or None without RMC/ZDA lines."""
        return int(statistics.median(self.offsets)) if self.offsets else None


def _scan(path, fmt: str | None, limit: int = _SCAN_LINES) -> _Scan:
    sc = _Scan()
    for i, line in enumerate(_lines(path)):
        if i >= limit or (i >= 2000 and sc.day0 is not None and (len(sc.offsets) >= 50 or sc.kind != "local")):
            break   # enough seen: checksums, VTG, prefix kind in 2000 lines; a date and the offsets
        m = _SENTENCE.search(line)
        if m is None:
            continue
        body = line[m.start():].strip()
        if "*" in body:
            sc.with_cs += 1
        else:
            sc.without_cs += 1
        if "VTG," in body[:8]:
            sc.vtg += 1
        pre = None
        if m.start() and fmt != "none":
            try:
                pre = prefix_time(line[:m.start()], fmt)
            except PrefixTimeError:
                pre = None
            if pre is not None and sc.kind is None:
                sc.first_prefix, sc.kind = pre
                words = line[:m.start()].split()
                sc.example = " ".join(words[:2] if sc.kind == "local" and fmt in (None, "auto") else words[:1])[:30]
        if body[3:7] not in ("RMC,", "ZDA,") and body[1:5] not in ("RMC,", "ZDA,"):
            continue
        try:
            smp = parse_sentence(body, require_checksum=False)
        except NmeaError:
            continue
        if smp.date is not None and sc.day0 is None:
            sc.day0 = date_ns(smp.date)
        if pre is not None and pre[1] == sc.kind and smp.gps_time_ns is not None and len(sc.offsets) < 50:
            sc.offsets.append(smp.gps_time_ns - pre[0])
    return sc


def _hms(ns: int) -> str:
    """A signed offset as ``+HH:MM`` (whole minutes) or ``+H h MM min SS.S s``."""
    sign = "-" if ns < 0 else "+"
    a = abs(ns)
    if a % 60_000_000_000 == 0:
        return f"{sign}{a // 3_600_000_000_000:02d}:{a // 60_000_000_000 % 60:02d}"
    return f"{sign}{a // 3_600_000_000_000} h {a // 60_000_000_000 % 60:02d} min {a % 60_000_000_000 / 1e9:.1f} s"


def _prefix_policy(sc: _Scan, mode: str | None, start_ns: int | None, report) -> tuple[bool, int]:
    """(use the prefix times, offset ns added to them) and the notes that say so."""
    if sc.kind is None or mode == "none":
        return False, 0
    if sc.kind == "utc":
        return True, 0
    off = sc.offset()
    what = "have no time zone" if sc.kind == "local" else "are relative"
    if mode is None and (sc.kind == "local" or (sc.day0 is not None and start_ns is None)):
        rel = "" if off is None else f" (they are UTC{_hms(-_zone(off)[0])}, measured against the sentences)"
        report.note(f"line prefix times ({sc.example!r}) {what}: not used, times from the sentences' "
                    f"UTC{rel}; give --prefix-time auto to use them")
        return False, 0
    if start_ns is not None:
        report.guesses["start_utc"] = "--start-utc (first stamped line)"
        report.note(f"line prefix times {what}: the first one is placed at --start-utc")
        return True, int(start_ns) - int(sc.first_prefix or 0)
    if off is not None:
        z, exact = _zone(off) if sc.kind == "local" else (off, False)
        how = f"zone UTC{_hms(-z)}" if exact else f"shifted by the measured {_hms(z)}"
        report.guesses["prefix_time"] = f"UTC{_hms(-z)}" if exact else f"offset {_hms(z)}"
        report.note(f"line prefix times ({sc.example!r}) {what}: put on the sentences' UTC (RMC/ZDA), {how}")
        return True, z
    if sc.kind == "local":
        report.guesses["prefix_time"] = "UTC (assumed)"
        report.note(f"line prefix times ({sc.example!r}) have no time zone and the file has no RMC/ZDA UTC: "
                    "taken as UTC")
        return True, 0
    report.guesses["start_utc"] = "1970-01-01T00:00:00Z"
    report.note("line time stamps are relative and no --start-utc was given: times start at the Unix epoch")
    return True, 0


def _zone(off: int) -> tuple[int, bool]:
    """(offset, is a time zone): ``off`` rounded to quarter hours when it is within a minute of one."""
    z = int(round(off / _ZONE_STEP_NS)) * _ZONE_STEP_NS
    return (z, True) if abs(off - z) <= 60_000_000_000 else (off, False)


class _Clock:
    """Calendar time of sentence times of day: RMC/ZDA dates, midnight roll-over."""

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


def _open(path, mode: str, **kw):
    """The file, gunzipped on the fly when it is gzip-compressed (from its magic bytes)."""
    if check_gzip(path):
        return gzip.open(path, mode, **kw)
    return open(path, mode, **kw)


def _lines(path) -> Iterator[str]:
    """The file's lines (undecodable bytes replaced); OS errors -> one-line StorageError.

    A generator, so the ``try`` of :func:`usvlog.io.atomic.reading` covers the file
    reads only, not what the caller does with each line.
    """
    with reading(path), _open(path, "rt", encoding="ascii", errors="replace", newline=None) as fh:
        yield from fh


class _Buf:
    def __init__(self):
        self.gnss = {k: [] for k in ("t_ns", "stamp_ns", "lat_deg", "lon_deg", "alt_m", "fix_quality", "hdop")}
        self.heading = {k: [] for k in ("t_ns", "stamp_ns", "heading_rad", "reference")}
        self.velocity = {k: [] for k in ("t_ns", "stamp_ns", "sog_mps", "cog_rad")}

    def __len__(self) -> int:
        return len(self.gnss["t_ns"]) + len(self.heading["t_ns"]) + len(self.velocity["t_ns"])

    def batch(self) -> dict:
        out = {}
        for name in ("gnss", "heading", "velocity"):
            d = getattr(self, name)
            if d["t_ns"]:
                out[name] = {k: np.asarray(v, dtype=object if k == "reference" else
                                           (np.int64 if k.endswith("_ns") or k == "fix_quality" else float))
                             for k, v in d.items()}
        self.__init__()
        return out


def _empty_heading(body: str) -> bool:
    """An HDT/HDG/HDM sentence whose heading field is empty (``$GPHDT,,*4F``)."""
    head, _, rest = body.partition(",")
    return head[-3:] in _HEADING and rest.split("*")[0].split(",")[0].strip() == ""


def read(path, opts, report, *, fmt="nmea", on_mapping=None, fast: bool | None = None) -> Iterator[dict]:
    """Batches of role streams (``gnss``, ``heading``, ``velocity``) from an NMEA 0183 log.

    See :mod:`usvlog.io.importers.core` for the batch layout and this module's docstring
    for the sentences used and how times are placed: ``t_ns`` is the line's prefix time
    when it is used, else the sentence's own UTC time; ``stamp_ns`` the sentence's own
    time. Both are ns since the Unix epoch. Headings and courses are in rad, speeds in
    m/s, altitudes in m (NaN when the sentence has none).

    Parameters
    ----------
    path : pathlib.Path
        The log file (ASCII; undecodable bytes are replaced).
    opts : usvlog.io.importers.ImportOptions
        ``prefix_time`` (None, ``"auto"``, ``"none"`` or a ``strptime`` format),
        ``start_utc_ns`` (ns since the Unix epoch: the time of the first stamped line for
        relative or zone-less prefixes, and the date when the file has no RMC/ZDA),
        ``chunk_rows`` samples per batch.
    report : usvlog.io.importers.core.ImportReport
        Filled with lines read, lines skipped by reason (``nmea_garbage``,
        ``nmea_bad_checksum``, ``nmea_no_checksum``, ``nmea_bad_field``,
        ``nmea_heading_empty``, ``nmea_bad_time``, ``gnss_no_fix``, ``nmea_untimed``,
        ``nmea_unsupported``), the mapping, guesses and notes.
    fmt : str
        Unused (one signature for every reader).
    on_mapping : callable, optional
        Called with ``report`` before the sentences are read.
    fast : bool or None, default None
        True: parse through the compiled kernels of :mod:`usvlog.io.importers.nmea_fast`
        (lines they do not read are parsed here); False: the per-line Python loop, the
        reference (the same samples, skips and counts; batch boundaries may differ); None:
        the kernels for files of :data:`FAST_MIN_BYTES` or more, else the Python loop.

    Raises
    ------
    InputError
        The file has no lines.
    StorageError
        The file cannot be read.
    """
    p = path
    start_ns = opts.start_utc_ns
    mode = getattr(opts, "prefix_time", None)
    sc = _scan(p, mode)
    day0 = sc.day0
    if day0 is None and start_ns is not None:
        day0 = (start_ns // _DAY_NS) * _DAY_NS
    if day0 is None:
        report.guesses["date"] = "1970-01-01"
        report.note("no RMC/ZDA date in the file and no --start-utc: sentence times are on 1970-01-01")
    use_prefix, offset = _prefix_policy(sc, mode, start_ns, report)
    prefix_hint = "" if use_prefix or sc.kind is None else " (give --prefix-time auto to use the line prefix times)"
    velocity_from = "VTG" if sc.vtg else "RMC"
    clock = _Clock(day0)
    report.mapping.update({"gnss": "GGA/RMC/GLL", "heading": "HDT/HDG/HDM", "velocity": velocity_from})
    if on_mapping is not None:
        on_mapping(report)
    buf = _Buf()
    pending: list[tuple[str, tuple]] = []   # untimed samples waiting for the next timed sentence
    last_t: int | None = None
    last_dt = 100_000_000
    fixes = FixSelector()
    n_lines = 0

    def emit_pending(t_next: int | None):
        nonlocal pending
        if not pending:
            return
        if last_t is None and t_next is None:
            report.skip("nmea_untimed", len(pending), where="sentences without a time of their own and no "
                        "timed sentence around them" + prefix_hint)
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

    if fast is None:
        fast = p.stat().st_size >= FAST_MIN_BYTES
    if fast and not _lone_cr(p):
        yield from _read_fast(p, report, sc, mode, use_prefix, offset, velocity_from, day0, prefix_hint)
        return
    for lineno, line in enumerate(_lines(p), 1):
        n_lines += 1
        report.records += 1
        line = line.strip()
        if not line:
            report.records -= 1
            continue
        got = _line_sample(line, lineno, sc, mode, use_prefix, offset, report)
        if got is None:
            continue
        smp, t_prefix = got
        typ = smp.kind
        if typ == "ZDA":
            if smp.date is not None and smp.time_of_day_ns is not None:
                clock.stamp(smp.time_of_day_ns, smp.date)   # the date for the sentences after it
            else:
                report.skip("nmea_unsupported", 1)
            continue
        if typ not in _USED:
            report.skip("nmea_unsupported", 1)
            continue
        kind, vals, stamp = _values(smp, clock)
        if kind == "nofix":
            report.skip("gnss_no_fix", 1, where=f"line {lineno}: {typ} without a fix")
            continue
        t = t_prefix if t_prefix is not None else stamp
        if t is None:
            if kind == "velocity" and velocity_from != "VTG":
                continue
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
            if typ == "RMC" and velocity_from == "RMC" and smp.sog_mps is not None:
                _put(buf, "velocity", t, stamp if stamp is not None else t,
                     (smp.sog_mps, math.nan if smp.cog_rad is None else smp.cog_rad))
        elif kind != "velocity" or velocity_from == "VTG":
            _put(buf, kind, t, stamp if stamp is not None else t, vals)
        if len(buf) >= opts.chunk_rows:
            yield buf.batch()
    for item in fixes.flush():
        _put(buf, "gnss", *item)
    emit_pending(None)
    if n_lines == 0:
        raise InputError(f"{p}: empty file")
    yield buf.batch()


def _line_sample(line: str, lineno: int, sc: _Scan, mode, use_prefix: bool, offset: int, report):
    """(sample, prefix time ns or None) of one stripped, non-blank line, or None when the
    line is skipped (counted in ``report`` with its reason)."""
    m = _SENTENCE.search(line)
    if m is None:
        report.skip("nmea_garbage", 1, where=f"line {lineno}: no sentence ({line[:30]!r})")
        return None
    body = line[m.start():]
    t_prefix = None
    if use_prefix and m.start():
        try:
            pre = prefix_time(line[:m.start()], mode)
        except PrefixTimeError as err:
            report.skip("nmea_bad_time", 1, where=f"line {lineno}: prefix time {err}")
            return None
        if pre is not None:
            if pre[1] != sc.kind:
                report.skip("nmea_bad_time", 1, where=f"line {lineno}: prefix time of another kind "
                            f"({pre[1]}, the file's are {sc.kind})")
                return None
            t_prefix = pre[0] + offset
            if not 0 <= t_prefix < 2**62:
                report.skip("nmea_bad_time", 1, where=f"line {lineno}: prefix time out of range")
                return None
    if sc.checksummed and "*" not in body:
        report.skip("nmea_no_checksum", 1, where=f"line {lineno}: sentence without its checksum "
                    f"({body[:30]!r})")
        return None
    try:
        smp = parse_sentence(body, require_checksum=False)
    except NmeaChecksumError:
        report.skip("nmea_bad_checksum", 1, where=f"line {lineno}: {body[:40]!r}")
        return None
    except NmeaFieldError:
        if _empty_heading(body):
            report.skip("nmea_heading_empty", 1, where=f"line {lineno}: {body[:40]!r}")
        else:
            report.skip("nmea_bad_field", 1, where=f"line {lineno}: {body[:60]!r}")
        return None
    except NmeaError:
        report.skip("nmea_garbage", 1, where=f"line {lineno}: {body[:40]!r}")
        return None
    return smp, t_prefix


class _Skips:
    """A report stand-in that records skips with their line, to hand them on in line order."""

    def __init__(self):
        self.events: list = []   # (line index, reason, n, where)

    def add(self, line: int, reason: str, n: int = 1, where: str | None = None) -> None:
        self.events.append((line, reason, n, where))

    def replay(self, report) -> None:
        for _, reason, n, where in sorted(self.events, key=lambda ev: ev[0]):
            report.skip(reason, n, where=where)


class _LineSkips:
    """``report.skip`` of one line, into :class:`_Skips`."""

    def __init__(self, skips: _Skips, line: int):
        self.skips, self.line = skips, line

    def skip(self, reason: str, n: int = 1, where: str | None = None) -> None:
        self.skips.add(self.line, reason, n, where)


FAST_MIN_BYTES = 2 << 20
"""Files smaller than this (about 30k lines, under a second in Python) go through the Python
parser: compiling the kernels on a fresh install takes ~20 s, which only a large file repays
(both paths give identical records; tests compare them)."""

_BLOCK_BYTES = 4 << 20   # the fast path reads the file in blocks of whole lines of about this size


def _lone_cr(p) -> bool:
    """The file breaks lines with a CR alone somewhere (old Mac line ends)."""
    prev = b""
    with reading(p), _open(p, "rb") as fh:
        for block in iter(lambda: fh.read(_BLOCK_BYTES), b""):
            b = prev + block
            cr = b.count(b"\r")
            if cr and cr != b.count(b"\r\n") + (b[-1:] == b"\r"):
                return True
            prev = b[-1:]
    return False


def _blocks(p, size: int) -> Iterator[bytes]:
    """The file's bytes in blocks that end at a line end (the last one maybe not)."""
    rest = b""
    with reading(p), _open(p, "rb") as fh:
        for block in iter(lambda: fh.read(size), b""):
            data = rest + block
            cut = data.rfind(b"\n") + 1
            if cut == 0:
                rest = data
                continue
            rest = data[cut:]
            yield data[:cut]
    if rest:
        yield rest


_COLUMNS = ("typ", "tod", "date", "tpre", "fix", "lat", "lon", "alt", "hdg", "ref", "sog", "cog", "qual", "hdop")


def _read_fast(p, report, sc: _Scan, mode, use_prefix: bool, offset: int, velocity_from: str,
               day0: int | None, prefix_hint: str) -> Iterator[dict]:
    """The role streams of :func:`read` through the compiled kernels of :mod:`.nmea_fast` (the
    lines they leave alone parsed by :func:`_line_sample`, as the reference loop does), block
    by block of the file (memory bounded by a block). Not for files with lone CR line breaks."""
    from . import nmea_fast as nf  # the compiled kernels: loaded when an NMEA file is read

    numeric_prefix = sc.kind in ("utc", "relative") and mode in (None, "auto")
    kernel_prefix = 0 if not use_prefix else (1 if numeric_prefix else 2)
    state = nf.new_state()
    carry = {k: v[:0] for k, v in _block_columns(nf, np.zeros(0, np.uint8), 0, sc, mode, use_prefix, offset,
                                                   kernel_prefix, _Skips())[0].items()}
    n_pending = 0
    line0 = 0
    names = {nf.SKIP_UNSUPPORTED: "nmea_unsupported", nf.SKIP_NO_FIX: "gnss_no_fix", nf.SKIP_UNTIMED: "nmea_untimed"}
    kinds = {v: k for k, v in nf.TYPE_CODE.items()}
    blocks = _blocks(p, _BLOCK_BYTES)
    data = next(blocks, None)
    if data is None:
        raise InputError(f"{p}: empty file")
    while data is not None:
        nxt = next(blocks, None)
        skips = _Skips()
        cols, line_no, n_lines, n_records = _block_columns(nf, np.frombuffer(data, np.uint8), line0, sc, mode,
                                                           use_prefix, offset, kernel_prefix, skips)
        report.records += n_records
        nc = len(carry["typ"])
        c = {k: np.concatenate([carry[k], cols[k]]) for k in _COLUMNS}
        line_no = np.concatenate([np.full(nc, -1), line_no])
        (g_i, g_t, g_s, h_i, h_t, h_s, v_i, v_t, v_s, k_i, k_r, k_n, undecided) = nf.sequence(
            c["typ"], c["tod"], c["date"], c["tpre"], c["fix"], c["sog"], int(day0 or 0), velocity_from == "VTG",
            FixSelector().window_ns, state, nc, n_pending, nxt is None)
        end = line0 + n_lines
        for j, r, n in zip(k_i.tolist(), k_r.tolist(), k_n.tolist()):
            where = None
            if r == nf.SKIP_NO_FIX:
                where = f"line {line_no[j] + 1}: {kinds[int(c['typ'][j])]} without a fix"
            elif r == nf.SKIP_UNTIMED:
                where = "sentences without a time of their own and no timed sentence around them" + prefix_hint
            skips.add(end if j >= len(line_no) else int(line_no[j]), names[r], n, where)
        skips.replay(report)
        out = {}
        if len(g_i):
            out["gnss"] = {"t_ns": g_t, "stamp_ns": g_s, "lat_deg": c["lat"][g_i], "lon_deg": c["lon"][g_i],
                           "alt_m": c["alt"][g_i], "fix_quality": c["qual"][g_i], "hdop": c["hdop"][g_i]}
        if len(h_i):
            out["heading"] = {"t_ns": h_t, "stamp_ns": h_s, "heading_rad": c["hdg"][h_i],
                              "reference": np.array(["true", "magnetic"], dtype=object)[c["ref"][h_i]]}
        if len(v_i):
            out["velocity"] = {"t_ns": v_t, "stamp_ns": v_s, "sog_mps": c["sog"][v_i], "cog_rad": c["cog"][v_i]}
        yield out
        carry = {k: v[undecided] for k, v in c.items()}
        n_pending = len(undecided) - int(state[5] != 0)
        line0 = end
        data = nxt


def _block_columns(nf, buf: np.ndarray, line0: int, sc: _Scan, mode, use_prefix: bool, offset: int,
                   kernel_prefix: int, skips: _Skips):
    """The parsed sentences of one block: columns (:data:`_COLUMNS`), their line indices, the
    block's line count and its non-blank line count; skipped lines into ``skips``."""
    (status, start, end, sent, typ, tod, date, tpre, fix, lat, lon, alt, hdg, sog,
     cog, qual, hdop) = nf.scan_lines(readonly(buf), kernel_prefix, sc.kind == "utc", int(offset))
    ref = np.zeros(len(status), np.int8)                  # heading reference: 0 true, 1 magnetic
    no_sentence = np.flatnonzero(status == nf.NO_SENTENCE)
    if len(no_sentence):
        i = int(no_sentence[0])
        line = bytes(buf[start[i]:end[i]]).decode("ascii")
        skips.add(line0 + i, "nmea_garbage", 1, f"line {line0 + i + 1}: no sentence ({line[:30]!r})")
        skips.add(line0 + i, "nmea_garbage", len(no_sentence) - 1)
    for i in np.flatnonzero(status == nf.FALLBACK).tolist():
        line = bytes(buf[start[i]:end[i]]).decode("ascii", "replace").strip()
        if not line:   # whitespace the kernel does not strip (non-ASCII): as Python reads it
            status[i] = nf.BLANK
            continue
        got = _line_sample(line, line0 + i + 1, sc, mode, use_prefix, offset, _LineSkips(skips, line0 + i))
        if got is None:
            continue
        smp, t_prefix = got
        status[i] = nf.OK
        typ[i] = nf.TYPE_CODE.get(smp.kind, nf.OTHER)
        tod[i] = nf.NONE_I64 if smp.time_of_day_ns is None else smp.time_of_day_ns
        date[i] = nf.NONE_I64 if smp.date is None else date_ns(smp.date)
        tpre[i] = nf.NONE_I64 if t_prefix is None else t_prefix
        fix[i] = smp.has_fix
        if smp.has_fix:
            lat[i], lon[i] = smp.lat_deg, smp.lon_deg
            alt[i] = math.nan if smp.alt_m is None else smp.alt_m
            qual[i], hdop[i] = _quality(smp)
        if smp.heading_rad is not None:
            hdg[i] = smp.heading_rad
            ref[i] = smp.reference == "magnetic"
        sog[i] = math.nan if smp.sog_mps is None else smp.sog_mps
        cog[i] = math.nan if smp.cog_rad is None else smp.cog_rad
    rec = np.flatnonzero(status == nf.OK)
    cols = dict(zip(_COLUMNS, (typ, tod, date, tpre, fix, lat, lon, alt, hdg, ref, sog, cog, qual, hdop)))
    return ({k: v[rec] for k, v in cols.items()}, line0 + rec, len(status),
            int(np.count_nonzero(status != nf.BLANK)))


def _quality(s: NmeaSample) -> tuple[int, float]:
    """(GGA fix quality, HDOP) of a fix sentence: (-1, NaN) where it has none (RMC, GLL)."""
    if s.kind != "GGA" or s.fix_quality is None:
        return -1, math.nan
    return int(s.fix_quality), math.nan if s.hdop is None else float(s.hdop)


def _values(s: NmeaSample, clock: _Clock):
    """(kind, values, own stamp ns or None) of one parsed sentence."""
    stamp = clock.stamp(s.time_of_day_ns, s.date) if s.time_of_day_ns is not None else None
    if s.kind in _POSITION:
        if not s.has_fix:
            return "nofix", None, None
        return "gnss", (s.lat_deg, s.lon_deg, math.nan if s.alt_m is None else s.alt_m, *_quality(s)), stamp
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
        d["fix_quality"].append(vals[3])
        d["hdop"].append(vals[4])
    elif kind == "heading":
        d["heading_rad"].append(vals[0])
        d["reference"].append(vals[1])
    else:
        d["sog_mps"].append(vals[0])
        d["cog_rad"].append(vals[1])


def catalog(path, opts) -> Catalog:
    """What an NMEA/text log holds (:func:`usvlog.io.importers.nmea_catalog.catalog`)."""
    from .nmea_catalog import catalog as listing_of  # local: the listing needs none of the reading above

    return listing_of(path, opts)
