"""What is in a log: channels, counts, rates, time range, gaps, backwards steps, damage.

Pure: takes a FieldLog, returns a LogSummary (``to_dict()`` for ``--json``); or, for a
file too big to load, :class:`TimeStats` builds each channel's summary from its time
stamps a chunk at a time (``usvlog.api.inspect`` streams an MCAP file through it).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass

import numpy as np

from .channels import schema_for_topic
from .fieldlog import FieldLog, format_time


@dataclass(frozen=True)
class Gap:
    """A gap in a channel: start (ns since the Unix epoch) and length (s)."""

    start_ns: int
    duration_s: float


@dataclass(frozen=True)
class ChannelSummary:
    """Counts, nominal rate, time range and timing faults of one channel.

    ``rate_hz`` comes from the median positive interval (None with fewer than two
    distinct stamps); ``first_ns``/``last_ns`` are ns since the Unix epoch; ``gaps`` are
    intervals longer than 3x the nominal period (the longest ones, in time order);
    ``backwards`` and ``duplicates`` count stamps earlier than / equal to the previous one.
    """

    topic: str
    schema: str
    count: int
    rate_hz: float | None          # nominal rate from the median interval
    first_ns: int | None
    last_ns: int | None
    duration_s: float
    gaps: tuple[Gap, ...]           # intervals longer than 3x the nominal period
    backwards: int                  # time stamps earlier than the previous one
    duplicates: int                 # time stamps equal to the previous one


@dataclass(frozen=True)
class LogSummary:
    """What is in a log: its channels, overall time range, metadata, damage, skipped records.

    ``first_ns``/``last_ns`` are ns since the Unix epoch over all channels, ``duration_s``
    their distance in s; ``metadata`` the log's metadata records; ``recovery`` the
    recovery report of a damaged file (None if intact); ``skipped`` counts of records
    skipped at import, by kind.
    """

    source: str | None
    channels: tuple[ChannelSummary, ...]
    first_ns: int | None
    last_ns: int | None
    duration_s: float
    metadata: dict
    recovery: dict | None
    skipped: dict                   # {what: count} from import provenance

    def to_dict(self) -> dict:
        """JSON-ready dict (for ``--json``): the fields plus ``start_utc``/``end_utc``,
        with ``channels`` keyed by topic."""
        d = asdict(self)
        d["start_utc"] = format_time(self.first_ns) if self.first_ns is not None else None
        d["end_utc"] = format_time(self.last_ns) if self.last_ns is not None else None
        d["channels"] = {c["topic"]: c for c in d["channels"]}
        d["health"] = self.health
        return d

    @property
    def health(self) -> dict | None:
        """The sensor health record of the last import (None for a log that was not imported).

        Parsed from the ``health`` key of the provenance records in :attr:`metadata`; the
        layout is documented in :mod:`usvlog.io.importers.audit`.
        """
        return health_from_metadata(self.metadata)

    def channel(self, topic: str) -> ChannelSummary:
        """The summary of ``topic``; ``StopIteration`` if the log has no such channel."""
        return next(c for c in self.channels if c.topic == topic)


def summarize_channel(topic: str, schema: str, t_ns: np.ndarray, max_gaps: int = 20) -> ChannelSummary:
    """Summarise one channel from its time stamps.

    Parameters
    ----------
    topic, schema : str
        Channel name and schema title, copied into the summary.
    t_ns : array_like of int
        Message times, ns since the Unix epoch, in recorded order.
    max_gaps : int, default 20
        Keep at most this many gaps (the longest).

    Returns
    -------
    ChannelSummary
    """
    t = np.asarray(t_ns, dtype=np.int64)
    n = len(t)
    if n == 0:
        return ChannelSummary(topic, schema, 0, None, None, None, 0.0, (), 0, 0)
    dt = np.diff(t)
    backwards = int(np.sum(dt < 0))
    dups = int(np.sum(dt == 0))
    pos = dt[dt > 0]
    rate = None
    gaps: list[Gap] = []
    if len(pos):
        period = float(np.median(pos))
        rate = 1e9 / period
        big = np.flatnonzero(dt > 3 * period)
        order = big[np.argsort(-dt[big], kind="stable")][:max_gaps]
        gaps = [Gap(int(t[i]), float(dt[i]) / 1e9) for i in sorted(order)]
    return ChannelSummary(topic, schema, n, rate, int(t.min()), int(t.max()),
                          float(t.max() - t.min()) / 1e9, tuple(gaps), backwards, dups)


_KEY_BITS = 12                      # a histogram bin is 2**-12 of its values wide (relative)
_POW2 = np.int64(1) << np.arange(63, dtype=np.int64)


def _bin_key(v: np.ndarray) -> np.ndarray:
    """Histogram bin of positive int64 values, increasing with the value: (bit length, the
    top ``_KEY_BITS + 1`` bits)."""
    bits = np.searchsorted(_POW2, v, side="right").astype(np.int64)       # bit length, exact
    shift = np.maximum(bits - (_KEY_BITS + 1), 0)
    return (bits << (_KEY_BITS + 2)) | (v >> shift)


def _merge_counts(parts: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """Sorted distinct values and their summed counts of several (values, counts) pairs."""
    if not parts:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    v = np.concatenate([p[0] for p in parts])
    c = np.concatenate([p[1] for p in parts])
    u, inv = np.unique(v, return_inverse=True)
    return u, np.bincount(inv, weights=c, minlength=len(u)).astype(np.int64)


class TimeStats:
    """One channel's :class:`ChannelSummary`, built from its time stamps a batch at a time.

    Gives exactly what :func:`summarize_channel` gives for all the stamps at once, keeping
    only counters, the 20 longest intervals and the positive intervals as distinct values
    with counts (for the median: few for a regular channel). When those pass
    ``max_distinct`` they become a histogram (bins 2**-12 of their values wide) and the
    median needs a second pass over the data (:meth:`needs_pass`, :meth:`refine`). Stamps
    must come in recorded (sequence) order; a batch whose sequence numbers go back makes
    the channel's second pass collect all its stamps (:meth:`needs_pass` is "all").

    Parameters
    ----------
    max_distinct : int
        Distinct positive intervals kept before the histogram takes over.
    max_gaps : int
        Gaps kept (the longest), as in :func:`summarize_channel`.
    """

    def __init__(self, max_distinct: int = 1 << 18, max_gaps: int = 20):
        self.max_distinct = int(max_distinct)
        self.max_gaps = int(max_gaps)
        self.count = 0
        self.t_min: int | None = None
        self.t_max: int | None = None
        self.backwards = 0
        self.duplicates = 0
        self._last_t: int | None = None
        self._last_seq: int | None = None
        self._pairs = 0                                   # intervals seen so far
        self._top = (np.zeros(0, np.int64),) * 3          # the longest intervals: dt, pair index, start time
        self._parts: list[tuple[np.ndarray, np.ndarray]] = []
        self._distinct = 0
        self._hist: tuple[np.ndarray, np.ndarray] | None = None   # bin keys, counts (histogram mode)
        self.ordered = True
        self._want: np.ndarray | None = None              # second pass: bins whose values are needed
        self._exact: list[tuple[np.ndarray, np.ndarray]] = []
        self._all: list[tuple[np.ndarray, np.ndarray]] = []   # second pass, unordered: (seq, t)

    # -- first pass ----------------------------------------------------------------------
    def add(self, t_ns: np.ndarray, seq: np.ndarray | None = None) -> None:
        """The next stamps of the channel in recorded order.

        Parameters
        ----------
        t_ns : array_like of int
            Message times, ns since the Unix epoch.
        seq : array_like of int, optional
            Their sequence numbers (checked to be in order).
        """
        t = np.asarray(t_ns, dtype=np.int64)
        if not len(t):
            return
        if seq is not None and self.ordered:
            q = np.asarray(seq, dtype=np.int64)
            if (self._last_seq is not None and q[0] < self._last_seq) or (np.diff(q) < 0).any():
                self.ordered = False
            self._last_seq = int(q[-1])
        self.count += len(t)
        lo, hi = int(t.min()), int(t.max())
        self.t_min = lo if self.t_min is None else min(self.t_min, lo)
        self.t_max = hi if self.t_max is None else max(self.t_max, hi)
        if not self.ordered:
            return
        full = t if self._last_t is None else np.concatenate(([self._last_t], t))
        self._last_t = int(t[-1])
        dt = np.diff(full)
        if not len(dt):
            return
        self.backwards += int(np.sum(dt < 0))
        self.duplicates += int(np.sum(dt == 0))
        idx = np.arange(self._pairs, self._pairs + len(dt), dtype=np.int64)
        self._pairs += len(dt)
        k = np.argsort(-dt, kind="stable")[:self.max_gaps]
        tdt, tidx, tstart = (np.concatenate((a, b)) for a, b in zip(self._top, (dt[k], idx[k], full[:-1][k])))
        best = np.lexsort((tidx, -tdt))[:self.max_gaps]
        self._top = (tdt[best], tidx[best], tstart[best])
        pos = dt[dt > 0]
        if not len(pos):
            return
        if self._hist is not None:
            self._hist = _merge_counts([self._hist, np.unique(_bin_key(pos), return_counts=True)])
            return
        self._parts.append(np.unique(pos, return_counts=True))
        self._distinct += len(self._parts[-1][0])
        if self._distinct > self.max_distinct:
            self._parts = [_merge_counts(self._parts)]
            self._distinct = len(self._parts[0][0])
            if self._distinct > self.max_distinct // 2:   # too many distinct intervals: to a histogram
                u, c = self._parts[0]
                self._hist = _merge_counts([(_bin_key(u), c)])
                self._parts, self._distinct = [], 0

    def _positives(self) -> int:
        src = self._hist if self._hist is not None else _merge_counts(self._parts)
        return int(src[1].sum())

    def _order_stats(self) -> tuple[int, int]:
        n = self._positives()
        return (n - 1) // 2, n // 2

    def needs_pass(self) -> str | None:
        """What a second pass must collect: None, "median" (values in the median's bins) or
        "all" (every stamp with its sequence number: they came out of order)."""
        if not self.ordered:
            return "all"
        if self._hist is not None and self._positives():
            return "median"
        return None

    # -- second pass ---------------------------------------------------------------------
    def start_pass(self) -> None:
        """Prepare the second pass (see :meth:`needs_pass`)."""
        self._last_t = None
        if self.needs_pass() == "median":
            keys, counts = self._hist
            cum = np.cumsum(counts)
            self._want = np.unique(keys[np.searchsorted(cum, np.array(self._order_stats()), side="right")])

    def refine(self, t_ns: np.ndarray, seq: np.ndarray | None = None) -> None:
        """The channel's stamps again, in the same batches as in the first pass."""
        t = np.asarray(t_ns, dtype=np.int64)
        if not len(t):
            return
        if not self.ordered:
            self._all.append((np.asarray(seq, dtype=np.int64), t))
            return
        if self._want is None:
            return
        full = t if self._last_t is None else np.concatenate(([self._last_t], t))
        self._last_t = int(t[-1])
        dt = np.diff(full)
        pos = dt[dt > 0]
        sel = pos[np.isin(_bin_key(pos), self._want)]
        if len(sel):
            self._exact.append(np.unique(sel, return_counts=True))

    # -- result --------------------------------------------------------------------------
    def _median(self) -> float:
        if self._hist is None:
            u, c = _merge_counts(self._parts)
            below = 0
        else:
            keys, counts = self._hist
            u, c = _merge_counts(self._exact)
            first = keys < self._want.min()
            below = int(counts[first].sum())
        cum = np.cumsum(c) + below
        a, b = (int(u[np.searchsorted(cum, k, side="right")]) for k in self._order_stats())
        return float(np.mean(np.array([a, b] if a != b or self._positives() % 2 == 0 else [a], dtype=np.int64)))

    def summary(self, topic: str, schema: str) -> ChannelSummary:
        """The channel's summary, as :func:`summarize_channel` gives it."""
        if not self.ordered:
            if self._all:
                seq = np.concatenate([a[0] for a in self._all])
                t = np.concatenate([a[1] for a in self._all])
                t = t[np.argsort(seq, kind="stable")]
            else:
                t = np.zeros(0, np.int64)
            return summarize_channel(topic, schema, t, self.max_gaps)
        if not self.count:
            return ChannelSummary(topic, schema, 0, None, None, None, 0.0, (), 0, 0)
        rate = None
        gaps: list[Gap] = []
        if self._positives():
            period = self._median()
            rate = 1e9 / period
            dt, idx, start = self._top
            big = dt > 3 * period
            gaps = [Gap(int(s), float(d) / 1e9) for _i, d, s in sorted(zip(idx[big], dt[big], start[big]))]
        return ChannelSummary(topic, schema, self.count, rate, self.t_min, self.t_max,
                              float(self.t_max - self.t_min) / 1e9, tuple(gaps), self.backwards, self.duplicates)


def skipped_counts(log: FieldLog) -> dict:
    """Records skipped at import, summed over the log's provenance records.

    Parameters
    ----------
    log : FieldLog

    Returns
    -------
    dict
        {what: count}.
    """
    return skipped_from_provenance(log.provenance)


def skipped_from_provenance(provenance: list[dict]) -> dict:
    """Records skipped at import, summed over provenance records: {what: count}.

    Parameters
    ----------
    provenance : list of dict
        Provenance records (``FieldLog.provenance``), each a {key: text} dict.

    Returns
    -------
    dict
        {what: count}.
    """
    out: dict[str, int] = {}
    for rec in provenance:
        raw = rec.get("skipped")
        if not raw:
            continue
        try:
            d = json.loads(raw)
        except json.JSONDecodeError:
            continue
        for k, v in d.items():
            if isinstance(v, (int, float)):
                out[k] = out.get(k, 0) + int(v)
    return out


def health_from_metadata(metadata: dict) -> dict | None:
    """The health record of the last import among a log's provenance metadata records.

    Parameters
    ----------
    metadata : dict
        Metadata records ``{name: {key: text}}``; the provenance records are
        ``usvlog.provenance/N``.

    Returns
    -------
    dict or None
        The record (layout in :mod:`usvlog.io.importers.audit`), None when no import
        stored one.
    """
    keys = sorted((k for k in metadata if k.startswith("usvlog.provenance/") and k.rsplit("/", 1)[1].isdigit()),
                  key=lambda k: int(k.rsplit("/", 1)[1]))
    return health_from_provenance([metadata[k] for k in keys])


def health_from_provenance(provenance: list[dict]) -> dict | None:
    """The health record of the last import among provenance records (None if none has one).

    Parameters
    ----------
    provenance : list of dict
        Provenance records ({key: text}), oldest first.

    Returns
    -------
    dict or None
        The record (layout in :mod:`usvlog.io.importers.audit`), parsed from its JSON text.
    """
    for rec in reversed(list(provenance)):
        d = _json_dict(rec, "health")
        if d is not None:
            return d
    return None


def _json_dict(rec: dict, key: str) -> dict | None:
    """A provenance record's JSON text under ``key`` as a dict (None when absent, not JSON or not a dict)."""
    try:
        d = json.loads(rec.get(key) or "null")
    except json.JSONDecodeError:
        return None
    return d if isinstance(d, dict) else None


def propulsion_from_provenance(provenance: list[dict]) -> dict | None:
    """What the last import found of a propulsion outside the twin-thruster model, if anything.

    Parameters
    ----------
    provenance : list of dict
        Provenance records ({key: text}), oldest first.

    Returns
    -------
    dict or None
        ``kind``, ``commands``, ``topics``, ``reason`` and ``why`` (one line each), as the import recorded them
        (:func:`usvlog.io.importers.mapping.propulsion_outside_model`); None when the last
        import that recorded a health record found none (or no import recorded one).
    """
    for rec in reversed(list(provenance)):
        if not rec.get("health") and not rec.get("propulsion"):
            continue
        d = _json_dict(rec, "propulsion")
        return d if d is not None and d.get("reason") else None
    return None


def format_health(h: dict) -> list[str]:
    """Text lines of a health record (the ``health`` section of ``usvlog inspect``).

    Parameters
    ----------
    h : dict
        A health record (:mod:`usvlog.io.importers.audit`).

    Returns
    -------
    list of str
        A header line (time base, track turn, thrust time) and one line per channel:
        status, rate (Hz), jitter (ms), gaps, republished copies collapsed, out-of-range
        values, longest stuck stretch (s), stamp offset (s); then why a channel is dead or
        suspect, the thrust unit, range and whether the force scale is known, the
        heading's mounting offset against the course over ground (or why none), and the
        errors and warnings as ``usvlog check`` words them
        (:func:`usvlog.log.findings.findings_from_health`).
    """
    base = h.get("time_base", "?")
    if h.get("time_counted_from"):
        base += f" (relative time, counted from {h['time_counted_from']})"
    turn = h.get("track_turn_deg")
    lines = [f"health    time base {base}; track turned "
             + ("-" if turn is None else f"{turn:.0f} deg") + f"; thrust applied {h.get('thrust_applied_s', 0):.0f} s"]
    lines.append(f"  {'channel':<22} {'status':<8} {'rate Hz':>8} {'jit ms':>7} {'gaps':>5} {'repub':>6} "
                 f"{'range':>6} {'stuck s':>8} {'stamp-log s':>12}")
    for topic, c in (h.get("channels") or {}).items():
        rate = f"{c['rate_hz']:.2f}" if c.get("rate_hz") else "-"
        jit = f"{c['jitter_s'] * 1e3:.1f}" if c.get("jitter_s") is not None else "-"
        off = c.get("stamp_offset_s")
        offs = f"{off['median']:+.3f}" if off else "-"
        lines.append(f"  {topic:<22} {c.get('status', '?'):<8} {rate:>8} {jit:>7} {c.get('gaps', 0):>5} "
                     f"{c.get('republished', 0):>6} {c.get('out_of_range', 0):>6} "
                     f"{c.get('stuck_longest_s', 0):>8.1f} {offs:>12}")
    for topic, c in (h.get("channels") or {}).items():
        if c.get("status") in ("dead", "suspect"):
            where = f"; written as {c['written_as']}" if c.get("written_as", topic) != topic else ""
            lines.append(f"  {c['status'].upper()} {topic}: {c.get('why', '')}{where}")
    th = h.get("thrust")
    if th:
        lo, hi = th.get("range", [None, None])
        lines.append(f"  thrust unit {th.get('unit')} range {lo:g}:{hi:g} ({th.get('reason', '')}); force scale "
                     f"{th.get('force_scale')}" + (f"; direction flag {th['direction_flag']}"
                                                   if th.get("direction_flag") else ""))
    ho = h.get("heading_offset")
    if ho and ho.get("text"):
        lines.append(f"  heading {ho['text']}")
    from .findings import findings_from_health  # light: standard library only (the lines usvlog check prints)

    found = [f for f in findings_from_health(h) if f.severity != "info"]
    if found:
        lines.append(f"  findings ({len(found)}; `usvlog check` runs every check):")
        lines += [f"    {f.line()}" for f in found]
    return lines


def summarize(log: FieldLog) -> LogSummary:
    """Summarise a log (what ``usvlog inspect`` shows).

    Parameters
    ----------
    log : FieldLog

    Returns
    -------
    LogSummary
        ``to_dict()`` for JSON, :func:`format_summary` for text.
    """
    chans = []
    for topic in log.topics:
        schema = log.schemas.get(topic, {}).get("title", "")
        if not schema:
            schema = (schema_for_topic(topic) or {}).get("title", "")
        chans.append(summarize_channel(topic, schema, log.channels[topic].index.to_numpy()))
    firsts = [c.first_ns for c in chans if c.first_ns is not None]
    lasts = [c.last_ns for c in chans if c.last_ns is not None]
    first = min(firsts) if firsts else None
    last = max(lasts) if lasts else None
    meta = {k: dict(v) for k, v in log.meta.items()}
    return LogSummary(log.source, tuple(chans), first, last,
                      (last - first) / 1e9 if first is not None else 0.0, meta,
                      log.recovery.to_dict() if log.recovery else None, skipped_counts(log))


def format_summary(s: LogSummary) -> str:
    """Human-readable multi-line text of a summary.

    Parameters
    ----------
    s : LogSummary

    Returns
    -------
    str
        Times in UTC, durations in s, rates in Hz; a damaged file gets a ``DAMAGED FILE:``
        line with the one-line report (:meth:`usvlog.log.fieldlog.RecoveryReport.one_line`)
        and the details under it, trailing bytes included.
    """
    lines = []
    if s.source:
        lines.append(f"file      {s.source}")
    if s.first_ns is not None:
        h = s.health or {}
        base, since = h.get("time_base"), str(h.get("time_counted_from") or "")
        if base in ("relative", "boot") and since.startswith("1970"):   # no absolute base: dates would be made up
            what = "time since boot" if base == "boot" else "relative time"
            lines.append(f"time      {what} {s.first_ns / 1e9:.3f} .. {s.last_ns / 1e9:.3f} s  "
                         f"({s.duration_s:.1f} s; no absolute time in the source: --start-utc ISO on import sets one)")
        else:
            lines.append(f"time      {format_time(s.first_ns)} .. {format_time(s.last_ns)}  ({s.duration_s:.1f} s)")
    lines.append("")
    lines.append(f"{'channel':<24} {'schema':<28} {'messages':>9} {'rate Hz':>8} {'gaps':>5} {'backwd':>6} {'dup':>5}")
    for c in s.channels:
        rate = f"{c.rate_hz:.2f}" if c.rate_hz else "-"
        lines.append(f"{c.topic:<24} {c.schema:<28} {c.count:>9} {rate:>8} {len(c.gaps):>5} {c.backwards:>6} "
                     f"{c.duplicates:>5}")
    for c in s.channels:
        for g in c.gaps[:5]:
            lines.append(f"  gap in {c.topic}: {g.duration_s:.2f} s from {format_time(g.start_ns)}")
        if c.backwards:
            lines.append(f"  {c.topic}: {c.backwards} time stamps go backwards")
    if s.skipped:
        lines.append("skipped records: " + ", ".join(f"{k} {v}" for k, v in sorted(s.skipped.items())))
    if s.recovery:
        r = s.recovery
        lines.append(f"DAMAGED FILE: {r['summary']}")
        lines.append(f"          {r['reason']}; recovered {r['messages_recovered']} messages, "
                     f"lost {r['bytes_lost']} of {r['file_size']} bytes"
                     + (f"; {r['trailing_bytes']} bytes after the end of the MCAP data (not part of it)"
                        if r.get("trailing_bytes") else ""))
    if "usvlog.datum" in s.metadata:
        d = s.metadata["usvlog.datum"]
        lines.append(f"datum     lat {d.get('lat_deg')} lon {d.get('lon_deg')}")
    if "usvlog.vessel" in s.metadata:
        v = s.metadata["usvlog.vessel"]
        lines.append("vessel    " + v.get("name", "") + "  " + " ".join(
            f"{k.split('.', 1)[1]}={v[k]}" for k in v if k.startswith("model.")))
    prov = [s.metadata[k] for k in sorted(s.metadata) if k.startswith("usvlog.provenance/")]
    for p in prov:
        lines.append(f"produced  by {p.get('producer', '?')} from {p.get('source', '?')}")
    health = s.health
    if health:
        lines.extend(format_health(health))
    return "\n".join(lines)
