"""The JSON codec of canonical channels: frames -> flat JSON messages -> columns.

A :class:`Codec` encodes a frame's rows to flat JSON messages and decodes messages
back to columns, for one schema; the columns and their kinds come from the schema
registry (:mod:`usvlog.log.channels`), which knows nothing of this codec. Encoding formats
each column with one ``orjson.dumps`` and assembles the messages around a fixed layout
(:func:`.kernels.assemble`); decoding goes through :mod:`.json_layout`'s compiled scans,
with ``orjson.loads`` as the reference path. :func:`codec_for_topic` and
:func:`codec_for_schema` give the (cached) codec of a registered or a stored schema;
:mod:`.cdr` is the other codec, :mod:`.codec` picks between them.
"""

from __future__ import annotations

import json
from functools import lru_cache
from typing import TYPE_CHECKING

import numpy as np
import orjson

from ...errors import InputError
from ...log.channels import (
    MESSAGE_ENCODING,
    SCHEMA_ENCODING,
    ChannelSpec,
    FieldSpec,
    concat_columns,
    schema_for_topic,
    spec_for_schema,
)
from . import kernels as K
from .json_layout import _NS, _decode_layout, _pack

if TYPE_CHECKING:   # pandas is imported where a frame is made (inspect never needs it)
    import pandas as pd


def _num(v) -> float | None:
    """A JSON number: NaN (and None) become null, as in :meth:`Codec.encode`."""
    if v is None:
        return None
    x = float(v)
    return None if x != x else x


class Codec:
    """Encodes frames to JSON messages and decodes them back, for one schema.

    Parameters
    ----------
    schema : dict
        A JSON Schema of one flat message with the ``x-usvlog-*`` column keywords
        (see :mod:`usvlog.log.channels`).

    Attributes
    ----------
    schema : dict
        The schema given.
    spec : ChannelSpec
        The schema's columns, from the registry.
    name : str
        The schema's title.
    fields : tuple of FieldSpec
        One per JSON property, in schema order.

    Times are int64 ns since the Unix epoch in frames and ``{sec, nsec}`` in
    messages; numbers are written as SI values with NaN as null.
    """

    message_encoding = MESSAGE_ENCODING
    schema_encoding = SCHEMA_ENCODING

    def __init__(self, schema: dict):
        self.schema = schema
        self.spec: ChannelSpec = spec_for_schema(schema)
        self.name: str = self.spec.name
        self.fields: tuple[FieldSpec, ...] = self.spec.fields
        self._template = None   # the message layout decoded last (see _decode_layout)

    @property
    def schema_name(self) -> str:
        """The name of the file's Schema record (the JSON Schema's title)."""
        return self.schema.get("title", "")

    @property
    def schema_data(self) -> bytes:
        """The bytes of the file's Schema record (the JSON Schema)."""
        return json.dumps(self.schema, sort_keys=False).encode()

    @property
    def columns(self) -> list[str]:
        """Frame column names, in schema order."""
        return self.spec.columns

    def dtypes(self) -> dict[str, object]:
        """{column: numpy dtype, or "str"}."""
        return self.spec.dtypes()

    # -- encode --------------------------------------------------------------------
    def encode(self, frame: pd.DataFrame, topic: str = "") -> list[bytes]:
        """Frame -> one JSON message (bytes) per row."""
        data, offs = self.encode_packed(frame, topic)
        b = data.tobytes()
        o = offs.tolist()
        return [b[o[i]:o[i + 1]] for i in range(len(o) - 1)]

    def encode_packed(self, frame: pd.DataFrame, topic: str = "") -> tuple[np.ndarray, np.ndarray]:
        """Frame -> (all messages' bytes as uint8, int64 offsets of the n+1 message bounds).

        The same bytes as :meth:`encode_reference`: each column is formatted by one
        ``orjson.dumps`` call and the messages are assembled around a fixed layout.
        """
        return self._encode(frame, topic, 0)

    def encode_spans(self, frame: pd.DataFrame, topic: str = "", gap: int = 0) -> tuple[np.ndarray, np.ndarray,
                                                                                         np.ndarray]:
        """Frame -> (uint8 buffer, int64 starts, int64 ends of the messages in it), each message
        after ``gap`` bytes left unset (room for what goes before it, e.g. a Message record's
        header: the writer fills it in place); the messages of :meth:`encode_packed`."""
        data, offs = self._encode(frame, topic, gap)
        return data, offs[:-1] + gap, offs[1:]

    def _encode(self, frame: pd.DataFrame, topic: str, gap: int) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`encode_packed` with ``gap`` bytes before each message (in the offsets' spans)."""
        import pandas as pd  # (loaded already: a frame is given)

        self._check_columns(frame, topic)
        n = len(frame)
        if n == 0:
            return np.zeros(0, dtype=np.uint8), np.zeros(1, dtype=np.int64)
        lits: list[bytes] = [b"{"]
        blobs: list[bytes] = []
        spans: list[tuple[int, np.ndarray, np.ndarray]] = []  # (blob index, starts, ends)

        def slot(values: np.ndarray | None = None, strings: list[str] | None = None, text=None) -> None:
            if strings is not None or text is not None:
                if text is not None:   # a string column: its distinct values, each made a str once
                    codes, uniq = pd.factorize(text, use_na_sentinel=False)
                    uniq = [str(u) for u in uniq]
                else:
                    codes, uniq = pd.factorize(np.array(strings, dtype=object))
                dumped = [orjson.dumps(u) for u in uniq]
                lens = np.fromiter((len(d) for d in dumped), dtype=np.int64, count=len(dumped))
                ends = np.cumsum(lens)
                blob = b"".join(dumped)
                spans.append((len(blobs), (ends - lens)[codes], ends[codes]))
            else:   # a numpy column straight (orjson's numbers are the same as from a list: ~2-4x faster)
                blob = orjson.dumps(np.ascontiguousarray(values), option=orjson.OPT_SERIALIZE_NUMPY)
                commas = np.flatnonzero(np.frombuffer(blob, dtype=np.uint8) == 44)
                starts = np.empty(n, dtype=np.int64)
                ends = np.empty(n, dtype=np.int64)
                starts[0] = 1
                starts[1:] = commas + 1
                ends[:-1] = commas
                ends[-1] = len(blob) - 1
                spans.append((len(blobs), starts, ends))
            blobs.append(blob)
            lits.append(b"")

        for i, f in enumerate(self.fields):
            lits[-1] += (b"," if i else b"") + orjson.dumps(f.prop) + b":"
            col = frame[f.columns[0]]
            if f.kind == "time":
                t = np.asarray(col.to_numpy(), dtype=np.int64)
                sec, nsec = np.divmod(t, _NS)
                lits[-1] += b'{"sec":'
                slot(sec)
                lits[-1] += b',"nsec":'
                slot(nsec)
                lits[-1] += b"}"
            elif f.kind == "array":
                lits[-1] += b"["
                for j, c in enumerate(f.columns):
                    if j:
                        lits[-1] += b","
                    slot(np.asarray(frame[c].to_numpy(), dtype=float))
                lits[-1] += b"]"
            elif f.kind == "float":
                slot(np.asarray(col.to_numpy(), dtype=float))
            elif f.kind == "int":
                slot(np.asarray(col.to_numpy(), dtype=np.int64))
            elif f.kind == "bool":
                slot(np.asarray(col.to_numpy(), dtype=bool))
            elif pd.api.types.is_string_dtype(col.dtype) and col.dtype != object:
                # str values only (pandas' string dtypes): grouped as they are, no str() per row;
                # an object column may mix 1, 1.0 and True, which group as one but print apart
                slot(text=col)
            else:
                slot(strings=[str(x) for x in col.tolist()])
        lits[-1] += b"}"
        if not blobs:
            return (np.frombuffer((b"\0" * gap + b"{}") * n, dtype=np.uint8).copy(),
                    np.arange(n + 1, dtype=np.int64) * (gap + 2))
        base = np.cumsum([0] + [len(b) for b in blobs])
        vs = np.empty((n, len(spans)), dtype=np.int64)
        ve = np.empty((n, len(spans)), dtype=np.int64)
        for k, (bi, st, en) in enumerate(spans):
            vs[:, k] = st + base[bi]
            ve[:, k] = en + base[bi]
        lit_buf, lit_off = _pack(lits)
        return K.assemble(lit_buf, lit_off, np.frombuffer(b"".join(blobs), dtype=np.uint8), vs, ve, gap)

    def _check_columns(self, frame: pd.DataFrame, topic: str) -> None:
        missing = [c for c in self.columns if c not in frame.columns]
        if missing:
            raise InputError(f"channel {topic}: frame lacks column(s) {', '.join(missing)} of schema {self.name}")

    def encode_reference(self, frame: pd.DataFrame, topic: str = "") -> list[bytes]:
        """Frame -> one JSON message per row through :meth:`encode_row` (the reference
        :meth:`encode_packed` is tested against)."""
        self._check_columns(frame, topic)
        if not self.fields:
            return [b"{}"] * len(frame)
        cols = self.columns
        values = [frame[c].tolist() for c in cols]
        return [self.encode_row(dict(zip(cols, row)), topic) for row in zip(*values)]

    def encode_row(self, row, topic: str = "") -> bytes:
        """One row ``{column: value}`` -> one JSON message, as :meth:`encode` writes it.

        For writers that produce one message at a time (the recorder: a one-row
        :meth:`encode_packed` costs over 100x more per message), and the per-row
        reference of the column-wise encoder. A column may be left out only when its
        property is nullable; NaN numbers become null.
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
    def empty_columns(self) -> dict[str, np.ndarray]:
        """{column: empty array of its dtype}."""
        return self.spec.empty_columns()

    def decode(self, payloads: list[bytes] | list[memoryview], topic: str = "") -> dict[str, np.ndarray]:
        """JSON messages -> {column: array}. Missing/null numbers become NaN."""
        if not payloads:
            return self.empty_columns()
        lens = np.fromiter((len(p) for p in payloads), dtype=np.int64, count=len(payloads))
        ends = np.cumsum(lens)
        buf = np.frombuffer(b"".join(payloads), dtype=np.uint8)
        return self.decode_spans(buf, ends - lens, ends, topic)

    def decode_spans(self, buf: np.ndarray, starts: np.ndarray, ends: np.ndarray,
                     topic: str = "", coded: bool = False) -> dict[str, np.ndarray]:
        """Messages buf[starts[i]:ends[i]] (uint8 array) -> {column: array}.

        Fast path: when every message has the first message's layout (same keys in
        the same order, values differing only), the values are located by one
        compiled scan and converted column by column. Anything else goes through
        :meth:`decode_reference`, which gives the same result. With ``coded``, a string
        column of the fast path is a :class:`usvlog.log.channels.StrCodes` (its distinct
        values and a code per row) instead of an object array, for a frame to be built from.
        """
        if len(starts) == 0:
            return self.empty_columns()
        starts, ends = np.asarray(starts, dtype=np.int64), np.asarray(ends, dtype=np.int64)
        # a block of messages at a time: the scan's temporaries stay small whatever the count
        parts = []
        for a in range(0, len(starts), _DECODE_BLOCK):
            out = _decode_layout(self, buf, starts[a:a + _DECODE_BLOCK], ends[a:a + _DECODE_BLOCK], coded)
            if out is None:
                break
            parts.append(out)
        else:
            if len(parts) == 1:
                return parts[0]
            return {c: concat_columns([p[c] for p in parts]) for c in parts[0]}
        b = buf.tobytes() if isinstance(buf, np.ndarray) else bytes(buf)
        return self.decode_reference([b[s:e] for s, e in zip(starts.tolist(), ends.tolist())], topic)

    def decode_reference(self, payloads: list[bytes] | list[memoryview], topic: str = "") -> dict[str, np.ndarray]:
        """JSON messages -> {column: array} through ``orjson.loads`` (the reference)."""
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
        """Parsed JSON messages (dicts) -> {column: array}, field by field of the schema.

        A ``{sec, nsec}`` time becomes one int64 ns column; an array field one float column
        per element (missing or null elements NaN); missing or null numbers become NaN,
        missing strings ``""``. Integer, boolean and time fields must be present.

        Parameters
        ----------
        objs : list of dict
            One dict per message, in order.
        topic : str
            Channel name, only for error messages.

        Raises
        ------
        InputError
            A required field is missing or a value has the wrong type.
        """
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
                    arr = np.array([[np.nan if x is None else x for x in r] for r in rows],
                                   dtype=float).reshape(len(objs), k)
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


_DECODE_BLOCK = 1 << 16   # messages decoded by one compiled scan


# -- codecs of the registered schemas -----------------------------------------------

def codec_for_topic(topic: str) -> Codec | None:
    """The codec of ``topic``'s registered schema, or None if it has none."""
    s = schema_for_topic(topic)
    return None if s is None else _codec_cached(json.dumps(s))


@lru_cache(maxsize=256)
def _codec_cached(schema_json: str) -> Codec:
    return Codec(json.loads(schema_json))


def codec_for_schema(schema: dict) -> Codec:
    """The codec of ``schema`` (e.g. the one stored in a file); cached by content."""
    return _codec_cached(json.dumps(schema))
