"""Compiled (numba) inner loops for reading and writing canonical logs.

Only byte-level loops live here: walking MCAP records, matching flat JSON messages
against a template, gathering fixed-size (CDR) messages, and assembling message/chunk bytes. The callers
(``usvlog.channels`` and ``usvlog.io.mcapio``) keep a simple pure-Python reference
path next to each fast path, and the tests check one against the other.
"""

from __future__ import annotations

import numpy as np

from ..._jit import njit

# value kinds found by ``match_template``
K_INT, K_FLOAT, K_STR, K_STR_ESC, K_TRUE, K_FALSE, K_NULL, K_INT_BIG = 0, 1, 2, 3, 4, 5, 6, 7

OP_MESSAGE, OP_CHUNK, OP_FOOTER, OP_DATA_END = 0x05, 0x06, 0x02, 0x0F

# MCAP record: opcode (uint8), body length (uint64 LE), body
REC_OPCODE, REC_LENGTH, REC_HEADER = 0, 1, 9
# Message record body: channel id (uint16), sequence (uint32), log time, publish time (uint64, ns), payload
MSG_CHANNEL, MSG_SEQUENCE, MSG_LOG_TIME, MSG_PUBLISH_TIME, MSG_HEADER = 0, 2, 6, 14, 22


# -----------------------------------------------------------------------------
# MCAP records
# -----------------------------------------------------------------------------

@njit(inline="always")
def _u64(buf, p):
    v = np.uint64(0)
    for i in range(7, -1, -1):
        v = (v << np.uint64(8)) | np.uint64(buf[p + i])
    return v


@njit(inline="always")
def _u32(buf, p):
    return (np.int64(buf[p]) | (np.int64(buf[p + 1]) << 8) | (np.int64(buf[p + 2]) << 16)
            | (np.int64(buf[p + 3]) << 24))


@njit
def _walk_headers(buf, start, end, top_level, ops, offs, lens, store):
    """The loop of :func:`walk_records`: (records, stop offset, complete), the records'
    fields stored in ops/offs/lens when ``store``."""
    n = 0
    off = start
    complete = False
    while off + REC_HEADER <= end:
        op = buf[off + REC_OPCODE]
        length = _u64(buf, off + REC_LENGTH)
        if length > np.uint64(end - off - REC_HEADER):
            break
        nxt = off + REC_HEADER + np.int64(length)
        if store:
            ops[n] = op
            offs[n] = off
            lens[n] = nxt - off - REC_HEADER
        n += 1
        off = nxt
        if top_level and (op == OP_FOOTER or op == OP_DATA_END):
            complete = True
            break
    if off == end and not top_level:
        complete = True
    return n, off, complete


@njit(nogil=True)
def walk_records(buf, start, end, top_level):
    """Records in buf[start:end] -> (ops, offsets, body lengths, stop offset, complete).

    Stops before the first record that does not fit (``complete`` False), or, at top
    level, after a Data End or Footer record (``complete`` True). Two passes over the
    record headers, counting then filling arrays of the exact size: cheaper than
    growing arrays as the walk goes (numba counts references on every rebinding).
    """
    none8 = np.empty(0, np.uint8)
    none64 = np.empty(0, np.int64)
    n, _stop, _complete = _walk_headers(buf, start, end, top_level, none8, none64, none64, False)
    ops = np.empty(n, np.uint8)
    offs = np.empty(n, np.int64)
    lens = np.empty(n, np.int64)
    n, off, complete = _walk_headers(buf, start, end, top_level, ops, offs, lens, True)
    return ops, offs, lens, off, complete


@njit(nogil=True)
def find_chunk(buf, start, end):
    """First offset p >= start where a chunk record with a consistent header begins, or -1.

    Consistent: opcode 0x06, the record fits in buf[:end], start time <= end time <
    2**63, compression "" / "lz4" / "zstd", and the data length agrees with the record
    length (and with the uncompressed size when not compressed). Used to find the next
    chunk after a damaged region; the caller still checks the chunk's CRC.
    """
    top = np.uint64(0x7FFFFFFFFFFFFFFF)
    p = start
    while p + 49 <= end:
        if buf[p] == OP_CHUNK:
            length = _u64(buf, p + 1)
            if np.uint64(40) <= length <= np.uint64(end - p - 9):
                t0 = _u64(buf, p + 9)
                t1 = _u64(buf, p + 17)
                clen = _u32(buf, p + 37)
                ok = t0 <= t1 <= top and np.uint64(40 + clen) <= length
                if ok and clen == 3:
                    ok = buf[p + 41] == 108 and buf[p + 42] == 122 and buf[p + 43] == 52     # lz4
                elif ok and clen == 4:
                    ok = (buf[p + 41] == 122 and buf[p + 42] == 115 and buf[p + 43] == 116
                          and buf[p + 44] == 100)                                            # zstd
                elif clen != 0:
                    ok = False
                if ok:
                    rlen = _u64(buf, p + 41 + clen)
                    ok = rlen == length - np.uint64(40 + clen)
                    if ok and clen == 0:
                        ok = _u64(buf, p + 25) == rlen
                    if ok:
                        return p
        p += 1
    return -1


@njit(nogil=True)
def message_fields(buf, offs, lens):
    """(channel id, sequence, log time, payload start, payload end) of message records, and
    False if one is malformed (shorter than its header, or a log time past int64)."""
    n = len(offs)
    cid = np.empty(n, np.int64)
    seq = np.empty(n, np.int64)
    t = np.empty(n, np.int64)
    ps = np.empty(n, np.int64)
    pe = np.empty(n, np.int64)
    ok = True
    for i in range(n):
        b = offs[i] + REC_HEADER
        if lens[i] < MSG_HEADER:
            ok = False
            cid[i] = -1
            seq[i] = 0
            t[i] = 0
            ps[i] = b
            pe[i] = b
            continue
        cid[i] = np.int64(buf[b + MSG_CHANNEL]) | (np.int64(buf[b + MSG_CHANNEL + 1]) << 8)
        seq[i] = _u32(buf, b + MSG_SEQUENCE)
        tu = _u64(buf, b + MSG_LOG_TIME)
        if tu > np.uint64(0x7FFFFFFFFFFFFFFF):  # not an int64 time: a malformed record
            ok = False
            cid[i] = -1
        t[i] = np.int64(tu & np.uint64(0x7FFFFFFFFFFFFFFF))
        ps[i] = b + MSG_HEADER
        pe[i] = b + lens[i]
    return cid, seq, t, ps, pe, ok


# -----------------------------------------------------------------------------
# flat JSON messages
# -----------------------------------------------------------------------------

# JSON bytes the scanners look at
CH_QUOTE, CH_BACKSLASH, CH_PLUS, CH_MINUS, CH_DOT = ord('"'), ord("\\"), ord("+"), ord("-"), ord(".")
CH_0, CH_9, CH_E, CH_E_UPPER = ord("0"), ord("9"), ord("e"), ord("E")
CH_T, CH_F, CH_N = ord("t"), ord("f"), ord("n")          # first bytes of true, false, null
CH_CONTROL_END = 0x20                                     # bytes below are not allowed raw in strings
MAX_EXACT_DIGITS = 19                                     # decimal digits that always fit a uint64

@njit(inline="always")
def _number(buf, p, end):
    """One pass over the JSON number at p: (its end, or -1 if malformed; whether it is an
    integer; whether it is negative; the decimal mantissa of its significant digits; the
    decimal exponent; whether the mantissa holds them all (at most 19, leading zeros not
    counted)). The number's value is mantissa * 10**exponent."""
    q = p
    neg = False
    if q < end and buf[q] == CH_MINUS:
        neg = True
        q += 1
    if q >= end or not CH_0 <= buf[q] <= CH_9:
        return -1, False, neg, _U(0), 0, False
    man = _U(0)
    nd = 0          # significant digits taken
    exact = True
    exp10 = 0
    if buf[q] == CH_0:  # no leading zeros
        q += 1
    else:
        while q < end and CH_0 <= buf[q] <= CH_9:
            if nd == MAX_EXACT_DIGITS:
                exact = False
            else:
                man = man * _U(10) + _U(buf[q] - CH_0)
                nd += 1
            q += 1
    is_int = True
    if q < end and buf[q] == CH_DOT:
        is_int = False
        q += 1
        d0 = q
        while q < end and CH_0 <= buf[q] <= CH_9:
            c = buf[q]
            if nd == 0 and c == CH_0:
                exp10 -= 1
            elif nd == MAX_EXACT_DIGITS:
                exact = False
            else:
                man = man * _U(10) + _U(c - CH_0)
                nd += 1
                exp10 -= 1
            q += 1
        if q == d0:
            return -1, False, neg, _U(0), 0, False
    if q < end and (buf[q] == CH_E or buf[q] == CH_E_UPPER):
        is_int = False
        q += 1
        eneg = False
        if q < end and (buf[q] == CH_PLUS or buf[q] == CH_MINUS):
            eneg = buf[q] == CH_MINUS
            q += 1
        d0 = q
        e = 0
        while q < end and CH_0 <= buf[q] <= CH_9:
            if e < 100000:
                e = e * 10 + np.int64(buf[q] - CH_0)
            q += 1
        if q == d0:
            return -1, False, neg, _U(0), 0, False
        exp10 += -e if eneg else e
    return q, is_int, neg, man, exp10, exact


@njit(inline="always")
def _lit(buf, p, end, word):
    n = len(word)
    if p + n > end:
        return False
    for i in range(n):
        if buf[p + i] != word[i]:
            return False
    return True


# -----------------------------------------------------------------------------
# decimal -> double with correct rounding (Eisel-Lemire, as in Go's strconv and
# fast_float); the rare inputs it cannot decide are left to the caller
# -----------------------------------------------------------------------------

_Q_MIN, _Q_MAX = -342, 308


def _powers_of_ten() -> np.ndarray:
    """(hi, lo) 64-bit halves of the 128-bit mantissa of 10**q, rounded down."""
    out = np.empty((_Q_MAX - _Q_MIN + 1, 2), dtype=np.uint64)
    for i, q in enumerate(range(_Q_MIN, _Q_MAX + 1)):
        if q >= 0:
            v = 10 ** q
            b = v.bit_length()
            m = v << (128 - b) if b <= 128 else v >> (b - 128)
        else:
            d = 10 ** -q
            m = (1 << (d.bit_length() + 127)) // d
        assert 1 << 127 <= m < 1 << 128
        out[i, 0] = m >> 64
        out[i, 1] = m & ((1 << 64) - 1)
    return out


_POW10 = _powers_of_ten()
_M32 = np.uint64(0xFFFFFFFF)
_U = np.uint64


@njit(inline="always")
def _mul64(a, b):
    """Full 128-bit product of two uint64: (hi, lo)."""
    a_lo, a_hi = a & _M32, a >> _U(32)
    b_lo, b_hi = b & _M32, b >> _U(32)
    p0 = a_lo * b_lo
    p1 = a_lo * b_hi
    p2 = a_hi * b_lo
    p3 = a_hi * b_hi
    mid = (p0 >> _U(32)) + (p1 & _M32) + (p2 & _M32)
    lo = (p0 & _M32) | (mid << _U(32))
    hi = p3 + (p1 >> _U(32)) + (p2 >> _U(32)) + (mid >> _U(32))
    return hi, lo


@njit(inline="always")
def _clz64(x):
    n = 0
    if x <= _U(0x00000000FFFFFFFF):
        n += 32
        x <<= _U(32)
    if x <= _U(0x0000FFFFFFFFFFFF):
        n += 16
        x <<= _U(16)
    if x <= _U(0x00FFFFFFFFFFFFFF):
        n += 8
        x <<= _U(8)
    if x <= _U(0x0FFFFFFFFFFFFFFF):
        n += 4
        x <<= _U(4)
    if x <= _U(0x3FFFFFFFFFFFFFFF):
        n += 2
        x <<= _U(2)
    if x <= _U(0x7FFFFFFFFFFFFFFF):
        n += 1
    return n


@njit(inline="always")
def _eisel_lemire(man, q, neg, pow10):
    """The bits of the double nearest man * 10**q, and whether that was decided."""
    sign = _U(0x8000000000000000) if neg else _U(0)
    if man == _U(0):
        return sign, True
    if q < _Q_MIN or q > _Q_MAX:
        return _U(0), False
    clz = _clz64(man)
    man = man << _U(clz)
    ret_exp2 = np.int64((217706 * q) >> 16) + 64 + 1023 - clz
    hi_t = pow10[q - _Q_MIN, 0]
    lo_t = pow10[q - _Q_MIN, 1]
    x_hi, x_lo = _mul64(man, hi_t)
    if (x_hi & _U(0x1FF)) == _U(0x1FF) and x_lo + man < man:
        y_hi, y_lo = _mul64(man, lo_t)
        m_hi, m_lo = x_hi, x_lo + y_hi
        if m_lo < x_lo:
            m_hi += _U(1)
        if (m_hi & _U(0x1FF)) == _U(0x1FF) and m_lo + _U(1) == _U(0) and y_lo + man < man:
            return _U(0), False
        x_hi, x_lo = m_hi, m_lo
    msb = x_hi >> _U(63)
    mant = x_hi >> (msb + _U(9))
    ret_exp2 -= 1 - np.int64(msb)
    if x_lo == _U(0) and (x_hi & _U(0x1FF)) == _U(0) and (mant & _U(3)) == _U(1):
        return _U(0), False  # exactly half-way: not decided here
    mant += mant & _U(1)
    mant >>= _U(1)
    if (mant >> _U(53)) > _U(0):
        mant >>= _U(1)
        ret_exp2 += 1
    if ret_exp2 < 1 or ret_exp2 >= 0x7FF:
        return _U(0), False  # subnormal or out of range
    return sign | (_U(ret_exp2) << _U(52)) | (mant & _U(0x000FFFFFFFFFFFFF)), True


_CLINGER_MAX_MAN = np.uint64(1 << 53)   # integers up to this are exact doubles
_CLINGER_MAX_EXP = 22                   # 10**22 is the largest exact power of ten
_EXACT_POW10 = np.array([10.0 ** k for k in range(_CLINGER_MAX_EXP + 1)])


@njit(inline="always")
def _to_double(man, exp10, neg, pow10):
    """The double nearest (-1)**neg * man * 10**exp10 -> (its bits, decided, the double
    itself, whether it is given as the double rather than as its bits)."""
    if man <= _CLINGER_MAX_MAN and -_CLINGER_MAX_EXP <= exp10 <= _CLINGER_MAX_EXP and man != _U(0):
        # Clinger's fast path: man and 10**|exp10| are exact doubles, so one IEEE
        # multiplication or division rounds correctly
        v = np.float64(man) * _EXACT_POW10[exp10] if exp10 >= 0 else np.float64(man) / _EXACT_POW10[-exp10]
        return _U(0), True, -v if neg else v, True
    bits, ok = _eisel_lemire(man, exp10, neg, pow10)
    return bits, ok, 0.0, False


_TRUE = np.frombuffer(b"true", np.uint8).copy()
_FALSE = np.frombuffer(b"false", np.uint8).copy()
_NULL = np.frombuffer(b"null", np.uint8).copy()


@njit(nogil=True)
def match_template(buf, starts, ends, lits, lit_off, w_true, w_false, w_null, fcol, icol, scol, pow10,
                   want_text):
    """Match messages buf[starts[i]:ends[i]] against ``lit_0 v_0 lit_1 ... v_{S-1} lit_S``.

    ``fcol``/``icol``/``scol`` map each value slot to a column of the number, integer
    and string outputs (or -1). Returns (kinds (n, S) int8, index of the first
    message that does not match or -1, the numbers as double bits (n, F) (null as
    0), which numbers were not decided here (n, F), the integer values (n, I), the
    string spans with their quotes (n, T), whether each string equals the one in the
    message before, and, with ``want_text``, the numbers' text instead of their bits:
    bytes + n*F+1 offsets row by row, null and -0 written as "0").
    """
    n = len(starts)
    nslots = len(fcol)
    nf, ni, ns = 0, 0, 0
    for k in range(nslots):
        nf += fcol[k] >= 0
        ni += icol[k] >= 0
        ns += scol[k] >= 0
    kinds = np.empty((n, nslots), np.int8)
    iv = np.zeros((n, ni), np.int64)
    svs = np.zeros((n, ns), np.int64)
    sve = np.zeros((n, ns), np.int64)
    same = np.zeros((n, ns), np.bool_)
    fbits = np.zeros((n, nf), np.uint64)
    fvals = fbits.view(np.float64)
    fund = np.zeros((n, nf), np.bool_)
    cap = 0
    if want_text:
        for i in range(n):
            cap += ends[i] - starts[i]
    fdata = np.empty(cap + (n * nf if want_text else 0), np.uint8)
    foff = np.zeros(n * nf + 1 if want_text else 1, np.int64)
    fp = 0
    for i in range(n):
        p = starts[i]
        end = ends[i]
        for k in range(nslots + 1):
            a = lit_off[k]
            m = lit_off[k + 1] - a
            if p + m > end:
                return kinds, i, fbits, fund, iv, svs, sve, same, fdata, foff
            for j in range(m):
                if buf[p + j] != lits[a + j]:
                    return kinds, i, fbits, fund, iv, svs, sve, same, fdata, foff
            p += m
            if k == nslots:
                break
            if p >= end:
                return kinds, i, fbits, fund, iv, svs, sve, same, fdata, foff
            c = buf[p]
            v0 = p
            ival = np.int64(0)
            man, exp10, neg, exact = _U(0), 0, False, False   # a number's decimal digits (_number)
            if c == CH_QUOTE:
                q = p + 1
                kind = K_STR
                while q < end:
                    d = buf[q]
                    if d == CH_QUOTE:
                        break
                    if d < CH_CONTROL_END:
                        return kinds, i, fbits, fund, iv, svs, sve, same, fdata, foff
                    if d == CH_BACKSLASH:
                        kind = K_STR_ESC
                        q += 1
                    q += 1
                if q >= end:
                    return kinds, i, fbits, fund, iv, svs, sve, same, fdata, foff
                p = q + 1
            elif c == CH_T:
                if not _lit(buf, p, end, w_true):
                    return kinds, i, fbits, fund, iv, svs, sve, same, fdata, foff
                p += len(w_true)
                kind = K_TRUE
            elif c == CH_F:
                if not _lit(buf, p, end, w_false):
                    return kinds, i, fbits, fund, iv, svs, sve, same, fdata, foff
                p += len(w_false)
                kind = K_FALSE
            elif c == CH_N:
                if not _lit(buf, p, end, w_null):
                    return kinds, i, fbits, fund, iv, svs, sve, same, fdata, foff
                p += len(w_null)
                kind = K_NULL
            else:
                q, is_int, neg, man, exp10, exact = _number(buf, p, end)
                if q < 0:
                    return kinds, i, fbits, fund, iv, svs, sve, same, fdata, foff
                if is_int:
                    kind = K_INT_BIG
                    if exact and man <= np.uint64(9223372036854775807):
                        ival = -np.int64(man) if neg else np.int64(man)
                        kind = K_INT
                else:
                    kind = K_FLOAT
                p = q
            kinds[i, k] = kind
            f = fcol[k]
            if f >= 0:
                if want_text:
                    if kind == K_NULL or (kind == K_INT and ival == 0):
                        fdata[fp] = 48  # orjson reads -0 as the integer 0
                        fp += 1
                    elif kind == K_FLOAT or kind == K_INT or kind == K_INT_BIG:
                        for j in range(v0, p):
                            fdata[fp] = buf[j]
                            fp += 1
                    foff[i * nf + f + 1] = fp
                elif kind == K_FLOAT or kind == K_INT_BIG or (kind == K_INT and ival != 0):
                    if exact:
                        bits, ok, v, as_double = _to_double(man, exp10, neg, pow10)
                    else:
                        bits, ok, v, as_double = _U(0), False, 0.0, False
                    if as_double:
                        fvals[i, f] = v
                    else:
                        fbits[i, f] = bits
                        fund[i, f] = not ok
            f = icol[k]
            if f >= 0:
                iv[i, f] = ival
            f = scol[k]
            if f >= 0:
                svs[i, f] = v0
                sve[i, f] = p
                if i > 0:
                    a0 = svs[i - 1, f]
                    m = sve[i - 1, f] - a0
                    if m == p - v0:
                        eq = True
                        for j in range(m):
                            if buf[a0 + j] != buf[v0 + j]:
                                eq = False
                                break
                        same[i, f] = eq
        if p != end:
            return kinds, i, fbits, fund, iv, svs, sve, same, fdata, foff
    return kinds, -1, fbits, fund, iv, svs, sve, same, fdata[:fp], foff


@njit
def assemble(lits, lit_off, data, vs, ve, gap):
    """Build messages ``lit_0 v_0 lit_1 ... v_{S-1} lit_S`` where value k of row i is
    data[vs[i, k]:ve[i, k]], each after ``gap`` bytes left unset (for the caller to fill).
    Returns (bytes uint8, int64 offsets of the n+1 bounds: message i is
    out[offs[i] + gap:offs[i + 1]])."""
    n, nslots = vs.shape
    offs = np.empty(n + 1, np.int64)
    offs[0] = 0
    litlen = lit_off[nslots + 1] - lit_off[0]
    tot = 0
    for i in range(n):
        s = gap + litlen
        for k in range(nslots):
            s += ve[i, k] - vs[i, k]
        tot += s
        offs[i + 1] = tot
    out = np.empty(tot, np.uint8)
    for i in range(n):
        p = offs[i] + gap
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


@njit(inline="always")
def _message_header(out, p, size, c, s, tt):
    """The 31 bytes before a Message record's payload of ``size`` bytes at ``out[p]``:
    opcode, length, channel ``c``, sequence ``s``, log and publish time ``tt`` (all uint64)."""
    out[p + REC_OPCODE] = OP_MESSAGE
    length = np.uint64(MSG_HEADER) + size
    for k in range(8):
        out[p + REC_LENGTH + k] = np.uint8((length >> np.uint64(8 * k)) & np.uint64(255))
    body = p + REC_HEADER
    out[body + MSG_CHANNEL] = np.uint8(c & np.uint64(255))
    out[body + MSG_CHANNEL + 1] = np.uint8((c >> np.uint64(8)) & np.uint64(255))
    for k in range(4):
        out[body + MSG_SEQUENCE + k] = np.uint8((s >> np.uint64(8 * k)) & np.uint64(255))
    for k in range(8):
        b = np.uint8((tt >> np.uint64(8 * k)) & np.uint64(255))
        out[body + MSG_LOG_TIME + k] = b
        out[body + MSG_PUBLISH_TIME + k] = b


@njit
def message_records(data, ps, pe, cid, seq, t):
    """MCAP Message records (publish time = log time) for payloads data[ps[i]:pe[i]].

    Returns (bytes uint8, int64 offsets of the n+1 record bounds)."""
    n = len(ps)
    offs = np.empty(n + 1, np.int64)
    offs[0] = 0
    for i in range(n):
        offs[i + 1] = offs[i] + REC_HEADER + MSG_HEADER + (pe[i] - ps[i])
    out = np.empty(offs[n], np.uint8)
    for i in range(n):
        p = offs[i]
        _message_header(out, p, np.uint64(pe[i] - ps[i]), np.uint64(cid[i]), np.uint64(seq[i]), np.uint64(t[i]))
        q = p + REC_HEADER + MSG_HEADER
        out[q:q + (pe[i] - ps[i])] = data[ps[i]:pe[i]]   # a slice copy: 2-3x a byte loop
    return out, offs


@njit
def message_headers(buf, ps, pe, cid, seq, t):
    """:func:`message_records` in place: when the payloads buf[ps[i]:pe[i]] are in order,
    each after a gap of exactly a Message record's 31 header bytes, the first at 31 and the
    last ending the buffer, the headers are written into the gaps (buf becomes the records).

    Returns (whether it was done, int64 offsets of the n+1 record bounds); nothing is
    written when not (then the caller copies with :func:`message_records`)."""
    n = len(ps)
    head = REC_HEADER + MSG_HEADER
    offs = np.empty(n + 1, np.int64)
    ok = n > 0 and ps[0] == head and pe[n - 1] == len(buf)
    for i in range(n):
        if not ok:
            break
        offs[i] = ps[i] - head
        ok = pe[i] >= ps[i] and (i == n - 1 or ps[i + 1] == pe[i] + head)
    if not ok:
        return False, offs
    offs[n] = len(buf)
    for i in range(n):
        _message_header(buf, offs[i], np.uint64(pe[i] - ps[i]), np.uint64(cid[i]), np.uint64(seq[i]),
                        np.uint64(t[i]))
    return True, offs


@njit(nogil=True)
def bare_messages(buf, ps, pe):
    """Whether ``buf`` is exactly Message records with the payloads buf[ps[i]:pe[i]], back to
    back in this order, each with its publish time equal to its log time."""
    n = len(ps)
    head = REC_HEADER + MSG_HEADER
    if n == 0 or ps[0] != head or pe[n - 1] != len(buf):
        return False
    for i in range(n):
        if i + 1 < n and ps[i + 1] - head != pe[i]:
            return False
        b = ps[i] - MSG_HEADER
        for k in range(8):
            if buf[b + MSG_LOG_TIME + k] != buf[b + MSG_PUBLISH_TIME + k]:
                return False
    return True


@njit
def message_index(cid, t, offset):
    """A chunk's Message Index entries: its messages grouped by channel, channels in order
    of their first message, messages in chunk order within a channel (a counting sort).

    Returns (channel ids (k,), their message counts (k,), uint64 (n, 2) entries of
    (log time, offset in the chunk) in that order)."""
    n = len(cid)
    m = 0
    for i in range(n):
        m = max(m, cid[i] + 1)
    slot = np.full(m, -1, np.int64)
    ids = np.empty(n, np.int64)
    counts = np.zeros(n, np.int64)
    k = 0
    for i in range(n):
        c = cid[i]
        if slot[c] < 0:
            slot[c] = k
            ids[k] = c
            k += 1
        counts[slot[c]] += 1
    start = np.empty(k, np.int64)
    acc = 0
    for j in range(k):
        start[j] = acc
        acc += counts[j]
    entries = np.empty((n, 2), np.uint64)
    for i in range(n):
        j = slot[cid[i]]
        entries[start[j], 0] = np.uint64(t[i])
        entries[start[j], 1] = np.uint64(offset[i])
        start[j] += 1
    return ids[:k], counts[:k], entries


@njit
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


# -----------------------------------------------------------------------------
# fixed-size (CDR) messages
# -----------------------------------------------------------------------------

@njit(nogil=True)
def scatter_fields(bits, offs, wide, head, pad, size, gap):
    """Fixed-size messages from their fields (the inverse of :func:`gather_fields`): message
    i of ``size`` bytes at ``gap + i * (gap + size)`` is ``head``, then field k of
    ``bits[k, i]`` (an (F, n) uint64 array) at ``offs[k]``: 8 bytes little-endian when
    ``wide[k]``, else one; the bytes at ``pad`` (those no field covers) are zero. The
    ``gap`` bytes before each message are left unset (for the caller to fill).

    Returns the uint8 buffer of n * (gap + size) bytes."""
    nf, n = bits.shape
    step = gap + size
    out = np.empty(n * step, np.uint8)
    for i in range(n):
        p = i * step + gap
        for j in range(len(head)):
            out[p + j] = head[j]
        for j in range(len(pad)):
            out[p + pad[j]] = 0
        for k in range(nf):
            v = bits[k, i]
            q = p + offs[k]
            if wide[k]:
                for b in range(8):
                    out[q + b] = np.uint8((v >> np.uint64(8 * b)) & np.uint64(255))
            else:
                out[q] = np.uint8(v & np.uint64(255))
    return out


@njit(nogil=True)
def gather_fields(buf, starts, offs, wide):
    """Fields of fixed-size messages -> one (F, n) uint64 array, a row per field: field k of
    message i is the little-endian unsigned integer at ``buf[starts[i] + offs[k]]`` of 8
    bytes when ``wide[k]``, else of one byte (a float64's or int64's bits, a bool)."""
    n = len(starts)
    nf = len(offs)
    out = np.empty((nf, n), np.uint64)
    for i in range(n):
        s = starts[i]
        for k in range(nf):
            p = s + offs[k]
            out[k, i] = _u64(buf, p) if wide[k] else np.uint64(buf[p])
    return out
