"""Canonical channels: the registry topic -> JSON Schema -> DataFrame columns.

Every schema in ``schemas/`` is a JSON Schema (draft 2020-12) of one flat JSON
message, plus a few ``x-usvlog-*`` keywords that say how it maps to columns:

* ``x-usvlog-topics``: topics that use this schema;
* ``x-usvlog-column``: column name of a property (defaults to the property name);
* ``x-usvlog-time``: a ``{sec, nsec}`` object stored as one int64 ns column;
* ``x-usvlog-columns``: a fixed-length number array spread over named columns.

:func:`channel_spec` gives a topic's columns (a :class:`ChannelSpec`) and
:func:`frame_from_columns` builds a canonical frame from them. Topics with no
registered schema get a schema generated from the frame's dtypes
(:func:`auto_schema`). Turning frames into JSON messages (CDR ones for the bulk derived
channels, :data:`BULK_TOPICS`) and back is the job of :mod:`usvlog.io.mcap.codec`, which
reads its column layout from here.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from functools import lru_cache
from typing import TYPE_CHECKING

import numpy as np

from ..resources import schemas_dir

if TYPE_CHECKING:   # pandas is imported where a frame is made (inspect never needs it)
    import pandas as pd

SCHEMA_ENCODING = "jsonschema"
MESSAGE_ENCODING = "json"

CDR_SCHEMA_ENCODING = "ros2msg"
CDR_MESSAGE_ENCODING = "cdr"

BULK_TOPICS = frozenset({
    "/estimate/state",             # smoother states and standard deviations
    "/replay/controller",          # replayed controller, every tick
    "/replay/whatif/controller",
    "/replay/whatif/state",
    "/identify/fit",               # measured vs simulated series of a fit
    "/truth/state",                # a simulation's plant state (derived, never measured)
})
"""High-rate derived channels written as little-endian CDR with a ``ros2msg`` schema
(:class:`usvlog.io.mcap.codec.CdrCodec`) instead of JSON: numbers only, so a message is a
fixed-size struct. Sensor channels stay JSON + JSON Schema. Both read back the same."""


@dataclass(frozen=True)
class FieldSpec:
    """How one JSON property maps to frame columns."""

    prop: str                 # JSON property
    kind: str                 # "float" | "int" | "str" | "bool" | "time" | "array"
    columns: tuple[str, ...]  # frame column(s)
    nullable: bool = False


def _kind(p: dict) -> tuple[str, bool]:
    t = p.get("type")
    types = t if isinstance(t, list) else [t]
    nullable = "null" in types
    types = [x for x in types if x != "null"]
    if p.get("x-usvlog-time"):
        return "time", nullable
    if "array" in types:
        return "array", nullable
    base = types[0] if types else "string"
    return {"number": "float", "integer": "int", "string": "str", "boolean": "bool"}.get(base, "str"), nullable


_DTYPES: dict[str, object] = {"float": np.float64, "array": np.float64, "int": np.int64, "time": np.int64,
                              "bool": np.bool_, "str": "str"}


@dataclass(frozen=True)
class ChannelSpec:
    """The frame columns of one schema: one :class:`FieldSpec` per JSON property.

    Attributes
    ----------
    name : str
        The schema's title (e.g. ``usvlog.GnssFix.v1``).
    fields : tuple of FieldSpec
        In schema order. Times are int64 ns since the Unix epoch; numbers are
        float64 in SI units (NaN where a message had null).
    """

    name: str
    fields: tuple[FieldSpec, ...]

    @classmethod
    def from_schema(cls, schema: dict) -> ChannelSpec:
        """The columns a JSON Schema with ``x-usvlog-*`` keywords maps to."""
        specs = []
        for prop, p in schema.get("properties", {}).items():
            kind, nullable = _kind(p)
            if kind == "array":
                cols = tuple(p.get("x-usvlog-columns") or [f"{prop}_{i}" for i in range(int(p.get("maxItems", 0)))])
            else:
                cols = (p.get("x-usvlog-column", prop),)
            specs.append(FieldSpec(prop, kind, cols, nullable))
        return cls(schema.get("title", ""), tuple(specs))

    @property
    def columns(self) -> list[str]:
        """Frame column names, in schema order."""
        return [c for f in self.fields for c in f.columns]

    def dtypes(self) -> dict[str, object]:
        """{column: numpy dtype, or "str" for text columns}."""
        return {c: _DTYPES[f.kind] for f in self.fields for c in f.columns}

    def empty_columns(self) -> dict[str, np.ndarray]:
        """{column: empty array of its dtype} (text columns: object arrays)."""
        return {c: np.zeros(0, dtype=d) if d != "str" else np.array([], dtype=object)
                for c, d in self.dtypes().items()}


# -----------------------------------------------------------------------------
# registry
# -----------------------------------------------------------------------------

@lru_cache(maxsize=1)
def _registry() -> tuple[dict[str, dict], dict[str, str]]:
    by_name: dict[str, dict] = {}
    by_topic: dict[str, str] = {}
    for path in sorted(schemas_dir().glob("*.json")):
        schema = json.loads(path.read_text())
        name = schema.get("title") or path.stem
        by_name[name] = schema
        for topic in schema.get("x-usvlog-topics", []):
            by_topic[topic] = name
    return by_name, by_topic


def schema_names() -> list[str]:
    """Titles of the registered schemas, sorted."""
    return sorted(_registry()[0])


def schema_by_name(name: str) -> dict:
    """The registered schema titled ``name`` (KeyError if none)."""
    return _registry()[0][name]


def registered_topics() -> dict[str, str]:
    """{topic: schema name} for every topic with a registered schema."""
    return dict(_registry()[1])


def schema_for_topic(topic: str) -> dict | None:
    """The registered schema of ``topic``, or None if it has none."""
    name = _registry()[1].get(topic)
    return None if name is None else _registry()[0][name]


def channel_spec(topic: str) -> ChannelSpec | None:
    """The columns of ``topic``'s registered schema, or None if it has none."""
    s = schema_for_topic(topic)
    return None if s is None else _spec_cached(json.dumps(s))


@lru_cache(maxsize=256)
def _spec_cached(schema_json: str) -> ChannelSpec:
    return ChannelSpec.from_schema(json.loads(schema_json))


def spec_for_schema(schema: dict) -> ChannelSpec:
    """The columns of ``schema`` (e.g. one stored in a file); cached by content."""
    return _spec_cached(json.dumps(schema))


def auto_schema(topic: str, frame: pd.DataFrame) -> dict:
    """A flat JSON Schema for a frame whose topic has no registered schema."""
    import pandas as pd  # (loaded already: a frame is given)

    props = {}
    for c in frame.columns:
        dt = frame[c].dtype
        if pd.api.types.is_bool_dtype(dt):
            props[c] = {"type": "boolean"}
        elif pd.api.types.is_integer_dtype(dt):
            props[c] = {"type": "integer"}
        elif pd.api.types.is_float_dtype(dt):
            props[c] = {"type": ["number", "null"]}
        else:
            props[c] = {"type": "string"}
    name = "usvlog.auto" + topic.replace("/", ".")
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", "title": name,
            "description": f"Generated for topic {topic}", "type": "object",
            "properties": props, "required": list(props)}


def empty_frame(topic: str) -> pd.DataFrame:
    """An empty frame with the registered columns of ``topic``."""
    spec = channel_spec(topic)
    if spec is None:
        raise KeyError(topic)
    return frame_from_columns(spec.empty_columns(), np.zeros(0, dtype=np.int64), spec)


class StrCodes:
    """A column of strings as its distinct values and one code per row (``uniques[codes]``).

    A reader decodes each distinct string of a channel once; built into a frame from here, the
    column's Arrow strings are gathered from the distinct ones (``take``) instead of being made
    one Python object per row (a 1-hour ``/thrust/command``'s ``unit``: 17 -> 3.4 ms).

    Parameters
    ----------
    uniques : numpy.ndarray
        The distinct strings (object array of ``str``).
    codes : numpy.ndarray
        Index into ``uniques`` of each row (integers).
    """

    __slots__ = ("codes", "uniques")

    def __init__(self, uniques: np.ndarray, codes: np.ndarray):
        self.uniques, self.codes = uniques, codes

    def __len__(self) -> int:
        return len(self.codes)

    def __getitem__(self, ix) -> StrCodes:
        """The rows ``ix`` (an index array, slice or boolean mask), still coded."""
        return StrCodes(self.uniques, self.codes[ix])

    def objects(self) -> np.ndarray:
        """The column as an object array of ``str`` (one object per row)."""
        return self.uniques[self.codes]

    @classmethod
    def of(cls, values, codes: np.ndarray) -> StrCodes:
        """``values[codes]`` coded: ``values`` a sequence of ``str``, ``codes`` indices into it."""
        uniques = np.empty(len(values), dtype=object)
        uniques[:] = list(values)
        return cls(uniques, np.asarray(codes, dtype=np.intp))

    @classmethod
    def repeat(cls, value: str, n: int) -> StrCodes:
        """``value`` on each of ``n`` rows."""
        return cls.of([value], np.zeros(n, dtype=np.intp))


def concat_columns(parts: list) -> np.ndarray | StrCodes:
    """One column from its parts in order: arrays concatenated, coded strings (:class:`StrCodes`)
    kept coded (an object array among them makes the whole an object array)."""
    if len(parts) == 1:
        return parts[0]
    if all(isinstance(p, StrCodes) for p in parts):
        offsets = np.cumsum([0] + [len(p.uniques) for p in parts[:-1]])
        return StrCodes(np.concatenate([p.uniques for p in parts]),
                        np.concatenate([p.codes + o for p, o in zip(parts, offsets.tolist(), strict=True)]))
    return np.concatenate([p.objects() if isinstance(p, StrCodes) else p for p in parts])


def frame_from_columns(cols: Mapping[str, np.ndarray | StrCodes], t_ns: np.ndarray,
                       spec: ChannelSpec | None = None, *, copy: bool = True) -> pd.DataFrame:
    """Build a canonical frame.

    Parameters
    ----------
    cols : dict of str to ndarray
        {column: values}; object arrays and :class:`StrCodes` become ``str`` columns.
    t_ns : ndarray
        Log times, int64 ns since the Unix epoch: the frame's index ``t_ns``.
    spec : ChannelSpec, optional
        The channel's columns (:func:`channel_spec`): the frame has exactly these, in
        schema order. Without it, the columns of ``cols`` in their order.
    copy : bool, default True
        False: the frame takes the arrays as they are (a column per block, no copy into
        one 2-D block), for a caller that does not touch them again (a reader's fresh arrays).

    Returns
    -------
    pandas.DataFrame
    """
    import pandas as pd

    idx = pd.Index(np.asarray(t_ns, dtype=np.int64), name="t_ns")
    data = {}
    order = spec.columns if spec is not None else list(cols)
    for c in order:
        a = cols[c]
        if isinstance(a, StrCodes):   # Arrow strings gathered from the distinct ones
            import pyarrow as pa  # (loaded with pandas)

            strings = pa.array(a.uniques.tolist(), type=pa.large_string())
            data[c] = pd.array(strings.take(pa.array(a.codes)), dtype="str")
        elif a.dtype == object:
            data[c] = pd.array(a, dtype="str")
        else:
            data[c] = a
    return pd.DataFrame(data, index=idx, copy=None if copy else False)
