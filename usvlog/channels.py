"""Canonical channels: topic -> JSON Schema -> DataFrame columns, and back.

Every schema in ``schemas/`` is a JSON Schema (draft 2020-12) of one flat JSON
message, plus a few ``x-usvlog-*`` keywords that say how it maps to columns:

* ``x-usvlog-topics``: topics that use this schema;
* ``x-usvlog-column``: column name of a property (defaults to the property name);
* ``x-usvlog-time``: a ``{sec, nsec}`` object stored as one int64 ns column;
* ``x-usvlog-columns``: a fixed-length number array spread over named columns.

Decoding uses the schema stored *in the file*, so a log stays readable after the
registry changes; encoding and validation use the registry. Topics with no
registered schema get a schema generated from the frame's dtypes.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import orjson
import pandas as pd

from .errors import InputError
from .resources import schemas_dir

SCHEMA_ENCODING = "jsonschema"
MESSAGE_ENCODING = "json"

_NS = 1_000_000_000


@dataclass(frozen=True)
class FieldSpec:
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


def _num(v) -> float | None:
    """A JSON number: NaN (and None) become null, as in :meth:`Codec.encode`."""
    if v is None:
        return None
    x = float(v)
    return None if x != x else x


class Codec:
    """Encodes frames to JSON messages and decodes them back, for one schema."""

    def __init__(self, schema: dict):
        self.schema = schema
        self.name: str = schema.get("title", "")
        specs = []
        for prop, p in schema.get("properties", {}).items():
            kind, nullable = _kind(p)
            if kind == "array":
                cols = tuple(p.get("x-usvlog-columns") or [f"{prop}_{i}" for i in range(int(p.get("maxItems", 0)))])
            else:
                cols = (p.get("x-usvlog-column", prop),)
            specs.append(FieldSpec(prop, kind, cols, nullable))
        self.fields: tuple[FieldSpec, ...] = tuple(specs)

    @property
    def columns(self) -> list[str]:
        return [c for f in self.fields for c in f.columns]

    def dtypes(self) -> dict[str, object]:
        out: dict[str, object] = {}
        for f in self.fields:
            dt = {"float": np.float64, "array": np.float64, "int": np.int64, "time": np.int64,
                  "bool": np.bool_, "str": "str"}[f.kind]
            for c in f.columns:
                out[c] = dt
        return out

    # -- encode --------------------------------------------------------------------
    def encode(self, frame: pd.DataFrame, topic: str = "") -> list[bytes]:
        """Frame -> one JSON message (bytes) per row."""
        missing = [c for c in self.columns if c not in frame.columns]
        if missing:
            raise InputError(f"channel {topic}: frame lacks column(s) {', '.join(missing)} of schema {self.name}")
        n = len(frame)
        per_field = []
        for f in self.fields:
            if f.kind == "time":
                t = np.asarray(frame[f.columns[0]].to_numpy(), dtype=np.int64)
                sec, nsec = np.divmod(t, _NS)
                vals = [{"sec": s, "nsec": ns} for s, ns in zip(sec.tolist(), nsec.tolist())]
            elif f.kind == "array":
                arr = np.column_stack([np.asarray(frame[c].to_numpy(), dtype=float) for c in f.columns]) if n else np.zeros((0, len(f.columns)))
                vals = [[None if math.isnan(x) else x for x in row] for row in arr.tolist()]
            elif f.kind == "float":
                a = np.asarray(frame[f.columns[0]].to_numpy(), dtype=float)
                vals = a.tolist()
                if np.isnan(a).any():
                    vals = [None if x != x else x for x in vals]
            elif f.kind == "int":
                vals = np.asarray(frame[f.columns[0]].to_numpy(), dtype=np.int64).tolist()
            elif f.kind == "bool":
                vals = np.asarray(frame[f.columns[0]].to_numpy(), dtype=bool).tolist()
            else:
                vals = [str(x) for x in frame[f.columns[0]].tolist()]
            per_field.append(vals)
        props = [f.prop for f in self.fields]
        dumps = orjson.dumps
        return [dumps(dict(zip(props, row))) for row in zip(*per_field)] if props else [b"{}"] * n

    def encode_row(self, row, topic: str = "") -> bytes:
        """One row ``{column: value}`` -> one JSON message, as :meth:`encode` writes it.

        For writers that produce one message at a time (the recorder). A column may be
        left out only when its property is nullable; NaN numbers become null.
        """
        obj = {}
        for f in self.fields:
            c = f.columns[0]
            try:
                if f.kind == "array":
                    obj[f.prop] = [_num(row[k]) for k in f.columns]
                    continue
                if c not in row and f.nullable:
                    obj[f.prop] = None
                    continue
                v = row[c]
                if f.kind == "time":
                    sec, nsec = divmod(int(v), _NS)
                    obj[f.prop] = {"sec": sec, "nsec": nsec}
                elif f.kind == "float":
                    obj[f.prop] = _num(v)
                elif f.kind == "int":
                    obj[f.prop] = int(v)
                elif f.kind == "bool":
                    obj[f.prop] = bool(v)
                else:
                    obj[f.prop] = str(v)
            except KeyError as err:
                raise InputError(f"channel {topic}: row lacks column {err.args[0]} of schema {self.name}") from None
            except (TypeError, ValueError) as err:
                raise InputError(f"channel {topic}: column {c} of schema {self.name}: bad value ({err})") from err
        return orjson.dumps(obj)

    # -- decode --------------------------------------------------------------------
    def decode(self, payloads: list[bytes] | list[memoryview], topic: str = "") -> dict[str, np.ndarray]:
        """JSON messages -> {column: array}. Missing/null numbers become NaN."""
        if not payloads:
            return {c: np.zeros(0, dtype=d) if d != "str" else np.array([], dtype=object)
                    for c, d in self.dtypes().items()}
        try:
            objs = orjson.loads(b"[" + b",".join(payloads) + b"]")
        except orjson.JSONDecodeError:
            objs = []
            for i, p in enumerate(payloads):
                try:
                    objs.append(orjson.loads(p))
                except orjson.JSONDecodeError as err:
                    raise InputError(f"channel {topic}: message {i} is not valid JSON: {err}") from err
        return self.decode_objects(objs, topic)

    def decode_objects(self, objs: list[dict], topic: str = "") -> dict[str, np.ndarray]:
        out: dict[str, np.ndarray] = {}
        for f in self.fields:
            p = f.prop
            try:
                if f.kind == "time":
                    vals = [o[p] for o in objs]
                    out[f.columns[0]] = np.array([v["sec"] * _NS + v["nsec"] for v in vals], dtype=np.int64)
                elif f.kind == "array":
                    k = len(f.columns)
                    rows = [o.get(p) or [None] * k for o in objs]
                    arr = np.array([[np.nan if x is None else x for x in r] for r in rows], dtype=float).reshape(len(objs), k)
                    for j, c in enumerate(f.columns):
                        out[c] = arr[:, j].copy()
                elif f.kind == "float":
                    vals = [o.get(p) for o in objs]
                    try:
                        out[f.columns[0]] = np.array(vals, dtype=float)
                    except TypeError:
                        out[f.columns[0]] = np.array([np.nan if v is None else v for v in vals], dtype=float)
                elif f.kind == "int":
                    out[f.columns[0]] = np.array([o[p] for o in objs], dtype=np.int64)
                elif f.kind == "bool":
                    out[f.columns[0]] = np.array([bool(o[p]) for o in objs], dtype=bool)
                else:
                    out[f.columns[0]] = np.array([str(o.get(p, "")) for o in objs], dtype=object)
            except (KeyError, TypeError, ValueError) as err:
                raise InputError(f"channel {topic}: field {p!r} missing or malformed ({err!r})") from err
        return out


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
    return sorted(_registry()[0])


def schema_by_name(name: str) -> dict:
    return _registry()[0][name]


def registered_topics() -> dict[str, str]:
    """{topic: schema name} for every topic with a registered schema."""
    return dict(_registry()[1])


def schema_for_topic(topic: str) -> dict | None:
    name = _registry()[1].get(topic)
    return None if name is None else _registry()[0][name]


def codec_for_topic(topic: str) -> Codec | None:
    s = schema_for_topic(topic)
    return None if s is None else _codec_cached(json.dumps(s))


@lru_cache(maxsize=256)
def _codec_cached(schema_json: str) -> Codec:
    return Codec(json.loads(schema_json))


def codec_for_schema(schema: dict) -> Codec:
    return _codec_cached(json.dumps(schema))


def auto_schema(topic: str, frame: pd.DataFrame) -> dict:
    """A flat JSON Schema for a frame whose topic has no registered schema."""
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
    codec = codec_for_topic(topic)
    if codec is None:
        raise KeyError(topic)
    return frame_from_columns(codec.decode([], topic), np.zeros(0, dtype=np.int64), codec)


def frame_from_columns(cols: dict[str, np.ndarray], t_ns: np.ndarray, codec: Codec | None = None) -> pd.DataFrame:
    """Build a canonical frame: int64 ``t_ns`` index, columns in schema order."""
    idx = pd.Index(np.asarray(t_ns, dtype=np.int64), name="t_ns")
    data = {}
    order = codec.columns if codec is not None else list(cols)
    for c in order:
        a = cols[c]
        if a.dtype == object:
            data[c] = pd.array(a, dtype="str")
        else:
            data[c] = a
    return pd.DataFrame(data, index=idx)
