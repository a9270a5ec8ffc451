"""NMEA 0183 text logs, raw or with a time stamp before each sentence, read line by line.

Sentences (any talker ID): GGA, RMC, GLL -> ``/gnss/fix``; HDT (true), HDG (magnetic
sensor heading + deviation + variation -> true when the variation is given), HDM
(magnetic) -> ``/compass/heading``; VTG -> ``/gnss/velocity``. The date comes from RMC
(or ``--start-utc``); the UTC time of day rolling past midnight moves to the next day.
The same fix reported by GGA and RMC is kept once. Lines with a bad checksum,
garbage and sentences that say "no fix" are skipped and counted.

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

_SENTENCE = re.compile(r"[$!][A-Z][A-Z0-9]{2,5},")
_DAY_NS = 86_400 * 1_000_000_000
_KNOT = 1852.0 / 3600.0
_POSITION = {"GGA", "RMC", "GLL"}
_HEADING = {"HDT", "HDG", "HDM"}
_USED = _POSITION | _HEADING | {"VTG"}


def looks_like_nmea(text: str) -> bool:
    lines = [ln for ln in text.splitlines()[:40] if ln.strip()]
    if not lines:
        return False
    hits = sum(1 for ln in lines if _SENTENCE.search(ln))
    return hits >= max(1, len(lines) // 2)


def _deg(value: str, hemi: str) -> float:
    """NMEA ddmm.mmmm / dddmm.mmmm + hemisphere -> signed degrees (NaN when empty)."""
    if not value:
        return math.nan
    v = float(value)
    d = math.floor(v / 100.0)
    deg = d + (v - 100.0 * d) / 60.0
    return -deg if hemi in ("S", "W") else deg


def _tod_ns(value: str) -> int | None:
    """hhmmss(.sss) -> ns since midnight, None when empty or malformed."""
    if len(value) < 6:
        return None
    try:
        hh, mm, ss = int(value[0:2]), int(value[2:4]), float(value[4:])
    except ValueError:
        return None
    if not (0 <= hh < 24 and 0 <= mm < 60 and 0 <= ss < 61):
        return None
    return (hh * 3600 + mm * 60) * 1_000_000_000 + int(round(ss * 1e9))


def _date_ns(value: str) -> int | None:
    """ddmmyy -> ns of that day's midnight UTC."""
    if len(value) != 6 or not value.isdigit():
        return None
    try:
        d = _dt.date(2000 + int(value[4:6]), int(value[2:4]), int(value[0:2]))
    except ValueError:
        return None
    return (d - _dt.date(1970, 1, 1)).days * _DAY_NS


def _float(value: str) -> float:
    return float(value) if value else math.nan


class _Clock:
    """Calendar day of sentence times: RMC dates, midnight rollover."""

    def __init__(self, day_ns: int | None):
        self.day = day_ns
        self.last_tod: int | None = None

    def stamp(self, tod: int) -> int:
        if self.last_tod is not None and tod < self.last_tod - _DAY_NS // 2:
            self.day = (self.day or 0) + _DAY_NS  # rolled past midnight
        self.last_tod = tod
        return (self.day or 0) + tod

    def set_date(self, day_ns: int, tod: int) -> None:
        self.day = day_ns
        self.last_tod = tod


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
        ts = _dt.datetime.fromisoformat(s.replace("Z", "+00:00"))
    except ValueError:
        return -1
    if ts.tzinfo is None:
        ts = ts.replace(tzinfo=_dt.timezone.utc)
    delta = ts - _dt.datetime(1970, 1, 1, tzinfo=_dt.timezone.utc)
    return (delta.days * 86400 + delta.seconds) * 1_000_000_000 + delta.microseconds * 1000


def _first_date(path, limit: int = 20000) -> int | None:
    """Date of the first RMC sentence near the start of the file (for sentences before it)."""
    with open(path, "r", encoding="ascii", errors="replace") as fh:
        for i, line in enumerate(fh):
            if i >= limit:
                break
            k = line.find("RMC,")
            if k >= 3:
                f = line[k + 4:].split("*")[0].split(",")
                if len(f) > 8 and (d := _date_ns(f[8])) is not None:
                    return d
    return None


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
    import pynmea2

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
    last_fix_stamp: int | None = None
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

    try:
        fh = open(p, "r", encoding="ascii", errors="replace", newline=None)
    except OSError as err:
        raise InputError(f"{p}: cannot read ({err})") from err
    with fh:
        for lineno, line in enumerate(fh, 1):
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
                msg = pynmea2.parse(body, check=False)
            except pynmea2.ChecksumError:
                report.skip("nmea_bad_checksum", 1, where=f"line {lineno}: {body[:40]!r}")
                continue
            except (pynmea2.ParseError, ValueError, TypeError, AttributeError) as err:
                if isinstance(err, pynmea2.SentenceTypeError):
                    report.skip("nmea_unsupported", 1)
                else:
                    report.skip("nmea_garbage", 1, where=f"line {lineno}: {body[:40]!r}")
                continue
            typ = getattr(msg, "sentence_type", "")
            if typ not in _USED:
                report.skip("nmea_unsupported", 1)
                continue
            f = list(msg.data) + [""] * 12
            try:
                kind, vals, stamp = _decode(typ, f, clock)
            except (ValueError, IndexError):
                report.skip("nmea_bad_field", 1, where=f"line {lineno}: {body[:60]!r}")
                continue
            if kind == "nofix":
                report.skip("gnss_no_fix", 1, where=f"line {lineno}: {typ} without a fix")
                continue
            if kind == "gnss":
                if stamp is not None and stamp == last_fix_stamp:
                    # the same fix from another sentence: GGA adds the altitude RMC/GLL lack
                    if typ == "GGA" and buf.gnss["stamp_ns"] and buf.gnss["stamp_ns"][-1] == stamp:
                        buf.gnss["alt_m"][-1] = vals[2]
                    continue
                last_fix_stamp = stamp
            t = t_prefix if t_prefix is not None else stamp
            if t is None:
                pending.append((kind, vals))
                continue
            emit_pending(t)
            if last_t is not None and t > last_t:
                last_dt = t - last_t
            last_t = t
            _put(buf, kind, t, stamp if stamp is not None else t, vals)
            if len(buf.gnss["t_ns"]) + len(buf.heading["t_ns"]) + len(buf.velocity["t_ns"]) >= opts.chunk_rows:
                yield buf.batch()
        emit_pending(None)
    if n_lines == 0:
        raise InputError(f"{p}: empty file")
    yield buf.batch()


def _decode(typ: str, f: list, clock: _Clock):
    """(kind, values, own stamp ns or None) of one sentence's fields."""
    if typ == "GGA":
        tod = _tod_ns(f[0])
        if not f[5] or f[5] == "0" or not f[1] or not f[3]:
            return "nofix", None, None
        stamp = clock.stamp(tod) if tod is not None else None
        return "gnss", (_deg(f[1], f[2]), _deg(f[3], f[4]), _float(f[8])), stamp
    if typ == "RMC":
        tod = _tod_ns(f[0])
        day = _date_ns(f[8])
        if day is not None and tod is not None:
            clock.set_date(day, tod)
            stamp = day + tod
        else:
            stamp = clock.stamp(tod) if tod is not None else None
        if f[1] != "A" or not f[2] or not f[4]:
            return "nofix", None, None
        return "gnss", (_deg(f[2], f[3]), _deg(f[4], f[5]), math.nan), stamp
    if typ == "GLL":
        tod = _tod_ns(f[4])
        stamp = clock.stamp(tod) if tod is not None else None
        if (f[5] and f[5] != "A") or not f[0] or not f[2]:
            return "nofix", None, None
        return "gnss", (_deg(f[0], f[1]), _deg(f[2], f[3]), math.nan), stamp
    if typ == "HDT":
        return "heading", (math.radians(float(f[0])), "true"), None
    if typ == "HDM":
        return "heading", (math.radians(float(f[0])), "magnetic"), None
    if typ == "HDG":
        h = float(f[0])
        if f[1]:
            h += float(f[1]) * (-1.0 if f[2] == "W" else 1.0)
        ref = "magnetic"
        if f[3]:
            h += float(f[3]) * (-1.0 if f[4] == "W" else 1.0)
            ref = "true"
        return "heading", (math.radians(h), ref), None
    if typ == "VTG":
        if f[1] == "T" or f[5] == "N" or f[7] == "K":
            cog, kn, kmh = f[0], f[4], f[6]
        else:  # old layout without the unit letters
            cog, kn, kmh = f[0], f[2], ""
        sog = float(kn) * _KNOT if kn else (float(kmh) / 3.6 if kmh else math.nan)
        return "velocity", (sog, math.radians(float(cog)) if cog else math.nan), None
    raise ValueError(typ)


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
