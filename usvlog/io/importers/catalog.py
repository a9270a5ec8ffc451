"""What a foreign source holds, before anything is imported: its topics and their field paths.

Every format reader offers ``catalog(path, opts) -> Catalog`` (ROS 1/2 bags, ULog, DataFlash,
NMEA/text, CSV). ``usvlog inspect SOURCE`` prints it, and the role mapping (which topic and
field feeds ``gnss``, ``heading``, ``thrust``, ``yaw_rate``, ``velocity``) is chosen from it by
structure (field names and types), not only by topic names.

Field paths are written the same way for every format: ``field.sub[i]`` after the topic name,
e.g. ``/fix.latitude``, ``/motors.data[1]``, ``actuator_outputs.1.output[0]`` (ULog topic,
multi-instance number, field), ``RCOU.C1`` (DataFlash message and field; ``GPS.1.Lat`` for
an instance).
"""

from __future__ import annotations

import datetime as _dt
import shlex
from dataclasses import dataclass, field
from pathlib import Path


@dataclass(frozen=True)
class FieldInfo:
    """One leaf field of a topic's messages.

    Attributes
    ----------
    path : str
        Path below the topic (``"latitude"``, ``"header.stamp.sec"``, ``"output[3]"``).
    type : str
        The source's type name (``"float64"``, ``"uint16"``, ``"string"``, ...).
    length : int or None
        Array length for an array field (the path then names the whole array), else None.
    sample : object
        A value from the first message (a number, a string, or a short list).
    """

    path: str
    type: str
    length: int | None = None
    sample: object = None

    def to_dict(self) -> dict:
        """JSON-ready form: ``path``, ``type``, ``length``, ``sample``."""
        return {"path": self.path, "type": self.type, "length": self.length, "sample": self.sample}


@dataclass(frozen=True)
class TopicInfo:
    """One topic (message type, ULog topic instance, DataFlash message, NMEA sentence, CSV file).

    Attributes
    ----------
    name : str
        The name ``--topic ROLE=NAME.field`` uses.
    type : str
        Message type (``"sensor_msgs/msg/NavSatFix"``, ``"vehicle_gps_position"``, ``"GGA"``, ``"csv"``).
    count : int
        Messages in the source.
    first_ns, last_ns : int or None
        Time span of the messages, ns (on the source's own time base: see ``Catalog.time_base``).
    fields : tuple of FieldInfo
        Every leaf field path.
    note : str
        Why the topic cannot be read (e.g. an unreadable message definition), else "".
    """

    name: str
    type: str
    count: int
    first_ns: int | None = None
    last_ns: int | None = None
    fields: tuple[FieldInfo, ...] = ()
    note: str = ""

    @property
    def rate_hz(self) -> float | None:
        """Mean message rate in Hz over the span (None for fewer than two messages)."""
        if self.count < 2 or self.first_ns is None or self.last_ns is None or self.last_ns <= self.first_ns:
            return None
        return (self.count - 1) / ((self.last_ns - self.first_ns) * 1e-9)

    def to_dict(self) -> dict:
        """JSON-ready form with ``rate_hz`` and every field."""
        return {"name": self.name, "type": self.type, "count": self.count, "first_ns": self.first_ns,
                "last_ns": self.last_ns, "rate_hz": self.rate_hz, "note": self.note,
                "fields": [f.to_dict() for f in self.fields]}


@dataclass
class Catalog:
    """Everything a source holds, and the role mapping chosen from it.

    Attributes
    ----------
    source : str
        The file (or ROS 2 bag directory).
    format : str
        ``csv``, ``nmea``, ``ros1``, ``ros2``, ``dataflash`` or ``ulog``.
    topics : list of TopicInfo
    time_base : str
        ``"utc"`` (absolute, from GNSS or the recorder's clock), ``"boot"`` (time since the
        logger started) or ``"relative"`` (no absolute base).
    mapping : dict
        role -> ``"topic.field.path"`` chosen (filled by the mapper).
    reasons : dict
        role -> why that source was chosen, or why none was.
    notes : list of str
        Anything the user should know (skipped topics, ambiguous candidates).
    msg_dirs : list of str
        ``--msg-dir`` directories whose ``.msg`` files were registered (ROS bags).
    propulsion : dict or None
        Commands found that the paper's twin-thruster model does not describe (a propeller
        and a rudder, or one thruster): :func:`usvlog.io.importers.mapping.propulsion_outside_model`.
    """

    source: str
    format: str
    topics: list[TopicInfo] = field(default_factory=list)
    time_base: str = "relative"
    mapping: dict = field(default_factory=dict)
    reasons: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)
    msg_dirs: list = field(default_factory=list)
    propulsion: dict | None = None

    def topic(self, name: str) -> TopicInfo | None:
        """The topic called ``name``, or None."""
        return next((t for t in self.topics if t.name == name), None)

    def import_command(self, out: str | None = None) -> str:
        """A ready-to-paste ``usvlog import`` command with the mapping spelled out as ``--topic``.

        Parameters
        ----------
        out : str, optional
            Output MCAP file; ``SOURCE-NAME.mcap`` in the current directory when None.
        """
        out = out or Path(self.source).stem + ".mcap"
        parts = ["usvlog", "import", self.source, "--out", out]
        for d in self.msg_dirs:
            parts += ["--msg-dir", d]
        if self.format in ("ros1", "ros2", "ulog", "dataflash"):
            mapping = dict(self.mapping)
            if "local_frame" in self.reasons and "local_n" in mapping:   # the pose, so its frame is decided again
                pose = mapping.pop("local_n").rsplit(".", 1)[0]
                mapping = {"local": pose, **{r: v for r, v in mapping.items() if r != "local_e"}}
            for role, spec in mapping.items():
                parts += ["--topic", f"{role}={spec}"]
        return " ".join(shlex.quote(p) for p in parts)

    def to_dict(self) -> dict:
        """JSON-ready form (``usvlog inspect SOURCE --json``), with ``import_command``."""
        return {"source": self.source, "format": self.format, "time_base": self.time_base,
                "topics": [t.to_dict() for t in self.topics], "mapping": dict(self.mapping),
                "reasons": dict(self.reasons), "notes": list(self.notes), "msg_dirs": list(self.msg_dirs),
                "propulsion": self.propulsion, "import_command": self.import_command()}


FRAME_WORDS = {"ned": "NED (x north, y east; theta clockwise from north)",
               "enu": "ROS REP-103 ENU (x east, y north; theta counter-clockwise from east)"}


def _fmt_ns(ns: int | None) -> str:
    if ns is None:
        return "-"
    if ns >= 946_684_800 * 10**9:
        return _dt.datetime.fromtimestamp(ns / 1e9, _dt.UTC).strftime("%Y-%m-%dT%H:%M:%S.%fZ")[:-4] + "Z"
    return f"{ns / 1e9:.3f} s"


def _fmt_sample(v, length: int | None = None) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return f"{v:.9g}"
    if isinstance(v, list):
        more = length is not None and length > len(v)
        return "[" + ", ".join(_fmt_sample(x) for x in v) + (", ...]" if more else "]")
    return repr(v) if isinstance(v, str) else str(v)


def format_catalog(cat: Catalog, fields: bool = True) -> str:
    """The text ``usvlog inspect SOURCE`` prints for a catalog.

    Parameters
    ----------
    cat : Catalog
        The source's topics and the role mapping.
    fields : bool
        List every field path of every topic (type, array length, sample value).

    Returns
    -------
    str
        Source, format and time base; per topic its type, count, rate (Hz) and span, then
        its field paths; the role mapping with its reasons; the notes; and a ready-to-paste
        ``usvlog import`` command.
    """
    base = {"utc": "UTC", "boot": "time since boot", "relative": "relative time (no absolute base)"}
    lines = [f"source    {cat.source}", f"format    {cat.format}",
             f"time      {base.get(cat.time_base, cat.time_base)}", f"topics    {len(cat.topics)}"]
    for t in cat.topics:
        rate = t.rate_hz
        span = "" if t.first_ns is None else f"  {_fmt_ns(t.first_ns)} .. {_fmt_ns(t.last_ns)}"
        lines.append(f"  {t.name}  [{t.type}]  {t.count} msgs" + (f"  {rate:.3g} Hz" if rate else "") + span)
        if t.note:
            lines.append(f"      skipped: {t.note}")
        if fields:
            for f in t.fields:
                arr = "" if f.length is None else (f" (length {f.length})" if f.type.endswith("[]")
                                                   else f"[{f.length}]")
                smp = _fmt_sample(f.sample, f.length)
                lines.append(f"      .{f.path:<36} {f.type}{arr}" + (f"  = {smp}" if smp else ""))
    lines.append("mapping")
    group = {"thrust_left": "thrust", "thrust_right": "thrust", "speed_mps": "velocity", "course": "velocity"}
    covered = {group[r] for r in cat.mapping if r in group}
    frames = {"local_frame": "local positions' frame", "heading_frame": "heading convention"}
    roles = list(cat.mapping) + [r for r in cat.reasons if r not in cat.mapping and r not in covered
                                 and r not in frames]
    for role in roles:
        src = cat.mapping.get(role, "(none)")
        why = cat.reasons.get(role) or cat.reasons.get(group.get(role, ""), "")
        lines.append(f"  {role:<13} <- {src}" + (f"   ({why})" if why else ""))
    for key, what in frames.items():
        if key in cat.reasons:
            lines.append(f"  {what}: {FRAME_WORDS.get(cat.reasons[key], cat.reasons[key])}")
    for n in cat.notes:
        lines.append(f"note      {n}")
    lines.append("import with")
    lines.append("  " + cat.import_command())
    return "\n".join(lines)
