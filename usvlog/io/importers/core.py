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

Thrust commands that are not newtons go through the vessel's thruster map
(:meth:`usvlog.model.vessel.Thrusters.command_to_force`); the recorded commands and
their unit are kept. The datum is the first kept fix unless one is given.

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

# stream -> (topic, value columns that must be finite)
STREAMS: dict[str, tuple[str, tuple[str, ...]]] = {
    "gnss": ("/gnss/fix", ("lat_deg", "lon_deg")),
    "heading": ("/compass/heading", ("heading_rad",)),
    "thrust": ("/thrust/command", ("left", "right")),
    "yaw_rate": ("/imu/yaw_rate", ("r_radps",)),
    "velocity": ("/gnss/velocity", ("sog_mps",)),
}
_COV = ("cov_ee_m2", "cov_en_m2", "cov_eu_m2", "cov_ne_m2", "cov_nn_m2", "cov_nu_m2",
        "cov_ue_m2", "cov_un_m2", "cov_uu_m2")


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
            ``first_bad``, ``guesses``, ``mapping``, ``notes`` and ``channels`` (topic ->
            samples written, sorted).
        """
        return {"source": self.source, "format": self.format, "records": self.records,
                "skipped": dict(sorted(self.skipped.items())), "first_bad": dict(self.first_bad),
                "guesses": dict(self.guesses), "mapping": dict(self.mapping), "notes": list(self.notes),
                "channels": dict(sorted(self.counts.items()))}


def clock_offset_fallback(opts, report, what: str) -> int:
    """UTC offset (ns) of a log's own clock when the log has no GPS time: ``--start-utc``, else the epoch.

    Records the guess and a note: ``"no GPS time in the log: {what} counted from ..."``.
    """
    report.guesses["time_base"] = "--start-utc" if opts.start_utc_ns else "1970-01-01T00:00:00Z"
    report.note(f"no GPS time in the log: {what} counted from " + report.guesses["time_base"])
    return opts.start_utc_ns or 0


def listing(names, limit: int = 30) -> str:
    """``a, b, c`` of names read from a file, on one line (whitespace inside a name collapsed)."""
    names = list(names)
    text = ", ".join(" ".join(str(x).split()) for x in names[:limit])
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
    text = " ".join(str(err).split())[:200]
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
    """Turns role batches into canonical frames, counting what it drops."""

    def __init__(self, report: ImportReport, *, vessel: Vessel | None = None, datum: Datum | None = None):
        self.report = report
        self.vessel = vessel
        self.datum = datum
        self._last: dict[str, int] = {}
        self._thrust_forces_known: bool | None = None

    def process(self, batch: dict[str, dict[str, np.ndarray]]) -> dict[str, pd.DataFrame]:
        """Turn one batch of role streams into canonical frames.

        Drops (and counts in the report) samples with a negative time, non-finite values,
        GNSS fixes with NaN, out-of-range or (0, 0) latitude/longitude, negative speeds
        and samples not later than the previous kept one of the same stream (kept across
        batches). Headings and courses are wrapped to [-pi, pi) rad; thrust commands that
        are not newtons are turned into forces (N) with the vessel's thruster map (forces
        NaN, and a note, without a vessel whose map is linear or quadratic). The datum is
        set from the first kept fix when none was given.

        Parameters
        ----------
        batch : dict
            ``{stream: {column: array}}``, streams and columns as in :data:`STREAMS`;
            ``t_ns`` (int64 ns since the Unix epoch) is required, ``stamp_ns`` defaults
            to it.

        Returns
        -------
        dict
            Topic -> DataFrame indexed by ``t_ns`` in the channel's canonical columns;
            streams with nothing kept are left out. :attr:`ImportReport.counts` is
            increased by the rows returned.

        Raises
        ------
        ConfigError
            A stream not in :data:`STREAMS`, or a thrust unit not in ``THRUST_UNITS``.
        """
        out = {}
        for stream, cols in batch.items():
            if stream not in STREAMS:
                raise ConfigError(f"unknown stream {stream!r}")
            frame = self._stream(stream, cols)
            if frame is not None and len(frame):
                topic = STREAMS[stream][0]
                self.report.counts[topic] += len(frame)
                out[topic] = frame
        return out

    def _stream(self, stream: str, cols: dict[str, np.ndarray]) -> pd.DataFrame | None:
        t = np.asarray(cols["t_ns"], dtype=np.int64)
        n = len(t)
        if n == 0:
            return None
        cols = {k: np.asarray(v) for k, v in cols.items()}
        cols.setdefault("stamp_ns", t)
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
            keep &= ~(nan | rng | zero)
        else:
            bad = np.zeros(n, bool)
            for c in values:
                bad |= ~np.isfinite(np.asarray(cols[c], float))
            self.report.skip(f"{stream}_nan", int((bad & keep).sum()))
            keep &= ~bad
            if stream == "velocity":
                with np.errstate(invalid="ignore"):
                    negv = keep & (np.asarray(cols["sog_mps"], float) < 0)
                self.report.skip("velocity_out_of_range", int(negv.sum()))
                keep &= ~negv
        t_keep = t[keep]
        tk, back, dup = _time_filter(t_keep, self._last.get(stream))
        self.report.skip(f"{stream}_time_backwards", back)
        self.report.skip(f"{stream}_time_duplicate", dup)
        idx = np.flatnonzero(keep)[tk]
        if len(idx) == 0:
            return None
        self._last[stream] = int(t[idx[-1]])
        sel = {k: v[idx] for k, v in cols.items()}
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
                "frame_id": np.asarray(c.get("frame_id", np.full(n, "gnss", dtype=object)), dtype=object),
                "lat_deg": c["lat_deg"].astype(float), "lon_deg": c["lon_deg"].astype(float), "alt_m": alt}
        for k in _COV:
            cols[k] = np.asarray(c.get(k, np.zeros(n)), float)
        cols["cov_type"] = np.asarray(c.get("cov_type", np.zeros(n, np.int64)), np.int64)
        return frame_from_columns(cols, c["t_ns"], channel_spec("/gnss/fix"))

    def _frame_heading(self, c) -> pd.DataFrame:
        n = len(c["t_ns"])
        cols = {"stamp_ns": c["stamp_ns"].astype(np.int64), "heading_rad": ssa(c["heading_rad"]),
                "reference": np.asarray(c.get("reference", np.full(n, "true", dtype=object)), dtype=object),
                "std_rad": np.asarray(c.get("std_rad", np.full(n, np.nan)), float)}
        return frame_from_columns(cols, c["t_ns"], channel_spec("/compass/heading"))

    def _frame_thrust(self, c) -> pd.DataFrame:
        n = len(c["t_ns"])
        left, right = c["left"].astype(float), c["right"].astype(float)
        unit = c.get("unit")
        units = np.asarray(unit if unit is not None else np.full(n, "newton", dtype=object), dtype=object)
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
                self.report.note(f"thrust commands in {u}: forces unknown (give a --vessel whose "
                                 "thruster map is linear or quadratic)")
                continue
            fl[m] = thr.command_to_force(left[m], u)
            fr[m] = thr.command_to_force(right[m], u)
        cols = {"stamp_ns": c["stamp_ns"].astype(np.int64), "left": left, "right": right,
                "unit": units, "thrust_left_n": fl, "thrust_right_n": fr}
        return frame_from_columns(cols, c["t_ns"], channel_spec("/thrust/command"))

    def _frame_yaw_rate(self, c) -> pd.DataFrame:
        cols = {"stamp_ns": c["stamp_ns"].astype(np.int64), "r_radps": c["r_radps"].astype(float)}
        return frame_from_columns(cols, c["t_ns"], channel_spec("/imu/yaw_rate"))

    def _frame_velocity(self, c) -> pd.DataFrame:
        n = len(c["t_ns"])
        cog = np.asarray(c.get("cog_rad", np.full(n, np.nan)), float)
        with np.errstate(invalid="ignore"):
            cog = np.where(np.isfinite(cog), ssa(cog), np.nan)
        cols = {"stamp_ns": c["stamp_ns"].astype(np.int64), "sog_mps": c["sog_mps"].astype(float),
                "cog_rad": cog}
        return frame_from_columns(cols, c["t_ns"], channel_spec("/gnss/velocity"))


def guess_thrust_unit(left: np.ndarray, right: np.ndarray) -> str:
    """Unit of thruster commands from their range: PWM microseconds, [-1, 1] or newtons."""
    v = np.concatenate([np.asarray(left, float), np.asarray(right, float)])
    v = v[np.isfinite(v)]
    if len(v) == 0:
        return "newton"
    lo, hi = float(v.min()), float(v.max())
    if lo >= 800.0 and hi <= 2200.0:
        return "pwm_us"
    if lo >= -1.0 and hi <= 1.0:
        return "normalized"
    return "newton"


def yaw_from_quaternion_enu(x, y, z, w):
    """Heading (rad, clockwise from north, NED) from a ROS ENU orientation quaternion.

    ROS REP-103: yaw is counter-clockwise from east about up, so psi_ned = pi/2 - yaw_enu
    (the body FLU -> FRD flip keeps the forward axis, so the same angle holds).
    """
    x, y, z, w = (np.asarray(a, float) for a in (x, y, z, w))
    yaw_enu = np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return ssa(math.pi / 2 - yaw_enu)
