"""NMEA 0183 sentences -> samples (pure: text in, frozen dataclasses out).

Shared by the live recorder (``usvlog.io.record``) and any importer of NMEA text
logs: one place turns a sentence into a position, a heading or a GPS time.

* position: GGA (with altitude, satellites, HDOP, fix quality), RMC, GLL;
* heading: HDT (true), HDG (magnetic + deviation, true when the variation is
  given), HDM (magnetic); radians clockwise from north, wrapped with ``ssa``;
* GPS time: RMC and ZDA carry the date; GGA and GLL only the time of day, which
  :func:`resolve_time_of_day` places on the day nearest a reference time.

Malformed sentences (bad or missing checksum, unparseable or out-of-range
fields) raise :class:`NmeaError` with the reason; sentence types that parse but
carry none of the above return a sample with only ``kind`` set.
"""

from __future__ import annotations

import datetime as _dt
import math
from dataclasses import dataclass

from .frames import ssa

_NS = 1_000_000_000
_DAY_NS = 86_400 * _NS


class NmeaError(ValueError):
    """A sentence that cannot be used; the message says why."""


@dataclass(frozen=True)
class NmeaSample:
    """What one sentence says. Fields a sentence type does not carry are None."""

    kind: str                          # sentence type: GGA, RMC, HDT, ...
    talker: str = ""
    lat_deg: float | None = None       # position (only when the receiver has a fix)
    lon_deg: float | None = None
    alt_m: float | None = None         # height above the ellipsoid when the geoid separation is given, else MSL
    fix_quality: int | None = None     # GGA quality; 0 = no fix
    satellites: int | None = None
    hdop: float | None = None
    has_fix: bool = False              # position fields are valid
    heading_rad: float | None = None
    reference: str | None = None       # "true" | "magnetic"
    time_of_day_ns: int | None = None  # ns since UTC midnight
    date: _dt.date | None = None       # UTC date (RMC, ZDA)

    @property
    def gps_time_ns(self) -> int | None:
        """GPS (UTC) time, ns since the epoch, when the sentence carries date and time."""
        if self.date is None or self.time_of_day_ns is None:
            return None
        return _date_ns(self.date) + self.time_of_day_ns


def checksum(body: str) -> str:
    """The two hex digits of the NMEA checksum of ``body`` (the text between $ and *)."""
    c = 0
    for ch in body.encode("ascii", "replace"):
        c ^= ch
    return f"{c:02X}"


def with_checksum(body: str) -> str:
    """``$body*CS`` — a complete sentence (no line ending)."""
    return f"${body}*{checksum(body)}"


def _date_ns(d: _dt.date) -> int:
    return (d - _dt.date(1970, 1, 1)).days * _DAY_NS


def _tod_ns(t) -> int | None:
    if t is None:
        return None
    if not isinstance(t, _dt.time):
        raise NmeaError(f"bad time of day {t!r}")
    return ((t.hour * 60 + t.minute) * 60 + t.second) * _NS + t.microsecond * 1000


def _float(x, what: str) -> float | None:
    if x in (None, ""):
        return None
    try:
        v = float(x)
    except (TypeError, ValueError):
        raise NmeaError(f"bad {what} {x!r}") from None
    if not math.isfinite(v):
        raise NmeaError(f"bad {what} {x!r}")
    return v


def _int(x, what: str) -> int | None:
    if x in (None, ""):
        return None
    try:
        return int(x)
    except (TypeError, ValueError):
        raise NmeaError(f"bad {what} {x!r}") from None


def _position(msg) -> tuple[float, float]:
    if not msg.lat or not msg.lon:
        raise NmeaError("position fields empty")
    try:
        lat, lon = float(msg.latitude), float(msg.longitude)
    except (TypeError, ValueError):
        raise NmeaError(f"bad position {msg.lat!r},{msg.lat_dir!r} {msg.lon!r},{msg.lon_dir!r}") from None
    if msg.lat_dir not in ("N", "S") or msg.lon_dir not in ("E", "W"):
        raise NmeaError(f"bad hemisphere {msg.lat_dir!r}/{msg.lon_dir!r}")
    if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0 and math.isfinite(lat) and math.isfinite(lon)):
        raise NmeaError(f"position {lat},{lon} out of range")
    return lat, lon


def _heading(value, what: str) -> float:
    h = _float(value, what)
    if h is None:
        raise NmeaError(f"{what} empty")
    if not (0.0 <= h <= 360.0):
        raise NmeaError(f"{what} {h} out of range [0, 360]")
    return float(ssa(math.radians(h)))


def _signed(value, direction, what: str) -> float:
    v = _float(value, what) or 0.0
    if direction in ("W",):
        return -v
    if direction not in ("E", "", None):
        raise NmeaError(f"bad {what} direction {direction!r}")
    return v


def parse_sentence(text: str) -> NmeaSample:
    """One sentence (``$...*CS``, line ending optional) -> :class:`NmeaSample`."""
    import pynmea2

    line = text.strip()
    if not line.startswith(("$", "!")):
        raise NmeaError("does not start with $")
    if "*" not in line:
        raise NmeaError("checksum missing")
    try:
        msg = pynmea2.parse(line, check=True)
    except pynmea2.SentenceTypeError:
        # a well-formed sentence of a type this parser does not know
        body = line[1:].split("*", 1)
        if len(body) != 2 or body[1][:2].upper() != checksum(body[0]):
            raise NmeaError("checksum does not match") from None
        head = body[0].split(",", 1)[0]
        return NmeaSample(kind=head[2:] if len(head) == 5 else head, talker=head[:2] if len(head) == 5 else "")
    except (pynmea2.ParseError, ValueError, TypeError, AttributeError) as err:
        reason = err.args[0] if err.args else str(err)
        raise NmeaError(str(reason)) from None
    kind = msg.sentence_type
    talker = getattr(msg, "talker", "")
    try:
        if kind == "GGA":
            q = _int(msg.gps_qual, "fix quality")
            tod = _tod_ns(msg.timestamp)
            sats = _int(msg.num_sats, "satellite count")
            hdop = _float(msg.horizontal_dil, "HDOP")
            if not q:
                return NmeaSample(kind, talker, fix_quality=0 if q is None else q, satellites=sats, hdop=hdop,
                                  time_of_day_ns=tod)
            lat, lon = _position(msg)
            alt = _float(msg.altitude, "altitude")
            sep = _float(msg.geo_sep, "geoid separation")
            if alt is not None and sep is not None:
                alt = alt + sep
            return NmeaSample(kind, talker, lat_deg=lat, lon_deg=lon, alt_m=alt, fix_quality=q,
                              satellites=sats, hdop=hdop, has_fix=True, time_of_day_ns=tod)
        if kind == "RMC":
            tod = _tod_ns(msg.timestamp)
            date = msg.datestamp
            if date is not None and not isinstance(date, _dt.date):
                raise NmeaError(f"bad date {date!r}")
            if msg.status != "A":
                return NmeaSample(kind, talker, time_of_day_ns=tod, date=date)
            lat, lon = _position(msg)
            return NmeaSample(kind, talker, lat_deg=lat, lon_deg=lon, has_fix=True, time_of_day_ns=tod, date=date)
        if kind == "GLL":
            tod = _tod_ns(msg.timestamp)
            if msg.status != "A":
                return NmeaSample(kind, talker, time_of_day_ns=tod)
            lat, lon = _position(msg)
            return NmeaSample(kind, talker, lat_deg=lat, lon_deg=lon, has_fix=True, time_of_day_ns=tod)
        if kind == "ZDA":
            tod = _tod_ns(msg.timestamp)
            y, mo, d = _int(msg.year, "year"), _int(msg.month, "month"), _int(msg.day, "day")
            if None in (y, mo, d):
                return NmeaSample(kind, talker, time_of_day_ns=tod)
            try:
                date = _dt.date(y, mo, d)
            except ValueError:
                raise NmeaError(f"bad date {y}-{mo}-{d}") from None
            return NmeaSample(kind, talker, time_of_day_ns=tod, date=date)
        if kind == "HDT":
            return NmeaSample(kind, talker, heading_rad=_heading(msg.heading, "heading"), reference="true")
        if kind == "HDM":
            return NmeaSample(kind, talker, heading_rad=_heading(msg.heading, "heading"), reference="magnetic")
        if kind == "HDG":
            h = _heading(msg.heading, "heading")
            dev = math.radians(_signed(msg.deviation, msg.dev_dir, "deviation"))
            if msg.variation not in (None, ""):
                var = math.radians(_signed(msg.variation, msg.var_dir, "variation"))
                return NmeaSample(kind, talker, heading_rad=float(ssa(h + dev + var)), reference="true")
            return NmeaSample(kind, talker, heading_rad=float(ssa(h + dev)), reference="magnetic")
    except (TypeError, ValueError, AttributeError) as err:
        if isinstance(err, NmeaError):
            raise
        raise NmeaError(f"bad {kind} fields ({err})") from None
    return NmeaSample(kind, talker)


def resolve_time_of_day(time_of_day_ns: int, reference_ns: int) -> int:
    """Place a UTC time of day on the day that puts it nearest ``reference_ns``.

    For sentences without a date (GGA, GLL); the reference is the receive time
    corrected by the clock offset, so midnight roll-overs land on the right day.
    """
    day0 = (reference_ns // _DAY_NS) * _DAY_NS
    best = None
    for d in (day0 - _DAY_NS, day0, day0 + _DAY_NS):
        cand = d + time_of_day_ns
        if best is None or abs(cand - reference_ns) < abs(best - reference_ns):
            best = cand
    return int(best)
