"""What is in a log: channels, counts, rates, time range, gaps, backwards steps, damage.

Pure: takes a FieldLog, returns a LogSummary (``to_dict()`` for ``--json``).
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
        return d

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


def skipped_counts(log: FieldLog) -> dict:
    """Records skipped at import, summed over the provenance records: {what: count}."""
    out: dict[str, int] = {}
    for rec in log.provenance:
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
    """Human-readable multi-line text of a :class:`LogSummary` (times in UTC, durations in s)."""
    lines = []
    if s.source:
        lines.append(f"file      {s.source}")
    if s.first_ns is not None:
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
        lines.append(f"DAMAGED FILE: {r['reason']}; recovered {r['messages_recovered']} messages, "
                     f"lost {r['bytes_lost']} of {r['file_size']} bytes"
                     + (f", data after {format_time(r['lost_from_ns'])}" if r.get('lost_from_ns') else ""))
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
    return "\n".join(lines)
