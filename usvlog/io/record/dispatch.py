"""Lines from live sources -> recorder samples: NMEA 0183 sentences and JSON lines.

:class:`LineInput` is the part of :class:`~usvlog.io.record.recorder.Recorder` that
reads text: every line is kept raw (``/raw/nmea``, ``/raw/json``, valid or not) and
what can be used goes to the canonical channels through the recorder's sample
methods (``gnss``, ``heading``, ``thrust``, ``event``, ``write``).
"""

from __future__ import annotations

import math

import orjson

from ...errors import InputError, StorageError
from ...log.channels import registered_topics
from ..nmea import POSITION_PRIORITY, NmeaError, parse_sentence, resolve_time_of_day
from .topics import TOPIC_QUALITY, TOPIC_RAW_JSON, TOPIC_RAW_NMEA, TOPIC_STATUS


class LineInput:
    """NMEA and JSON line input of the recorder (a mixin: the host provides the samples API)."""

    def nmea(self, text: str, *, source: str = "nmea", t_ns: int | None = None):
        """One NMEA 0183 sentence as received.

        Kept in ``/raw/nmea``; positions, headings, fix quality and GPS time go to their
        canonical channels. Parsed by :func:`usvlog.io.nmea.parse_sentence` (as the file
        importer does), checksum required; a time of day without a date is placed nearest
        the receive time minus the source's clock offset.

        Parameters
        ----------
        text : str
            The sentence, without line ending.
        source : str
            Source name (counters, clock offset, ``/raw/nmea``).
        t_ns : int, optional
            Receive time, ns since the Unix epoch (default: now).

        Returns
        -------
        sample or None
            The parsed sample; None when malformed, whatever the reason (counted as
            garbage, still kept raw).
        """
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
        kind = s.kind if s is not None else guess_kind(text)
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
        if s.has_fix and s.kind in POSITION_PRIORITY:
            # one fix per epoch, from its best valid sentence (GGA, else RMC, else GLL)
            for fix in src.fixes.offer(s, t, (s, t, stamp, source)):
                self._write_fix(*fix)
        if s.heading_rad is not None:
            self.heading(s.heading_rad, s.reference, t_ns=t, source=source, _counted=True)
        return s

    def _write_fix(self, s, t: int, stamp: int | None, source: str) -> None:
        self.gnss(s.lat_deg, s.lon_deg, math.nan if s.alt_m is None else s.alt_m, t_ns=t,
                  stamp_ns=stamp, source=source, _counted=True)

    def _release_fixes(self, before_ns: int | None) -> None:
        """Write the fixes held for a better sentence of their epoch that did not come
        (every held one with ``before_ns`` None: closing)."""
        for src in list(self._sources.values()):
            for fix in (src.fixes.flush() if before_ns is None else src.fixes.release_older(before_ns)):
                self._write_fix(*fix)

    def json_line(self, text: str, *, source: str = "json", t_ns: int | None = None) -> bool:
        """One JSON line (see docs/recording.md for the message forms).

        Parameters
        ----------
        text : str
            The line, without line ending.
        source : str
            Source name (counters, clock offset, ``/raw/json``).
        t_ns : int, optional
            Receive time, ns since the Unix epoch (default: now).

        Returns
        -------
        bool
            True when used; a line that cannot be used is counted as garbage and kept in
            ``/raw/json``.
        """
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


def guess_kind(text: str) -> str:
    """The sentence type of a malformed NMEA line.

    Parameters
    ----------
    text : str
        The line.

    Returns
    -------
    str
        ``GGA``, ``RMC``, ... when its head looks like a sentence's, else "".
    """
    head = text.strip()[1:].split(",", 1)[0] if text.strip().startswith(("$", "!")) else ""
    return head[2:] if len(head) == 5 and head.isalnum() else ""
