"""NMEA 0183 sentences -> samples (pure: text in, frozen dataclasses out).

The one sentence parser of usvlog: the live recorder (``usvlog.io.record``) and the
file importer (``usvlog.io.importers.nmea``) both turn sentences into samples here.
What is left to them is what differs between a live stream and a file: the
recorder places times of day with the receive clock, the importer with the
previous sentence's time and the file's RMC date, and reads line prefixes.

* position: GGA (with altitude, satellites, HDOP, fix quality), RMC, GLL;
* heading: HDT (true), HDG (magnetic sensor heading + deviation, + variation when
  given -> true), HDM (magnetic); radians clockwise from north, wrapped with ``ssa``;
* ground velocity: VTG and RMC (speed over ground m/s, course over true north rad; an
  unreadable RMC speed or course is left None, the position is kept);
* GPS time: RMC and ZDA carry the date; GGA and GLL only the time of day, which
  :func:`resolve_time_of_day` places on the day nearest a reference time (this is
  also how both callers handle a midnight roll-over).

Semantics both callers share:

* altitude (GGA): ``alt_m`` is the height above the WGS-84 ellipsoid, i.e. the
  sentence's height above mean sea level plus its geoid separation, as ROS
  NavSatFix and Foxglove LocationFix define altitude; when the sentence gives no
  geoid separation the height above sea level is all there is and is kept as is;
* talker IDs: any (GP, GN, GL, HE, HC, II, ...); the sample keeps it in ``talker``;
  proprietary sentences (``$P...``) and heads that are not 5 characters have none;
* "no fix" (GGA quality 0, RMC/GLL status V, empty position fields) is a valid
  sample with ``has_fix`` False, not an error;
* errors: :class:`NmeaChecksumError` (checksum does not match, or missing when
  required), :class:`NmeaFieldError` (a field that cannot be read or is out of
  range), :class:`NmeaError` for the rest (not a sentence); all are ``NmeaError``,
  so a caller that only counts bad sentences (the recorder) catches that one.
  A sentence with no checksum is accepted only with ``require_checksum=False``
  (the importer: some loggers strip it); a checksum that is there must match.
* sentence types that parse but carry none of the above return a sample with only
  ``kind`` (and ``talker``) set.
"""

from __future__ import annotations

import datetime as _dt
import math
import re
from functools import lru_cache
from typing import NamedTuple

from .._jit import jitable
from ..model.frames import ssa

_NS = 1_000_000_000
_DAY_NS = 86_400 * _NS
_KNOT_MPS = 1852.0 / 3600.0
_HEAD = re.compile(r"[A-Z0-9]{2,8}")


class NmeaError(ValueError):
    """A sentence that cannot be used; the message says why."""


class NmeaChecksumError(NmeaError):
    """The checksum does not match the sentence (or is missing where it is required)."""


class NmeaFieldError(NmeaError):
    """A sentence whose field cannot be read or is out of range."""


class NmeaSample(NamedTuple):
    """What one sentence says. Fields a sentence type does not carry are None.

    Immutable; a NamedTuple rather than a frozen dataclass because one is made per
    sentence and it is three times cheaper to build (imports parse >100k lines/s).
    """

    kind: str                          # sentence type: GGA, RMC, HDT, ...
    talker: str = ""
    lat_deg: float | None = None       # position (only when the receiver has a fix)
    lon_deg: float | None = None
    alt_m: float | None = None         # WGS-84 ellipsoidal height (MSL + geoid separation); MSL without the separation
    fix_quality: int | None = None     # GGA quality; 0 = no fix
    satellites: int | None = None
    hdop: float | None = None
    has_fix: bool = False              # position fields are valid
    heading_rad: float | None = None
    reference: str | None = None       # "true" | "magnetic"
    sog_mps: float | None = None       # VTG / RMC speed over ground, m/s
    cog_rad: float | None = None       # VTG / RMC course over ground (true), rad in [-pi, pi)
    time_of_day_ns: int | None = None  # ns since UTC midnight
    date: _dt.date | None = None       # UTC date (RMC, ZDA)

    @property
    def gps_time_ns(self) -> int | None:
        """GPS (UTC) time, ns since the epoch, when the sentence carries date and time."""
        if self.date is None or self.time_of_day_ns is None:
            return None
        return date_ns(self.date) + self.time_of_day_ns


def checksum(body: str) -> str:
    """The two hex digits of the NMEA checksum of ``body`` (the text between $ and *)."""
    c = 0
    for ch in body.encode("ascii", "replace"):
        c ^= ch
    return f"{c:02X}"


def with_checksum(body: str) -> str:
    """``$body*CS`` — a complete sentence (no line ending)."""
    return f"${body}*{checksum(body)}"


def format_deg_min(value_deg: float, lat: bool, decimals: int = 6) -> tuple[str, str]:
    """Signed degrees -> an NMEA position field and its hemisphere letter.

    Parameters
    ----------
    value_deg : float
        Latitude or longitude, degrees (north / east positive).
    lat : bool
        Latitude (``ddmm.mmmm``, N/S) or longitude (``dddmm.mmmm``, E/W).
    decimals : int
        Decimals of the minutes.

    Returns
    -------
    (str, str)
        The field and ``N``/``S`` or ``E``/``W``. Minutes that round to 60 as printed
        (59.9999996 with 6 decimals) carry into the degree: ``0100.000000``, never
        ``0060.000000``, which a reader rejects.
    """
    a = abs(value_deg)
    d = int(a)
    m = (a - d) * 60.0
    if round(m, decimals) >= 60.0:
        d, m = d + 1, 0.0
    hemi = ("N" if value_deg >= 0 else "S") if lat else ("E" if value_deg >= 0 else "W")
    return f"{d:0{2 if lat else 3}d}{m:0{decimals + 3}.{decimals}f}", hemi


def date_ns(d: _dt.date) -> int:
    """ns since the epoch of the UTC midnight starting ``d``."""
    return (d - _dt.date(1970, 1, 1)).days * _DAY_NS


# -- fields ---------------------------------------------------------------------

def _tod_ns(value: str) -> int | None:
    """hhmmss(.sss) -> ns since midnight (None when empty)."""
    if not value:
        return None
    hh, mm, ss, frac = value[0:2], value[2:4], value[4:6], value[6:]
    if not (len(value) >= 6 and (hh + mm + ss).isdigit() and (not frac or (frac[0] == "." and frac[1:].isdigit()))):
        raise NmeaFieldError(f"bad time of day {value!r}")
    h, m, s = int(hh), int(mm), int(ss)
    if not (h < 24 and m < 60 and s < 61):  # 60: leap second
        raise NmeaFieldError(f"time of day {value!r} out of range")
    return ((h * 60 + m) * 60 + s) * _NS + int((frac[1:] + "000000000")[:9] if frac else 0)


@lru_cache(maxsize=64)
def _date(value: str) -> _dt.date | None:
    """ddmmyy -> date (None when empty); two-digit years as ``%y`` (1969-2068)."""
    if not value:
        return None
    if len(value) == 6 and value.isdigit():
        yy = int(value[4:6])
        try:
            return _dt.date(yy + (2000 if yy < 69 else 1900), int(value[2:4]), int(value[0:2]))
        except ValueError:
            pass
    raise NmeaFieldError(f"bad date {value!r}")


def _float(x: str, what: str) -> float | None:
    if not x:
        return None
    try:
        v = float(x)
    except ValueError:
        raise NmeaFieldError(f"bad {what} {x!r}") from None
    if not math.isfinite(v):
        raise NmeaFieldError(f"bad {what} {x!r}")
    return v


def _int(x: str, what: str) -> int | None:
    if not x:
        return None
    try:
        return int(x)
    except ValueError:
        raise NmeaFieldError(f"bad {what} {x!r}") from None


def _dm(value: str, width: int, what: str) -> float:
    """(d)ddmm.mmmm -> degrees (unsigned)."""
    k = value.find(".")
    k = len(value) if k < 0 else k
    d, m = value[:k - 2], value[k - 2:]
    if k < 2 or not (d == "" or d.isdigit()) or len(d) > width:
        raise NmeaFieldError(f"bad {what} {value!r}")
    minutes = _float(m, what)
    if minutes is None or not (0.0 <= minutes < 60.0):
        raise NmeaFieldError(f"bad {what} {value!r}")
    return int(d or 0) + minutes / 60.0


def _position(lat: str, ns: str, lon: str, ew: str) -> tuple[float, float] | None:
    """Signed degrees, or None when the fields are empty (no fix)."""
    if not lat or not lon:
        return None
    if ns not in ("N", "S") or ew not in ("E", "W"):
        raise NmeaFieldError(f"bad hemisphere {ns!r}/{ew!r}")
    la, lo = _dm(lat, 2, "latitude"), _dm(lon, 3, "longitude")
    if not (la <= 90.0 and lo <= 180.0):
        raise NmeaFieldError(f"position {lat}{ns} {lon}{ew} out of range")
    return (-la if ns == "S" else la), (-lo if ew == "W" else lo)


def _angle(value: str, what: str) -> float:
    """Degrees in [0, 360] -> rad wrapped to [-pi, pi)."""
    h = _float(value, what)
    if h is None:
        raise NmeaFieldError(f"{what} empty")
    if not (0.0 <= h <= 360.0):
        raise NmeaFieldError(f"{what} {h} out of range [0, 360]")
    return float(ssa(math.radians(h)))


def _signed(value: str, direction: str, what: str) -> float:
    """Deviation / variation in degrees, east positive (empty -> 0)."""
    v = _float(value, what) or 0.0
    if direction == "W":
        return -v
    if direction not in ("E", ""):
        raise NmeaFieldError(f"bad {what} direction {direction!r}")
    return v


def _rmc_velocity(kn: str, course: str) -> tuple[float | None, float | None]:
    """RMC speed over ground (knots -> m/s) and course (deg -> rad); None for a field that is
    empty or unreadable (a bad speed does not cost the sentence its position)."""
    try:
        v = _float(kn, "speed over ground")
        sog = v * _KNOT_MPS if v is not None and v >= 0 else None
    except NmeaFieldError:
        sog = None
    try:
        cog = _angle(course, "course") if course else None
    except NmeaFieldError:
        cog = None
    return sog, cog


# -- sentences ------------------------------------------------------------------

_PAD = [""] * 14


def _split(text: str, require_checksum: bool) -> tuple[str, str, list[str]]:
    """(talker, kind, fields) of a sentence whose checksum holds."""
    line = text.strip()
    if line[:1] not in ("$", "!"):
        raise NmeaError("does not start with $")
    star = line.rfind("*")
    if star < 0:
        if require_checksum:
            raise NmeaChecksumError("checksum missing")
        body = line[1:]
    else:
        body = line[1:star]
        cs = line[star + 1:]
        if cs != checksum(body) and cs.strip().upper() != checksum(body):
            raise NmeaChecksumError("checksum does not match")
    parts = body.split(",")
    head = parts[0]
    if len(parts) < 2 or not _HEAD.fullmatch(head):
        raise NmeaError(f"bad sentence head {head[:10]!r}")
    parts[0:1] = ()
    parts += _PAD
    if len(head) == 5 and head[0] != "P":
        return head[:2], head[2:], parts
    return "", head, parts


def parse_sentence(text: str, *, require_checksum: bool = True) -> NmeaSample:
    """One sentence (``$...*CS``, line ending optional) -> :class:`NmeaSample`."""
    talker, kind, f = _split(text, require_checksum)
    if kind == "GGA":
        # time, lat, N/S, lon, E/W, quality, satellites, HDOP, altitude MSL, M, geoid separation, M
        tod = _tod_ns(f[0])
        q = _int(f[5], "fix quality")
        sats, hdop = _int(f[6], "satellite count"), _float(f[7], "HDOP")
        pos = _position(f[1], f[2], f[3], f[4]) if q else None
        if pos is None:
            return NmeaSample(kind, talker, fix_quality=q or 0, satellites=sats, hdop=hdop, time_of_day_ns=tod)
        alt, sep = _float(f[8], "altitude"), _float(f[10], "geoid separation")
        if alt is not None and sep is not None:
            alt += sep
        return NmeaSample(kind, talker, lat_deg=pos[0], lon_deg=pos[1], alt_m=alt, fix_quality=q,
                          satellites=sats, hdop=hdop, has_fix=True, time_of_day_ns=tod)
    if kind == "RMC":
        # time, status, lat, N/S, lon, E/W, SOG kn, COG, date, variation, E/W, mode
        tod, date = _tod_ns(f[0]), _date(f[8])
        pos = _position(f[2], f[3], f[4], f[5]) if f[1] == "A" else None
        if pos is None:
            return NmeaSample(kind, talker, time_of_day_ns=tod, date=date)
        sog, cog = _rmc_velocity(f[6], f[7])
        return NmeaSample(kind, talker, lat_deg=pos[0], lon_deg=pos[1], has_fix=True, sog_mps=sog, cog_rad=cog,
                          time_of_day_ns=tod, date=date)
    if kind == "GLL":
        # lat, N/S, lon, E/W, time, status (absent before NMEA 2.3: valid), mode
        tod = _tod_ns(f[4])
        pos = _position(f[0], f[1], f[2], f[3]) if f[5] in ("A", "") else None
        if pos is None:
            return NmeaSample(kind, talker, time_of_day_ns=tod)
        return NmeaSample(kind, talker, lat_deg=pos[0], lon_deg=pos[1], has_fix=True, time_of_day_ns=tod)
    if kind == "ZDA":
        # time, day, month, year, local zone hours, minutes
        tod = _tod_ns(f[0])
        d, mo, y = _int(f[1], "day"), _int(f[2], "month"), _int(f[3], "year")
        if None in (y, mo, d):
            return NmeaSample(kind, talker, time_of_day_ns=tod)
        try:
            date = _dt.date(y, mo, d)
        except ValueError:
            raise NmeaFieldError(f"bad date {y}-{mo}-{d}") from None
        return NmeaSample(kind, talker, time_of_day_ns=tod, date=date)
    if kind == "HDT":
        return NmeaSample(kind, talker, heading_rad=_angle(f[0], "heading"), reference="true")
    if kind == "HDM":
        return NmeaSample(kind, talker, heading_rad=_angle(f[0], "heading"), reference="magnetic")
    if kind == "HDG":
        # magnetic sensor heading, deviation, E/W, variation, E/W
        h = _angle(f[0], "heading")
        dev = math.radians(_signed(f[1], f[2], "deviation"))
        if f[3]:
            var = math.radians(_signed(f[3], f[4], "variation"))
            return NmeaSample(kind, talker, heading_rad=float(ssa(h + dev + var)), reference="true")
        return NmeaSample(kind, talker, heading_rad=float(ssa(h + dev)), reference="magnetic")
    if kind == "VTG":
        # COG true, T, COG magnetic, M, SOG kn, N, SOG km/h, K, mode; before NMEA 2.3 the
        # unit letters may be missing: COG true, COG magnetic, SOG kn, SOG km/h
        if f[1] == "T" or f[5] == "N" or f[7] == "K":
            cog, kn, kmh = f[0], f[4], f[6]
        else:
            cog, kn, kmh = f[0], f[2], f[3]
        v_kn, v_kmh = _float(kn, "speed over ground"), _float(kmh, "speed over ground")
        sog = v_kn * _KNOT_MPS if v_kn is not None else (v_kmh / 3.6 if v_kmh is not None else None)
        if sog is not None and sog < 0:
            raise NmeaFieldError(f"speed over ground {sog} < 0")
        return NmeaSample(kind, talker, sog_mps=sog, cog_rad=_angle(cog, "course") if cog else None)
    return NmeaSample(kind, talker)


@jitable
def resolve_time_of_day(time_of_day_ns: int, reference_ns: int) -> int:
    """Place a UTC time of day on the day that puts it nearest ``reference_ns``.

    For sentences without a date (GGA, GLL). The recorder's reference is the receive
    time corrected by the clock offset; the importer's is the previous sentence's
    time. Either way a midnight roll-over lands on the right day. Callable from compiled
    kernels too (the importer's fast path).
    """
    day0 = (reference_ns // _DAY_NS) * _DAY_NS
    best = day0 - _DAY_NS + time_of_day_ns
    for d in (day0, day0 + _DAY_NS):   # the earlier day on a tie
        cand = d + time_of_day_ns
        if abs(cand - reference_ns) < abs(best - reference_ns):
            best = cand
    return int(best)


# -- one fix per epoch ---------------------------------------------------------------

POSITION_PRIORITY = {"GGA": 0, "RMC": 1, "GLL": 2}   # the best sentence for a fix first


class FixSelector:
    """One position fix per epoch, from the best valid sentence: GGA, else RMC, else GLL.

    The rule the recorder and the importer share. Receivers send several position
    sentences per epoch (same UTC time of day); only valid fixes (``has_fix``) are
    offered, so a corrupt or no-fix GGA leaves the epoch's RMC (or GLL) to give the fix.

    When the winner is known: a sentence of the best kind the source sent in earlier
    epochs within ``window_ns`` (GGA at the start, before anything is known) wins at once and is
    returned by :meth:`offer`; a lesser one is held until a better one of the same epoch
    replaces it, or the epoch ends (a position sentence with another time of day,
    :meth:`release_older`, :meth:`flush`), and is returned then. A sentence without a
    time of day is an epoch of its own. Items are whatever the caller passes (returned
    as they were given); times are the caller's clock (ns).

    Parameters
    ----------
    window_ns : int
        How long a sentence kind the source sent counts as "sent by this source", ns.
    """

    def __init__(self, window_ns: int = 2 * _NS):
        self.window_ns = int(window_ns)
        self._seen: dict[str, tuple] = {}   # kind -> (caller time, time of day) it was last offered
        self._epoch: int | None = None      # time of day of the current epoch
        self._held = None                   # (priority, t_ns, item) waiting for a better sentence
        self._done = False                  # the current epoch's fix was returned

    def offer(self, sample: NmeaSample, t_ns: int, item) -> list:
        """Offer a valid position sentence (GGA, RMC or GLL with ``has_fix``) received at ``t_ns``.

        Returns the items whose fix is decided now, in order (none, this one, the held
        one of the previous epoch, or both).
        """
        prio = POSITION_PRIORITY[sample.kind]
        tod = sample.time_of_day_ns
        # the best kind this source sent lately, in earlier epochs (GGA while nothing is known)
        expected = min((POSITION_PRIORITY[k] for k, (seen, epoch) in self._seen.items()
                        if t_ns - seen < self.window_ns and (epoch is None or epoch != tod)), default=0)
        self._seen[sample.kind] = (t_ns, tod)
        out = []
        if tod is None or tod != self._epoch:
            out += self._end_epoch()
            self._epoch = tod
        if self._done:
            return out                       # this epoch's fix is decided: a later sentence adds nothing
        if self._held is None or prio < self._held[0]:
            self._held = (prio, t_ns, item)
        if self._held[0] <= expected or tod is None:
            out += self._end_epoch()
            self._done = True
        return out

    def same_epoch(self, sample: NmeaSample) -> bool:
        """``sample`` belongs to the epoch of the last offered sentence."""
        return sample.time_of_day_ns is not None and sample.time_of_day_ns == self._epoch

    def release_older(self, t_ns: int) -> list:
        """The held item if it was offered before ``t_ns`` (a live source's epoch is over by then)."""
        if self._held is not None and self._held[1] < t_ns:
            out = self._end_epoch()
            self._done = True
            return out
        return []

    def flush(self) -> list:
        """The held item, if any (end of the stream)."""
        out = self._end_epoch()
        self._done = True
        return out

    def _end_epoch(self) -> list:
        held, self._held = self._held, None
        self._done = False
        return [] if held is None else [held[2]]
