"""usvlog's NMEA sentence parser against pynmea2, the field's reference reader.

usvlog parses sentences itself (fields by position; several times faster than pynmea2, which
matters for imports of long logs), so pynmea2 is the independent truth here: on random
well-formed sentences of every supported type the values agree, and both reject the same
corrupted checksums.
"""

from __future__ import annotations

import datetime as dt
import math

import pynmea2
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from usvlog.io.nmea import (
    NmeaChecksumError,
    NmeaError,
    format_deg_min,
    parse_sentence,
    with_checksum,
)
from usvlog.model.frames import ssa

TALKERS = st.sampled_from(["GP", "GN", "GL", "GA", "HE", "HC", "II"])


positions = st.tuples(st.floats(-89.9, 89.9), st.floats(-179.9, 179.9))
times = st.tuples(st.integers(0, 23), st.integers(0, 59), st.integers(0, 59), st.integers(0, 99))


def _hms(t) -> str:
    return f"{t[0]:02d}{t[1]:02d}{t[2]:02d}.{t[3]:02d}"


@settings(max_examples=150, deadline=None)
@given(TALKERS, positions, times, st.floats(-50, 3000), st.floats(-100, 100), st.integers(0, 8),
       st.integers(0, 40), st.floats(0.5, 9.9))
def test_gga_agrees(talker, pos, t, alt, sep, qual, sats, hdop):
    la, lh = format_deg_min(pos[0], True)
    lo, oh = format_deg_min(pos[1], False)
    s = with_checksum(f"{talker}GGA,{_hms(t)},{la},{lh},{lo},{oh},{qual},{sats:02d},{hdop:.1f},"
                      f"{alt:.2f},M,{sep:.2f},M,,")
    ref = pynmea2.parse(s)
    got = parse_sentence(s)
    assert got.kind == "GGA" and got.talker == talker
    assert got.fix_quality == ref.gps_qual and got.satellites == int(ref.num_sats)
    assert got.hdop == pytest.approx(float(ref.horizontal_dil))
    tod = ref.timestamp
    assert got.time_of_day_ns == ((tod.hour * 60 + tod.minute) * 60 + tod.second) * 10**9 + tod.microsecond * 1000
    if qual > 0:
        assert got.has_fix
        assert got.lat_deg == pytest.approx(ref.latitude, abs=1e-9)
        assert got.lon_deg == pytest.approx(ref.longitude, abs=1e-9)
        # canonical altitude: ellipsoidal height = MSL altitude + geoid separation
        assert got.alt_m == pytest.approx(ref.altitude + float(ref.geo_sep), abs=1e-9)
    else:
        assert not got.has_fix


@settings(max_examples=100, deadline=None)
@given(TALKERS, positions, times, st.dates(dt.date(2000, 1, 1), dt.date(2079, 12, 31)), st.booleans())
def test_rmc_and_gll_agree(talker, pos, t, date, valid):
    la, lh = format_deg_min(pos[0], True)
    lo, oh = format_deg_min(pos[1], False)
    status = "A" if valid else "V"
    for s in (with_checksum(f"{talker}RMC,{_hms(t)},{status},{la},{lh},{lo},{oh},0.5,54.7,{date:%d%m%y},,,A"),
              with_checksum(f"{talker}GLL,{la},{lh},{lo},{oh},{_hms(t)},{status},A")):
        ref = pynmea2.parse(s)
        got = parse_sentence(s)
        assert got.has_fix == valid
        if valid:
            assert got.lat_deg == pytest.approx(ref.latitude, abs=1e-9)
            assert got.lon_deg == pytest.approx(ref.longitude, abs=1e-9)
        if got.kind == "RMC":
            assert got.date == ref.datestamp


@settings(max_examples=100, deadline=None)
@given(TALKERS, st.floats(0, 359.99), st.floats(-20, 20), st.floats(-30, 30))
def test_headings_agree(talker, hdg, dev, var):
    def ew(x):
        return f"{abs(x):.1f},{'E' if x >= 0 else 'W'}"

    hdt = with_checksum(f"{talker}HDT,{hdg:.2f},T")
    hdm = with_checksum(f"{talker}HDM,{hdg:.2f},M")
    hdgs = with_checksum(f"{talker}HDG,{hdg:.2f},{ew(dev)},{ew(var)}")
    assert parse_sentence(hdt).heading_rad == pytest.approx(float(ssa(math.radians(float(pynmea2.parse(hdt).heading)))))
    assert parse_sentence(hdt).reference == "true"
    assert parse_sentence(hdm).reference == "magnetic"
    ref = pynmea2.parse(hdgs)
    sign = {"E": 1.0, "W": -1.0}
    true_deg = float(ref.heading) + sign[ref.dev_dir] * float(ref.deviation) + sign[ref.var_dir] * float(ref.variation)
    got = parse_sentence(hdgs)
    assert got.reference == "true"
    assert got.heading_rad == pytest.approx(float(ssa(math.radians(true_deg))), abs=1e-12)


@settings(max_examples=50, deadline=None)
@given(TALKERS, st.floats(0, 359.9), st.floats(0, 40))
def test_vtg_agrees(talker, course, knots):
    s = with_checksum(f"{talker}VTG,{course:.1f},T,,M,{knots:.2f},N,{knots * 1.852:.2f},K,A")
    ref = pynmea2.parse(s)
    got = parse_sentence(s)
    assert got.sog_mps == pytest.approx(float(ref.spd_over_grnd_kts) * 1852 / 3600)
    assert got.cog_rad == pytest.approx(float(ssa(math.radians(float(ref.true_track)))))


@settings(max_examples=150, deadline=None)
@given(TALKERS, st.floats(0, 359.99), st.integers(0, 255))
def test_checksum_verdicts_agree(talker, hdg, flip):
    good = with_checksum(f"{talker}HDT,{hdg:.2f},T")
    body, cs = good[1:].split("*")
    bad_cs = f"{(int(cs, 16) ^ (flip or 1)):02X}"
    bad = f"${body}*{bad_cs}"
    pynmea2.parse(good)  # accepted by both
    parse_sentence(good)
    with pytest.raises(pynmea2.ChecksumError):
        pynmea2.parse(bad)
    with pytest.raises(NmeaChecksumError):
        parse_sentence(bad)


def test_garbage_is_an_nmea_error_for_both():
    for junk in ("hello world", "$GPGGA", "\x00\x01\x02", "$$$*00"):
        with pytest.raises(NmeaError):
            parse_sentence(junk)
        with pytest.raises((pynmea2.ParseError, pynmea2.ChecksumError, ValueError)):
            pynmea2.parse(junk)
