"""CSV and NMEA 0183 imports: round trips against the values written, bad input skipped and counted."""

from __future__ import annotations

import datetime as dt
import math

import numpy as np
import pandas as pd
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from usvlog.errors import FormatError, InputError, UsvlogError
from usvlog.io.importers import import_file
from usvlog.io.mcap import read_log
from usvlog.io.nmea import format_deg_min
from usvlog.io.nmea import with_checksum as _cs
from usvlog.log.summary import skipped_counts
from usvlog.model.frames import ssa
from usvlog.model.vessel import Thrusters, Vessel

T0 = 1_714_557_600_000_000_000  # 2024-05-01T10:00:00Z


def merged_csv(path, n=1000, *, thrust=True, start_epoch=True):
    """100 Hz rows; lat/lon on every 10th row, heading on every 5th, thrust on every row."""
    k = np.arange(n)
    t = (T0 / 1e9 if start_epoch else 0.0) + k * 0.01
    lat = 59.1234567 + 1e-6 * k
    lon = 10.7654321 - 2e-6 * k
    hdg = (350.0 + 0.37 * k) % 360.0
    df = pd.DataFrame({"time": t,
                       "Latitude": np.where(k % 10 == 0, lat, np.nan),
                       "Longitude": np.where(k % 10 == 0, lon, np.nan),
                       "heading": np.where(k % 5 == 0, hdg, np.nan)})
    if thrust:
        df["left"] = 1500 + (k % 400)
        df["right"] = 1900 - (k % 400)
    df.to_csv(path, index=False, float_format="%.10f", na_rep="")
    return dict(k=k, t=t, lat=lat, lon=lon, hdg=hdg)


def test_csv_sparse_columns_give_native_rates(tmp_path):
    p = tmp_path / "merged.csv"
    tr = merged_csv(p)
    res = import_file(p, chunk_rows=337)  # chunk edges fall anywhere
    log = res.log
    g, h, th = log["/gnss/fix"], log["/compass/heading"], log["/thrust/command"]
    assert len(g) == 100 and len(h) == 200 and len(th) == 1000
    np.testing.assert_array_equal(g.index.to_numpy(), T0 + tr["k"][::10] * 10_000_000)
    np.testing.assert_array_equal(np.diff(h.index.to_numpy()), 50_000_000)  # 20 Hz
    np.testing.assert_allclose(g["lat_deg"], tr["lat"][::10], atol=1e-7, rtol=0)
    np.testing.assert_allclose(g["lon_deg"], tr["lon"][::10], atol=1e-7, rtol=0)
    np.testing.assert_allclose(ssa(h["heading_rad"] - np.radians(tr["hdg"][::5])), 0.0, atol=1e-6)
    assert (g["lat_deg"] != 0).all() and (h["heading_rad"] != 0).all()  # nothing zero-filled
    assert res.report.guesses["thrust_unit"] == "pwm_us" and set(th["unit"]) == {"pwm_us"}
    assert res.report.mapping["lat_deg"] == "Latitude"
    assert sum(res.report.skipped.values()) == 0
    assert log.datum.lat_deg == pytest.approx(tr["lat"][0], abs=1e-9)


def test_csv_streamed_to_mcap_equals_in_memory(tmp_path):
    p = tmp_path / "merged.csv"
    merged_csv(p)
    mem = import_file(p).log
    out = tmp_path / "run.mcap"
    import_file(p, out=out, chunk_rows=250)  # many batches -> many chunks
    back = read_log(out)
    for topic in mem.topics:
        pd.testing.assert_frame_equal(back[topic], mem[topic], check_dtype=False)
    # the file is valid MCAP for the mcap library too: summary, indexes, messages in order
    from mcap.reader import make_reader

    with open(out, "rb") as fh:
        rd = make_reader(fh)
        summ = rd.get_summary()
        assert summ.statistics.message_count == sum(len(mem[t]) for t in mem.topics)
        assert len(summ.chunk_indexes) > 1
        msgs = list(rd.iter_messages(topics=["/gnss/fix"]))
        assert [m.log_time for _, _, m in msgs] == mem["/gnss/fix"].index.tolist()
        assert rd.get_summary().metadata_indexes and "usvlog.datum" in {m.name for m in rd.iter_metadata()}
    prov = back.provenance[0]
    import hashlib

    assert prov["sha256"] == hashlib.sha256(p.read_bytes()).hexdigest()
    assert int(prov["size"]) == p.stat().st_size and prov["format"] == "csv" and prov["source"] == "merged.csv"


def test_csv_relative_time_and_thrust_map(tmp_path):
    p = tmp_path / "rel.csv"
    tr = merged_csv(p, n=200, start_epoch=False)
    vessel = Vessel(thrusters=Thrusters(map="quadratic", forward_n=40.0, reverse_n=20.0, pwm_span_us=500.0))
    res = import_file(p, start_utc="2024-05-01T10:00:00Z", thrust_unit="pwm_us", vessel=vessel)
    th = res.log["/thrust/command"]
    np.testing.assert_array_equal(th.index.to_numpy(), T0 + tr["k"] * 10_000_000)
    c = np.clip((1500 + (tr["k"] % 400) - 1500) / 500.0, -1, 1)
    np.testing.assert_allclose(th["thrust_left_n"], np.where(c >= 0, 40.0, 20.0) * c * np.abs(c), atol=1e-12)
    np.testing.assert_array_equal(th["left"], 1500 + (tr["k"] % 400))  # recorded commands kept


# ------------------------------------------------------------------ bad input (CSV)

def test_csv_nan_and_out_of_range_counted(tmp_path):
    p = tmp_path / "bad.csv"
    p.write_text("time_s,lat,lon\n"
                 "1714557600.0,59.1,10.2\n"
                 "1714557600.1,nan,10.2\n"
                 "1714557600.2,93.1,10.2\n"
                 "1714557600.3,59.1,-181\n"
                 "1714557600.4,59.2,10.3\n"
                 "1714557600.5,xyz,10.3\n")
    res = import_file(p)
    assert list(res.log["/gnss/fix"]["lat_deg"]) == [59.1, 59.2]
    assert res.report.skipped == {"gnss_nan": 1, "gnss_out_of_range": 2, "csv_bad_value": 1, "gnss_incomplete": 1}
    assert "line 7" in res.report.first_bad["csv_bad_value"]
    assert skipped_counts(res.log) == dict(res.report.skipped)  # in the provenance too


def test_csv_zero_zero_no_fix(tmp_path):
    p = tmp_path / "nofix.csv"
    rows = [f"{i * 0.1},0,0,{i}" for i in range(20)] + [f"{2 + i * 0.1},59.1,10.2,{i}" for i in range(5)]
    p.write_text("t,lat,lon,heading\n" + "\n".join(rows) + "\n")
    res = import_file(p, start_utc="2024-05-01T10:00:00Z")
    assert len(res.log["/gnss/fix"]) == 5 and res.report.skipped["gnss_no_fix"] == 20
    assert res.log.datum.lat_deg == 59.1  # datum from the first valid fix, not (0, 0)
    only = tmp_path / "only_nofix.csv"
    only.write_text("t,lat,lon\n" + "\n".join(f"{i},0,0" for i in range(5)) + "\n")
    with pytest.raises(InputError, match="only_nofix.csv: nothing imported.*gnss_no_fix 5"):
        import_file(only, start_utc="2024-05-01T10:00:00Z")


def test_csv_time_backwards_and_duplicated(tmp_path):
    p = tmp_path / "time.csv"
    times = [0.0, 0.1, 0.2, 0.15, 0.2, 0.3, 0.3, 0.4]
    p.write_text("t,heading\n" + "\n".join(f"{t},{i}" for i, t in enumerate(times)) + "\n")
    res = import_file(p, start_utc="2024-05-01T10:00:00Z")
    h = res.log["/compass/heading"]
    assert np.all(np.diff(h.index.to_numpy()) > 0)
    np.testing.assert_allclose(np.degrees(h["heading_rad"]), [0, 1, 2, 5, 7], atol=1e-9)
    assert res.report.skipped["heading_time_backwards"] == 1
    assert res.report.skipped["heading_time_duplicate"] == 2


def test_csv_role_mapped_to_missing_column(tmp_path):
    p = tmp_path / "m.csv"
    merged_csv(p, n=20)
    with pytest.raises(InputError, match=r"m.csv: column 'LAT_X' for role lat_deg is not in the header"):
        import_file(p, columns={"lat_deg": "LAT_X"})


def test_csv_empty_and_header_only(tmp_path):
    e = tmp_path / "empty.csv"
    e.write_bytes(b"")
    with pytest.raises(InputError, match="empty.csv: empty file"):
        import_file(e)
    with pytest.raises(InputError, match="empty.csv: empty file"):
        import_file(e, "csv")
    h = tmp_path / "header.csv"
    h.write_text("time,lat,lon\n")
    with pytest.raises(InputError, match="header.csv: nothing imported"):
        import_file(h)


def test_csv_truncated_and_malformed_rows(tmp_path):
    p = tmp_path / "merged.csv"
    tr = merged_csv(p, n=300)
    text = p.read_text()
    lines = text.splitlines()
    lines[50] = lines[50] + ",1,2,3"        # one row with too many fields
    cut = "\n".join(lines)
    cut = cut[: cut.rfind("\n") + 12]         # file cut inside the last row
    q = tmp_path / "cut.csv"
    q.write_text(cut)
    res = import_file(q)
    assert res.report.skipped["csv_malformed_row"] == 1
    g = res.log["/gnss/fix"]
    np.testing.assert_allclose(g["lat_deg"], tr["lat"][::10][: len(g)], atol=1e-7, rtol=0)
    assert len(res.log["/compass/heading"]) >= 58


def test_garbage_file_auto_and_forced(tmp_path):
    p = tmp_path / "noise.dat"
    p.write_bytes(bytes(np.random.default_rng(0).integers(0, 256, 4000, dtype=np.uint8)))
    with pytest.raises(FormatError, match="noise.dat: unknown format"):
        import_file(p)
    with pytest.raises(UsvlogError, match="noise.dat"):
        import_file(p, "csv")
    with pytest.raises(UsvlogError, match="noise.dat"):
        import_file(p, "nmea")


def test_wrong_text_format_forced(tmp_path):
    c = tmp_path / "merged.csv"
    merged_csv(c, n=50)
    with pytest.raises(InputError, match="merged.csv: nothing imported as nmea.*nmea_garbage 51"):
        import_file(c, "nmea")
    n = tmp_path / "gps.nmea"
    n.write_text("\n".join(nmea_lines()[:30]) + "\n")
    with pytest.raises(InputError, match="gps.nmea"):
        import_file(n, "csv")


# ------------------------------------------------------------------ NMEA

def nmea_truth(n=50):
    k = np.arange(n)
    return dict(k=k, lat=-33.8561234 + 1.1e-6 * k, lon=151.2153456 - 1.3e-6 * k, hdg=(355.0 + 0.5 * k) % 360.0)


def nmea_lines(n=50, start=dt.datetime(2024, 5, 1, 23, 59, 57, tzinfo=dt.UTC), prefix=False):
    """10 Hz GGA+RMC (mixed talkers), 20 Hz HDT; optionally an ISO time stamp before every line."""
    tr = nmea_truth(n)
    out = []
    for i in range(n):
        ts = start + dt.timedelta(milliseconds=100 * i)
        hms = ts.strftime("%H%M%S") + f".{ts.microsecond // 10000:02d}"
        la, lh = format_deg_min(tr["lat"][i], True, decimals=7)
        lo, oh = format_deg_min(tr["lon"][i], False, decimals=7)
        talker = ("GP", "GN")[i % 2]
        rows = [_cs(f"{talker}RMC,{hms},A,{la},{lh},{lo},{oh},3.9,90.0,{ts:%d%m%y},,,A"),
                _cs(f"{talker}GGA,{hms},{la},{lh},{lo},{oh},1,10,0.8,5.0,M,20.0,M,,"),
                _cs(f"HEHDT,{tr['hdg'][i]:.4f},T")]
        stamps = [ts, ts, ts + dt.timedelta(milliseconds=20)]
        if i % 2 == 0:
            rows.append(_cs(f"IIHDT,{(tr['hdg'][i] + 0.25) % 360:.4f},T"))
            stamps.append(ts + dt.timedelta(milliseconds=70))
        for s, r in zip(stamps, rows):
            out.append((s.isoformat(timespec="milliseconds").replace("+00:00", "Z") + " " + r) if prefix else r)
    return out


def test_nmea_round_trip_midnight_rollover(tmp_path):
    p = tmp_path / "gps.nmea"
    p.write_text("\n".join(nmea_lines()) + "\n")
    res = import_file(p)
    tr = nmea_truth()
    g = res.log["/gnss/fix"]
    start = int(dt.datetime(2024, 5, 1, 23, 59, 57, tzinfo=dt.UTC).timestamp()) * 10**9
    np.testing.assert_array_equal(g.index.to_numpy(), start + tr["k"] * 100_000_000)  # crosses midnight
    np.testing.assert_allclose(g["lat_deg"], tr["lat"], atol=1e-7, rtol=0)
    np.testing.assert_allclose(g["lon_deg"], tr["lon"], atol=1e-7, rtol=0)
    # GGA kept, the RMC of the same fix not duplicated; altitude above the WGS-84 ellipsoid:
    # the sentences' 5.0 m above sea level + 20.0 m geoid separation
    np.testing.assert_allclose(g["alt_m"], 5.0 + 20.0)
    assert len(res.log["/compass/heading"]) == 75
    assert sum(res.report.skipped.values()) == 0


def test_nmea_prefixed_times_and_bad_lines(tmp_path):
    lines = nmea_lines(prefix=True)
    lines.insert(10, lines[10][:-2] + "00")             # bad checksum
    lines.insert(20, "\x00\x17 random junk ~~~")         # garbage
    lines.insert(30, "2024-05-01T23:59:58.05Z " + _cs("GPGGA,235958.05,,,,,0,00,99.9,,M,,M,,"))  # no fix
    p = tmp_path / "pref.nmea"
    p.write_text("\n".join(lines) + "\n")
    res = import_file(p)
    h = res.log["/compass/heading"]
    tr = nmea_truth()
    start = int(dt.datetime(2024, 5, 1, 23, 59, 57, tzinfo=dt.UTC).timestamp()) * 10**9
    hdt = h[(h.index.to_numpy() - start) % 100_000_000 == 20_000_000]
    assert len(hdt) >= 48
    k = (hdt.index.to_numpy() - start - 20_000_000) // 100_000_000
    np.testing.assert_allclose(ssa(hdt["heading_rad"] - np.radians(tr["hdg"][k])), 0.0, atol=1e-6)
    sk = res.report.skipped
    assert sk == {"nmea_bad_checksum": 1, "nmea_garbage": 1, "gnss_no_fix": 1}
    assert "line 21" in res.report.first_bad["nmea_garbage"]


def test_nmea_hdg_deviation_variation(tmp_path):
    p = tmp_path / "hdg.nmea"
    lines = ["1714557600.0 " + _cs("HCHDG,100.0,2.0,E,3.5,W"),
             "1714557600.1 " + _cs("HCHDG,10.0,1.0,W,,"),
             "1714557600.2 " + _cs("HCHDM,200.0,M"),
             "1714557600.3 " + _cs("GPVTG,45.0,T,,M,10.0,N,18.52,K,A")]
    p.write_text("\n".join(lines) + "\n")
    log = import_file(p).log
    h = log["/compass/heading"]
    np.testing.assert_allclose(np.degrees(ssa(h["heading_rad"].to_numpy())) % 360, [98.5, 9.0, 200.0], atol=1e-9)
    assert list(h["reference"]) == ["true", "magnetic", "magnetic"]
    v = log["/gnss/velocity"]
    assert v["sog_mps"].iloc[0] == pytest.approx(10.0 * 1852 / 3600, abs=1e-12)
    assert v["cog_rad"].iloc[0] == pytest.approx(math.pi / 4, abs=1e-12)


def test_nmea_empty_file(tmp_path):
    p = tmp_path / "e.nmea"
    p.write_text("")
    with pytest.raises(InputError, match="e.nmea: empty file"):
        import_file(p, "nmea")


# ------------------------------------------------------------------ property tests

_nmea_bits = st.sampled_from(["$GPGGA,", "$GPRMC,", "$HEHDT,", "$GPVTG,", "*", ",", "A", "N", "E", "W", "T",
                              "1234.5678", "12", ".", "-", "nan", "inf", "\n", " ", "2024-05-01T00:00:00Z",
                              "1714557600.5", "$", "010524", "235959.99", "999999"])


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.binary(max_size=600))
def test_random_bytes_only_usvlog_errors(tmp_path, data):
    p = tmp_path / "rand.bin"
    p.write_bytes(data)
    for fmt in ("auto", "csv", "nmea"):
        try:
            import_file(p, fmt)
        except UsvlogError as err:
            assert str(err) and "\n" not in str(err)  # a clear one-line error, nothing else escapes


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(lines=st.lists(st.lists(_nmea_bits, max_size=14).map("".join), max_size=30),
       csv_cells=st.lists(st.lists(st.sampled_from(["", "1", "-5.5", "nan", "x", "1e400", "59.1", "\"", "1714557600",
                                                    "2024-05-01T10:00:00Z", ";"]), min_size=1, max_size=5),
                          max_size=30))
def test_random_lines_only_usvlog_errors(tmp_path, lines, csv_cells):
    p = tmp_path / "rand.nmea"
    p.write_text("\n".join(lines))
    for fmt in ("auto", "nmea"):
        try:
            import_file(p, fmt, start_utc="2024-05-01T00:00:00Z")
        except UsvlogError as err:
            assert str(err) and "\n" not in str(err)  # a clear one-line error, nothing else escapes
    q = tmp_path / "rand.csv"
    q.write_text("time,lat,lon,heading,left,right\n" + "\n".join(",".join(r) for r in csv_cells))
    for fmt in ("auto", "csv"):
        try:
            import_file(q, fmt)
        except UsvlogError as err:
            assert str(err) and "\n" not in str(err)  # a clear one-line error, nothing else escapes


def test_simulated_run_through_merged_csv_is_exact(tmp_path, excitation_log):
    """A simulated run written as one merged CSV (t_ns column) imports back to the same values and times."""
    from usvlog.io.mergedcsv import write_merged_csv

    p = tmp_path / "merged.csv"
    write_merged_csv(excitation_log, p)
    unit = str(excitation_log["/thrust/command"]["unit"].iloc[0])
    back = import_file(p, vessel=excitation_log.vessel, thrust_unit=unit, chunk_rows=5000).log
    first = excitation_log["/gnss/fix"].iloc[0]
    assert (back.datum.lat_deg, back.datum.lon_deg) == (first["lat_deg"], first["lon_deg"])  # the first fix
    for topic, cols in (("/gnss/fix", ["lat_deg", "lon_deg"]), ("/compass/heading", ["heading_rad"]),
                        ("/thrust/command", ["left", "right", "thrust_left_n", "thrust_right_n"])):
        a, b = excitation_log[topic], back[topic]
        np.testing.assert_array_equal(b.index.to_numpy(), a.index.to_numpy())
        for c in cols:
            np.testing.assert_allclose(b[c].to_numpy(), a[c].to_numpy(), rtol=0, atol=1e-12, err_msg=f"{topic} {c}")


@pytest.mark.parametrize("topic", ["/compass/heading", "/thrust/command", "/imu/yaw_rate", "/gnss/velocity",
                                   "/gnss/fix", "/truth/state"])
def test_column_encoder_matches_codec_bytes(topic):
    """The column-wise message encoder (Codec.encode, the one the importer and write_log use)
    writes exactly what one orjson.dumps per row writes (Codec.encode_reference)."""
    from usvlog.io.mcap.codec import codec_for_topic
    from usvlog.log.channels import frame_from_columns

    codec = codec_for_topic(topic)
    rng = np.random.default_rng(7)
    n = 257
    cols = {}
    for c, d in codec.dtypes().items():
        if d == "str":
            cols[c] = np.array(rng.choice(["true", 'we"ird, {x}]', "pwm_us", "ü"], n), dtype=object)
        elif d is np.int64:
            cols[c] = rng.integers(0, 2**62, n)
        else:
            v = rng.normal(0, 1e3, n) * 10.0 ** rng.integers(-9, 9, n)
            v[rng.random(n) < 0.2] = np.nan
            cols[c] = v
    frame = frame_from_columns(cols, np.arange(n, dtype=np.int64), codec.spec)
    assert codec.encode(frame, topic) == codec.encode_reference(frame, topic)


def test_imported_messages_validate_against_their_schemas(tmp_path):
    """Every message an import writes (CSV with gaps, NMEA with RMC-only fixes, VTG, HDG) is schema-valid."""
    import json

    import jsonschema
    from mcap.reader import make_reader

    from usvlog.log.channels import schema_by_name, schema_names

    validators = {n: jsonschema.Draft202012Validator(schema_by_name(n)) for n in schema_names()}
    c = tmp_path / "merged.csv"
    merged_csv(c, n=200)
    n = tmp_path / "nav.nmea"
    n.write_text("\n".join(nmea_lines(20, prefix=True) + [
        "2024-05-02T00:00:00Z " + _cs("GPRMC,000000.00,A,3351.3674,S,15112.9207,E,3.9,90.0,020524,,,A"),
        "2024-05-02T00:00:00.1Z " + _cs("GPVTG,45.0,T,,M,10.0,N,18.52,K,A"),
        "2024-05-02T00:00:00.2Z " + _cs("HCHDG,100.0,2.0,E,3.5,W")]) + "\n")
    seen = set()
    for src in (c, n):
        out = tmp_path / (src.stem + ".mcap")
        import_file(src, out=out)
        with open(out, "rb") as fh:
            for schema, channel, message in make_reader(fh).iter_messages():
                validators[schema.name].validate(json.loads(message.data))
                seen.add(channel.topic)
    assert seen == {"/gnss/fix", "/compass/heading", "/thrust/command", "/gnss/velocity", "/gnss/quality"}


def test_nmea_gga_only_rolls_past_midnight_without_dates(tmp_path):
    """No RMC: the day comes from --start-utc and a time of day is placed nearest the previous one."""
    start = dt.datetime(2024, 5, 1, 23, 59, 59, 500000, tzinfo=dt.UTC)
    tr = nmea_truth(20)
    lines = []
    for i in range(20):
        ts = start + dt.timedelta(milliseconds=100 * i)
        la, lh = format_deg_min(tr["lat"][i], True, decimals=7)
        lo, oh = format_deg_min(tr["lon"][i], False, decimals=7)
        lines.append(_cs(f"GPGGA,{ts:%H%M%S}.{ts.microsecond // 10000:02d},{la},{lh},{lo},{oh},1,10,0.8,5.0,M,,M,,"))
    p = tmp_path / "gga.nmea"
    p.write_text("\n".join(lines) + "\n")
    g = import_file(p, start_utc="2024-05-01T23:00:00Z").log["/gnss/fix"]
    t0 = int(start.timestamp() * 10**3) * 10**6
    np.testing.assert_array_equal(g["stamp_ns"].to_numpy(), t0 + np.arange(20) * 100_000_000)
    np.testing.assert_allclose(g["alt_m"], 5.0)   # no geoid separation given: height above sea level kept


@pytest.mark.parametrize("gga_first", [True, False])
def test_nmea_epoch_with_a_bad_gga_keeps_the_rmc_fix(tmp_path, gga_first):
    """One fix per epoch from its best valid sentence: GGA, else RMC (the recorder's rule too).

    RMC reports each position 1e-5 deg north of its GGA, so the values show which sentence
    gave the fix. Epoch 3's GGA has a bad checksum, epoch 6's says "no fix": RMC gives those.
    """
    tr = nmea_truth(10)
    start = dt.datetime(2024, 5, 1, 23, 59, 57, tzinfo=dt.UTC)
    lines = []
    for i in range(10):
        ts = start + dt.timedelta(milliseconds=100 * i)
        hms = ts.strftime("%H%M%S") + f".{ts.microsecond // 10000:02d}"
        lo, oh = format_deg_min(tr["lon"][i], False, decimals=7)
        la, lh = format_deg_min(tr["lat"][i], True, decimals=7)
        la_r, lh_r = format_deg_min(tr["lat"][i] + 1e-5, True, decimals=7)
        rmc = _cs(f"GPRMC,{hms},A,{la_r},{lh_r},{lo},{oh},3.9,90.0,{ts:%d%m%y},,,A")
        gga = _cs(f"GPGGA,{hms},{la},{lh},{lo},{oh},1,10,0.8,5.0,M,20.0,M,,")
        if i == 3:
            gga = gga[:-2] + ("00" if gga[-2:] != "00" else "01")
        if i == 6:
            gga = _cs(f"GPGGA,{hms},,,,,0,00,99.9,,M,,M,,")
        lines += [gga, rmc] if gga_first else [rmc, gga]
    p = tmp_path / "bad_gga.nmea"
    p.write_text("\n".join(lines) + "\n")
    res = import_file(p)
    g = res.log["/gnss/fix"]
    t0 = int(start.timestamp()) * 10**9
    np.testing.assert_array_equal(g.index.to_numpy(), t0 + tr["k"] * 100_000_000)   # every epoch has its fix
    from_rmc = np.isin(tr["k"], [3, 6])
    np.testing.assert_allclose(g["lat_deg"], tr["lat"] + np.where(from_rmc, 1e-5, 0.0), atol=1e-8, rtol=0)
    np.testing.assert_allclose(g["lon_deg"], tr["lon"], atol=1e-8, rtol=0)
    np.testing.assert_allclose(g["alt_m"].to_numpy()[~from_rmc], 25.0)   # GGA: 5 m MSL + 20 m geoid
    assert res.report.skipped == {"nmea_bad_checksum": 1, "gnss_no_fix": 1}


def test_binary_file_is_an_unknown_format_and_names_stay_printable(tmp_path):
    """Random bytes that happen to read as CSV (a separator and a letter in the first line) are
    refused as binary, not parsed as CSV; a forced CSV import's error lists the "columns" it
    found printable and short."""
    rng = np.random.default_rng(3)
    data = b"a,b" + bytes(rng.integers(0, 256, 5000, dtype=np.uint8)).replace(b"\n", b" ") + b"\n"
    p = tmp_path / "noise.bin"
    p.write_bytes(data)
    with pytest.raises(FormatError, match="noise.bin: unknown format .binary content"):
        import_file(p)
    with pytest.raises(UsvlogError, match="noise.bin") as err:
        import_file(p, "csv")
    msg = str(err.value)
    assert msg.isprintable() and "\ufffd" not in msg and len(msg) < 2000
    nmea = tmp_path / "mixed.nmea"   # a capture with a binary message among its sentences is still NMEA
    nmea.write_bytes(("\n".join(nmea_lines()[:30]) + "\n").encode() + bytes(range(256)) + b"\n")
    from usvlog.io.importers import detect_format
    assert detect_format(nmea) == "nmea"
