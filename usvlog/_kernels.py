"""Compiled (numba) inner loops for reading and writing canonical logs.

Only byte-level loops live here: walking MCAP records, matching flat JSON messages
against a template, and assembling message/chunk bytes. The callers
(``usvlog.channels`` and ``usvlog.io.mcapio``) keep a simple pure-Python reference
path next to each fast path, and the tests check one against the other.
"""

from __future__ import annotations

import numpy as np
from numba import njit

# value kinds found by ``match_template``
K_INT, K_FLOAT, K_STR, K_STR_ESC, K_TRUE, K_FALSE, K_NULL, K_INT_BIG = 0, 1, 2, 3, 4, 5, 6, 7

OP_MESSAGE, OP_CHUNK, OP_FOOTER, OP_DATA_END = 0x05, 0x06, 0x02, 0x0F


# -----------------------------------------------------------------------------
# MCAP records
# -----------------------------------------------------------------------------

@njit(cache=True)
def _u64(buf, p):
    v = np.uint64(0)
    for i in range(7, -1, -1):
        v = (v << np.uint64(8)) | np.uint64(buf[p + i])
    return v


@njit(cache=True)
def _u32(buf, p):
    return (np.int64(buf[p]) | (np.int64(buf[p + 1]) << 8) | (np.int64(buf[p + 2]) << 16)
            | (np.int64(buf[p + 3]) << 24))


@njit(cache=True)
def walk_records(buf, start, end, top_level):
    """Records in buf[start:end] -> (ops, offsets, body lengths, stop offset, complete).

    Stops before the first record that does not fit (``complete`` False), or, at top
    level, after a Data End or Footer record (``complete`` True).
    """
    cap = 1024
    ops = np.empty(cap, np.uint8)
    offs = np.empty(cap, np.int64)
    lens = np.empty(cap, np.int64)
    n = 0
    off = start
    complete = False
    while off + 9 <= end:
        op = buf[off]
        length = _u64(buf, off + 1)
        if length > np.uint64(end - off - 9):
            break
        nxt = off + 9 + np.int64(length)
        if n == cap:
            cap *= 2
            ops2 = np.empty(cap, np.uint8)
            offs2 = np.empty(cap, np.int64)
            lens2 = np.empty(cap, np.int64)
            ops2[:n] = ops[:n]
            offs2[:n] = offs[:n]
            lens2[:n] = lens[:n]
            ops, offs, lens = ops2, offs2, lens2
        ops[n] = op
        offs[n] = off
        lens[n] = nxt - off - 9
        n += 1
        off = nxt
        if top_level and (op == OP_FOOTER or op == OP_DATA_END):
            complete = True
            break
    if off == end and not top_level:
        complete = True
    return ops[:n], offs[:n], lens[:n], off, complete


@njit(cache=True)
def message_fields(buf, offs, lens):
    """(channel id, sequence, log time, payload start, payload end) of message records."""
    n = len(offs)
    cid = np.empty(n, np.int64)
    seq = np.empty(n, np.int64)
    t = np.empty(n, np.int64)
    ps = np.empty(n, np.int64)
    pe = np.empty(n, np.int64)
    ok = True
    for i in range(n):
        b = offs[i] + 9
        if lens[i] < 22:
            ok = False
            cid[i] = -1
            seq[i] = 0
            t[i] = 0
            ps[i] = b
            pe[i] = b
            continue
        cid[i] = np.int64(buf[b]) | (np.int64(buf[b + 1]) << 8)
        seq[i] = _u32(buf, b + 2)
        t[i] = np.int64(_u64(buf, b + 6))
        ps[i] = b + 22
        pe[i] = b + lens[i]
    return cid, seq, t, ps, pe, ok


# -----------------------------------------------------------------------------
# flat JSON messages
# -----------------------------------------------------------------------------

@njit(cache=True)
def _scan_number(buf, p, end):
    """End of a JSON number at p (or -1 if malformed), and whether it is an integer."""
    q = p
    if q < end and buf[q] == 45:  # '-'
        q += 1
    if q >= end:
        return -1, False
    c = buf[q]
    if c == 48:  # '0'
        q += 1
    elif 49 <= c <= 57:
        while q < end and 48 <= buf[q] <= 57:
            q += 1
    else:
        return -1, False
    is_int = True
    if q < end and buf[q] == 46:  # '.'
        is_int = False
        q += 1
        d0 = q
        while q < end and 48 <= buf[q] <= 57:
            q += 1
        if q == d0:
            return -1, False
    if q < end and (buf[q] == 101 or buf[q] == 69):  # e E
        is_int = False
        q += 1
        if q < end and (buf[q] == 43 or buf[q] == 45):
            q += 1
        d0 = q
        while q < end and 48 <= buf[q] <= 57:
            q += 1
        if q == d0:
            return -1, False
    return q, is_int


@njit(cache=True)
def _lit(buf, p, end, word):
    n = len(word)
    if p + n > end:
        return False
    for i in range(n):
        if buf[p + i] != word[i]:
            return False
    return True


_TRUE = np.frombuffer(b"true", np.uint8).copy()
_FALSE = np.frombuffer(b"false", np.uint8).copy()
_NULL = np.frombuffer(b"null", np.uint8).copy()


@njit(cache=True)
def match_template(buf, starts, ends, lits, lit_off, nslots, w_true, w_false, w_null):
    """Match messages buf[starts[i]:ends[i]] against ``lit_0 v_0 lit_1 ... v_{S-1} lit_S``.

    Returns (kinds (n, S) int8, value starts, value ends (strings include quotes),
    integer values, index of the first message that does not match or -1).
    """
    n = len(starts)
    kinds = np.empty((n, nslots), np.int8)
    vs = np.empty((n, nslots), np.int64)
    ve = np.empty((n, nslots), np.int64)
    iv = np.zeros((n, nslots), np.int64)
    for i in range(n):
        p = starts[i]
        end = ends[i]
        for k in range(nslots + 1):
            a = lit_off[k]
            b = lit_off[k + 1]
            if p + (b - a) > end:
                return kinds, vs, ve, iv, i
            for j in range(b - a):
                if buf[p + j] != lits[a + j]:
                    return kinds, vs, ve, iv, i
            p += b - a
            if k == nslots:
                break
            if p >= end:
                return kinds, vs, ve, iv, i
            c = buf[p]
            vs[i, k] = p
            if c == 34:  # '"'
                q = p + 1
                kind = K_STR
                while q < end:
                    d = buf[q]
                    if d == 34:
                        break
                    if d < 32:
                        return kinds, vs, ve, iv, i
                    if d == 92:  # backslash
                        kind = K_STR_ESC
                        q += 1
                    q += 1
                if q >= end:
                    return kinds, vs, ve, iv, i
                p = q + 1
                kinds[i, k] = kind
            elif c == 116:
                if not _lit(buf, p, end, w_true):
                    return kinds, vs, ve, iv, i
                p += 4
                kinds[i, k] = K_TRUE
            elif c == 102:
                if not _lit(buf, p, end, w_false):
                    return kinds, vs, ve, iv, i
                p += 5
                kinds[i, k] = K_FALSE
            elif c == 110:
                if not _lit(buf, p, end, w_null):
                    return kinds, vs, ve, iv, i
                p += 4
                kinds[i, k] = K_NULL
            else:
                q, is_int = _scan_number(buf, p, end)
                if q < 0:
                    return kinds, vs, ve, iv, i
                if is_int:
                    neg = buf[p] == 45
                    d0 = p + 1 if neg else p
                    kinds[i, k] = K_INT_BIG
                    if q - d0 <= 19:
                        v = np.uint64(0)
                        for j in range(d0, q):
                            v = v * np.uint64(10) + np.uint64(buf[j] - 48)
                        if v <= np.uint64(9223372036854775807):
                            iv[i, k] = -np.int64(v) if neg else np.int64(v)
                            kinds[i, k] = K_INT
                else:
                    kinds[i, k] = K_FLOAT
                p = q
            ve[i, k] = p
        if p != end:
            return kinds, vs, ve, iv, i
    return kinds, vs, ve, iv, -1


@njit(cache=True)
def gather(buf, vs, ve):
    """Concatenate the spans buf[vs[i]:ve[i]] -> (data uint8, int32 offsets)."""
    n = len(vs)
    offs = np.empty(n + 1, np.int32)
    offs[0] = 0
    tot = 0
    for i in range(n):
        tot += ve[i] - vs[i]
        offs[i + 1] = tot
    out = np.empty(tot, np.uint8)
    p = 0
    for i in range(n):
        for j in range(vs[i], ve[i]):
            out[p] = buf[j]
            p += 1
    return out, offs


@njit(cache=True)
def runs_of_equal_spans(buf, vs, ve):
    """Label spans so that consecutive equal spans share a label: (labels, first index of each)."""
    n = len(vs)
    lab = np.empty(n, np.int64)
    firsts = np.empty(n, np.int64)
    m = 0
    for i in range(n):
        same = False
        if i > 0:
            a, b = vs[i - 1], vs[i]
            la, lb = ve[i - 1] - a, ve[i] - b
            if la == lb:
                same = True
                for j in range(la):
                    if buf[a + j] != buf[b + j]:
                        same = False
                        break
        if not same:
            firsts[m] = i
            m += 1
        lab[i] = m - 1
    return lab, firsts[:m]


@njit(cache=True)
def assemble(lits, lit_off, data, vs, ve):
    """Build messages ``lit_0 v_0 lit_1 ... v_{S-1} lit_S`` where value k of row i is
    data[vs[i, k]:ve[i, k]]. Returns (bytes uint8, int64 offsets of the n messages)."""
    n, nslots = vs.shape
    offs = np.empty(n + 1, np.int64)
    offs[0] = 0
    litlen = lit_off[nslots + 1] - lit_off[0]
    tot = 0
    for i in range(n):
        s = litlen
        for k in range(nslots):
            s += ve[i, k] - vs[i, k]
        tot += s
        offs[i + 1] = tot
    out = np.empty(tot, np.uint8)
    p = 0
    for i in range(n):
        for k in range(nslots + 1):
            for j in range(lit_off[k], lit_off[k + 1]):
                out[p] = lits[j]
                p += 1
            if k == nslots:
                break
            for j in range(vs[i, k], ve[i, k]):
                out[p] = data[j]
                p += 1
    return out, offs


@njit(cache=True)
def message_records(data, ps, pe, cid, seq, t):
    """MCAP Message records (publish time = log time) for payloads data[ps[i]:pe[i]].

    Returns (bytes uint8, int64 offsets of the n+1 record bounds)."""
    n = len(ps)
    offs = np.empty(n + 1, np.int64)
    offs[0] = 0
    for i in range(n):
        offs[i + 1] = offs[i] + 31 + (pe[i] - ps[i])
    out = np.empty(offs[n], np.uint8)
    for i in range(n):
        p = offs[i]
        out[p] = OP_MESSAGE
        length = np.uint64(22 + pe[i] - ps[i])
        for k in range(8):
            out[p + 1 + k] = np.uint8((length >> np.uint64(8 * k)) & np.uint64(255))
        c = np.uint64(cid[i])
        out[p + 9] = np.uint8(c & np.uint64(255))
        out[p + 10] = np.uint8((c >> np.uint64(8)) & np.uint64(255))
        s = np.uint64(seq[i])
        for k in range(4):
            out[p + 11 + k] = np.uint8((s >> np.uint64(8 * k)) & np.uint64(255))
        tt = np.uint64(t[i])
        for k in range(8):
            b = np.uint8((tt >> np.uint64(8 * k)) & np.uint64(255))
            out[p + 15 + k] = b
            out[p + 23 + k] = b
        q = p + 31
        for j in range(ps[i], pe[i]):
            out[q] = data[j]
            q += 1
    return out, offs


@njit(cache=True)
def chunk_bounds(rec_offs, chunk_size, first_extra):
    """Split records into chunks the way the mcap Writer does: a chunk is closed right
    after the record that takes its size past ``chunk_size``. Returns the index one
    past the last record of each chunk."""
    n = len(rec_offs) - 1
    ends = np.empty(n, np.int64)
    m = 0
    count = first_extra
    for i in range(n):
        count += rec_offs[i + 1] - rec_offs[i]
        if count > chunk_size:
            ends[m] = i + 1
            m += 1
            count = 0
    if m == 0 or ends[m - 1] != n:
        if n > 0:
            ends[m] = n
            m += 1
    return ends[:m]
