"""Fast decoding of JSON messages that share one layout: compiled scans instead of a parser.

A channel's JSON messages are written with the same keys in the same order, only the values
differing. :func:`_template` works that layout out once from one message (the literal text
between its scalar values and each value's path, :func:`_layout`) and plans which value
goes to which column; :func:`_decode_layout` then locates every message's values with one
compiled scan (:func:`.kernels.match_template`) and converts them column by column (numbers
the scan leaves undecided go to pyarrow, :func:`_floats`; strings are decoded once per
distinct value, :func:`_strings`). It returns None when the messages do not all match, and
:meth:`.json_codec.Codec.decode_spans` then takes the reference path (``orjson.loads``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import orjson

from ..._jit import readonly
from ...log.channels import StrCodes
from . import kernels as K

if TYPE_CHECKING:
    from .json_codec import Codec


_NS = 1_000_000_000


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
