"""NMEA sentence parsing, time-of-day placement, clock offset estimation, single-row encoding."""

import datetime as dt
import math

import numpy as np
import pandas as pd
import pytest

from usvlog.io.mcap.codec import codec_for_topic
from usvlog.io.nmea import (
    FixSelector,
    NmeaError,
    checksum,
    format_deg_min,
    parse_sentence,
    resolve_time_of_day,
    with_checksum,
)
from usvlog.io.record.timesync import OffsetEstimator
from usvlog.log.channels import frame_from_columns, registered_topics


def test_checksum_of_a_published_sentence():
    # NMEA 0183 reference example (checksum *47 is printed in the standard's examples)
    assert checksum("GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,") == "47"


def test_gga_values_and_quality():
    s = parse_sentence(with_checksum("GPGGA,123519.50,4807.038,S,01131.000,W,2,08,0.9,545.4,M,46.9,M,,"))
    assert s.kind == "GGA" and s.has_fix
    assert s.lat_deg == pytest.approx(-(48 + 7.038 / 60), abs=1e-12)
    assert s.lon_deg == pytest.approx(-(11 + 31.0 / 60), abs=1e-12)
    assert s.alt_m == pytest.approx(545.4 + 46.9)          # ellipsoid = MSL + geoid separation
    assert (s.fix_quality, s.satellites, s.hdop) == (2, 8, 0.9)
    assert s.time_of_day_ns == ((12 * 60 + 35) * 60 + 19) * 10**9 + 500_000_000
    assert s.gps_time_ns is None                            # GGA has no date
    nofix = parse_sentence(with_checksum("GPGGA,123520,,,,,0,00,,,M,,M,,"))
    assert not nofix.has_fix and nofix.fix_quality == 0 and nofix.lat_deg is None


def test_rmc_zda_dates_and_gll():
    r = parse_sentence(with_checksum("GPRMC,235959.90,A,5954.000,N,01042.000,E,1.0,90.0,311224,,"))
    assert r.date == dt.date(2024, 12, 31) and r.has_fix
    midnight = int(dt.datetime(2024, 12, 31, tzinfo=dt.UTC).timestamp()) * 10**9
    assert r.gps_time_ns == midnight + 86_399 * 10**9 + 900_000_000
    void = parse_sentence(with_checksum("GPRMC,000000,V,,,,,,,010125,,"))
    assert not void.has_fix and void.date == dt.date(2025, 1, 1)
    z = parse_sentence(with_checksum("GPZDA,201530.00,04,07,2002,00,00"))
    assert z.gps_time_ns == int(dt.datetime(2002, 7, 4, 20, 15, 30, tzinfo=dt.UTC).timestamp()) * 10**9
    g = parse_sentence(with_checksum("GPGLL,4916.45,N,12311.12,W,225444,A,"))
    assert g.has_fix and g.lat_deg == pytest.approx(49 + 16.45 / 60) and g.lon_deg == pytest.approx(-(123 + 11.12 / 60))


def test_headings_true_magnetic_and_hdg_corrections():
    t = parse_sentence(with_checksum("HEHDT,274.07,T"))
    assert t.reference == "true" and t.heading_rad == pytest.approx(math.radians(274.07 - 360.0))
    m = parse_sentence(with_checksum("HCHDM,10.5,M"))
    assert m.reference == "magnetic" and m.heading_rad == pytest.approx(math.radians(10.5))
    # sensor 98.3, deviation 1.5 E, variation 12.6 W: true = 98.3 + 1.5 - 12.6
    h = parse_sentence(with_checksum("HCHDG,98.3,1.5,E,12.6,W"))
    assert h.reference == "true" and h.heading_rad == pytest.approx(math.radians(98.3 + 1.5 - 12.6))
    hm = parse_sentence(with_checksum("HCHDG,359.0,2.0,E,,"))
    assert hm.reference == "magnetic" and hm.heading_rad == pytest.approx(math.radians(1.0))


@pytest.mark.parametrize("text, reason", [
    ("$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*48", "checksum"),
    ("$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,", "checksum missing"),
    ("GPGGA,123519,4807.038,N", "does not start"),
    (with_checksum("GPGGA,12a519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,"), "time"),
    (with_checksum("GPGGA,123519,9907.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,"), "out of range"),
    (with_checksum("GPGGA,123519,4807.038,Q,01131.000,E,1,08,0.9,545.4,M,46.9,M,,"), "hemisphere"),
    (with_checksum("HEHDT,abc,T"), "heading"),
    (with_checksum("HEHDT,400.0,T"), "out of range"),
    ("$GP\x00\x01garbage", "checksum missing"),
])
def test_malformed_sentences_raise_with_a_reason(text, reason):
    with pytest.raises(NmeaError, match=reason):
        parse_sentence(text)


def test_unknown_sentence_type_with_good_checksum_is_not_garbage():
    s = parse_sentence(with_checksum("GPXYZ,1,2,3"))
    assert s.kind == "XYZ" and not s.has_fix and s.heading_rad is None


def test_time_of_day_lands_on_the_nearest_day():
    day = 20_000 * 86_400 * 10**9
    tod = (23 * 3600 + 59 * 60 + 59) * 10**9
    # received just after midnight: the fix is from the day before
    assert resolve_time_of_day(tod, day + 86_400 * 10**9 + 2 * 10**9) == day + tod
    # received just before midnight: same day; early time of day received late: next day
    assert resolve_time_of_day(tod, day + tod + 10**8) == day + tod
    assert resolve_time_of_day(10**9, day + 86_399 * 10**9) == day + 86_400 * 10**9 + 10**9


def test_offset_estimator_median_ignores_latency_bursts():
    rng = np.random.default_rng(0)
    est = OffsetEstimator(window=500)
    true_off = 250_000_000
    sensor = np.arange(1000) * 100_000_000 + 10**18
    recv = sensor + true_off + rng.normal(0, 1e6, 1000).astype(np.int64)
    recv[::10] += 2_000_000_000                  # 10% of messages arrive 2 s late
    for r, s in zip(recv, sensor):
        est.add(int(r), int(s))
    e = est.estimate()
    assert e.samples == 500 and abs(e.offset_ns - true_off) < 1_000_000
    assert e.mad_ns < 2_000_000


def _row_frame(topic, rng):
    codec = codec_for_topic(topic)
    cols = {}
    for c, d in codec.dtypes().items():
        if d == "str":
            cols[c] = np.array(["true"], dtype=object)
        elif d is np.bool_:
            cols[c] = np.array([True])
        elif d is np.int64:
            cols[c] = np.array([int(rng.integers(0, 2**62))])
        else:
            cols[c] = np.array([rng.normal()])
    return codec, frame_from_columns(cols, np.array([5], dtype=np.int64), codec.spec)


@pytest.mark.parametrize("topic", sorted(registered_topics()))
def test_encode_row_matches_frame_encoding(topic):
    codec, frame = _row_frame(topic, np.random.default_rng(1))
    row = {c: frame[c].iloc[0] for c in frame.columns}
    assert codec.encode_row(row, topic) == codec.encode(frame, topic)[0]
    # a NaN number becomes null either way; decoding gives NaN back
    fcols = [c for c, d in codec.dtypes().items() if d is np.float64]
    if fcols:
        row[fcols[0]] = math.nan
        back = codec.decode([codec.encode_row(row, topic)], topic)
        assert math.isnan(back[fcols[0]][0])


def test_encode_row_names_missing_column():
    codec = codec_for_topic("/thrust/command")
    with pytest.raises(ValueError, match="/thrust/command.*left"):
        codec.encode_row({"stamp_ns": 1, "right": 1.0, "unit": "newton"}, "/thrust/command")
    # nullable columns may be left out
    obj = codec.decode([codec.encode_row({"stamp_ns": 1, "left": 2.0, "right": 1.0, "unit": "newton"})])
    assert math.isnan(obj["thrust_left_n"][0]) and obj["left"][0] == 2.0
    assert isinstance(pd.Series(obj["left"]).iloc[0], float)


def test_error_kinds_and_optional_checksum():
    from usvlog.io.nmea import NmeaChecksumError, NmeaFieldError

    good = "GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,"
    with pytest.raises(NmeaChecksumError):
        parse_sentence("$" + good + "*00")
    with pytest.raises(NmeaChecksumError, match="missing"):
        parse_sentence("$" + good)
    # without a checksum only when the caller allows it (files); a present one must still match
    s = parse_sentence("$" + good, require_checksum=False)
    assert s.has_fix and s.lat_deg == pytest.approx(48 + 7.038 / 60, abs=1e-12)
    with pytest.raises(NmeaChecksumError):
        parse_sentence("$" + good + "*00", require_checksum=False)
    with pytest.raises(NmeaFieldError, match="time"):
        parse_sentence(with_checksum("GPGGA,12a519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,"))
    with pytest.raises(NmeaError) as err:
        parse_sentence("$" + "\x01\x02,1,2", require_checksum=False)
    assert not isinstance(err.value, (NmeaChecksumError, NmeaFieldError))


def test_talkers_no_fix_forms_gll_without_status_and_altitude_without_separation():
    for talker in ("GP", "GN", "GL", "GA", "BD"):
        s = parse_sentence(with_checksum(f"{talker}GGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,,M,,"))
        assert s.talker == talker and s.kind == "GGA"
        assert s.alt_m == pytest.approx(545.4)       # no geoid separation: height above sea level kept
    # quality > 0 with empty position, RMC void: no fix, not an error
    assert not parse_sentence(with_checksum("GPGGA,123519,,,,,1,08,0.9,,M,,M,,")).has_fix
    assert not parse_sentence(with_checksum("GPGLL,4916.45,N,12311.12,W,225444,V,")).has_fix
    old = parse_sentence(with_checksum("GPGLL,4916.45,N,12311.12,W,225444"))   # NMEA 2.0: no status field
    assert old.has_fix and old.time_of_day_ns == (22 * 3600 + 54 * 60 + 44) * 10**9
    p = parse_sentence(with_checksum("PGRME,15.0,M,45.0,M,25.0,M"))
    assert p.kind == "PGRME" and p.talker == ""


def test_vtg_both_layouts():
    v = parse_sentence(with_checksum("GPVTG,270.0,T,,M,10.0,N,18.52,K,A"))
    assert v.sog_mps == pytest.approx(10.0 * 1852 / 3600, abs=1e-12)
    assert v.cog_rad == pytest.approx(-math.pi / 2, abs=1e-12)       # 270 deg wrapped to [-pi, pi)
    old = parse_sentence(with_checksum("GPVTG,054.7,034.4,005.5,010.2"))
    assert old.sog_mps == pytest.approx(5.5 * 1852 / 3600, abs=1e-12)
    assert old.cog_rad == pytest.approx(math.radians(54.7), abs=1e-12)
    kmh = parse_sentence(with_checksum("GPVTG,10.0,T,,M,,N,36.0,K,A"))
    assert kmh.sog_mps == pytest.approx(10.0, abs=1e-12)


@pytest.mark.parametrize("text, dt_utc, extra_ns", [
    ("2024-05-01T10:00:00Z", dt.datetime(2024, 5, 1, 10, tzinfo=dt.UTC), 0),
    ("2024-05-01T12:00:00.25+02:00", dt.datetime(2024, 5, 1, 10, tzinfo=dt.UTC), 250_000_000),
    ("2024-05-01 10:00", dt.datetime(2024, 5, 1, 10, tzinfo=dt.UTC), 0),          # no zone: UTC
    ("1999-12-31T23:59:59.123456789Z", dt.datetime(1999, 12, 31, 23, 59, 59, tzinfo=dt.UTC), 123_456_789),
])
def test_parse_time_is_exact_to_the_nanosecond(text, dt_utc, extra_ns):
    """The one ISO 8601 reader (import --start-utc, NMEA line prefixes, simulate start_utc)."""
    from usvlog.io.importers import parse_start_utc
    from usvlog.log.fieldlog import parse_time
    from usvlog.sim.simulate import start_ns

    want = int(dt_utc.timestamp()) * 10**9 + extra_ns
    assert parse_time(text) == parse_start_utc(text) == start_ns(text) == want
    with pytest.raises(ValueError):
        parse_time("yesterday-ish")


@pytest.mark.parametrize("deg, lat, decimals, text", [
    (59.99999999999, True, 6, ("6000.000000", "N")),    # minutes round to 60 as printed: carried
    (-10.5, False, 6, ("01030.000000", "W")),
    (12.3456789, True, 7, ("1220.7407340", "N")),
    (-0.0000001, True, 3, ("0000.000", "S")),
    (179.999999999, False, 4, ("18000.0000", "E")),
])
def test_format_deg_min_round_trips_through_pynmea2(deg, lat, decimals, text):
    import pynmea2

    assert format_deg_min(deg, lat, decimals) == text
    field, hemi = text
    body = f"GPGLL,{field},{hemi},00000.0,E,120000.00,A,A" if lat else f"GPGLL,0000.0,N,{field},{hemi},120000.00,A,A"
    ref = pynmea2.parse(with_checksum(body))
    got = parse_sentence(with_checksum(body))
    assert (got.lat_deg if lat else got.lon_deg) == pytest.approx(ref.latitude if lat else ref.longitude, abs=1e-12)
    assert (got.lat_deg if lat else got.lon_deg) == pytest.approx(deg, abs=0.6 * 10.0**-decimals / 60.0)


def _fix(kind, tod_s, lat=59.0):
    """A parsed position sentence of ``kind`` at time of day ``tod_s`` (None: no time)."""
    hms = "" if tod_s is None else f"{int(tod_s) // 3600:02d}{int(tod_s) % 3600 // 60:02d}{tod_s % 60:05.2f}"
    la, lh = format_deg_min(lat, True)
    body = {"GGA": f"GPGGA,{hms},{la},{lh},01000.000,E,1,08,0.9,1.0,M,0.0,M,,",
            "RMC": f"GPRMC,{hms},A,{la},{lh},01000.000,E,0.0,0.0,010624,,",
            "GLL": f"GPGLL,{la},{lh},01000.000,E,{hms},A"}[kind]
    return parse_sentence(with_checksum(body))


def _run(selector, sentences, dt_ns=10_000_000):
    """Offer (kind, time of day s) in order, one every ``dt_ns``; the winners' (kind, tod) in order."""
    out = []
    for i, (kind, tod) in enumerate(sentences):
        out += selector.offer(_fix(kind, tod), i * dt_ns, (kind, tod))
    return out + selector.flush()


@pytest.mark.parametrize("order", [("GGA", "RMC"), ("RMC", "GGA"), ("RMC", "GLL", "GGA"), ("GLL", "GGA", "RMC")])
def test_fix_selector_one_fix_per_epoch_from_gga(order):
    sentences = [(k, 10.0 + 0.1 * e) for e in range(5) for k in order]
    assert _run(FixSelector(), sentences) == [("GGA", 10.0 + 0.1 * e) for e in range(5)]


def test_fix_selector_keeps_rmc_when_the_epoch_has_no_valid_gga():
    # epoch 2's GGA is corrupt (never offered); epoch 4 only has GLL
    sentences = [("GGA", 1.0), ("RMC", 1.0), ("GGA", 2.0), ("RMC", 2.0), ("RMC", 3.0), ("GLL", 3.0),
                 ("GGA", 4.0), ("GLL", 5.0), ("RMC", 6.0), ("GGA", 6.0)]
    assert _run(FixSelector(), sentences) == [("GGA", 1.0), ("GGA", 2.0), ("RMC", 3.0), ("GGA", 4.0),
                                              ("GLL", 5.0), ("GGA", 6.0)]


def test_fix_selector_decides_at_once_for_the_best_kind_a_source_sends():
    sel = FixSelector(window_ns=2 * 10**9)
    # an RMC-only source: the first RMC waits for its epoch to end (GGA might follow), later ones do not
    assert sel.offer(_fix("RMC", 1.0), 0, "r1") == []
    assert sel.offer(_fix("RMC", 2.0), 10**9, "r2") == ["r1", "r2"]
    assert sel.offer(_fix("RMC", 3.0), 2 * 10**9, "r3") == ["r3"]
    # a GGA appears: from then on an RMC waits for its epoch's GGA, which wins at once
    assert sel.offer(_fix("GGA", 4.0), 3 * 10**9, "g4") == ["g4"]
    assert sel.offer(_fix("RMC", 5.0), 4 * 10**9, "r5") == []
    assert sel.offer(_fix("GGA", 5.0), 4 * 10**9 + 1, "g5") == ["g5"]
    # an RMC whose GGA never comes: released once it is old enough, and its epoch is closed
    assert sel.offer(_fix("RMC", 6.0), 5 * 10**9, "r6") == []
    assert sel.release_older(5 * 10**9) == [] and sel.release_older(5 * 10**9 + 1) == ["r6"]
    assert sel.offer(_fix("GGA", 6.0), 5 * 10**9 + 2, "g6") == []
    # sentences without a time of day cannot be matched: each one is a fix
    assert sel.offer(_fix("GLL", None), 6 * 10**9, "l1") == ["l1"]
    assert sel.offer(_fix("GLL", None), 6 * 10**9 + 1, "l2") == ["l2"]
    assert sel.flush() == []
