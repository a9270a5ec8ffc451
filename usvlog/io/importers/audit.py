"""Sensor health audit at import: duplicates, rate, gaps, stuck and dead channels, time base.

The :class:`~usvlog.io.importers.core.Assembler` feeds every role stream through one
:class:`HealthAudit`, a batch at a time, so memory stays flat: per channel it keeps
counters, a histogram of the intervals (0.1 ms bins), the stamp offsets (1 ms bins) and
a few running values. What needs the whole run (is a channel dead?) is decided at
:meth:`HealthAudit.finish`; the Assembler holds back only the frames of a channel that
could still be dead (one whose values have not moved yet) and writes them then, under
``/raw/...`` when the channel is dead.

The checks (thresholds are the module constants):

* **republished duplicates**, collapsed (dropped and counted): a sample whose own sensor
  stamp (``stamp_ns``, when it differs from the record time) equals one of the
  :data:`DUP_STAMP_DEPTH` samples before it in the stream; and a GNSS fix whose
  latitude, longitude and altitude are exactly those of the fix before it, less than
  :data:`DUP_PAYLOAD_WINDOW_S` later, when the copied fix had moved at least
  :data:`DUP_PAYLOAD_MOVE_M` from the fix before it (a still receiver repeats its fix
  legitimately, so copies of the very first fix are kept; scalar streams repeat values
  legitimately, so the payload rule is for fixes only);
* **rate, jitter and real gaps**, after the collapse: nominal rate from the median
  interval, jitter the standard deviation of the intervals that are not gaps, gaps the
  intervals longer than :data:`GAP_FACTOR` x the median;
* **stuck values**: the longest stretch (s) over which a channel repeats exactly the
  same value;
* **dead channels**: a heading whose unwrapped span stays under
  :data:`HEADING_STILL_DEG` while the GNSS track turns through at least
  :data:`TRACK_TURN_DEG`; a yaw rate that never changes while the track turns; a
  position that never changes (exactly) while thrust is applied for at least
  :data:`THRUST_APPLIED_S`. A position that moves less than :data:`POSITION_STILL_M`
  under thrust is *suspect* (a moored bollard test looks the same) and kept;
* **heading mounting offset**: heading - course over ground on the straight runs of the
  GNSS track, constant across courses (:func:`usvlog.model.heading_offset.detect_heading_offset`
  on fixes and headings thinned to one per :data:`OFFSET_SAMPLE_S`);
* **time base** (``utc``; ``boot`` for a flight log's boot clock or ``relative`` for a
  relative time column, with what it was counted from) and the offset
  between each sensor's own stamps and the log time (median, min, max, s).

The record (:meth:`HealthAudit.finish`, stored as JSON text in the import's provenance
record under the key ``health``; read it back with :func:`health_of`)::

    {"version": 1,
     "time_base": "utc" | "boot" | "relative",  "time_counted_from": str | None,
     "keep_dead": bool,
     "track_turn_deg": float | None,   # total turning of the GNSS track (deg)
     "thrust_applied_s": float,        # time with a non-zero thrust command (s)
     "dead": [topic, ...],             # channels judged dead (canonical topics)
     "suspect": [topic, ...],
     "thrust": {"unit", "range", "reason", "direction_flag", "force_scale"} | None,
     "heading_offset": {"decided", "offset_deg", "std_deg", "runs", "courses", "reason", ...,
                        "text": str, "note": str} | None,   # note: one line when decided
     "channels": {topic: {
         "records": int,               # samples the importer handed over
         "invalid": int,               # non-finite or negative-time samples
         "out_of_range": int,          # impossible values (skipped)
         "republished": int,           # duplicates collapsed (stamp + payload)
         "republished_same_stamp": int, "republished_same_payload": int,
         "time_disorder": int,         # record time not after the previous one
         "written": int,
         "rate_hz": float | None, "jitter_s": float | None,
         "gaps": int, "longest_gap_s": float | None,
         "own_stamps": bool,           # the sensor has its own stamps
         "stamp_offset_s": {"median", "min", "max"} | None,   # stamp - log time
         "stuck_longest_s": float,     # longest run of one exact value
         "status": "ok" | "suspect" | "dead",
         "why": str,                   # one line, empty when ok
         "written_as": topic}}}        # /raw/... for a dead channel (unless keep_dead)
"""

from __future__ import annotations

import math

import numpy as np

from ...log.summary import health_from_provenance
from ...model.heading_offset import detect_heading_offset

DUP_STAMP_DEPTH = 8
"""A sample whose own stamp equals one of this many samples before it is a republished copy."""
DUP_PAYLOAD_WINDOW_S = 0.9
"""A GNSS fix identical to the previous one less than this many s later is a republished copy."""
DUP_PAYLOAD_MOVE_M = 0.5
"""...and only when that fix moved at least this far (m) from the one before the copies."""
GAP_FACTOR = 3.0
"""An interval longer than this many median intervals is a gap."""
HEADING_STILL_DEG = 2.0
"""A heading whose unwrapped span stays under this many degrees has not moved."""
TRACK_TURN_DEG = 90.0
"""The GNSS track must turn at least this much (deg, summed) to judge a still heading dead."""
TRACK_LEG_M = 5.0
"""Legs of the track at least this long (m) give its course (smaller moves are GNSS noise)."""
POSITION_STILL_M = 1.0
"""A position spread (m) under this while thrust is applied is suspect."""
THRUST_APPLIED_S = 30.0
"""Thrust applied at least this long (s) makes a still position suspect (or dead when exact)."""
MIN_SAMPLES = 10
"""Channels with fewer samples are not judged."""
_DT_BIN_NS = 100_000            # interval histogram bin (0.1 ms)
_OFF_BIN_NS = 1_000_000         # stamp offset histogram bin (1 ms)
_M_PER_DEG = 111_320.0          # metres per degree of latitude (spherical, enough here)
_LEG_WINDOW = 64                # fixes first searched for the end of a track leg (doubled until found)

OFFSET_SAMPLE_S = 0.2
"""Fixes and headings kept for the mounting offset check: one per this many s (bounded memory)."""

RAW_PREFIX = "/raw"
DEAD_CAPABLE = ("gnss", "heading", "yaw_rate")
"""Streams that can be judged dead (and are held back while their values have not moved)."""


def raw_topic(topic: str) -> str:
    """Where a dead channel's samples go: ``/compass/heading`` -> ``/raw/compass/heading``."""
    return RAW_PREFIX + topic


class _Counts:
    """Integer values with counts, merged a batch at a time (bounded by the bin width)."""

    def __init__(self):
        self.parts: list[tuple[np.ndarray, np.ndarray]] = []
        self.n_parts_values = 0

    def add(self, v: np.ndarray) -> None:
        if len(v):
            self.parts.append(np.unique(v, return_counts=True))
            self.n_parts_values += len(self.parts[-1][0])
            if len(self.parts) > 16 or self.n_parts_values > 1 << 16:
                self.parts = [self.merged()]
                self.n_parts_values = len(self.parts[0][0])

    def merged(self) -> tuple[np.ndarray, np.ndarray]:
        if not self.parts:
            return np.zeros(0, np.int64), np.zeros(0, np.int64)
        v = np.concatenate([p[0] for p in self.parts])
        c = np.concatenate([p[1] for p in self.parts])
        u, inv = np.unique(v, return_inverse=True)
        return u, np.bincount(inv, weights=c, minlength=len(u)).astype(np.int64)


def _median_of(u: np.ndarray, c: np.ndarray) -> float:
    cum = np.cumsum(c)
    n = int(cum[-1])
    a = u[np.searchsorted(cum, (n - 1) // 2, side="right")]
    b = u[np.searchsorted(cum, n // 2, side="right")]
    return (float(a) + float(b)) / 2.0


class ChannelHealth:
    """Streaming health of one channel (see the module docstring for the checks)."""

    def __init__(self, stream: str, topic: str):
        self.stream = stream
        self.topic = topic
        self.records = 0
        self.invalid = 0
        self.out_of_range = 0
        self.rep_stamp = 0
        self.rep_payload = 0
        self.time_disorder = 0
        self.written = 0
        self._stamps = np.zeros(0, np.int64)      # the last DUP_STAMP_DEPTH stamps seen
        self._prev_payload: tuple | None = None   # (t_ns, values) of the previous valid sample
        self._last_t: int | None = None
        self._dt = _Counts()
        self._off = _Counts()
        self.own_stamps = False
        self._off_min: int | None = None
        self._off_max: int | None = None
        # stuck: the current run of one exact value
        self._run_val: tuple | None = None
        self._run_start: int | None = None
        self.stuck_longest_ns = 0
        # motion: heading/yaw-rate span, position bounding box
        self.lo = math.inf
        self.hi = -math.inf
        self._unwrapped = 0.0
        self._prev_angle: float | None = None
        self.lat = [math.inf, -math.inf]
        self.lon = [math.inf, -math.inf]
        self.distinct_values = 0   # 0, 1 or 2 (= more than one)
        self._first_val: tuple | None = None

    # -- duplicates --------------------------------------------------------------------
    def republished(self, t: np.ndarray, stamp: np.ndarray, payload: list[np.ndarray] | None) -> np.ndarray:
        """Mask of republished copies among valid samples (counted); updates the state.

        Parameters
        ----------
        t, stamp : ndarray of int64
            Record times and the sensor's own stamps (ns since the Unix epoch).
        payload : list of ndarray, optional
            Value columns compared for the payload rule (GNSS fixes), or None.
        """
        n = len(t)
        dup = np.zeros(n, bool)
        own = stamp != t
        if own.any():
            self.own_stamps = True
            hist = np.concatenate((self._stamps, stamp))
            h = len(self._stamps)
            pos = np.arange(n) + h
            for k in range(1, DUP_STAMP_DEPTH + 1):
                j = pos - k
                ok = j >= 0
                dup[ok] |= stamp[ok] == hist[j[ok]]
            dup &= own
            self._stamps = hist[-DUP_STAMP_DEPTH:]
        self.rep_stamp += int(dup.sum())
        if payload is not None and n:
            vals = np.column_stack([np.asarray(p, float) for p in payload])
            prev = np.empty_like(vals)
            prev[1:] = vals[:-1]
            prev_t = np.empty(n, np.int64)
            prev_t[1:] = t[:-1]
            if self._prev_payload is not None:
                prev_t[0], prev[0], moved0 = self._prev_payload
            else:
                prev_t[0], prev[0], moved0 = t[0], np.nan, False
            equal = np.all((vals == prev) | (np.isnan(vals) & np.isnan(prev)), axis=1)
            if self._prev_payload is None:
                equal[0] = False
            # a run of copies counts only when its value moved off the one before it (a
            # still receiver repeats its fix legitimately)
            dn = (vals[:, 0] - prev[:, 0]) * _M_PER_DEG
            de = (vals[:, 1] - prev[:, 1]) * _M_PER_DEG * np.cos(np.radians(vals[:, 0]))
            with np.errstate(invalid="ignore"):
                moved = np.hypot(dn, de) >= DUP_PAYLOAD_MOVE_M    # NaN (no fix before): not moved
            start = ~equal
            grp = np.maximum.accumulate(np.where(start, np.arange(n), -1))
            run_moved = np.where(grp >= 0, moved[np.maximum(grp, 0)], moved0)
            same = equal & run_moved & ((t - prev_t) < DUP_PAYLOAD_WINDOW_S * 1e9)
            self._prev_payload = (int(t[-1]), vals[-1].copy(), bool(run_moved[-1]))
            same &= ~dup
            self.rep_payload += int(same.sum())
            dup |= same
        return dup

    # -- kept samples --------------------------------------------------------------------
    def observe(self, t: np.ndarray, stamp: np.ndarray, values: list[np.ndarray]) -> None:
        """Take the samples written: intervals, stamp offsets, stuck runs, motion.

        Parameters
        ----------
        t, stamp : ndarray of int64
            Record times and own stamps (ns), in order, after every filter.
        values : list of ndarray
            The channel's value columns (heading rad, yaw rate rad/s, lat/lon deg, ...).
        """
        n = len(t)
        if not n:
            return
        self.written += n
        full = t if self._last_t is None else np.concatenate(([self._last_t], t))
        dt = np.diff(full)
        self._dt.add(np.round(dt[dt > 0] / _DT_BIN_NS).astype(np.int64))
        self._last_t = int(t[-1])
        off = stamp - t
        if (off != 0).any():
            self._off.add(np.round(off / _OFF_BIN_NS).astype(np.int64))
            lo, hi = int(off.min()), int(off.max())
            self._off_min = lo if self._off_min is None else min(self._off_min, lo)
            self._off_max = hi if self._off_max is None else max(self._off_max, hi)
        vals = np.column_stack([np.asarray(v, float) for v in values])
        self._stuck(t, vals)
        if self.stream == "gnss":
            lat, lon = vals[:, 0], vals[:, 1]
            self.lat = [min(self.lat[0], float(lat.min())), max(self.lat[1], float(lat.max()))]
            self.lon = [min(self.lon[0], float(lon.min())), max(self.lon[1], float(lon.max()))]
        elif self.stream == "heading":
            a = vals[:, 0]
            prev = a[0] if self._prev_angle is None else self._prev_angle
            d = np.diff(np.concatenate(([prev], a)))
            d = (d + math.pi) % (2 * math.pi) - math.pi
            u = self._unwrapped + np.cumsum(d)
            self._unwrapped = float(u[-1])
            self._prev_angle = float(a[-1])
            self.lo, self.hi = min(self.lo, float(u.min())), max(self.hi, float(u.max()))
        else:
            a = vals[:, 0]
            self.lo, self.hi = min(self.lo, float(a.min())), max(self.hi, float(a.max()))

    def _stuck(self, t: np.ndarray, vals: np.ndarray) -> None:
        n = len(t)
        if self._first_val is None:
            self._first_val = tuple(vals[0].tolist())
            self.distinct_values = 1
        if self.distinct_values == 1 and not np.all(vals == np.asarray(self._first_val)):
            self.distinct_values = 2
        change = np.ones(n, bool)
        if n > 1:
            change[1:] = np.any(vals[1:] != vals[:-1], axis=1)
        if self._run_val is not None:
            change[0] = tuple(vals[0].tolist()) != self._run_val
        last = np.maximum.accumulate(np.where(change, np.arange(n), -1))
        carried = self._run_start if self._run_start is not None else int(t[0])
        run_start = np.where(last >= 0, t[np.maximum(last, 0)], carried)
        self.stuck_longest_ns = max(self.stuck_longest_ns, int((t - run_start).max()))
        self._run_start = int(run_start[-1])
        self._run_val = tuple(vals[-1].tolist())

    # -- results ---------------------------------------------------------------------------
    def still(self) -> bool:
        """Whether the values have not moved so far (the channel could still be dead)."""
        if self.written == 0:
            return True
        if self.stream == "gnss":
            return self.spread_m() < POSITION_STILL_M
        if self.stream == "heading":
            return math.degrees(self.hi - self.lo) < HEADING_STILL_DEG
        if self.stream == "yaw_rate":
            return self.distinct_values <= 1
        return False

    def spread_m(self) -> float:
        """Diagonal (m) of the bounding box of the fixes written (0 without fixes)."""
        if self.written == 0:
            return 0.0
        mid = math.radians((self.lat[0] + self.lat[1]) / 2)
        dn = (self.lat[1] - self.lat[0]) * _M_PER_DEG
        de = (self.lon[1] - self.lon[0]) * _M_PER_DEG * math.cos(mid)
        return math.hypot(dn, de)

    def to_dict(self) -> dict:
        """This channel's part of the health record (see the module docstring)."""
        rate = jitter = longest = None
        gaps = 0
        u, c = self._dt.merged()
        if len(u):
            med = _median_of(u, c)
            rate = 1e9 / (med * _DT_BIN_NS) if med > 0 else None
            big = u > GAP_FACTOR * med
            gaps = int(c[big].sum())
            longest = float(u.max()) * _DT_BIN_NS / 1e9 if gaps else None
            ok = ~big
            if c[ok].sum() > 1:
                x = u[ok].astype(float) * _DT_BIN_NS / 1e9
                w = c[ok].astype(float)
                mean = float(np.sum(x * w) / w.sum())
                jitter = float(math.sqrt(max(np.sum(w * (x - mean) ** 2) / w.sum(), 0.0)))
        offset = None
        ou, oc = self._off.merged()
        if len(ou):
            offset = {"median": _median_of(ou, oc) * _OFF_BIN_NS / 1e9,
                      "min": self._off_min / 1e9, "max": self._off_max / 1e9}
        return {"records": self.records, "invalid": self.invalid, "out_of_range": self.out_of_range,
                "republished": self.rep_stamp + self.rep_payload, "republished_same_stamp": self.rep_stamp,
                "republished_same_payload": self.rep_payload, "time_disorder": self.time_disorder,
                "written": self.written, "rate_hz": rate, "jitter_s": jitter, "gaps": gaps,
                "longest_gap_s": longest, "own_stamps": self.own_stamps, "stamp_offset_s": offset,
                "stuck_longest_s": self.stuck_longest_ns / 1e9, "status": "ok", "why": "",
                "written_as": self.topic}


class TrackTurn:
    """Total turning (deg) of a GNSS track, from legs of at least :data:`TRACK_LEG_M`."""

    def __init__(self):
        self._anchor: tuple[float, float] | None = None
        self._coslat = 1.0
        self._course: float | None = None
        self.turn_rad = 0.0
        self.legs = 0

    def add(self, lat: np.ndarray, lon: np.ndarray) -> None:
        """The next fixes (deg), in time order."""
        lat = np.asarray(lat, float)
        lon = np.asarray(lon, float)
        if not len(lat):
            return
        if self._anchor is None:
            self._anchor = (float(lat[0]), float(lon[0]))
            self._coslat = math.cos(math.radians(float(lat[0])))
        coslat = self._coslat
        i, n = 0, len(lat)
        w = _LEG_WINDOW
        while i < n:
            a_lat, a_lon = self._anchor
            # the first fix at least TRACK_LEG_M from the anchor, searched in windows that double
            # until it is found: each fix is looked at O(1) times, not once per leg after it
            while True:
                hi = min(n, i + w)
                dn = (lat[i:hi] - a_lat) * _M_PER_DEG
                de = (lon[i:hi] - a_lon) * _M_PER_DEG * coslat
                far = np.flatnonzero(dn * dn + de * de >= TRACK_LEG_M ** 2)
                if len(far) or hi == n:
                    break
                w *= 2
            if not len(far):
                return
            j = int(far[0])
            w = max(_LEG_WINDOW, 2 * (j + 1))   # the next leg is likely as long as this one
            course = math.atan2(float(de[j]), float(dn[j]))
            if self._course is not None:
                self.turn_rad += abs((course - self._course + math.pi) % (2 * math.pi) - math.pi)
            self._course = course
            self.legs += 1
            self._anchor = (float(lat[i + j]), float(lon[i + j]))
            i += j + 1

    @property
    def turn_deg(self) -> float | None:
        """Total turning (deg), None with fewer than two legs."""
        return math.degrees(self.turn_rad) if self.legs >= 2 else None


class HeadingCourse:
    """GNSS positions and headings of an import, thinned to one per :data:`OFFSET_SAMPLE_S`,
    for the heading mounting offset check (:meth:`result`)."""

    def __init__(self):
        self.parts: dict[str, list[np.ndarray]] = {"gnss": [], "local": [], "heading": []}
        self._bin: dict[str, int] = {}
        self._origin: tuple[float, float] | None = None

    def observe(self, stream: str, t: np.ndarray, cols: dict) -> None:
        """Samples written of ``stream`` (``gnss``: lat/lon deg; ``local``: n/e m; ``heading``: rad)."""
        names = {"gnss": ("lat_deg", "lon_deg"), "local": ("n_m", "e_m"), "heading": ("heading_rad",)}.get(stream)
        if names is None or not len(t):
            return
        b = np.asarray(t, np.int64) // int(OFFSET_SAMPLE_S * 1e9)
        keep = np.ones(len(b), bool)
        keep[1:] = b[1:] != b[:-1]
        keep[0] = int(b[0]) != self._bin.get(stream)
        self._bin[stream] = int(b[-1])
        vals = [np.asarray(cols[c], float)[keep] for c in names]
        if stream == "gnss":
            if self._origin is None:
                self._origin = (float(vals[0][0]), float(vals[1][0])) if len(vals[0]) else None
            if self._origin is None:
                return
            coslat = math.cos(math.radians(self._origin[0]))
            vals = [(vals[0] - self._origin[0]) * _M_PER_DEG, (vals[1] - self._origin[1]) * _M_PER_DEG * coslat]
        self.parts[stream].append(np.column_stack([np.asarray(t, np.int64)[keep], *vals]))

    def result(self) -> dict | None:
        """The offset check as a JSON-ready dict (:meth:`HeadingOffset.to_dict` plus ``text`` and
        ``note``, the import report's line when an offset is found); None without fixes or headings."""
        pos = self.parts["gnss"] or self.parts["local"]
        if not pos or not self.parts["heading"]:
            return None
        g, h = np.concatenate(pos), np.concatenate(self.parts["heading"])
        t0 = min(int(g[0, 0]), int(h[0, 0]))
        found = detect_heading_offset((g[:, 0] - t0) * 1e-9, g[:, 1], g[:, 2], (h[:, 0] - t0) * 1e-9, h[:, 1])
        note = (f"heading: {found.describe()}; apply it with `usvlog estimate --heading-offset auto` or "
                "heading_offset_deg in the vessel file's [sensors]") if found.decided else ""
        return {**found.to_dict(), "text": found.describe(), "note": note}


class HealthAudit:
    """The health of every channel of one import, built a batch at a time.

    Parameters
    ----------
    topics : dict
        Stream -> canonical topic (``{"heading": "/compass/heading", ...}``).
    keep_dead : bool
        Write dead channels as data all the same (they are still flagged).
    """

    def __init__(self, topics: dict[str, str], *, keep_dead: bool = False):
        self.topics = dict(topics)
        self.keep_dead = keep_dead
        self.channels: dict[str, ChannelHealth] = {}
        self.track = TrackTurn()
        self.thrust_applied_ns = 0
        self._thrust_last: tuple[int, bool] | None = None
        self.thrust: dict | None = None
        self.heading_course = HeadingCourse()

    def channel(self, stream: str) -> ChannelHealth:
        """The :class:`ChannelHealth` of ``stream`` (made on first use)."""
        if stream not in self.channels:
            self.channels[stream] = ChannelHealth(stream, self.topics[stream])
        return self.channels[stream]

    def observe(self, stream: str, t: np.ndarray, stamp: np.ndarray, cols: dict) -> None:
        """Samples written of ``stream`` (after every filter), with their value columns."""
        values = {"gnss": ("lat_deg", "lon_deg"), "heading": ("heading_rad",), "yaw_rate": ("r_radps",),
                  "velocity": ("sog_mps",), "thrust": ("left", "right"), "local": ("n_m", "e_m")}[stream]
        self.channel(stream).observe(t, stamp, [cols[v] for v in values])
        self.heading_course.observe(stream, t, cols)
        if stream == "gnss":
            self.track.add(cols["lat_deg"], cols["lon_deg"])
        elif stream == "local":   # metres as degrees at the equator: the same courses
            self.track.add(np.asarray(cols["n_m"], float) / _M_PER_DEG, np.asarray(cols["e_m"], float) / _M_PER_DEG)
        elif stream == "thrust" and len(t):
            on = (np.asarray(cols["left"], float) != 0) | (np.asarray(cols["right"], float) != 0)
            full_t = t if self._thrust_last is None else np.concatenate(([self._thrust_last[0]], t))
            full_on = on if self._thrust_last is None else np.concatenate(([self._thrust_last[1]], on))
            dt = np.minimum(np.diff(full_t), 1_000_000_000)   # a hold longer than 1 s counts 1 s
            self.thrust_applied_ns += int(dt[full_on[:-1]].sum())
            self._thrust_last = (int(t[-1]), bool(on[-1]))

    def judge(self) -> dict[str, tuple[str, str]]:
        """Stream -> (status, why) for every channel; ``dead`` only for :data:`DEAD_CAPABLE`."""
        out = {}
        turn = self.track.turn_deg
        applied_s = self.thrust_applied_ns / 1e9
        for stream, ch in self.channels.items():
            status, why = "ok", ""
            if ch.written >= MIN_SAMPLES:
                if stream == "heading" and ch.still():
                    span = math.degrees(ch.hi - ch.lo)
                    if turn is not None and turn >= TRACK_TURN_DEG:
                        status = "dead"
                        why = (f"heading moved {span:.2f} deg in all while the GNSS track turned "
                               f"{turn:.0f} deg")
                    else:
                        status = "suspect"
                        why = (f"heading moved {span:.2f} deg in all (GNSS track turn "
                               f"{'unknown' if turn is None else f'{turn:.0f} deg'}: not enough to judge)")
                elif stream == "yaw_rate" and ch.still():
                    if turn is not None and turn >= TRACK_TURN_DEG:
                        status = "dead"
                        why = f"yaw rate constant at {ch.lo:g} rad/s while the GNSS track turned {turn:.0f} deg"
                    else:
                        status, why = "suspect", f"yaw rate constant at {ch.lo:g} rad/s"
                elif stream == "gnss" and ch.still() and applied_s >= THRUST_APPLIED_S:
                    if ch.distinct_values <= 1:
                        status = "dead"
                        why = f"position never changed while thrust was applied for {applied_s:.0f} s"
                    else:
                        status = "suspect"
                        why = (f"position moved {ch.spread_m():.2f} m while thrust was applied for "
                               f"{applied_s:.0f} s (moored?)")
            out[stream] = (status, why)
        return out

    def finish(self, *, time_base: str = "utc", time_counted_from: str | None = None) -> dict:
        """The health record (JSON-ready; layout in the module docstring).

        Parameters
        ----------
        time_base : str
            ``utc``, ``boot`` or ``relative``.
        time_counted_from : str, optional
            What relative times were counted from (``--start-utc``, the epoch).
        """
        verdict = self.judge()
        chans = {}
        dead, suspect = [], []
        for stream in sorted(self.channels, key=lambda s: self.topics[s]):
            ch = self.channels[stream]
            d = ch.to_dict()
            status, why = verdict[stream]
            d["status"], d["why"] = status, why
            if status == "dead":
                dead.append(ch.topic)
                if not self.keep_dead:
                    d["written_as"] = raw_topic(ch.topic)
            elif status == "suspect":
                suspect.append(ch.topic)
            chans[ch.topic] = d
        return {"version": 1, "time_base": time_base, "time_counted_from": time_counted_from,
                "keep_dead": self.keep_dead, "track_turn_deg": self.track.turn_deg,
                "thrust_applied_s": self.thrust_applied_ns / 1e9, "dead": dead, "suspect": suspect,
                "thrust": self.thrust, "channels": chans, "heading_offset": self.heading_course.result()}


def health_of(log) -> dict:
    """The sensor health record an import stored in a log, for later stages.

    Parameters
    ----------
    log : usvlog.log.fieldlog.FieldLog
        An imported log.

    Returns
    -------
    dict
        The record (layout in :mod:`usvlog.io.importers.audit`); ``{}`` for a log with
        none (made by the simulator or an older usvlog). ``health_of(log).get("dead")``
        lists the channels judged dead, ``["thrust"]["force_scale"]`` is ``"unknown"``
        when the commands could not be turned into forces.
    """
    return health_from_provenance(log.provenance) or {}
