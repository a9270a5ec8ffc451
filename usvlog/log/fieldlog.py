"""FieldLog: the in-memory form of one run.

One pandas DataFrame per topic, indexed by int64 ``t_ns`` (ns since the Unix epoch,
the MCAP log time), plus metadata records ``{name: {key: str}}`` as stored in MCAP.
"""

from __future__ import annotations

import datetime as _dt
import json
import re
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from .._version import __version__
from ..errors import InputError
from ..model.frames import Datum
from ..model.vessel import Vessel

META_DATUM = "usvlog.datum"
META_VESSEL = "usvlog.vessel"
META_PROVENANCE = "usvlog.provenance"  # stored as usvlog.provenance/0, /1, ... in order


@dataclass(frozen=True)
class RecoveryReport:
    """What was recovered from a damaged (truncated) file."""

    file_size: int
    bytes_recovered: int     # bytes of the file that were used (complete records)
    bytes_lost: int          # bytes after the last complete chunk
    messages_recovered: int
    lost_from_ns: int | None  # earliest time that may be missing (end of recovered data)
    lost_to_ns: int | None    # latest time known to be missing, when known (else None)
    reason: str

    def describe(self) -> str:
        s = (f"recovered {self.messages_recovered} messages; {self.bytes_lost} of {self.file_size} bytes lost"
             f" ({self.reason})")
        if self.lost_from_ns is not None:
            s += f"; data after {format_time(self.lost_from_ns)} lost"
        return s

    def to_dict(self) -> dict:
        return {"file_size": self.file_size, "bytes_recovered": self.bytes_recovered,
                "bytes_lost": self.bytes_lost, "messages_recovered": self.messages_recovered,
                "lost_from_ns": self.lost_from_ns, "lost_to_ns": self.lost_to_ns, "reason": self.reason}


def format_time(t_ns: int) -> str:
    """ns since the Unix epoch -> ISO 8601 UTC text with milliseconds."""
    return _dt.datetime.fromtimestamp(t_ns / 1e9, tz=_dt.UTC).isoformat(timespec="milliseconds")


_FRACTION = re.compile(r"(?<=\d)[.,](\d+)")
_EPOCH = _dt.datetime(1970, 1, 1, tzinfo=_dt.UTC)


def parse_time(text: str) -> int:
    """ISO 8601 time -> ns since the epoch, exact (fractions to the ns); UTC when it has no
    zone. Raises ValueError when ``text`` is not one."""
    s = str(text).strip().replace("Z", "+00:00").replace("z", "+00:00")
    frac = _FRACTION.search(s)
    ns = 0
    if frac is not None:
        ns = int((frac.group(1) + "000000000")[:9])
        s = s[:frac.start()] + s[frac.end():]
    t = _dt.datetime.fromisoformat(s)
    if t.tzinfo is None:
        t = t.replace(tzinfo=_dt.UTC)
    d = t - _EPOCH
    return (d.days * 86_400 + d.seconds) * 1_000_000_000 + ns


@dataclass
class FieldLog:
    """One run in memory: a pandas DataFrame per channel plus the run's metadata.

    ``usvlog.load`` reads one from a canonical MCAP file and ``usvlog.save`` writes one; the
    importers and the simulator make them, and every stage (estimate, identify, replay) returns
    a copy with its results added as new channels.

    Attributes
    ----------
    channels : dict of str to pandas.DataFrame
        Topic (``/gnss/fix``, ``/compass/heading``, ...) -> frame indexed by int64 ``t_ns``
        (ns since the Unix epoch, the MCAP log time), one row per message; columns carry their
        unit in the name (``lat_deg``, ``heading_rad``, ``u_mps``).
    meta : dict of str to dict of str to str
        Metadata records as stored in MCAP: ``usvlog.datum`` (see :attr:`datum`),
        ``usvlog.vessel`` (see :attr:`vessel`), ``usvlog.provenance/N`` (see :attr:`provenance`).
    schemas : dict of str to dict
        Topic -> JSON Schema read from the file (empty for channels made in memory).
    recovery : RecoveryReport or None
        What was lost when the file was damaged (None when it was read whole).
    source : str or None
        The path the log was loaded from.
    """

    channels: dict[str, pd.DataFrame] = field(default_factory=dict)
    meta: dict[str, dict[str, str]] = field(default_factory=dict)
    schemas: dict[str, dict] = field(default_factory=dict)  # topic -> schema read from file (if any)
    recovery: RecoveryReport | None = None
    source: str | None = None  # path it was loaded from

    # -- channels -------------------------------------------------------------------
    def __contains__(self, topic: str) -> bool:
        """True when the log has channel ``topic``."""
        return topic in self.channels

    def __getitem__(self, topic: str) -> pd.DataFrame:
        """The frame of channel ``topic`` (indexed by ``t_ns``, ns since the Unix epoch).

        Raises
        ------
        InputError
            When the log has no such channel (the message names the channels it has).
        """
        try:
            return self.channels[topic]
        except KeyError:
            where = f"{self.source}: " if self.source else ""
            have = ", ".join(sorted(self.channels)) or "none"
            raise InputError(f"{where}channel {topic} is missing (channels: {have})") from None

    def get(self, topic: str) -> pd.DataFrame | None:
        """The frame of channel ``topic``, or None when the log has no such channel."""
        return self.channels.get(topic)

    def set(self, topic: str, frame: pd.DataFrame) -> None:
        """Add or replace a channel.

        Parameters
        ----------
        topic : str
            Channel name, e.g. ``/estimate/state``.
        frame : pandas.DataFrame
            One row per message. Its index becomes int64 ``t_ns`` (ns since the Unix epoch): an
            integer index is taken as ns, a DatetimeIndex is converted.
        """
        idx = frame.index
        if idx.name != "t_ns" or idx.dtype != np.int64:
            if isinstance(idx, pd.DatetimeIndex):
                vals = idx.as_unit("ns").asi8
            else:
                vals = np.asarray(idx, dtype=np.int64)
            frame = frame.set_axis(pd.Index(vals, name="t_ns"), axis=0)
        self.channels[topic] = frame

    @property
    def topics(self) -> list[str]:
        """The channel names, sorted."""
        return sorted(self.channels)

    def time_range(self) -> tuple[int, int] | None:
        """(first, last) time stamp over every channel in ns since the Unix epoch; None when empty."""
        lo = [int(f.index.min()) for f in self.channels.values() if len(f)]
        hi = [int(f.index.max()) for f in self.channels.values() if len(f)]
        return (min(lo), max(hi)) if lo else None

    # -- metadata -------------------------------------------------------------------
    @property
    def datum(self) -> Datum | None:
        """Origin (latitude, longitude in degrees, altitude in m) of the local NED frame, if stored."""
        d = self.meta.get(META_DATUM)
        return Datum.from_dict(d) if d else None

    @datum.setter
    def datum(self, value: Datum) -> None:
        self.meta[META_DATUM] = value.to_dict()

    @property
    def vessel(self) -> Vessel | None:
        """The vessel stored with the run (model parameters in SI units, thrusters), if any."""
        d = self.meta.get(META_VESSEL)
        return Vessel.from_dict(d) if d else None

    @vessel.setter
    def vessel(self, value: Vessel) -> None:
        self.meta[META_VESSEL] = value.to_dict()

    @property
    def provenance(self) -> list[dict[str, str]]:
        """Provenance records in order: producer, usvlog version, source, settings (JSON text)."""
        keys = sorted((k for k in self.meta if k.startswith(META_PROVENANCE + "/")),
                      key=lambda k: int(k.rsplit("/", 1)[1]))
        return [self.meta[k] for k in keys]

    def add_provenance(self, *, producer: str, source: str = "", settings: dict | None = None,
                       **extra) -> None:
        """Append a provenance record: what produced (or changed) this log, from what, how.

        Parameters
        ----------
        producer : str
            What made the change, e.g. ``"usvlog estimate"``.
        source : str
            The input it came from (a file name).
        settings : dict, optional
            Settings used; stored as JSON text.
        **extra
            Further fields; values that are not text are stored as JSON.
        """
        rec = {"producer": producer, "usvlog_version": __version__, "source": source,
               "settings": json.dumps(settings or {}, sort_keys=True, default=str)}
        rec.update({k: v if isinstance(v, str) else json.dumps(v, sort_keys=True, default=str)
                    for k, v in extra.items()})
        n = len(self.provenance)
        self.meta[f"{META_PROVENANCE}/{n}"] = rec

    def copy(self, deep: bool = False) -> FieldLog:
        """A copy whose channels and metadata can be added, replaced or removed independently.

        By default the copy **shares the DataFrames** with this log (so copying a large log costs
        nothing): adding, replacing (:meth:`set`) or removing a channel in either log does not
        affect the other, and metadata records are copied, but changing a shared frame in place
        (``log["/gnss/fix"].loc[...] = ...``) changes it in both. ``deep=True`` copies the frames
        too.

        Parameters
        ----------
        deep : bool
            Also copy every DataFrame.

        Returns
        -------
        FieldLog
        """
        channels = {k: f.copy(deep=True) for k, f in self.channels.items()} if deep else dict(self.channels)
        return FieldLog(channels=channels, meta={k: dict(v) for k, v in self.meta.items()},
                        schemas=dict(self.schemas), recovery=self.recovery, source=self.source)

    def equals(self, other: FieldLog) -> bool:
        """True when both logs have the same channels (values, index, column order) and metadata."""
        if set(self.channels) != set(other.channels) or self.meta != other.meta:
            return False
        return all(self.channels[k].equals(other.channels[k]) and
                   list(self.channels[k].columns) == list(other.channels[k].columns)
                   for k in self.channels)
