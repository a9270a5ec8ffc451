"""A long log drawn a time window at a time: the view's and the report's memory flat in its length.

``usvlog view`` and ``usvlog report`` of a file (:func:`usvlog.view.source.read_drawn`) get a
:class:`WindowedLog` when the file allows it (:func:`open_windowed`): its small channels
(positions, compass, innovations) decoded, its big ones (:data:`WINDOWED`: the states at 100 Hz
and the thrust commands) left in the file, to be drawn from a block of rows at a time
(:func:`blocks`), and a :class:`Survey` of the run made first, by passes over the big channels
before the viewer's or the plots' library is imported:

* what the whole-run analyses find, one after the other: the standard manoeuvres (the thrust
  commands made from their blocks and read into the detection's plan, then the estimate's track
  made from its blocks: :class:`usvlog.trials.CommandsBuilder`, :class:`usvlog.trials.TrackBuilder`)
  with each one's stretch of the estimated track; the findings of ``usvlog check`` (on the small
  sensor channels read whole and the commands gathered from their blocks, the checks' smoothing
  of the run made first on the commands' forces alone when every command records both);
* the whole-run facts the drawing needs before it starts: each state channel's thinning step for
  the 10 Hz tracks (:func:`usvlog.view.data.thin_indices`' median step, from a count of the
  steps), the thrust commands' first unit and whether any force was recorded.

Everything else is drawn from the blocks as they come: the view sends each time series a block at
a time (:mod:`usvlog.view.rrd_windows`); the report draws the big channels decimated as they are
read (:class:`Decimator`). A file that cannot be read so (no summary statistics, a channel the
blocks do not cover, a channel of another kind drawn: a controller, an identification fit) is
read whole, as before.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from ..check import smooth
from ..io.mcap.decode import _return_freed_memory
from ..io.mcap.reader import chunk_spans, read_log
from ..io.mcap.windows import NotWindowed, iter_windows, topic_counts
from ..log.fieldlog import FieldLog
from ..trials import CommandsBuilder, TrackBuilder, uses_forces
from . import data as vd
from . import findings as vfind
from . import manoeuvres as vman

WINDOWED = ("/estimate/state", "/truth/state", "/thrust/command")
"""The big channels drawn a block at a time (the others a windowed log draws are small)."""

BLOCK_ROWS = 65_536
"""Rows of the largest channel in a block (about 11 minutes at 100 Hz)."""

MIN_ROWS = BLOCK_ROWS
"""A log whose big channels are all shorter is read whole (one block: nothing to gain)."""

_CURRENT = ("current_n_mps", "current_e_mps")
"""The estimate's columns gathered whole in the survey (the report's current arrow, vd.mean_current)."""


@dataclass
class Survey:
    """What one pass over a log's big channels found (see the module's description)."""

    steps: dict[str, int] = field(default_factory=dict)   # state channel -> thinning step at OVERLAY_HZ
    rows: dict[str, int] = field(default_factory=dict)    # big channel -> its rows
    first: dict[str, int] = field(default_factory=dict)   # big channel -> its first time (ns)
    last: dict[str, int] = field(default_factory=dict)    # big channel -> its last time (ns)
    thrust_unit: str | None = None                        # the commands' unit in their first row
    thrust_forces: bool = False                           # any force recorded with the commands
    forces_rows: tuple[int, int] = (0, 0)                 # commands' rows with thrust_left_n finite, with both
    current: tuple[float, float] | None = None            # the estimate's mean current (vd.mean_current)
    heads: dict = field(default_factory=dict)             # big channel -> its first row
    findings: object = None                               # usvlog.check.CheckResult or None
    manoeuvres: object = None                             # usvlog.trials.Manoeuvres or None
    stretches: list = field(default_factory=list)         # each manoeuvre's (n, e) of the estimate


@dataclass
class WindowedLog(FieldLog):
    """A log whose big channels (:attr:`windowed`) stay in its file and are drawn a block at a time.

    Its :meth:`time_range` is the whole log's, from the file's summary; the big channels are listed
    as deferred channels (decoded whole if touched, as any deferred channel), but the view and the
    report draw them from :func:`blocks` and :attr:`survey` instead.
    """

    range_ns: tuple[int, int] | None = None
    windowed: tuple[str, ...] = ()
    survey: Survey = field(default_factory=Survey)

    def time_range(self) -> tuple[int, int] | None:
        """(first, last) time stamp of the whole log in ns since the Unix epoch (from the file's summary)."""
        return self.range_ns

    def without_windowed(self, frames: dict[str, pd.DataFrame] | None = None) -> WindowedLog:
        """This log with its decoded channels only (none deferred) and ``frames`` (e.g. the big
        channels thinned or decimated) in place of the big ones: nothing drawn from it decodes a
        big channel whole."""
        channels = {t: f for t, f in self.channels.decoded().items() if t not in self.windowed}   # type: ignore[attr-defined]
        channels.update(frames or {})
        return WindowedLog(channels=channels, meta=self.meta, schemas=self.schemas, recovery=self.recovery,
                           source=self.source, range_ns=self.range_ns, windowed=self.windowed, survey=self.survey)


def open_windowed(path, drawn: tuple[str, ...], small: tuple[str, ...], read) -> WindowedLog | None:
    """The log at ``path`` as a :class:`WindowedLog`, surveyed; None when it is to be read whole.

    Parameters
    ----------
    path : str or os.PathLike
        A canonical MCAP file.
    drawn : tuple of str
        Every channel the caller draws.
    small : tuple of str
        Those of ``drawn`` to decode now (the others of ``drawn`` must be among :data:`WINDOWED`).
    read : callable
        :func:`usvlog.io.mcap.read_log`.
    """
    spans, counts = chunk_spans(path), topic_counts(path)
    if not spans or not counts:
        return None
    present = {t for _a, _b, ts in spans for t in ts}
    big = tuple(t for t in WINDOWED if t in drawn and counts.get(t, 0) > 0)
    if not big or max(counts[t] for t in big) < MIN_ROWS:
        return None
    if any(t in present for t in drawn if t not in small and t not in WINDOWED):
        return None   # a controller or a fit: drawn from the whole log
    log = read(path, topics=[], defer=True)   # the small channels decoded after the survey: not in its peak
    if log.recovery is not None or log.deferred is None or not set(big) <= set(log.deferred.topics):
        return None
    topics = set(log.channels)   # every canonical channel of the file (most deferred)
    mine = [(a, b, ts) for a, b, ts in spans if ts & topics]
    if any(not ts <= topics for _a, _b, ts in mine):
        return None   # a chunk shared with a channel the log leaves out: no exact time range
    rng = (min(a for a, _b, _ts in mine), max(b for _a, b, _ts in mine))
    out = WindowedLog(channels=log.channels, meta=log.meta, schemas=log.schemas, source=log.source,
                      range_ns=rng, windowed=big)
    try:
        out.survey = survey(out)
    except NotWindowed:
        return None
    out.channels.load_deferred([t for t in small if t in topics])   # type: ignore[attr-defined]
    return out


def whole(log: FieldLog) -> FieldLog:
    """``log``, a :class:`WindowedLog` read whole from its file (the way back when its file cannot be
    read in windows after all)."""
    if not isinstance(log, WindowedLog):
        return log
    return read_log(log.source)


def blocks(log: WindowedLog, topics=None, rows: int | None = None):
    """Yield the big channels of ``log`` (or ``topics`` of them) a block of rows at a time.

    Parameters
    ----------
    log : WindowedLog
        The log (its file is read).
    topics : iterable of str, optional
        The channels (default: every big channel).
    rows : int, optional
        A block is handed on once one channel has this many rows in it (default :data:`BLOCK_ROWS`).

    Yields
    ------
    dict
        Topic -> DataFrame of the channel's rows in the block (channels without a row left out);
        in time order, the blocks of a channel joined are its frame as read whole.

    Raises
    ------
    usvlog.io.mcap.windows.NotWindowed
        The file cannot be read so after all (changed since it was surveyed).
    """
    rows = BLOCK_ROWS if rows is None else rows
    held: dict[str, list] = {}
    n = 0
    for window in iter_windows(log.source, list(log.windowed if topics is None else topics)):
        for t, f in window.items():
            held.setdefault(t, []).append(f)
            n = max(n, sum(len(x) for x in held[t]))
        if n >= rows:
            yield {t: fs[0] if len(fs) == 1 else pd.concat(fs) for t, fs in held.items()}
            held, n = {}, 0
    if held:
        yield {t: fs[0] if len(fs) == 1 else pd.concat(fs) for t, fs in held.items()}


class _Steps:
    """The median of a channel's time steps, from a count of each step (its frame never whole)."""

    def __init__(self):
        self.values = np.zeros(0, np.int64)
        self.counts = np.zeros(0, np.int64)
        self.last: int | None = None
        self.rows = 0

    def add(self, t_ns: np.ndarray) -> None:
        if not len(t_ns):
            return
        d = np.diff(t_ns) if self.last is None else np.diff(np.r_[np.int64(self.last), t_ns])
        v, c = np.unique(np.r_[self.values, d], return_inverse=True)
        self.counts = np.bincount(c, weights=np.r_[self.counts, np.ones(len(d), np.int64)],
                                  minlength=len(v)).astype(np.int64)
        self.values, self.last, self.rows = v, int(t_ns[-1]), self.rows + len(t_ns)

    def thin_step(self, max_hz: float) -> int:
        """:func:`usvlog.view.data.thin_indices`' step for the whole channel (1 under 3 rows)."""
        if self.rows < 3:
            return 1
        m = int(self.counts.sum())
        cum = np.cumsum(self.counts)
        mid = [m // 2] if m % 2 else [m // 2 - 1, m // 2]
        middle = self.values[np.searchsorted(cum, np.asarray(mid) + 1)]
        return vd.thin_step(float(np.median(middle)), max_hz)   # the median of the two middle values as numpy's


class _Gather:
    """A channel's columns (some, or all) gathered from its blocks into arrays allocated once; its
    text columns as categories."""

    def __init__(self, rows: int, head: pd.DataFrame, columns=None):
        self.t = np.empty(rows, np.int64)
        self.cols: dict[str, np.ndarray] = {}
        self.cats: dict[str, dict] = {}   # text column -> {value: code}
        for c in head.columns if columns is None else columns:
            numeric = pd.api.types.is_numeric_dtype(head[c].dtype)
            self.cols[c] = np.empty(rows, head[c].dtype if numeric else np.int32)
            if not numeric:
                self.cats[c] = {}
        self.n = 0

    def add(self, f: pd.DataFrame) -> None:
        k = len(f)
        if self.n + k > len(self.t):
            raise NotWindowed("a channel has more rows than the summary counts")
        self.t[self.n:self.n + k] = np.asarray(f.index.to_numpy(), np.int64)
        for c, a in self.cols.items():
            if c in self.cats:   # the block's codes mapped to the channel's (a missing value: -1)
                codes, values = pd.factorize(f[c])
                known = np.asarray([self.cats[c].setdefault(v, len(self.cats[c])) for v in values] + [-1], np.int32)
                a[self.n:self.n + k] = known[codes]
            elif f[c].dtype != a.dtype:
                raise NotWindowed(f"a column's type changes between blocks ({c})")
            else:
                a[self.n:self.n + k] = f[c].to_numpy()
        self.n += k

    def frame(self) -> pd.DataFrame:
        cols = {c: pd.Categorical.from_codes(a[:self.n], list(self.cats[c])) if c in self.cats else a[:self.n]
                for c, a in self.cols.items()}
        return pd.DataFrame(cols, index=pd.Index(self.t[:self.n], name="t_ns"), copy=False)


def survey(log: WindowedLog) -> Survey:
    """One pass over ``log``'s big channels: the :class:`Survey` (see the module's description).

    The analyses come one after the other, each letting go of what it read before the next: the
    pass (the estimate's current gathered), the manoeuvres (the commands, then the estimate's track,
    each made from a pass over its channel's blocks), only when there are manoeuvres a pass
    for their stretches of the estimate, and the findings (the sensor channels read whole, the
    commands gathered from their blocks).
    """
    s = Survey()
    counts = topic_counts(log.source)
    steps, current = _pass(log, s, counts)
    if any(s.rows.get(t, 0) != counts[t] for t in log.windowed):
        raise NotWindowed("a channel's rows and the summary's count differ")
    s.steps = {t: st.thin_step(vd.OVERLAY_HZ) for t, st in steps.items()}
    if current is not None:
        s.current = vd.mean_current(current.frame())
    del current
    _return_freed_memory()
    s.manoeuvres = _manoeuvres(log, s)
    _return_freed_memory()
    s.stretches = _stretches(log, s.manoeuvres)
    s.findings = _findings(log, s)
    _return_freed_memory()
    return s


def _pass(log: WindowedLog, s: Survey, counts: dict[str, int]):
    """The survey's pass over the big channels: fills ``s``'s facts; returns each state channel's
    :class:`_Steps` and the estimate's current gathered (or None) (a function of its own: the last
    block is let go with it)."""
    steps = {t: _Steps() for t in log.windowed if t != vman.THRUST}
    current: _Gather | None = None
    for blk in blocks(log):
        for t, f in blk.items():
            if t not in s.first:
                s.first[t], s.heads[t] = int(f.index[0]), f.iloc[:1].copy()
                if t == vman.STATE and any(c in f.columns for c in _CURRENT):
                    current = _Gather(counts[t], f, [c for c in _CURRENT if c in f.columns])
                if t == vman.THRUST:
                    s.thrust_unit = str(f["unit"].iloc[0]) if "unit" in f.columns else None
            s.last[t] = int(f.index[-1])
            s.rows[t] = s.rows.get(t, 0) + len(f)
            if s.rows[t] > counts[t]:
                raise NotWindowed("a channel has more rows than the summary counts")
            if t in steps:
                steps[t].add(np.asarray(f.index.to_numpy(), np.int64))
            if t == vman.STATE and current is not None:
                current.add(f)
            if t == vman.THRUST and {"thrust_left_n", "thrust_right_n"} <= set(f.columns):
                left = np.isfinite(f["thrust_left_n"].to_numpy(float))
                both = left & np.isfinite(f["thrust_right_n"].to_numpy(float))
                s.forces_rows = (s.forces_rows[0] + int(left.sum()), s.forces_rows[1] + int(both.sum()))
            if t == vman.THRUST and not s.thrust_forces and {"thrust_left_n", "thrust_right_n"} <= set(f.columns):
                s.thrust_forces = bool(np.isfinite(f["thrust_left_n"].to_numpy(float)).any()
                                       or np.isfinite(f["thrust_right_n"].to_numpy(float)).any())
    return steps, current


def _findings(log: WindowedLog, s: Survey):
    """``usvlog check``'s findings on the log's sensor channels, over the whole log's time: the small
    ones read whole, the commands gathered from their blocks (the frame read whole, its text as
    categories; the read's own copies never made). When every command records both forces, the
    checks' smoothing of the run is made first, on the commands' forces alone (all the smoothing
    reads of them, :func:`usvlog.identify.data.thrust_forces`), before their other columns are read."""
    have = [t for t in vfind.CHECK_TOPICS if t in log.channels]
    small = [t for t in have if t not in log.windowed]
    sensors = read_log(log.source, topics=small) if small else FieldLog()
    channels = dict(sensors.channels)
    del sensors
    _return_freed_memory()   # the read's own copies
    counts = topic_counts(log.source)
    big = [t for t in have if t in log.windowed]
    smoothed = None
    if vman.THRUST in big and s.forces_rows[1] == counts[vman.THRUST]:
        forces = gathered(log, vman.THRUST, counts[vman.THRUST], ("thrust_left_n", "thrust_right_n"))
        try:
            smoothed = smooth(FieldLog(channels={**channels, vman.THRUST: forces}, meta=log.meta, source=log.source))
        except Exception:   # noqa: S110 -- left to the checks: they smooth the run again and report it
            pass
        del forces
        _return_freed_memory()
    for t in big:
        channels[t] = gathered(log, t, counts[t])
    checked = WindowedLog(channels=channels, meta=log.meta, source=log.source, range_ns=log.range_ns)
    return vfind.checked(checked, smoothed)


def gathered(log: WindowedLog, topic: str, rows: int, columns=None) -> pd.DataFrame:
    """The frame of ``log``'s big channel ``topic`` (of ``rows`` rows; its ``columns``, default all) as
    read whole, gathered from its blocks: its arrays allocated once, its text columns as categories
    (the read's copies never made)."""
    g = None
    for blk in blocks(log, [topic]):
        g = g or _Gather(rows, blk[topic], columns)
        g.add(blk[topic])
    if g is None or g.n != rows:
        raise NotWindowed(f"{topic}: its rows and the summary's count differ")
    return g.frame()


def _manoeuvres(log: WindowedLog, s: Survey):
    """The manoeuvres (:func:`usvlog.view.manoeuvres.measure`'s of the whole log), each of their inputs
    made from a pass over its channel's blocks: the commands (read into the detection's plan and let
    go), then the estimate's track."""
    rows, state = s.rows.get(vman.THRUST, 0), s.heads.get(vman.STATE)
    if log.range_ns is None or state is None or "n_m" not in state.columns or s.rows[vman.STATE] < 10 or rows < 2:
        return None
    t0 = int(log.range_ns[0])

    def made(builder, topic):
        n = 0
        for blk in blocks(log, [topic]):
            n += len(blk[topic])
            if n > s.rows[topic]:
                raise NotWindowed(f"{topic}: more rows than when surveyed")
            builder.add(blk[topic])
        return builder

    uses = uses_forces(s.heads[vman.THRUST].columns, s.forces_rows[0], rows)
    return vman.find_on(lambda: made(CommandsBuilder(rows, t0, uses, s.thrust_unit), vman.THRUST).commands(),
                        lambda: made(TrackBuilder(s.rows[vman.STATE], t0), vman.STATE).track(), t0)


def _stretches(log: WindowedLog, found) -> list:
    """Each manoeuvre's stretch of the estimated track (:func:`usvlog.view.manoeuvres.stretches`), from
    a pass over the estimate's blocks (none without manoeuvres)."""
    if not found:
        return []
    parts: list[tuple[list, list]] = [([], []) for _ in found]
    for blk in blocks(log, [vman.STATE]):
        for (ns, es), (n, e) in zip(parts, vman.stretches(FieldLog(channels=blk), found)):
            ns.append(n)
            es.append(e)
    return [(np.concatenate(ns), np.concatenate(es)) for ns, es in parts]


def findings_of(log: FieldLog):
    """The findings of ``usvlog check`` about a log: the survey's for a :class:`WindowedLog`."""
    return log.survey.findings if isinstance(log, WindowedLog) else vfind.of_log(log)


def manoeuvres_of(log: FieldLog):
    """(manoeuvres, their stretches of the estimated track) of a log: the survey's for a
    :class:`WindowedLog`, else found on the log now."""
    if isinstance(log, WindowedLog):
        return log.survey.manoeuvres, log.survey.stretches
    found = vman.of_log(log)
    return found, vman.stretches(log, found)
