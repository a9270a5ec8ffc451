"""The CDR codec of the bulk derived channels: frames -> little-endian CDR messages -> columns.

The high-rate derived channels (:data:`usvlog.log.channels.BULK_TOPICS`) are written by
:class:`CdrCodec` instead of JSON: little-endian CDR messages with a ``ros2msg`` schema (what
Foxglove and Rerun's MCAP loaders read). Their fields are all float64 / int64 / bool, so
every message is one fixed-size struct and a whole block is encoded or decoded at once by
compiled loops (:func:`.kernels.scatter_fields`, :func:`.kernels.gather_fields`); ``struct``
per message is the reference path. :func:`cdr_codec` gives a schema's codec (None when a
field does not fit CDR); :func:`_cdr_schema` reads a stored ros2msg definition back into a
JSON Schema. :mod:`.codec` decides which channels use it.
"""

from __future__ import annotations

import json
import re
import struct
from functools import cached_property, lru_cache
from typing import TYPE_CHECKING

import numpy as np

from ..._jit import readonly
from ...errors import InputError
from ...log.channels import CDR_MESSAGE_ENCODING, CDR_SCHEMA_ENCODING, spec_for_schema
from . import kernels as K
from .json_codec import Codec

if TYPE_CHECKING:   # pandas is imported where a frame is made (inspect never needs it)
    import pandas as pd


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
