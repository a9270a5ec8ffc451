"""The message codecs of canonical channels: frames -> JSON (or CDR) messages -> columns.

A :class:`Codec` encodes a frame's rows to flat JSON messages and decodes messages
back to columns, for one schema; the columns and their kinds come from the schema
registry (:mod:`usvlog.log.channels`), which knows nothing of this codec.

Decoding uses the schema stored *in the file*, so a log stays readable after the
registry changes; encoding uses the registry. Messages that share one layout are
decoded by compiled scans (:mod:`usvlog.io.mcap.kernels`), with pyarrow for the
rare numbers those leave undecided; ``orjson.loads`` is the reference path.

The high-rate derived channels (:data:`usvlog.log.channels.BULK_TOPICS`) are written by
:class:`CdrCodec` instead: little-endian CDR messages with a ``ros2msg`` schema (what
Foxglove and Rerun's MCAP loaders read). Their fields are all float64 / int64 / bool,
so every message is one fixed-size struct and a numpy structured array encodes or
decodes a whole block at once; ``struct`` per message is the reference path.
:func:`channel_codec` picks the codec of a channel read from a file by its encodings.
"""

from __future__ import annotations

import json
import re
import struct
from functools import cached_property, lru_cache
from typing import TYPE_CHECKING

import numpy as np
import orjson

from ..._jit import readonly
from ...errors import InputError
from ...log.channels import (
    BULK_TOPICS,
    CDR_MESSAGE_ENCODING,
    CDR_SCHEMA_ENCODING,
    MESSAGE_ENCODING,
    SCHEMA_ENCODING,
    ChannelSpec,
    FieldSpec,
    StrCodes,
    concat_columns,
    schema_for_topic,
    spec_for_schema,
)
from . import kernels as K

if TYPE_CHECKING:   # pandas is imported where a frame is made (inspect never needs it)
    import pandas as pd

__all__ = ["CdrCodec", "Codec", "cdr_codec", "channel_codec", "codec_for_schema", "codec_for_topic",
           "writer_codec"]

_NS = 1_000_000_000


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



# -----------------------------------------------------------------------------
# fast decoding of messages that share one layout
# -----------------------------------------------------------------------------

def _pack(pieces: list[bytes]) -> tuple[np.ndarray, np.ndarray]:
    offs = np.zeros(len(pieces) + 1, dtype=np.int64)
    offs[1:] = np.cumsum([len(p) for p in pieces])
    return np.frombuffer(b"".join(pieces), dtype=np.uint8).copy(), offs


_WS = b" \t\r\n"


def _layout(msg: bytes) -> tuple[list[bytes], list[tuple]] | None:
    """Split one JSON object message into the literal text between its scalar values
    and the path of each value (keys and array indexes), or None if it is not valid
    JSON, not an object, or repeats a key."""
    try:
        orjson.loads(msg)
    except orjson.JSONDecodeError:
        return None
    if not msg.startswith(b"{"):
        return None
    lits: list[bytes] = []
    paths: list[tuple] = []
    stack: list[list] = []  # [is_object, current key or index]
    lit_start = 0
    expect_key = False
    i, n = 0, len(msg)
    while i < n:
        c = msg[i]
        if c in _WS:
            i += 1
        elif c == 0x7B:  # {
            stack.append([True, None])
            expect_key = True
            i += 1
        elif c == 0x5B:  # [
            stack.append([False, 0])
            expect_key = False
            i += 1
        elif c in (0x7D, 0x5D):  # } ]
            stack.pop()
            i += 1
        elif c == 0x3A:  # :
            expect_key = False
            i += 1
        elif c == 0x2C:  # ,
            top = stack[-1]
            if top[0]:
                expect_key = True
            else:
                top[1] += 1
            i += 1
        else:
            if c == 0x22:  # "
                j = i + 1
                while msg[j] != 0x22:
                    j += 2 if msg[j] == 0x5C else 1
                j += 1
                if expect_key:
                    stack[-1][1] = orjson.loads(msg[i:j])
                    i = j
                    continue
            else:
                j = i
                while j < n and msg[j] not in b",]} \t\r\n":
                    j += 1
            lits.append(msg[lit_start:i])
            paths.append(tuple(e[1] for e in stack))
            lit_start = i = j
    lits.append(msg[lit_start:])
    if len(set(paths)) != len(paths):
        return None
    return lits, paths


class _Mismatch(Exception):
    pass


_DECODE_BLOCK = 1 << 16   # messages decoded by one compiled scan


def _template(codec: Codec, msg: bytes):
    """The decoding plan of messages laid out as ``msg``: (literal bytes, their offsets,
    value paths, the plan of :func:`_decode_layout`), or None when ``msg`` has no usable
    layout. The last plan is kept on the codec (checked again per message by the scan)."""
    layout = _layout(msg)
    if layout is None:
        return None
    lits, paths = layout
    slot = {p: k for k, p in enumerate(paths)}

    def need(*path) -> int:
        k = slot.get(path)
        if k is None:
            raise _Mismatch
        return k

    try:
        plan = []
        for f in codec.fields:
            if f.kind == "time":
                plan.append((f, [need(f.prop, "sec"), need(f.prop, "nsec")]))
            elif f.kind == "array":
                if (f.prop, len(f.columns)) in slot:
                    raise _Mismatch
                plan.append((f, [need(f.prop, j) for j in range(len(f.columns))]))
            else:
                plan.append((f, [need(f.prop)]))
    except _Mismatch:
        return None
    lit_buf, lit_off = _pack(lits)
    return lit_buf, lit_off, paths, plan


def _decode_layout(codec: Codec, buf: np.ndarray, starts: np.ndarray, ends: np.ndarray, coded: bool = False
                   ) -> dict[str, np.ndarray] | None:
    """The fast path of :meth:`Codec.decode_spans`; None when it does not apply.

    The messages are matched against the template the codec last used (a channel's
    messages share one layout: it is worked out once, not once per block or chunk);
    when they do not match it, against the first message's own layout."""
    cached = codec._template
    if cached is not None:
        out = _decode_template(codec, cached, buf, starts, ends, coded)
        if out is not None:
            return out
    tpl = _template(codec, buf[starts[0]:ends[0]].tobytes())
    if tpl is None or (cached is not None and tpl[0].tobytes() == cached[0].tobytes()
                       and np.array_equal(tpl[1], cached[1])):
        return None
    codec._template = tpl
    return _decode_template(codec, tpl, buf, starts, ends, coded)


def _decode_template(codec: Codec, tpl, buf: np.ndarray, starts: np.ndarray, ends: np.ndarray, coded: bool = False
                     ) -> dict[str, np.ndarray] | None:
    """Messages decoded against one template (see :func:`_template`); None when one
    does not match it."""
    lit_buf, lit_off, paths, plan = tpl

    def columns(kinds_wanted: tuple[str, ...]) -> tuple[list[int], np.ndarray]:
        slots = [k for f, ks in plan if f.kind in kinds_wanted for k in ks]
        col = np.full(len(paths), -1, dtype=np.int64)
        col[slots] = np.arange(len(slots))
        return slots, col

    float_slots, fcol = columns(("float", "array"))
    int_slots, icol = columns(("int", "time"))
    str_slots, scol = columns(("str",))
    def match(s, e, want_text):
        return K.match_template(readonly(buf), s, e, lit_buf, lit_off, K._TRUE, K._FALSE, K._NULL, fcol, icol, scol,
                                K._POW10, want_text)

    kinds, bad, fbits, fund, iv, svs, sve, same, _, _ = match(starts, ends, False)
    if bad >= 0:
        return None
    rows = np.flatnonzero(fund.any(axis=1)) if float_slots else []
    if len(rows):  # numbers the compiled parser left undecided: their rows' text to pyarrow
        text = match(starts[rows], ends[rows], True)
        undecided = (rows, text[8], text[9])
    else:
        undecided = None
    ints = {k: iv[:, j] for j, k in enumerate(int_slots)}
    try:
        floats = _floats(kinds, fbits, undecided, float_slots) if float_slots else {}
        out: dict[str, np.ndarray] = {}
        for f, ks in plan:
            if f.kind in ("float", "array"):
                for c, k in zip(f.columns, ks):
                    out[c] = floats[k]
            elif f.kind == "int":
                k = ks[0]
                if not np.all(kinds[:, k] == K.K_INT):
                    return None
                out[f.columns[0]] = ints[k].copy()
            elif f.kind == "time":
                sec, nsec = ints[ks[0]], ints[ks[1]]
                if (not np.all(kinds[:, ks] == K.K_INT) or np.abs(sec).max() >= 9_000_000_000
                        or np.abs(nsec).max() >= 10**17):
                    return None
                out[f.columns[0]] = sec * _NS + nsec
            elif f.kind == "bool":
                kk = kinds[:, ks[0]]
                if not np.all((kk == K.K_TRUE) | (kk == K.K_FALSE)):
                    return None
                out[f.columns[0]] = kk == K.K_TRUE
            else:
                j = str_slots.index(ks[0])
                out[f.columns[0]] = _strings(buf, kinds[:, ks[0]], svs[:, j], sve[:, j], same[:, j], coded)
    except _Mismatch:
        return None
    return out


def _floats(kinds, fbits, undecided, slots: list[int]) -> dict[int, np.ndarray]:
    """Number columns (null -> NaN): the doubles ``match_template`` decided, and for the
    rows with a number it could not decide (half-way cases, subnormals, more than 19
    digits) all the row's numbers parsed by pyarrow, both with correct rounding (the
    doubles orjson gives)."""
    kk = kinds[:, slots]
    if not np.all((kk == K.K_FLOAT) | (kk == K.K_INT) | (kk == K.K_INT_BIG) | (kk == K.K_NULL)):
        raise _Mismatch
    vals = fbits.view(np.float64)
    if undecided is not None:
        # rare path (half-way cases, >19 digits): pyarrow is loaded only when needed
        import pyarrow as pa
        import pyarrow.compute as pc

        rows, fdata, foff = undecided
        arr = pa.Array.from_buffers(pa.large_string(), len(foff) - 1, [None, pa.py_buffer(foff), pa.py_buffer(fdata)])
        try:
            vals[rows] = pc.cast(arr, pa.float64()).to_numpy(zero_copy_only=False).reshape(len(rows), -1)
        except (pa.ArrowInvalid, pa.ArrowNotImplementedError) as err:
            raise _Mismatch from err
    if not np.all(np.isfinite(vals)):
        raise _Mismatch  # out of range: orjson refuses the message, so the reference path reports it
    null = kk == K.K_NULL
    out = {}
    for i, k in enumerate(slots):
        col = vals[:, i].copy()
        if null[:, i].any():
            col[null[:, i]] = np.nan
        out[k] = col
    return out


_SHORT_STRING = 64   # spans up to this long (bytes) are grouped by content before decoding


def _strings(buf, kinds, vs, ve, same, coded: bool = False):
    """String values (spans with quotes); each distinct string is decoded once. An object
    array, or with ``coded`` the distinct strings and a code per row (:class:`StrCodes`)."""
    if not np.all((kinds == K.K_STR) | (kinds == K.K_STR_ESC)):
        raise _Mismatch
    firsts = np.flatnonzero(~same)
    labels = np.cumsum(~same) - 1
    lens = ve[firsts] - vs[firsts]
    if len(firsts) > 1 and lens.max() <= _SHORT_STRING:
        # the runs' spans as zero-padded rows (a span holds no zero byte: JSON strings
        # have no raw control characters), grouped by content: one decode per distinct string
        width = int(lens.max())
        at = vs[firsts, None] + np.arange(width)
        rows = np.where(at < ve[firsts, None], buf[np.minimum(at, len(buf) - 1)], 0).astype(np.uint8)
        _, first_of, inverse = np.unique(rows.view(f"V{width}").ravel(), return_index=True, return_inverse=True)
        labels = inverse.ravel()[labels]
        firsts = firsts[first_of]
    vals = []
    try:
        for i in firsts.tolist():
            s = buf[vs[i]:ve[i]].tobytes()
            vals.append(s[1:-1].decode("utf-8") if kinds[i] == K.K_STR else orjson.loads(s))
    except (UnicodeDecodeError, orjson.JSONDecodeError) as err:
        raise _Mismatch from err
    uniq = np.empty(len(vals), dtype=object)
    uniq[:] = vals
    return StrCodes(uniq, labels) if coded else uniq[labels]



# -----------------------------------------------------------------------------
# codecs of the registered schemas
# -----------------------------------------------------------------------------

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


# -----------------------------------------------------------------------------
# CDR (ros2msg) messages of the bulk derived channels
# -----------------------------------------------------------------------------

CDR_LE = b"\x00\x01\x00\x00"
"""Encapsulation header of a little-endian plain CDR message (ROS 2's)."""
_HEAD = np.frombuffer(CDR_LE, dtype=np.uint8).copy()

ROS2MSG_PACKAGE = "usvlog/msg/"
"""Prefix of the ros2msg type names usvlog writes; only such CDR channels are loaded."""

# field kind -> (ros2msg type, numpy dtype in the message, frame dtype, struct code, size)
_CDR_KINDS = {"float": ("float64", "<f8", np.float64, "d", 8), "array": ("float64", "<f8", np.float64, "d", 8),
              "int": ("int64", "<i8", np.int64, "q", 8), "bool": ("bool", "u1", np.bool_, "B", 1)}
_ROS2_FIELD = re.compile(r"^(float64|int64|bool)(?:\[(\d+)\])?\s+([a-z][a-z0-9_]*)\s*(?:#.*)?$")


def ros2msg_name(title: str) -> str:
    """ros2msg type name of a schema title: ``usvlog.ControllerState.v1`` -> ``usvlog/msg/ControllerStateV1``."""
    parts = [p for p in title.split(".") if p]
    if parts and parts[0] == "usvlog":
        parts = parts[1:]
    name = "".join(re.sub(r"[^A-Za-z0-9]", "", p[:1].upper() + p[1:]) for p in parts)
    return ROS2MSG_PACKAGE + (name or "Message")


class CdrCodec(Codec):
    """Encodes frames to little-endian CDR messages and decodes them back, for one schema.

    A message is the 4-byte encapsulation header then the schema's properties in
    order, each aligned to its size counted from after the header (CDR's rule): float64
    for numbers (NaN and inf kept bit for bit), int64 for integers, bool (one byte),
    ``float64[N]`` for fixed-length number arrays. Every message has the same size, so
    :meth:`encode_packed` and :meth:`decode_spans` convert whole columns through a numpy
    structured dtype; :meth:`encode_row` and :meth:`decode_reference` are the per-message
    ``struct`` reference.

    Parameters
    ----------
    schema : dict
        A JSON Schema of the channel (see :mod:`usvlog.log.channels`) whose properties are
        numbers, integers, booleans or number arrays only (:func:`cdr_codec` checks).

    Attributes
    ----------
    msgdef : str
        The ros2msg definition written as the file's schema (one ``type name`` line per
        property).
    size : int
        Bytes of every message, header included.
    """

    message_encoding = CDR_MESSAGE_ENCODING
    schema_encoding = CDR_SCHEMA_ENCODING

    def __init__(self, schema: dict):
        super().__init__(schema)
        lines, names, formats, offsets, packs = [], [], [], [], []
        pos = 0   # offset after the encapsulation header
        for f in self.fields:
            rtype, mdt, _fdt, code, size = _CDR_KINDS[f.kind]
            pos = -(-pos // size) * size
            lines.append(f"{rtype}[{len(f.columns)}] {f.prop}" if f.kind == "array" else f"{rtype} {f.prop}")
            packs.append((f, pos))
            for j, c in enumerate(f.columns):
                names.append(c)
                formats.append(mdt)
                offsets.append(4 + pos + j * size)
            pos += size * len(f.columns)
        self.size: int = 4 + pos
        self.msgdef: str = "\n".join(lines) + "\n"
        self._dtype = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": self.size})
        fmt, at = "<4s", 0
        for f, p in packs:
            code, size = _CDR_KINDS[f.kind][3], _CDR_KINDS[f.kind][4]
            fmt += "x" * (p - at) + code * len(f.columns)
            at = p + size * len(f.columns)
        self._struct = struct.Struct(fmt)

    @property
    def schema_name(self) -> str:
        """The ros2msg type name (``usvlog/msg/...``) of the file's Schema record."""
        return ros2msg_name(self.name)

    @property
    def schema_data(self) -> bytes:
        """The bytes of the file's Schema record (the ros2msg definition)."""
        return self.msgdef.encode()

    # -- encode --------------------------------------------------------------------
    def encode_packed(self, frame: pd.DataFrame, topic: str = "") -> tuple[np.ndarray, np.ndarray]:
        """Frame -> (all messages' bytes as uint8, int64 offsets of the n+1 message bounds);
        the bytes of :meth:`encode_reference`."""
        data, _starts, _ends = self.encode_spans(frame, topic)
        return data, np.arange(len(frame) + 1, dtype=np.int64) * self.size

    def encode_spans(self, frame: pd.DataFrame, topic: str = "", gap: int = 0) -> tuple[np.ndarray, np.ndarray,
                                                                                         np.ndarray]:
        """Frame -> (uint8 buffer, int64 starts, int64 ends of the messages in it), each message
        after ``gap`` bytes left unset (room for what goes before it, e.g. a Message record's header:
        the writer fills it in place); the messages of :meth:`encode_packed`.

        One compiled pass writes the messages from the columns' bits (:func:`.kernels.scatter_fields`).
        """
        self._check_columns(frame, topic)
        n = len(frame)
        offs, wide = self._fields
        bits = np.empty((len(offs), n), dtype=np.uint64)
        k = 0
        for f in self.fields:
            for c in f.columns:
                bits[k] = np.asarray(frame[c].to_numpy(), dtype=_CDR_KINDS[f.kind][2]).view(
                    np.uint8 if f.kind == "bool" else np.uint64)
                k += 1
        step = gap + self.size
        starts = np.arange(n, dtype=np.int64) * step + gap
        return K.scatter_fields(bits, offs, wide, _HEAD, self._pad, self.size, gap), starts, starts + self.size

    @cached_property
    def _pad(self) -> np.ndarray:
        """The offsets of a message's padding bytes (after a bool, before an aligned field)."""
        used = np.zeros(self.size, dtype=bool)
        used[:len(CDR_LE)] = True
        for dt, o in (self._dtype.fields[c] for c in self._dtype.names):
            used[o:o + dt.itemsize] = True
        return np.flatnonzero(~used).astype(np.int64)

    def encode_row(self, row, topic: str = "") -> bytes:
        """One row ``{column: value}`` -> one CDR message (``struct``: the reference of
        :meth:`encode_packed`)."""
        vals = []
        for f in self.fields:
            for c in f.columns:
                try:
                    v = row[c]
                except KeyError:
                    raise InputError(f"channel {topic}: row lacks column {c} of schema {self.name}") from None
                vals.append(float(v) if f.kind in ("float", "array") else int(v) if f.kind == "int" else int(bool(v)))
        return self._struct.pack(CDR_LE, *vals)

    # -- decode --------------------------------------------------------------------
    def _check_sizes(self, lens: np.ndarray, topic: str) -> None:
        bad = np.flatnonzero(lens != self.size)
        if len(bad):
            raise InputError(f"channel {topic}: message {int(bad[0])} is {int(lens[bad[0]])} bytes; "
                             f"a {self.schema_name} CDR message is {self.size}")

    def decode_spans(self, buf: np.ndarray, starts: np.ndarray, ends: np.ndarray,
                     topic: str = "", coded: bool = False) -> dict[str, np.ndarray]:
        """Messages buf[starts[i]:ends[i]] (uint8 array) -> {column: array}, a column at a
        time through the structured dtype (bit for bit: NaN and inf kept). ``coded``: as for
        JSON (:meth:`Codec.decode_spans`); CDR channels hold numbers and booleans only."""
        n = len(starts)
        if n == 0:
            return self.empty_columns()
        starts = np.asarray(starts, dtype=np.int64)
        self._check_sizes(np.asarray(ends, dtype=np.int64) - starts, topic)
        buf = np.asarray(buf, dtype=np.uint8)
        head = buf[starts[:, None] + np.arange(2)]
        bad = np.flatnonzero((head[:, 0] != CDR_LE[0]) | (head[:, 1] != CDR_LE[1]))
        if len(bad):
            raise InputError(f"channel {topic}: message {int(bad[0])} is not little-endian CDR "
                             f"(encapsulation {head[bad[0]].tobytes().hex()})")
        # every field's bits gathered in one pass, a contiguous row per column (no copy of the
        # messages nor a structured view: ~2x faster); NaN and inf kept bit for bit
        offs, wide = self._fields
        bits = K.gather_fields(readonly(buf), starts, offs, wide)
        out, k = {}, 0
        for f in self.fields:
            for c in f.columns:
                out[c] = bits[k] != 0 if f.kind == "bool" else bits[k].view(_CDR_KINDS[f.kind][2])
                k += 1
        return out

    @cached_property
    def _fields(self) -> tuple[np.ndarray, np.ndarray]:
        """(byte offset of each column in a message, whether it is 8 bytes wide, else one)."""
        cols = [self._dtype.fields[c] for c in self._dtype.names]
        return (np.array([o for _dt, o in cols], dtype=np.int64),
                np.array([dt.itemsize == 8 for dt, _o in cols], dtype=np.bool_))

    def decode_reference(self, payloads: list[bytes] | list[memoryview], topic: str = "") -> dict[str, np.ndarray]:
        """CDR messages -> {column: array} through ``struct.unpack``, one message at a time
        (the reference of :meth:`decode_spans`)."""
        if not payloads:
            return self.empty_columns()
        self._check_sizes(np.array([len(p) for p in payloads]), topic)
        rows = []
        for i, p in enumerate(payloads):
            vals = self._struct.unpack(bytes(p))
            if vals[0][:2] != CDR_LE[:2]:
                raise InputError(f"channel {topic}: message {i} is not little-endian CDR")
            rows.append(vals[1:])
        out, k = {}, 0
        for f in self.fields:
            for c in f.columns:
                col = [r[k] for r in rows]
                out[c] = np.array(col, dtype=_CDR_KINDS[f.kind][2]) if f.kind != "bool" else \
                    np.array([v != 0 for v in col], dtype=bool)
                k += 1
        return out


def _cdr_schema(sname: str, msgdef: str) -> dict:
    """The JSON Schema (columns) of a ros2msg definition of float64 / int64 / bool fields
    (ValueError for anything else: such a channel is not one usvlog wrote)."""
    props: dict[str, dict] = {}
    for line in msgdef.splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        m = _ROS2_FIELD.match(line)
        if m is None or m.group(3) in props:
            raise ValueError(f"unsupported ros2msg line {line!r}")
        rtype, count, name = m.groups()
        if count is not None:
            if rtype != "float64":
                raise ValueError(f"unsupported ros2msg array {line!r}")
            props[name] = {"type": "array", "items": {"type": ["number", "null"]},
                           "minItems": int(count), "maxItems": int(count)}
        else:
            props[name] = {"type": {"float64": ["number", "null"], "int64": "integer", "bool": "boolean"}[rtype]}
    return {"title": sname, "type": "object", "properties": props, "required": list(props)}


@lru_cache(maxsize=256)
def _cdr_cached(schema_json: str) -> CdrCodec | None:
    schema = json.loads(schema_json)
    spec = spec_for_schema(schema)
    if not spec.fields or any(f.kind not in _CDR_KINDS or not re.fullmatch(r"[a-z][a-z0-9_]*", f.prop)
                              for f in spec.fields):
        return None
    return CdrCodec(schema)


def cdr_codec(schema: dict) -> CdrCodec | None:
    """The :class:`CdrCodec` of ``schema``, or None when a property is not a number,
    integer, boolean or number array (or its name is not a ros2msg field name)."""
    return _cdr_cached(json.dumps(schema))


def writer_codec(topic: str, schema: dict) -> Codec:
    """The codec a channel is written with: CDR for the bulk derived channels
    (:data:`usvlog.log.channels.BULK_TOPICS`) whose schema allows it, else JSON."""
    if topic in BULK_TOPICS:
        c = cdr_codec(schema)
        if c is not None:
            return c
    return codec_for_topic(topic) or codec_for_schema(schema)


def loadable(message_encoding: str, schema_encoding: str, schema_name: str) -> bool:
    """Whether :func:`usvlog.io.mcap.read_log` loads a channel of these encodings: JSON with a
    JSON Schema, or CDR with a ros2msg schema usvlog wrote (``usvlog/msg/...``)."""
    if message_encoding == MESSAGE_ENCODING and schema_encoding == SCHEMA_ENCODING:
        return True
    return (message_encoding == CDR_MESSAGE_ENCODING and schema_encoding == CDR_SCHEMA_ENCODING
            and schema_name.startswith(ROS2MSG_PACKAGE))


def channel_codec(topic: str, message_encoding: str, schema_encoding: str, schema_name: str,
                  schema_data: bytes) -> tuple[dict, Codec]:
    """(JSON Schema, codec) of a channel as stored in a file (see :func:`loadable`).

    A JSON channel's codec is its stored JSON Schema's. A CDR channel's is its topic's
    registered schema when that gives the same ros2msg fields (the frame's columns as
    registered), else one made from the ros2msg definition (a column per field).

    Raises
    ------
    ValueError, TypeError
        The stored schema is not usable.
    """
    if message_encoding == CDR_MESSAGE_ENCODING:
        schema, codec = _cdr_channel(topic, schema_name, schema_data.decode("utf-8"))
        return json.loads(json.dumps(schema)), codec   # the caller's own copy (the registry's is cached)
    schema = json.loads(schema_data) if schema_data else {"title": schema_name, "properties": {}}
    if not isinstance(schema, dict):
        raise TypeError("not an object")
    return schema, codec_for_schema(schema)


@lru_cache(maxsize=256)
def _cdr_channel(topic: str, schema_name: str, msgdef: str) -> tuple[dict, CdrCodec]:
    synth = _cdr_schema(schema_name, msgdef)
    registered = schema_for_topic(topic)
    if registered is not None:
        c = cdr_codec(registered)
        if c is not None and _cdr_schema(schema_name, c.msgdef) == synth:
            return registered, c
    c = cdr_codec(synth)
    if c is None:
        raise ValueError(f"ros2msg {schema_name} has no usable field")
    return synth, c
