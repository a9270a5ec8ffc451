"""The format-independent half of every importer: role streams -> canonical channels.

Each format reader yields *batches*: ``{stream: {column: array}}`` with ``stream`` one
of :data:`STREAMS` and the columns listed there (``t_ns`` is the record time,
``stamp_ns`` the source's own time stamp; when the source has only one, both are
equal). :class:`Assembler` turns batches into canonical frames, one batch at a time
(so memory stays flat), and counts every record it drops in an :class:`ImportReport`:

* GNSS fixes with NaN, out-of-range or (0, 0) latitude/longitude;
* samples with a non-finite value;
* samples whose record time is not after the previous kept sample of the same
  stream (backwards or duplicated time stamps).

* headings beyond +-360 deg and thrust commands outside their unit's range
  (:data:`~.thrust_guess.THRUST_LIMITS`; newtons beyond +-:data:`~.thrust_guess.THRUST_ABSURD_N`);
* republished copies of a sample (same sensor stamp, or a GNSS fix identical to the
  one before it): collapsed, see :mod:`usvlog.io.importers.audit`;
* held repeats a reader marked (a ``held`` column: sample-and-hold resampling, see
  :mod:`usvlog.io.importers.held`): collapsed and counted as ``{stream}_held_repeat``.

A stream that keeps less than :data:`USABLE_SHARE` of its samples (collapsed copies and
held repeats apart) makes the import unusable: :meth:`Assembler.shortfalls` says which.

Thrust commands that are not newtons go through the vessel's thruster map
(:meth:`usvlog.model.vessel.Thrusters.command_to_force`); the recorded commands and
their unit are kept, except ``counts``: they are written as normalized commands
(counts / full scale, the sign of a direction flag applied) and the unit and range
recorded go to the health record (``health["thrust"]``). A unit the reader guessed is
guessed again here, robustly (:func:`guess_thrust`), from the first
:data:`THRUST_GUESS_ROWS` commands once one is not zero (held back until then). The
datum is the first kept fix unless one is given.

Every stream also goes through the sensor health audit
(:class:`~usvlog.io.importers.audit.HealthAudit`); :meth:`Assembler.finish` gives the
frames held back while a channel could still be dead, under ``/raw/...`` for a dead one.

Pure numpy/pandas: no file is opened here (the sinks that write live in
``usvlog.io.importers.sink``).

Errors: the readers turn what they find wrong in a file into one-line
:class:`~usvlog.errors.InputError` / :class:`~usvlog.errors.FormatError` themselves,
by checking what they read. Exceptions of the third-party parsers they call
(pandas, rosbags, pymavlink, pyulog) are wrapped where the call is made, with
:func:`foreign` / :func:`guarded`, ``from`` the library's exception; anything else
(a bug in usvlog) propagates as it is.
"""

from __future__ import annotations

import contextlib
import math
from collections import Counter
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from ...errors import ConfigError, FormatError
from ...log.channels import channel_spec, frame_from_columns
from ...model.frames import Datum, ssa
from ...model.vessel import THRUST_UNITS, Vessel
from .audit import DEAD_CAPABLE, HealthAudit
from .thrust_guess import THRUST_GUESS_ROWS, THRUST_LIMITS, guess_thrust

# stream -> (topic, value columns that must be finite)
STREAMS: dict[str, tuple[str, tuple[str, ...]]] = {
    "gnss": ("/gnss/fix", ("lat_deg", "lon_deg")),
    "heading": ("/compass/heading", ("heading_rad",)),
    "thrust": ("/thrust/command", ("left", "right")),
    "yaw_rate": ("/imu/yaw_rate", ("r_radps",)),
    "velocity": ("/gnss/velocity", ("sog_mps",)),
    "local": ("/local/position", ("n_m", "e_m")),
}
QUALITY_TOPIC = "/gnss/quality"
"""GGA fix quality and HDOP of the fixes that carry them (``fix_quality``, ``hdop`` columns of the gnss stream)."""
_COV = ("cov_ee_m2", "cov_en_m2", "cov_eu_m2", "cov_ne_m2", "cov_nn_m2", "cov_nu_m2",
        "cov_ue_m2", "cov_un_m2", "cov_uu_m2")
_TWO_PI = 2.0 * math.pi
USABLE_SHARE = 0.5
"""A stream keeping less than this share of its samples (copies collapsed on purpose apart) is unusable."""
USABLE_MIN_SAMPLES = 10
"""Streams with fewer samples (copies apart) are not judged unusable."""
COLLAPSED = ("_republished", "_held_repeat")
"""Skip reasons that are collapsed copies, not losses."""


@dataclass
class ImportReport:
    """What an import did: records read, kept, skipped (by reason) and the guesses made."""

    source: str = ""
    format: str = ""
    records: int = 0                                    # source records looked at (rows, lines, messages)
    skipped: Counter = field(default_factory=Counter)   # reason -> count
    guesses: dict = field(default_factory=dict)         # what was guessed -> the guess
    mapping: dict = field(default_factory=dict)         # role -> source column/topic used
    notes: list = field(default_factory=list)
    counts: Counter = field(default_factory=Counter)    # topic -> samples written
    first_bad: dict = field(default_factory=dict)       # reason -> where the first one was
    health: dict | None = None                          # the sensor health record (audit.py)
    unusable: str | None = None                         # why the result is unusable (written with --force)
    propulsion: dict | None = None                      # commands outside the twin-thruster model

    def skip(self, reason: str, n: int = 1, where: str | None = None) -> None:
        """Count ``n`` records dropped for ``reason``; remember where the first one was.

        Parameters
        ----------
        reason : str
            Why they were dropped (``"gnss_nan"``, ``"csv_bad_value"``, ...): the key in
            :attr:`skipped`.
        n : int
            How many; nothing is recorded when ``n <= 0``.
        where : str, optional
            Where the first one of this reason was (``"line 12: ..."``); kept in
            :attr:`first_bad` only for the first call that gives one for ``reason``.
        """
        if n <= 0:
            return
        self.skipped[reason] += int(n)
        if where is not None and reason not in self.first_bad:
            self.first_bad[reason] = where

    def note(self, text: str) -> None:
        """Add a note for the user (shown once: a note already made is not repeated).

        Parameters
        ----------
        text : str
            One line, e.g. ``"altitude unknown for some fixes (e.g. RMC-only fixes): written as null"``.
        """
        if text not in self.notes:
            self.notes.append(text)

    def to_dict(self) -> dict:
        """The report as a JSON-ready dict (for ``--json`` and the log's provenance).

        Returns
        -------
        dict
            ``source``, ``format``, ``records``, ``skipped`` (reason -> count, sorted),
            ``first_bad``, ``guesses``, ``mapping``, ``notes``, ``channels`` (topic ->
            samples written, sorted), ``health`` (the sensor health record of
            :mod:`usvlog.io.importers.audit`, None before the import finished) and
            ``propulsion`` (commands the twin-thruster model does not describe, else None);
            ``unusable`` (why, one line) only for a result written with ``force`` although a
            sensor kept less than half of its samples.
        """
        return {"source": self.source, "format": self.format, "records": self.records,
                "skipped": dict(sorted(self.skipped.items())), "first_bad": dict(self.first_bad),
                "guesses": dict(self.guesses), "mapping": dict(self.mapping), "notes": list(self.notes),
                "channels": dict(sorted(self.counts.items())), "health": self.health,
                **({"unusable": self.unusable} if self.unusable else {}),
                "propulsion": self.propulsion}


def clock_offset_fallback(opts, report, what: str, first_ns: int | None = None) -> int:
    """UTC offset (ns) of a log's own clock when the log has no GPS time.

    With ``--start-utc`` the first sample (own-clock time ``first_ns``, ns) is placed at that
    time; without it the own clock is counted from the Unix epoch. Records the guess and a
    note: ``"no GPS time in the log: {what} counted from ..."``.

    Returns
    -------
    int
        ns to add to the log's own clock (ns) to get the log time.
    """
    report.guesses["time_base"] = "--start-utc" if opts.start_utc_ns else "1970-01-01T00:00:00Z"
    if opts.start_utc_ns:
        report.note(f"no GPS time in the log: {what} counted so that the first sample is at --start-utc")
        return int(opts.start_utc_ns) - int(first_ns or 0)
    report.note(f"no GPS time in the log: {what} counted from 1970-01-01T00:00:00Z")
    return 0


def text_column(n: int, value: str) -> np.ndarray:
    """``n`` times the one string ``value``, as an object array (a text column of a stream).

    ``np.full(n, value, dtype=object)`` makes a new ``str`` per element (from a numpy
    unicode scalar), ~20x slower on a batch; this fills in the one object.

    Parameters
    ----------
    n : int
        Length.
    value : str
        The text of every element.
    """
    a = np.empty(n, dtype=object)
    a.fill(value)
    return a


def listing(names, limit: int = 30, width: int = 40) -> str:
    """``a, b, c`` of names read from a file, on one line and printable (whitespace inside a
    name collapsed, unprintable and undecodable characters shown as ``?``, a name cut to ``width``
    characters)."""
    names = list(names)

    def show(x) -> str:
        s = "".join(c if c.isprintable() and c != "\ufffd" else "?" for c in " ".join(str(x).split()))
        return s if len(s) <= width else s[:width - 3] + "..."

    text = ", ".join(show(x) for x in names[:limit])
    return text + (f", ... ({len(names)} in all)" if len(names) > limit else "")


def foreign_error(path, what: str, err: BaseException) -> FormatError:
    """A one-line :class:`FormatError` for an exception a third-party reader raised on ``path``.

    Parameters
    ----------
    path : path-like
        The file being read (named first in the message).
    what : str
        What could not be done, with the channel/topic or time when known
        (``"not a readable ROS 1 bag"``, ``"unreadable message after t_ns 17..."``).
    err : BaseException
        The library's exception; raise the result ``from err``.
    """
    # one line, and never the file's raw bytes: the library's text with anything unprintable
    # shown as "?" (a damaged definition can put control characters into its message)
    text = "".join(c if c.isprintable() else "?" for c in " ".join(str(err).split()))[:200]
    return FormatError(f"{path}: {what} ({type(err).__name__}{': ' + text if text else ''})")


@contextlib.contextmanager
def foreign(path, what):
    """Wrap the exceptions of third-party parser calls on ``path`` in a :class:`FormatError`.

    Put only calls into the library inside (``AnyReader.open()``, ``ULog(...)``): those
    parsers have no single error type for a damaged or foreign file (rosbags raises its
    ``*Error`` classes but also ``AssertionError``, ``UnicodeDecodeError``, apsw's
    ``CorruptError``; pymavlink ``struct.error``, ``IndexError``, ...), so whatever the
    library raises is the file's fault; usvlog's own code stays outside, and a bug there
    propagates as itself. ``MemoryError`` is not a bad file and passes through.
    """
    try:
        yield
    except MemoryError:
        raise
    except Exception as err:
        raise foreign_error(path, what() if callable(what) else what, err) from err


def guarded(items: Iterable, path, what) -> Iterator:
    """Iterate a third-party iterator, wrapping its exceptions as :func:`foreign` does.

    Only the library's ``next()`` is guarded: what the caller does with each item (usvlog
    code) runs outside the ``try``. ``what`` is a text or a function returning one (called
    on failure, so it can say how far the reading got).
    """
    it = iter(items)
    while True:
        with foreign(path, what):
            try:
                item = next(it)
            except StopIteration:
                return
        yield item


def _time_filter(t: np.ndarray, last: int | None) -> tuple[np.ndarray, int, int]:
    """Keep samples strictly after every earlier one (and after ``last``)."""
    if len(t) == 0:
        return np.zeros(0, bool), 0, 0
    prev = np.empty(len(t), dtype=np.int64)
    prev[0] = np.iinfo(np.int64).min if last is None else last
    if len(t) > 1:
        prev[1:] = np.maximum.accumulate(t[:-1])
        if last is not None:
            np.maximum(prev, last, out=prev)
    keep = t > prev
    return keep, int(np.sum(t < prev)), int(np.sum(t == prev))


class Assembler:
    """Turns role batches into canonical frames, counting what it drops and auditing each channel.

    Parameters
    ----------
    report : ImportReport
        Filled with what is dropped, guessed and written.
    vessel : usvlog.model.vessel.Vessel, optional
        Its thruster map turns commands that are not newtons into forces (N).
    datum : usvlog.model.frames.Datum, optional
        Origin of the local frame; the first kept fix when None.
    thrust_unit : str, optional
        The unit the user gave (``--thrust-unit``); None when the reader's unit is
        either known from the format or guessed (then guessed again here).
    thrust_range : tuple of float, optional
        ``(lo, hi)`` of ``counts`` commands (``--thrust-range``); implies ``counts``
        when no unit is given.
    keep_dead : bool
        Write channels judged dead as data all the same (still flagged).
    """

    def __init__(self, report: ImportReport, *, vessel: Vessel | None = None, datum: Datum | None = None,
                 thrust_unit: str | None = None, thrust_range: tuple[float, float] | None = None,
                 keep_dead: bool = False):
        self.report = report
        self.vessel = vessel
        self.datum = datum
        self.local_geo = datum is not None   # a given datum is the origin of local positions
        self.thrust_unit = thrust_unit
        self.thrust_range = None if thrust_range is None else (float(thrust_range[0]), float(thrust_range[1]))
        self.keep_dead = keep_dead
        self.audit = HealthAudit({s: STREAMS[s][0] for s in STREAMS}, keep_dead=keep_dead)
        self.health: dict | None = None
        self._last: dict[str, int] = {}
        self._thrust_forces_known: bool | None = None
        self._held: dict[str, list[pd.DataFrame]] = {}     # frames of channels that could still be dead
        self._thrust_pending: list[dict] = []                # thrust columns waiting for the unit guess
        self._thrust: dict | None = None                     # unit, lo, hi, reason, full scale, guessed
        self._dir_sign: bool | None = None                   # direction flags: +-1 signs (else 0/1)
        self._quality: list[pd.DataFrame] = []               # /gnss/quality frames not yet returned
        self.held: Counter = Counter()                       # stream -> held repeats dropped

    def process(self, batch: dict[str, dict[str, np.ndarray]]) -> dict[str, pd.DataFrame]:
        """Turn one batch of role streams into canonical frames.

        Drops (and counts in the report) samples with a negative time, non-finite values,
        GNSS fixes with NaN, out-of-range or (0, 0) latitude/longitude, negative speeds,
        headings beyond +-360 deg, thrust commands outside their unit's range,
        republished copies (same sensor stamp, or a fix identical to the one before it)
        and samples not later than the previous kept one of the same stream (kept across
        batches). Headings and courses are wrapped to [-pi, pi) rad; thrust commands that
        are not newtons are turned into forces (N) with the vessel's thruster map (forces
        NaN, and a note, without a vessel whose map is linear or quadratic). The datum is
        set from the first kept fix when none was given. Heading, GNSS and yaw-rate frames
        are held back while their values have not moved (the channel could be dead) and
        come out of a later call or of :meth:`finish`.

        Parameters
        ----------
        batch : dict
            ``{stream: {column: array}}``, streams and columns as in :data:`STREAMS`;
            ``t_ns`` (int64 ns since the Unix epoch) is required, ``stamp_ns`` defaults
            to it. Thrust may carry ``left_dir``/``right_dir`` direction flags (0 forward,
            non-zero reverse; or signs -1/+1 when the stream has negative flags).
            ``batch["raw"]`` is ``{"/raw/...": {column: array}}`` kept as it is.

        Returns
        -------
        dict
            Topic -> DataFrame indexed by ``t_ns`` in the channel's canonical columns;
            streams with nothing to write now are left out. :attr:`ImportReport.counts` is
            increased by the rows returned.

        Raises
        ------
        ConfigError
            A stream not in :data:`STREAMS`, or a thrust unit not in ``THRUST_UNITS``.
        """
        out = {}
        for stream, cols in batch.items():
            if stream == "raw":
                out.update(self._raw(cols))
                continue
            if stream not in STREAMS:
                raise ConfigError(f"unknown stream {stream!r}")
            if stream == "thrust":
                cols = self._thrust_ready(cols)
                if cols is None:
                    continue
            frame = self._stream(stream, cols)
            self._emit(stream, frame, out)
        if self._quality:   # the fix quality of the GNSS fixes written (NMEA GGA)
            q = self._quality[0] if len(self._quality) == 1 else pd.concat(self._quality)
            self._quality = []
            self.report.counts[QUALITY_TOPIC] += len(q)
            out[QUALITY_TOPIC] = q
        return out

    def _raw(self, topics: dict[str, dict[str, np.ndarray]]) -> dict[str, pd.DataFrame]:
        """Source data kept as it is under ``/raw/...`` (e.g. commands outside the model): a frame
        per topic, columns as given (``t_ns`` the index), nothing checked or dropped."""
        out = {}
        for topic, cols in topics.items():
            t = np.asarray(cols["t_ns"], np.int64)
            if len(t):
                out[topic] = frame_from_columns({k: v for k, v in cols.items() if k != "t_ns"}, t)
                self.report.counts[topic] += len(t)
        return out

    def _emit(self, stream: str, frame: pd.DataFrame | None, out: dict) -> None:
        topic = STREAMS[stream][0]
        if stream in DEAD_CAPABLE and self.audit.channel(stream).still():
            if frame is not None and len(frame):
                self._held.setdefault(stream, []).append(frame)
            return
        parts = self._held.pop(stream, [])
        if frame is not None and len(frame):
            parts.append(frame)
        if not parts:
            return
        f = parts[0] if len(parts) == 1 else pd.concat(parts)
        self.report.counts[topic] += len(f)
        out[topic] = f

    def finish(self) -> dict[str, pd.DataFrame]:
        """The frames still held back, and the health record (:attr:`health`).

        Call once after the last :meth:`process`. A channel judged dead
        (:mod:`usvlog.io.importers.audit`) is returned under ``/raw/<topic>`` (unless
        ``keep_dead``), with a note; thrust commands still waiting for their unit guess
        are guessed from what there is.

        Returns
        -------
        dict
            Topic -> DataFrame, as :meth:`process` returns.
        """
        out: dict[str, pd.DataFrame] = {}
        if self._thrust_pending:
            cols = self._thrust_ready(None)
            if cols is not None:
                self._emit("thrust", self._stream("thrust", cols), out)
        tb = self.report.guesses.get("time_base") or self.report.guesses.get("start_utc")
        base = "utc" if not tb else "boot" if self.report.format in ("ulog", "dataflash") else "relative"
        self.health = self.audit.finish(time_base=base, time_counted_from=tb)
        self.health["thrust"] = self._thrust_record()
        self.report.health = self.health
        for stream, parts in self._held.items():
            topic = STREAMS[stream][0]
            ch = self.health["channels"].get(topic, {})
            dest = ch.get("written_as", topic)
            f = parts[0] if len(parts) == 1 else pd.concat(parts)
            if dest != topic:
                self.report.note(f"{topic} looks dead ({ch.get('why', '')}): written as {dest}, not as data "
                                 "(--keep-dead writes it as data)")
            elif ch.get("status") == "dead":
                self.report.note(f"{topic} looks dead ({ch.get('why', '')}): kept as data (--keep-dead)")
            self.report.counts[dest] += len(f)
            out[dest] = f
        self._held = {}
        thr = self.health["channels"].get(STREAMS["thrust"][0])
        if thr and self._thrust and thr["out_of_range"] > thr["written"]:
            th = self._thrust
            self.report.note(f"most thrust commands ({thr['out_of_range']} of {thr['records']}) are outside "
                             f"{th['lo']:g}..{th['hi']:g} {th['unit']}: is the unit right (--thrust-unit, "
                             "--thrust-range)?")
        if (self.health.get("heading_offset") or {}).get("note"):
            self.report.note(self.health["heading_offset"]["note"])
        for topic, ch in self.health["channels"].items():
            if ch["status"] == "suspect":
                self.report.note(f"{topic} suspect: {ch['why']}")
            if ch["republished"]:
                self.report.note(f"{topic}: {ch['republished']} republished copies collapsed")
        return out

    def shortfalls(self) -> list[dict]:
        """Streams that kept less than :data:`USABLE_SHARE` of their samples (call after :meth:`finish`).

        Republished copies and held repeats are collapsed on purpose, and fixes the receiver
        itself marks as no fix are honest gaps: none is counted as a sample. Streams with fewer
        than :data:`USABLE_MIN_SAMPLES` samples are not judged, nor thrust commands in a unit
        the user gave (written as asked, with the note that most are out of range).

        Returns
        -------
        list of dict
            One per such stream: ``topic``, ``kept``, ``of``, ``reason`` (the main skip
            reason, None if unknown), ``count`` (how many for it) and ``first`` (where its
            first one was, or None).
        """
        out = []
        for stream, (topic, _) in STREAMS.items():
            ch = (self.health or {}).get("channels", {}).get(topic)
            if not ch:
                continue
            if stream == "thrust" and (self.thrust_unit is not None or self.thrust_range is not None):
                continue   # the user gave the unit: written as asked, with a note when mostly out of range
            honest = self.report.skipped.get(f"{stream}_no_fix", 0)
            n = int(ch["records"]) - int(ch["republished"]) - int(self.held[stream]) - honest
            if n < USABLE_MIN_SAMPLES or ch["written"] >= USABLE_SHARE * n:
                continue
            lost = {k: v for k, v in self.report.skipped.items()
                    if k.startswith(stream + "_") and not k.endswith(COLLAPSED + ("_no_fix",))}
            main = max(lost, key=lost.get) if lost else None
            out.append({"topic": topic, "kept": int(ch["written"]), "of": n, "reason": main,
                        "count": lost.get(main, 0), "first": self.report.first_bad.get(main)})
        return out

    # -- thrust units --------------------------------------------------------------------
    def _thrust_ready(self, cols: dict | None) -> dict | None:
        """Thrust columns with their unit settled (None: held until a command is not zero)."""
        if self._thrust is None:
            if cols is not None:
                self._thrust_pending.append({k: np.asarray(v) for k, v in cols.items()})
            pend = self._thrust_pending
            given = self.thrust_unit
            if given is None and self.thrust_range is not None:
                given = "counts"
            reader_unit = None
            if pend and "unit" in pend[0] and len(pend[0]["unit"]):
                reader_unit = str(pend[0]["unit"][0])
            guessing = given is None and (reader_unit is None or "thrust_unit" in self.report.guesses)
            lr = [np.concatenate([np.asarray(p[c], float) for p in pend]) for c in ("left", "right")]
            informative = any(bool(np.any(np.isfinite(a) & (a != 0))) for a in lr)
            rows = sum(len(p["t_ns"]) for p in pend)
            if guessing and (not informative or rows < THRUST_GUESS_ROWS) and cols is not None:
                return None
            if given is not None or guessing:
                g = guess_thrust(*lr) if guessing or (given == "counts" and self.thrust_range is None) else None
                unit = given or g.unit
                if unit == "counts":
                    rng = self.thrust_range or (g.lo, g.hi)
                    reason = (g.reason if g is not None and g.unit == "counts" else
                              "--thrust-range" if self.thrust_range is not None else g.reason)
                else:
                    rng = THRUST_LIMITS[unit]
                    reason = g.reason if guessing else "--thrust-unit"
                if guessing:
                    self.report.guesses["thrust_unit"] = unit
                    self.report.note(f"thrust unit guessed: {unit} ({reason})")
            else:
                unit = reader_unit or "newton"
                if unit not in THRUST_UNITS:
                    raise ConfigError(f"thrust unit {unit!r} is not one of {', '.join(THRUST_UNITS)}")
                rng = self.thrust_range if unit == "counts" and self.thrust_range else THRUST_LIMITS.get(unit)
                reason = "from the format"
                if rng is None:
                    raise ConfigError("thrust commands in counts need --thrust-range LO:HI")
            if unit == "counts":
                self.report.guesses["thrust_range"] = f"{rng[0]:g}:{rng[1]:g}"
            self._thrust = {"unit": unit, "lo": float(rng[0]), "hi": float(rng[1]), "reason": reason,
                            "set": given is not None or not guessing}
            cols = {k: np.concatenate([np.asarray(p[k]) for p in pend]) for k in pend[0]} if pend else None
            self._thrust_pending = []
            if cols is None:
                return None
        cols = {k: np.asarray(v) for k, v in cols.items()}
        n = len(cols["t_ns"])
        cols["unit"] = text_column(n, self._thrust["unit"])
        return cols

    def _thrust_record(self) -> dict | None:
        if self._thrust is None:
            return None
        th = self._thrust
        known = self._thrust_forces_known
        return {"unit": th["unit"], "range": [th["lo"], th["hi"]], "reason": th["reason"],
                "direction_flag": None if self._dir_sign is None else ("sign" if self._dir_sign else "0/1"),
                "written_unit": "normalized" if th["unit"] == "counts" else th["unit"],
                "force_scale": "known" if th["unit"] == "newton" or known else "unknown"}

    def _thrust_values(self, cols: dict, keep: np.ndarray, ch) -> np.ndarray:
        """Range check (counted), direction flags and counts -> normalized; returns ``keep``."""
        th = self._thrust
        left = np.asarray(cols["left"], float)
        right = np.asarray(cols["right"], float)
        with np.errstate(invalid="ignore"):
            out = keep & ((left < th["lo"]) | (left > th["hi"]) | (right < th["lo"]) | (right > th["hi"]))
        n_out = int(out.sum())
        if n_out:
            i = int(np.flatnonzero(out)[0])
            self.report.skip("thrust_out_of_range", n_out,
                             where=f"t_ns {int(cols['t_ns'][i])}: {left[i]:g}, {right[i]:g} {th['unit']} "
                                   f"outside {th['lo']:g}..{th['hi']:g}")
            ch.out_of_range += n_out
        keep = keep & ~out
        for side, flag in (("left", "left_dir"), ("right", "right_dir")):
            if flag not in cols:
                continue
            f = np.asarray(cols[flag], float)
            if self._dir_sign is None:
                self._dir_sign = bool(np.any(f[np.isfinite(f)] < 0))
                self.report.guesses["thrust_direction_flag"] = (
                    "sign (-1 reverse, +1 forward)" if self._dir_sign else "0 forward, non-zero reverse")
            bad = keep & ~np.isfinite(f)
            self.report.skip("thrust_nan", int(bad.sum()))
            keep &= ~bad
            with np.errstate(invalid="ignore"):
                rev = (f < 0) if self._dir_sign else (f != 0)
            v = np.abs(left if side == "left" else right)
            signed = np.where(rev, -v, v)
            if side == "left":
                left = signed
            else:
                right = signed
        if th["unit"] == "counts":
            fs = max(abs(th["lo"]), abs(th["hi"]))
            left, right = left / fs, right / fs
            cols["unit"] = text_column(len(left), "normalized")
        cols["left"], cols["right"] = left, right
        return keep

    # -- one stream ------------------------------------------------------------------------
    def _stream(self, stream: str, cols: dict[str, np.ndarray]) -> pd.DataFrame | None:
        t = np.asarray(cols["t_ns"], dtype=np.int64)
        n = len(t)
        if n == 0:
            return None
        ch = self.audit.channel(stream)
        ch.records += n
        cols = {k: np.asarray(v) for k, v in cols.items()}
        cols.setdefault("stamp_ns", t)
        stamp = np.asarray(cols["stamp_ns"], dtype=np.int64)
        neg = t < 0
        self.report.skip(f"{stream}_time_negative", int(neg.sum()))
        keep = ~neg
        values = STREAMS[stream][1]
        if stream == "gnss":
            lat = np.asarray(cols["lat_deg"], float)
            lon = np.asarray(cols["lon_deg"], float)
            nan = ~(np.isfinite(lat) & np.isfinite(lon))
            with np.errstate(invalid="ignore"):
                rng = ~nan & ((np.abs(lat) > 90.0) | (np.abs(lon) > 180.0))
            zero = ~nan & (lat == 0.0) & (lon == 0.0)
            self.report.skip("gnss_nan", int((nan & keep).sum()))
            self.report.skip("gnss_out_of_range", int((rng & keep).sum()))
            self.report.skip("gnss_no_fix", int((zero & keep).sum()))
            ch.invalid += int(neg.sum() + (nan & keep).sum() + (zero & keep).sum())
            ch.out_of_range += int((rng & keep).sum())
            keep &= ~(nan | rng | zero)
        else:
            bad = np.zeros(n, bool)
            for c in values:
                bad |= ~np.isfinite(np.asarray(cols[c], float))
            self.report.skip(f"{stream}_nan", int((bad & keep).sum()))
            ch.invalid += int(neg.sum() + (bad & keep).sum())
            keep &= ~bad
            if stream == "velocity":
                with np.errstate(invalid="ignore"):
                    negv = keep & (np.asarray(cols["sog_mps"], float) < 0)
                self.report.skip("velocity_out_of_range", int(negv.sum()))
                ch.out_of_range += int(negv.sum())
                keep &= ~negv
            elif stream == "heading":
                with np.errstate(invalid="ignore"):
                    far = keep & (np.abs(np.asarray(cols["heading_rad"], float)) > _TWO_PI * (1 + 1e-9))
                if far.any():
                    i = int(np.flatnonzero(far)[0])
                    self.report.skip("heading_out_of_range", int(far.sum()),
                                     where=f"t_ns {int(t[i])}: heading {float(cols['heading_rad'][i]):.6g} rad "
                                           "(beyond +-360 deg)")
                ch.out_of_range += int(far.sum())
                keep &= ~far
            elif stream == "thrust":
                keep = self._thrust_values(cols, keep, ch)
        if "held" in cols:
            h = keep & np.asarray(cols["held"], bool)
            self.report.skip(f"{stream}_held_repeat", int(h.sum()))
            self.held[stream] += int(h.sum())
            keep &= ~h
        vi = np.flatnonzero(keep)
        payload = [cols[c][vi] for c in ("lat_deg", "lon_deg", "alt_m") if c in cols] if stream == "gnss" else None
        # a GNSS message's own fix time (when the reader has one: -1 where not) names the fix
        # better than its header stamp, which a republisher renews
        key = stamp[vi]
        if "fix_time_ns" in cols:
            ft = np.asarray(cols["fix_time_ns"], np.int64)[vi]
            key = np.where(ft >= 0, ft, key)
        dup = ch.republished(t[vi], key, payload)
        if dup.any():
            self.report.skip(f"{stream}_republished", int(dup.sum()))
            keep[vi[dup]] = False
        t_keep = t[keep]
        tk, back, dupt = _time_filter(t_keep, self._last.get(stream))
        self.report.skip(f"{stream}_time_backwards", back)
        self.report.skip(f"{stream}_time_duplicate", dupt)
        ch.time_disorder += back + dupt
        idx = np.flatnonzero(keep)[tk]
        if len(idx) == 0:
            return None
        self._last[stream] = int(t[idx[-1]])
        sel = {k: v[idx] for k, v in cols.items()}
        self.audit.observe(stream, sel["t_ns"].astype(np.int64), sel["stamp_ns"].astype(np.int64), sel)
        return getattr(self, f"_frame_{stream}")(sel)

    # -- per stream --------------------------------------------------------------------
    def _frame_gnss(self, c) -> pd.DataFrame:
        n = len(c["t_ns"])
        if self.datum is None:
            alt0 = float(c["alt_m"][0]) if "alt_m" in c and np.isfinite(c["alt_m"][0]) else 0.0
            self.datum = Datum(lat_deg=float(c["lat_deg"][0]), lon_deg=float(c["lon_deg"][0]), alt_m=alt0)
        alt = np.asarray(c.get("alt_m", np.full(n, np.nan)), float)
        if not np.isfinite(alt).all():
            # unknown stays unknown: LocationFix altitude is null then (the 3-DOF model never uses it)
            self.report.note("altitude unknown for some fixes (e.g. RMC-only fixes): written as null")
            alt = np.where(np.isfinite(alt), alt, np.nan)
        cols = {"stamp_ns": c["stamp_ns"].astype(np.int64),
                "frame_id": np.asarray(c["frame_id"] if "frame_id" in c else text_column(n, "gnss"), dtype=object),
                "lat_deg": c["lat_deg"].astype(float), "lon_deg": c["lon_deg"].astype(float), "alt_m": alt}
        for k in _COV:
            cols[k] = np.asarray(c.get(k, np.zeros(n)), float)
        cols["cov_type"] = np.asarray(c.get("cov_type", np.zeros(n, np.int64)), np.int64)
        if "fix_quality" in c:
            self._frame_quality(c)
        return frame_from_columns(cols, c["t_ns"], channel_spec("/gnss/fix"))

    def _frame_quality(self, c) -> None:
        """Hold the ``/gnss/quality`` records (GGA fix quality, HDOP) of the fixes written that
        have one (``fix_quality`` >= 0; an RMC-only fix has none): written by :meth:`process`."""
        q = np.asarray(c["fix_quality"], float)
        ok = np.isfinite(q) & (q >= 0)
        if not ok.any():
            return
        hdop = np.asarray(c.get("hdop", np.full(len(q), np.nan)), float)[ok]
        cols = {"stamp_ns": c["stamp_ns"][ok].astype(np.int64), "fix_quality": q[ok].astype(np.int64),
                "satellites": np.full(int(ok.sum()), -1, np.int64), "hdop": np.where(np.isfinite(hdop), hdop, np.nan)}
        self._quality.append(frame_from_columns(cols, c["t_ns"][ok], channel_spec(QUALITY_TOPIC)))

    def _frame_heading(self, c) -> pd.DataFrame:
        n = len(c["t_ns"])
        cols = {"stamp_ns": c["stamp_ns"].astype(np.int64), "heading_rad": ssa(c["heading_rad"]),
                "reference": np.asarray(c["reference"] if "reference" in c else text_column(n, "true"), dtype=object),
                "std_rad": np.asarray(c.get("std_rad", np.full(n, np.nan)), float)}
        return frame_from_columns(cols, c["t_ns"], channel_spec("/compass/heading"))

    def _frame_thrust(self, c) -> pd.DataFrame:
        n = len(c["t_ns"])
        left, right = c["left"].astype(float), c["right"].astype(float)
        unit = c.get("unit")
        units = np.asarray(unit if unit is not None else text_column(n, "newton"), dtype=object)
        fl = np.full(n, np.nan)
        fr = np.full(n, np.nan)
        for u in pd.unique(units):
            m = units == u
            if u == "newton":
                fl[m], fr[m] = left[m], right[m]
                continue
            if u not in THRUST_UNITS:
                raise ConfigError(f"thrust unit {u!r} is not one of {', '.join(THRUST_UNITS)}")
            thr = self.vessel.thrusters if self.vessel is not None else None
            if thr is None or thr.map == "identity":
                shown = self._thrust["unit"] if self._thrust else u
                self.report.note(f"thrust commands in {shown}: forces unknown (give a --vessel whose "
                                 "thruster map is linear or quadratic)")
                self._thrust_forces_known = False
                continue
            if self._thrust_forces_known is None:
                self._thrust_forces_known = True
            fl[m] = thr.command_to_force(left[m], u, side="left")
            fr[m] = thr.command_to_force(right[m], u, side="right")
        cols = {"stamp_ns": c["stamp_ns"].astype(np.int64), "left": left, "right": right,
                "unit": units, "thrust_left_n": fl, "thrust_right_n": fr}
        return frame_from_columns(cols, c["t_ns"], channel_spec("/thrust/command"))

    def _frame_yaw_rate(self, c) -> pd.DataFrame:
        cols = {"stamp_ns": c["stamp_ns"].astype(np.int64), "r_radps": c["r_radps"].astype(float)}
        return frame_from_columns(cols, c["t_ns"], channel_spec("/imu/yaw_rate"))

    def _frame_local(self, c) -> pd.DataFrame:
        n = len(c["t_ns"])
        cols = {"stamp_ns": c["stamp_ns"].astype(np.int64),
                "frame_id": np.asarray(c["frame_id"] if "frame_id" in c else text_column(n, "local"), dtype=object),
                "n_m": c["n_m"].astype(float), "e_m": c["e_m"].astype(float),
                "var_m2": np.asarray(c.get("var_m2", np.full(n, np.nan)), float),
                "geo": np.full(n, self.local_geo, bool)}
        return frame_from_columns(cols, c["t_ns"], channel_spec("/local/position"))

    def _frame_velocity(self, c) -> pd.DataFrame:
        n = len(c["t_ns"])
        cog = np.asarray(c.get("cog_rad", np.full(n, np.nan)), float)
        with np.errstate(invalid="ignore"):
            cog = np.where(np.isfinite(cog), ssa(cog), np.nan)
        cols = {"stamp_ns": c["stamp_ns"].astype(np.int64), "sog_mps": c["sog_mps"].astype(float),
                "cog_rad": cog}
        return frame_from_columns(cols, c["t_ns"], channel_spec("/gnss/velocity"))


def yaw_from_quaternion_enu(x, y, z, w):
    """Heading (rad, clockwise from north, NED) from a ROS ENU orientation quaternion.

    ROS REP-103: yaw is counter-clockwise from east about up, so psi_ned = pi/2 - yaw_enu
    (the body FLU -> FRD flip keeps the forward axis, so the same angle holds).
    """
    x, y, z, w = (np.asarray(a, float) for a in (x, y, z, w))
    yaw_enu = np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return ssa(math.pi / 2 - yaw_enu)
