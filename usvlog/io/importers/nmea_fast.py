"""Compiled NMEA import: the whole file's bytes -> per-line samples -> role streams.

The fast path of :func:`usvlog.io.importers.nmea.read`; the per-line Python parser
(:func:`usvlog.io.nmea.parse_sentence` and the importer's loop) stays the reference, and
tests compare the two on real and generated logs. Two kernels:

* :func:`scan_lines` finds the lines, their sentence, the line-prefix epoch/relative
  time, checks the checksum and parses the hot sentence types (GGA, RMC, HDT, VTG) with
  fixed field indices. Anything it is not sure of (another type, a field written in a way
  it does not read exactly like Python's ``float``/``int``, a bad checksum, an out-of-range
  value, a prefix it cannot read) it leaves to the Python parser: status ``FALLBACK``.
  Numbers are read as an integer mantissa and a power of ten (at most 15 digits), which
  is exact and so equal to Python's correctly rounded ``float``.
* :func:`sequence` runs what depends on the lines before: calendar time of the sentence
  times of day (RMC/ZDA dates, midnight roll-over), one fix per epoch (the rule of
  :class:`usvlog.io.nmea.FixSelector`), and the spreading of untimed sentences between
  the timed ones.

Why compiled and not vectorised numpy: ``scan_lines`` reads a 1-hour capture (144k lines,
every field of GGA/RMC/HDT, prefix times, checksums) in ~0.11 CPU s; a numpy version of
only the line split, the checksums (``bitwise_xor.reduceat``), the comma positions and one
field of half the lines already took ~0.2-0.25 s, so the whole parse would be several times
slower. What numba costs an import to MCAP is its load, which the MCAP writer's own kernels
pay anyway (these two kernels add ~25 ms to it); the one-off compilation on a cold cache
(~17 CPU s) is why small files (:data:`usvlog.io.importers.nmea.FAST_MIN_BYTES`) stay on
the Python parser.
"""

from __future__ import annotations

import math

import numpy as np

from ..._jit import jitable, njit
from ...model.frames import wrap_angle
from ..nmea import resolve_time_of_day

# line status (scan_lines)
BLANK, OK, FALLBACK, NO_SENTENCE = 0, 1, 2, 3
# sentence types
GGA, RMC, GLL, HDT, HDG, HDM, VTG, ZDA, OTHER = range(9)
TYPE_CODE = {"GGA": GGA, "RMC": RMC, "GLL": GLL, "HDT": HDT, "HDG": HDG, "HDM": HDM, "VTG": VTG, "ZDA": ZDA}
NONE_I64 = np.iinfo(np.int64).min      # "None" of an int64 column
# skip events (sequence)
SKIP_UNSUPPORTED, SKIP_NO_FIX, SKIP_UNTIMED = 1, 2, 3

_NS = 1_000_000_000
_DAY_NS = 86_400 * _NS
_KNOT_MPS = 1852.0 / 3600.0
_POW10 = np.array([float(10 ** k) for k in range(23)])   # exact powers of ten
_DEG = math.pi / 180.0


@jitable
def _num(buf, a, b):
    """A plain decimal number ``[-]ddd[.ddd]`` (at most 15 digits) in buf[a:b].

    Returns (status, value): status 0 empty, 1 read (exactly Python's float()), 2 written
    otherwise (left to Python).
    """
    if a >= b:
        return 0, 0.0
    neg = buf[a] == 45
    i = a + 1 if neg else a
    m = 0
    nd = 0
    k = 0
    dot = False
    while i < b:
        c = buf[i]
        if 48 <= c <= 57:
            m = m * 10 + (c - 48)
            nd += 1
            if dot:
                k += 1
        elif c == 46 and not dot:
            dot = True
        else:
            return 2, 0.0
        i += 1
    if nd == 0 or nd > 15:
        return 2, 0.0
    v = float(m) / _POW10[k]
    return 1, (-v if neg else v)


@jitable
def _uint(buf, a, b):
    """Digits only (at most 18) -> (status, value) as :func:`_num`."""
    if a >= b:
        return 0, 0
    if b - a > 18:
        return 2, 0
    m = 0
    for i in range(a, b):
        c = buf[i]
        if not 48 <= c <= 57:
            return 2, 0
        m = m * 10 + (c - 48)
    return 1, m


@jitable
def _tod(buf, a, b):
    """hhmmss(.sss) -> (status, ns since midnight); status 0 empty, 1 read, 2 not readable."""
    if a >= b:
        return 0, 0
    if b - a < 6:
        return 2, 0
    for i in range(a, a + 6):
        if not 48 <= buf[i] <= 57:
            return 2, 0
    h = (buf[a] - 48) * 10 + buf[a + 1] - 48
    mi = (buf[a + 2] - 48) * 10 + buf[a + 3] - 48
    s = (buf[a + 4] - 48) * 10 + buf[a + 5] - 48
    if not (h < 24 and mi < 60 and s < 61):
        return 2, 0
    frac = 0
    if b > a + 6:
        if buf[a + 6] != 46 or b == a + 7:
            return 2, 0
        scale = 100_000_000
        for i in range(a + 7, b):
            c = buf[i]
            if not 48 <= c <= 57:
                return 2, 0
            if scale:
                frac += (c - 48) * scale
                scale //= 10
    return 1, ((h * 60 + mi) * 60 + s) * _NS + frac


@jitable
def _days_from_civil(y, m, d):
    """Days since 1970-01-01 of a proleptic Gregorian date."""
    y -= m <= 2
    era = (y if y >= 0 else y - 399) // 400
    yoe = y - era * 400
    doy = (153 * (m + (-3 if m > 2 else 9)) + 2) // 5 + d - 1
    doe = yoe * 365 + yoe // 4 - yoe // 100 + doy
    return era * 146097 + doe - 719468


@jitable
def _date(buf, a, b):
    """ddmmyy -> (status, ns of that UTC midnight); years as ``%y`` (1969-2068)."""
    if a >= b:
        return 0, 0
    st, v = _uint(buf, a, b)
    if st != 1 or b - a != 6:
        return 2, 0
    d, mo, yy = v // 10000, v // 100 % 100, v % 100
    y = yy + (2000 if yy < 69 else 1900)
    if not 1 <= mo <= 12 or d < 1:
        return 2, 0
    leap = (y % 4 == 0 and y % 100 != 0) or y % 400 == 0
    mdays = (31, 29 if leap else 28, 31, 30, 31, 30, 31, 31, 30, 31, 30, 31)[mo - 1]
    if d > mdays:
        return 2, 0
    return 1, _days_from_civil(y, mo, d) * _DAY_NS


@jitable
def _dm(buf, a, b, width):
    """(d)ddmm.mmmm -> (ok, unsigned degrees)."""
    k = b
    for i in range(a, b):
        if buf[i] == 46:
            k = i
            break
    if k - a < 2 or k - 2 - a > width:
        return False, 0.0
    st, deg = _uint(buf, a, k - 2)
    if st == 2:
        return False, 0.0
    st, minutes = _num(buf, k - 2, b)
    if st != 1 or not (0.0 <= minutes < 60.0):
        return False, 0.0
    return True, deg + minutes / 60.0


@jitable
def _position(buf, fa, fb, i):
    """Fields i..i+3 (lat, N/S, lon, E/W) -> (status, lat, lon): 0 empty (no fix), 1 read, 2 not."""
    if fa[i] >= fb[i] or fa[i + 2] >= fb[i + 2]:
        return 0, 0.0, 0.0
    if fb[i + 1] - fa[i + 1] != 1 or fb[i + 3] - fa[i + 3] != 1:
        return 2, 0.0, 0.0
    ns, ew = buf[fa[i + 1]], buf[fa[i + 3]]
    if ns not in (78, 83) or ew not in (69, 87):        # N S / E W
        return 2, 0.0, 0.0
    ok1, la = _dm(buf, fa[i], fb[i], 2)
    ok2, lo = _dm(buf, fa[i + 2], fb[i + 2], 3)
    if not (ok1 and ok2 and la <= 90.0 and lo <= 180.0):
        return 2, 0.0, 0.0
    return 1, (-la if ns == 83 else la), (-lo if ew == 87 else lo)


@jitable
def _angle(buf, a, b):
    """Degrees in [0, 360] -> (status, rad wrapped to [-pi, pi)); status as :func:`_num`,
    2 also when out of range."""
    st, h = _num(buf, a, b)
    if st != 1:
        return st, 0.0
    if not 0.0 <= h <= 360.0:
        return 2, 0.0
    return 1, wrap_angle(h * _DEG)


@jitable
def _is(buf, fa, fb, i, ch):
    return fb[i] - fa[i] == 1 and buf[fa[i]] == ch


@jitable
def _ws(c):
    return c == 32 or 9 <= c <= 13 or 28 <= c <= 31


@jitable
def _prefix_ns(buf, s, e, want_utc):
    """The epoch/relative seconds at the start of a line prefix buf[s:e] (the default or
    ``auto`` reading of :func:`usvlog.io.importers.nmea.prefix_time`).

    Returns (status, ns): 0 no time stamp, 1 read and of the file's kind (``want_utc``),
    2 left to Python (another form, another kind, out of range).
    """
    while s < e and _ws(buf[s]):                 # strip()
        s += 1
    while e > s and _ws(buf[e - 1]):
        e -= 1
    while s < e and (buf[s] == 91 or buf[s] == 40):   # lstrip("[(")
        s += 1
    if s >= e:
        return 0, 0
    c = buf[s]
    if not 48 <= c <= 57:
        return (2, 0) if c in (43, 45, 46) else (0, 0)     # + - . : left to Python
    j = s
    while j < e and (48 <= buf[j] <= 57 or buf[j] == 46):
        j += 1
    if j < e:
        c = buf[j]
        if 48 <= c <= 57 or 65 <= c <= 90 or 97 <= c <= 122 or c in (95, 46, 58, 45):
            return 2, 0                                     # an ISO date, an exponent, ...
    st, v = _num(buf, s, j)
    if st != 1 or not v < 4e9:
        return 2, 0
    if (v >= 1e8) != want_utc:
        return 2, 0
    x = v * 1e9
    r = math.floor(x)
    f = x - r
    if f > 0.5 or (f == 0.5 and r % 2 == 1):
        r += 1
    return 1, np.int64(r)


@njit
def scan_lines(buf, use_prefix, prefix_utc, offset):
    """Every line of ``buf`` (the file's bytes, lines ending in ``\\n``; ``\\r\\n`` too).

    Parameters: ``use_prefix`` 0: line-prefix times are not used; 1: read them here when
    they are epoch or relative seconds (``prefix_utc``: the file's are epoch seconds), plus
    ``offset`` ns; 2: leave every line with a prefix to Python.

    Returns per line: status (BLANK, OK, FALLBACK, NO_SENTENCE), start and end of the
    stripped line, sentence start, type, time of day ns, date ns (NONE_I64: none), prefix
    time ns (NONE_I64: none), has_fix, and lat (deg), lon (deg), alt (m, NaN none),
    heading (rad), sog (m/s, NaN none), cog (rad, NaN none), GGA fix quality (-1 none) and
    HDOP (NaN none).
    """
    n = len(buf)
    nl = 0
    for i in range(n):
        if buf[i] == 10:
            nl += 1
    if n and buf[n - 1] != 10:
        nl += 1
    status = np.zeros(nl, np.int8)
    start = np.zeros(nl, np.int64)
    end = np.zeros(nl, np.int64)
    sent = np.zeros(nl, np.int64)
    typ = np.full(nl, OTHER, np.int8)
    tod = np.full(nl, NONE_I64, np.int64)
    date = np.full(nl, NONE_I64, np.int64)
    tpre = np.full(nl, NONE_I64, np.int64)
    fix = np.zeros(nl, np.bool_)
    lat = np.full(nl, np.nan)
    lon = np.full(nl, np.nan)
    alt = np.full(nl, np.nan)
    hdg = np.full(nl, np.nan)
    sog = np.full(nl, np.nan)
    cog = np.full(nl, np.nan)
    qual = np.full(nl, -1, np.int64)
    hdop = np.full(nl, np.nan)
    fa = np.zeros(24, np.int64)
    fb = np.zeros(24, np.int64)
    a = 0
    for li in range(nl):
        b = a
        while b < n and buf[b] != 10:
            b += 1
        nxt = b + 1
        s, e = a, b
        while s < e and _ws(buf[s]):
            s += 1
        while e > s and _ws(buf[e - 1]):
            e -= 1
        start[li], end[li] = s, e
        a = nxt
        if s == e:
            status[li] = BLANK
            continue
        p = -1
        ascii_only = True
        for i in range(s, e):
            c = buf[i]
            if c >= 128:
                ascii_only = False
                break
            if p < 0 and (c == 36 or c == 33):
                p = i
        if not ascii_only:
            status[li] = FALLBACK
            continue
        if p < 0:
            status[li] = NO_SENTENCE
            continue
        sent[li] = p
        status[li] = FALLBACK
        # the hot form: $ttTTT, with a 2-letter talker (not proprietary)
        if buf[p] != 36 or e - p < 8 or buf[p + 6] != 44 or not 65 <= buf[p + 1] <= 90 or buf[p + 1] == 80:
            continue
        good = True
        for i in range(p + 2, p + 6):
            c = buf[i]
            if not (48 <= c <= 57 or 65 <= c <= 90):
                good = False
        if not good:
            continue
        k0, k1, k2 = buf[p + 3], buf[p + 4], buf[p + 5]
        if k0 == 71 and k1 == 71 and k2 == 65:
            t = GGA
        elif k0 == 82 and k1 == 77 and k2 == 67:
            t = RMC
        elif k0 == 72 and k1 == 68 and k2 == 84:
            t = HDT
        elif k0 == 86 and k1 == 84 and k2 == 71:
            t = VTG
        else:
            continue
        # checksum: one '*', then exactly two upper-case hex digits
        q = -1
        nstar = 0
        cs = 0
        for i in range(p + 1, e):
            if buf[i] == 42:
                nstar += 1
                if q < 0:
                    q = i
            elif q < 0:
                cs ^= buf[i]
        if nstar != 1 or e - q != 3:
            continue
        h1, h2 = buf[q + 1], buf[q + 2]
        if not ((48 <= h1 <= 57 or 65 <= h1 <= 70) and (48 <= h2 <= 57 or 65 <= h2 <= 70)):
            continue
        v1 = h1 - 48 if h1 <= 57 else h1 - 55
        v2 = h2 - 48 if h2 <= 57 else h2 - 55
        if v1 * 16 + v2 != cs:
            continue
        # prefix time
        tp = NONE_I64
        if use_prefix and p > s:
            if use_prefix == 2:
                continue
            pst, pns = _prefix_ns(buf, s, p, prefix_utc)
            if pst == 2:
                continue
            if pst == 1:
                tp = pns + offset
                if not 0 <= tp < 2 ** 62:
                    continue
        # fields (1 = the first after the head), padded with empty ones
        nf = 0
        fs = p + 7
        for i in range(p + 7, q + 1):
            if i == q or buf[i] == 44:
                if nf < 24:
                    fa[nf] = fs
                    fb[nf] = i
                nf += 1
                fs = i + 1
        if nf > 24:
            continue
        for i in range(nf, 24):
            fa[i] = q
            fb[i] = q
        if t == GGA:
            st0, td = _tod(buf, fa[0], fb[0])
            sq, qv = _uint(buf, fa[5], fb[5])
            s6, _ = _uint(buf, fa[6], fb[6])
            s7, hd7 = _num(buf, fa[7], fb[7])
            if st0 == 2 or sq == 2 or s6 == 2 or s7 == 2:
                continue
            ps, la, lo = (0, 0.0, 0.0) if qv == 0 else _position(buf, fa, fb, 1)
            if ps == 2:
                continue
            if ps == 1:
                s8, al = _num(buf, fa[8], fb[8])
                s10, sep = _num(buf, fa[10], fb[10])
                if s8 == 2 or s10 == 2:
                    continue
                if s8 == 1 and s10 == 1:
                    al += sep
                fix[li] = True
                lat[li], lon[li] = la, lo
                alt[li] = al if s8 == 1 else np.nan
                qual[li] = qv
                hdop[li] = hd7 if s7 == 1 else np.nan
            if st0 == 1:
                tod[li] = td
        elif t == RMC:
            st0, td = _tod(buf, fa[0], fb[0])
            sd, dn = _date(buf, fa[8], fb[8])
            if st0 == 2 or sd == 2:
                continue
            ps = 0
            if _is(buf, fa, fb, 1, 65):                     # status A
                ps, la, lo = _position(buf, fa, fb, 2)
                if ps == 2:
                    continue
                if ps == 1:
                    sk, kn = _num(buf, fa[6], fb[6])
                    sc, cg = _angle(buf, fa[7], fb[7])
                    if sk == 2 or sc == 2:                  # unreadable: Python says which is None
                        continue
                    fix[li] = True
                    lat[li], lon[li] = la, lo
                    sog[li] = kn * _KNOT_MPS if sk == 1 and kn >= 0 else np.nan
                    cog[li] = cg if sc == 1 else np.nan
            if st0 == 1:
                tod[li] = td
            if sd == 1:
                date[li] = dn
        elif t == HDT:
            sh, hv = _angle(buf, fa[0], fb[0])
            if sh != 1:
                continue
            hdg[li] = hv
        else:   # VTG
            if _is(buf, fa, fb, 1, 84) or _is(buf, fa, fb, 5, 78) or _is(buf, fa, fb, 7, 75):
                ic, ik, ih = 0, 4, 6
            else:
                ic, ik, ih = 0, 2, 3
            sk, kn = _num(buf, fa[ik], fb[ik])
            sh, kh = _num(buf, fa[ih], fb[ih])
            sc, cg = _angle(buf, fa[ic], fb[ic])
            if sk == 2 or sh == 2 or sc == 2:
                continue
            v = kn * _KNOT_MPS if sk == 1 else (kh / 3.6 if sh == 1 else np.nan)
            if v < 0:
                continue
            sog[li] = v
            cog[li] = cg if sc == 1 else np.nan
        typ[li] = t
        tpre[li] = tp
        status[li] = OK
    return status, start, end, sent, typ, tod, date, tpre, fix, lat, lon, alt, hdg, sog, cog, qual, hdop


@jitable
def _emit(pend_i, npend, base, step, typ, h_i, h_t, h_s, nh, v_i, v_t, v_s, nv):
    """Untimed sentences spread evenly after ``base`` (ns) by ``step`` (ns): headings and
    velocities appended to their rows; returns the new row counts."""
    for kk in range(npend):
        tt = np.int64(base + (kk + 1) * step)
        jj = pend_i[kk]
        if typ[jj] == VTG:
            v_i[nv], v_t[nv], v_s[nv] = jj, tt, tt
            nv += 1
        else:
            h_i[nh], h_t[nh], h_s[nh] = jj, tt, tt
            nh += 1
    return nh, nv


@njit
def sequence(typ, tod, date, tpre, fix, sog, day0, velocity_vtg, window_ns, state, n_carry, n_pending, final):
    """Times, one fix per epoch and untimed sentences of the parsed sentences, in order.

    The importer loop of :func:`usvlog.io.importers.nmea.read` after the parsing: ``typ``,
    ``tod`` (ns, NONE_I64 none), ``date`` (ns, NONE_I64 none), ``tpre`` (prefix time ns,
    NONE_I64 none), ``fix`` (has_fix), ``sog`` (NaN none) per sentence; ``day0`` the first
    date (ns); ``velocity_vtg`` whether velocity comes from VTG (else RMC); ``window_ns``
    the FixSelector window.

    A file goes through in blocks: ``state`` (int64, :func:`new_state`) carries the clocks
    and the fix selection from one block to the next (updated in place); the first
    ``n_carry`` sentences are the previous block's still undecided ones (the first
    ``n_pending`` untimed ones, then the held fix, if ``state`` says there is one, at index
    ``n_pending``), not sentences of this block. ``final``: the last block (the held fix and
    the untimed sentences are settled).

    Returns rows (sentence index, t_ns, stamp_ns) of gnss, heading and velocity, skip
    events (sentence index, reason, count; index ``len(typ)`` for the end of the block) and
    the indices of the sentences still undecided (untimed ones, then the held fix).
    """
    n = len(typ)
    g_i, g_t, g_s = np.empty(n, np.int64), np.empty(n, np.int64), np.empty(n, np.int64)
    h_i, h_t, h_s = np.empty(n, np.int64), np.empty(n, np.int64), np.empty(n, np.int64)
    v_i, v_t, v_s = np.empty(n, np.int64), np.empty(n, np.int64), np.empty(n, np.int64)
    k_i, k_r, k_n = np.empty(n + 1, np.int64), np.empty(n + 1, np.int64), np.empty(n + 1, np.int64)
    ng = nh = nv = nk = 0
    pend_i = np.empty(n, np.int64)    # pending untimed: sentence index
    for kk in range(n_pending):
        pend_i[kk] = kk
    npend = n_pending
    clock_last, last_t, last_dt, epoch = state[0], state[1], state[2], state[3]
    epoch_set, held, held_p, held_i = state[4] != 0, state[5] != 0, state[6], n_pending
    held_t, held_s, done = state[8], state[9], state[10] != 0
    # FixSelector state: per kind (GGA, RMC, GLL) last offered (t, tod, seen)
    seen = state[11:14] != 0
    seen_t = state[14:17].copy()
    seen_tod = state[17:20].copy()
    for j in range(n_carry, n):
        ty = typ[j]
        if ty == ZDA:
            if date[j] != NONE_I64 and tod[j] != NONE_I64:
                clock_last = date[j] + tod[j]
            else:
                k_i[nk], k_r[nk], k_n[nk] = j, SKIP_UNSUPPORTED, 1
                nk += 1
            continue
        if ty == OTHER:
            k_i[nk], k_r[nk], k_n[nk] = j, SKIP_UNSUPPORTED, 1
            nk += 1
            continue
        stamp = NONE_I64
        if tod[j] != NONE_I64:
            if date[j] != NONE_I64:
                stamp = date[j] + tod[j]
            elif clock_last == NONE_I64:
                stamp = day0 + tod[j]
            else:
                stamp = resolve_time_of_day(tod[j], clock_last)
            clock_last = stamp
        gnss = ty <= GLL
        velo = ty == VTG
        if gnss and not fix[j]:
            k_i[nk], k_r[nk], k_n[nk] = j, SKIP_NO_FIX, 1
            nk += 1
            continue
        t = tpre[j] if tpre[j] != NONE_I64 else stamp
        if t == NONE_I64:
            if velo and not velocity_vtg:
                continue
            pend_i[npend] = j
            npend += 1
            continue
        same_epoch = gnss and tod[j] != NONE_I64 and epoch_set and tod[j] == epoch
        if not same_epoch:
            if npend:   # emit_pending(t)
                if last_t == NONE_I64:
                    step = last_dt / (npend + 1)
                    base = max(0, t - last_dt)
                else:
                    step = (t - last_t) / (npend + 1)
                    base = last_t
                nh, nv = _emit(pend_i, npend, base, step, typ, h_i, h_t, h_s, nh, v_i, v_t, v_s, nv)
                npend = 0
            if last_t != NONE_I64 and t > last_t:
                last_dt = t - last_t
            last_t = t
        st = stamp if stamp != NONE_I64 else t
        if gnss:
            # FixSelector.offer
            prio = ty
            td = tod[j]
            expected = 0
            first = True
            for kd in range(3):
                if seen[kd] and t - seen_t[kd] < window_ns and (seen_tod[kd] == NONE_I64 or seen_tod[kd] != td):
                    if first or kd < expected:
                        expected = kd
                        first = False
            seen[prio] = True
            seen_t[prio] = t
            seen_tod[prio] = td
            if td == NONE_I64 or not epoch_set or td != epoch:
                if held:
                    g_i[ng], g_t[ng], g_s[ng] = held_i, held_t, held_s
                    ng += 1
                held = False
                done = False
                epoch = td
                epoch_set = td != NONE_I64
            if not done:
                if not held or prio < held_p:
                    held, held_p, held_i, held_t, held_s = True, prio, j, t, st
                if held_p <= expected or td == NONE_I64:
                    g_i[ng], g_t[ng], g_s[ng] = held_i, held_t, held_s
                    ng += 1
                    held = False
                    done = True
            if ty == RMC and not velocity_vtg and not np.isnan(sog[j]):
                v_i[nv], v_t[nv], v_s[nv] = j, t, st
                nv += 1
        elif not velo or velocity_vtg:
            if velo:
                v_i[nv], v_t[nv], v_s[nv] = j, t, st
                nv += 1
            else:
                h_i[nh], h_t[nh], h_s[nh] = j, t, st
                nh += 1
    if final and held:
        g_i[ng], g_t[ng], g_s[ng] = held_i, held_t, held_s
        ng += 1
        held = False
    if final and npend:   # emit_pending(None)
        if last_t == NONE_I64:
            k_i[nk], k_r[nk], k_n[nk] = n, SKIP_UNTIMED, npend
            nk += 1
        else:
            nh, nv = _emit(pend_i, npend, last_t, last_dt / (npend + 1), typ, h_i, h_t, h_s, nh, v_i, v_t, v_s, nv)
        npend = 0
    undecided = np.empty(npend + (1 if held else 0), np.int64)
    undecided[:npend] = pend_i[:npend]
    if held:
        undecided[npend] = held_i
    state[0], state[1], state[2], state[3] = clock_last, last_t, last_dt, epoch
    state[4], state[5], state[6], state[7] = epoch_set, held, held_p, 0
    state[8], state[9], state[10] = held_t, held_s, done
    for kd in range(3):
        state[11 + kd], state[14 + kd], state[17 + kd] = seen[kd], seen_t[kd], seen_tod[kd]
    return (g_i[:ng], g_t[:ng], g_s[:ng], h_i[:nh], h_t[:nh], h_s[:nh], v_i[:nv], v_t[:nv], v_s[:nv],
            k_i[:nk], k_r[:nk], k_n[:nk], undecided)


def new_state() -> np.ndarray:
    """The :func:`sequence` state at the start of a file (nothing seen)."""
    st = np.zeros(20, np.int64)
    st[0] = st[1] = st[3] = NONE_I64       # clock, last time, epoch: none
    st[2] = 100_000_000                      # the step assumed before two timed sentences
    st[17:20] = NONE_I64
    return st
