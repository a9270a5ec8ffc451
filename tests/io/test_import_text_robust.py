"""Text logs from other people's loggers: the real ArduSub NMEA capture, prefix times, damaged lines.

The real file (tests/data/real/ardusub_nmea_log.txt, MIT, see LICENSE.ardusub_log_tools.txt beside
it) is counted independently with pynmea2; damaged-line property tests compare a damaged import
with the clean one: only the damaged line's own samples may differ.
"""

from __future__ import annotations

import datetime as dt
import json
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from usvlog.errors import InputError
from usvlog.io.importers import ImportOptions, import_file
from usvlog.io.importers.csvlog import catalog as csv_catalog
from usvlog.io.importers.csvlog import looks_like_csv
from usvlog.io.importers.nmea import PrefixTimeError, looks_like_nmea, prefix_time
from usvlog.io.importers.nmea import catalog as nmea_catalog
from usvlog.io.nmea import with_checksum as _cs

REAL = Path(__file__).resolve().parents[1] / "data" / "real" / "ardusub_nmea_log.txt"
KNOT = 1852.0 / 3600.0


def _pynmea2_truth():
    """Per line: prefix time (naive, local), parsed pynmea2 message; counted by pynmea2 alone."""
    pynmea2 = pytest.importorskip("pynmea2")
    out = []
    for line in REAL.read_text().splitlines():
        k = line.find("$")
        if k < 0:
            continue
        msg = pynmea2.parse(line[k:], check=True)
        out.append((dt.datetime.strptime(line[:23], "%Y-%m-%d %H:%M:%S.%f"), msg))
    return out


def _epoch_ns(d: dt.datetime) -> int:
    d = d.replace(tzinfo=dt.UTC) if d.tzinfo is None else d
    return int(round(d.timestamp() * 1e6)) * 1000


def test_real_logger_prefixed_nmea_imports_every_fix_on_rmc_utc():
    truth = _pynmea2_truth()
    rmc = [m for _, m in truth if m.sentence_type == "RMC" and m.status == "A"]
    gga = [m for _, m in truth if m.sentence_type == "GGA" and int(m.gps_qual or 0) > 0]
    hdt = [m for _, m in truth if m.sentence_type == "HDT"]
    epochs = sorted({_epoch_ns(m.datetime) for m in rmc})
    assert len(rmc) == 129 and len(gga) == 16 and len(epochs) == 129   # the measured facts of docs/importing.md
    res = import_file(REAL)
    log, rep = res.log, res.report
    g = log["/gnss/fix"]
    assert len(g) == len(epochs) == 129
    # record time = RMC's UTC (the 7 h behind local logger prefix is not taken as UTC)
    np.testing.assert_array_equal(g.index.to_numpy(), epochs)
    np.testing.assert_array_equal(g["stamp_ns"].to_numpy(), epochs)
    lat = {_epoch_ns(m.datetime): m.latitude for m in rmc}
    np.testing.assert_allclose(g["lat_deg"].to_numpy(), [lat[t] for t in epochs], atol=1e-9, rtol=0)
    # GGA epochs carry altitude above the ellipsoid (MSL + geoid separation); RMC-only ones: unknown, not 0
    gga_t = {int(g.index[0] // 86_400_000_000_000 * 86_400_000_000_000)
             + ((m.timestamp.hour * 60 + m.timestamp.minute) * 60 + m.timestamp.second) * 10**9
             + m.timestamp.microsecond * 1000: float(m.altitude) + float(m.geo_sep) for m in gga}
    alt = g["alt_m"].to_numpy()
    is_gga = np.isin(g.index.to_numpy(), list(gga_t))
    assert is_gga.sum() == 16
    np.testing.assert_allclose(alt[is_gga], [gga_t[t] for t in g.index.to_numpy()[is_gga]], atol=1e-9)
    assert np.isnan(alt[~is_gga]).all()
    # RMC speed and course -> /gnss/velocity
    v = log["/gnss/velocity"]
    assert len(v) == 129
    np.testing.assert_allclose(v["sog_mps"].to_numpy(), [float(m.spd_over_grnd) * KNOT for m in rmc], atol=1e-12)
    cog = np.radians([float(m.true_course) for m in rmc])
    np.testing.assert_allclose(np.angle(np.exp(1j * (v["cog_rad"].to_numpy() - cog))), 0.0, atol=1e-12)
    # the empty headings ($GPHDT,,*4F) are skipped and counted, and nothing else is lost
    assert all(not m.heading for m in hdt) and len(hdt) == 129
    assert "/compass/heading" not in log.channels
    assert rep.skipped == {"nmea_heading_empty": 129, "nmea_garbage": 5}
    assert any("UTC-07:00" in n and "not used" in n for n in rep.notes)


def test_real_nmea_prefix_time_auto_is_put_on_rmc_utc():
    truth = _pynmea2_truth()
    pre = {_epoch_ns(m.datetime): p for p, m in truth if m.sentence_type == "RMC"}
    day = dt.datetime(2023, 9, 1, tzinfo=dt.UTC)
    for p, m in truth:   # an epoch's fix comes from its GGA when there is one: that line's prefix
        if m.sentence_type == "GGA":
            pre[_epoch_ns(dt.datetime.combine(day.date(), m.timestamp, tzinfo=dt.UTC))] = p
    res = import_file(REAL, prefix_time="auto")
    g = res.log["/gnss/fix"]
    # the prefix is the record time, on UTC by its zone (-07:00, measured against RMC), not as if UTC
    want = [_epoch_ns(pre[int(s)]) + 7 * 3600 * 10**9 for s in g["stamp_ns"].to_numpy()]
    np.testing.assert_array_equal(g.index.to_numpy(), want)
    assert res.report.guesses["prefix_time"] == "UTC-07:00"
    fmt = import_file(REAL, prefix_time="%Y-%m-%d %H:%M:%S.%f").log["/gnss/fix"]
    np.testing.assert_array_equal(fmt.index.to_numpy(), want)
    # --start-utc: the first stamped line is placed there
    s0 = "2023-09-01T22:56:44.626Z"
    first = import_file(REAL, prefix_time="auto", start_utc=s0).log["/gnss/fix"]
    t_first_line = _epoch_ns(truth[0][0])    # the first sentence line's prefix
    np.testing.assert_array_equal(first.index.to_numpy() - first.index.to_numpy()[0],
                                  g.index.to_numpy() - g.index.to_numpy()[0])
    assert first.index[0] == _epoch_ns(dt.datetime(2023, 9, 1, 22, 56, 44, 626000)) + (
        _epoch_ns(pre[int(g["stamp_ns"].iloc[0])]) - t_first_line)


def test_real_nmea_catalog_lists_sentences_and_fields():
    truth = _pynmea2_truth()
    cat = nmea_catalog(REAL, ImportOptions())
    counts = {t.name: t.count for t in cat.topics}
    want = {}
    for _, m in truth:
        want[m.sentence_type] = want.get(m.sentence_type, 0) + 1
    assert counts == want == {"RMC": 129, "HDT": 129, "GGA": 16}
    rmc = cat.topic("RMC")
    f = {x.path: x for x in rmc.fields}
    assert f["sog_kn"].type == "float (field 7)" and f["sog_kn"].sample == pytest.approx(0.1)
    assert f["date"].sample == "010923" and f["time_utc"].sample == "225644.620"
    assert rmc.first_ns == _epoch_ns(truth[0][1].datetime) and cat.time_base == "utc"
    assert cat.mapping["gnss"] == "GGA.lat_ddmm/RMC.lat_ddmm" and cat.mapping["velocity"] == "RMC.sog_kn"
    assert "no" not in cat.reasons["gnss"]
    assert any("5 lines without a sentence" in n for n in cat.notes)
    json.dumps(cat.to_dict())   # JSON-ready


# ------------------------------------------------------------------ single bad lines

def _lines(n=40):
    """Epoch-second prefixed 1 Hz GGA+RMC, HDT between (checksums on every sentence)."""
    t0 = dt.datetime(2024, 5, 1, 10, 0, 0, tzinfo=dt.UTC)
    out = []
    for i in range(n):
        ts = t0 + dt.timedelta(seconds=i)
        hms = ts.strftime("%H%M%S") + ".00"
        lat = f"{5907 + i * 0.001:.4f}"
        e = ts.timestamp()
        out.append(f"{e:.2f} " + _cs(f"GPGGA,{hms},{lat},N,01045.0000,E,1,10,0.8,5.0,M,20.0,M,,"))
        out.append(f"{e:.2f} " + _cs(f"GPRMC,{hms},A,{lat},N,01045.0000,E,3.9,{(10 * i) % 360:.1f},010524,,,A"))
        out.append(f"{e + 0.5:.2f} " + _cs(f"HEHDT,{(20.0 + 7 * i) % 360:.1f},T"))
    return out


def _samples(path, **kw):
    res = import_file(path, **kw)
    out = {}
    for topic, fr in res.log.channels.items():
        for t, row in zip(fr.index.to_numpy(), fr.itertuples(index=False)):
            out[(topic, int(t))] = tuple(round(x, 9) if isinstance(x, float) and math.isfinite(x) else
                                         (None if isinstance(x, float) else x) for x in row)
    return out, res.report


def _damage(line: str, how: str, k: int) -> str:
    pre, _, body = line.partition(" ")
    if how == "overflow":
        return "1e300 " + body
    fields = body.split(",")
    j = 1 + k % (len(fields) - 1)
    if how == "nan":
        fields[j] = "nan"
        return pre + " " + ",".join(fields)
    if how == "missing":
        del fields[j]
        return pre + " " + ",".join(fields)
    cut = 3 + k % max(1, body.index("*") - 3)       # truncated: the line ends early, no checksum
    return pre + " " + body[:cut]


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(i=st.integers(0, 119), how=st.sampled_from(["overflow", "nan", "missing", "truncated"]),
       k=st.integers(0, 50))
def test_one_damaged_nmea_line_changes_only_its_own_samples(tmp_path, i, how, k):
    lines = _lines()
    clean = tmp_path / "clean.nmea"
    clean.write_text("\n".join(lines) + "\n")
    a, _ = _samples(clean)
    bad = list(lines)
    bad[i] = _damage(lines[i], how, k)
    p = tmp_path / "bad.nmea"
    p.write_text("\n".join(bad) + "\n")
    b, rep = _samples(p)
    t_line = int(round(float(lines[i].split()[0]) * 1e6)) * 1000
    changed = {key for key in a.keys() | b.keys() if a.get(key) != b.get(key)}
    assert all(t == t_line for _, t in changed), (bad[i], changed)
    assert len(changed) <= 2          # the line's fix (the epoch's other sentence may give it) and velocity
    assert sum(rep.skipped.values()) <= 1


def test_truncated_sentence_without_checksum_is_not_a_heading(tmp_path):
    lines = _lines(10)
    lines[2] = lines[2].split(" ")[0] + " $HEHDT,2"          # true 34.0 deg: a truncated copy would say 2
    p = tmp_path / "t.nmea"
    p.write_text("\n".join(lines) + "\n")
    res = import_file(p)
    assert res.report.skipped == {"nmea_no_checksum": 1}
    assert len(res.log["/compass/heading"]) == 9
    assert not np.isclose(np.degrees(res.log["/compass/heading"]["heading_rad"]), 2.0).any()


def test_overflow_prefix_costs_one_line(tmp_path):
    lines = _lines(10)
    lines[4] = "1e300 " + lines[4].partition(" ")[2]
    p = tmp_path / "o.nmea"
    p.write_text("\n".join(lines) + "\n")
    res = import_file(p)
    assert res.report.skipped == {"nmea_bad_time": 1}
    assert len(res.log["/gnss/fix"]) == 10 and len(res.log["/compass/heading"]) == 10


def test_zoneless_prefix_without_sentence_utc_is_taken_as_utc_only_when_asked(tmp_path):
    p = tmp_path / "h.nmea"
    p.write_text("\n".join(f"2024-05-01 10:00:0{i}.000 INFO {_cs(f'HEHDT,{10 * i}.0,T')}" for i in range(5)) + "\n")
    with pytest.raises(InputError, match="nmea_untimed 5.*--prefix-time auto"):
        import_file(p)
    res = import_file(p, prefix_time="auto")
    h = res.log["/compass/heading"]
    np.testing.assert_array_equal(h.index.to_numpy(), 1_714_557_600_000_000_000 + np.arange(5) * 10**9)
    assert any("taken as UTC" in n for n in res.report.notes)


# ------------------------------------------------------------------ CSV

def test_csv_lat_without_lon_is_one_line_naming_the_missing_column(tmp_path):
    p = tmp_path / "half.csv"
    p.write_text("time,lat,heading\n1714557600,59.1,10\n1714557601,59.2,11\n")
    with pytest.raises(InputError, match=r"half.csv: column 'lat' \(lat_deg\) has no lon_deg column") as e:
        import_file(p)
    assert "\n" not in str(e.value)


def test_csv_with_one_malformed_row_early_is_still_csv(tmp_path):
    rows = [f"{1714557600 + i},59.{i},10.{i},{i}" for i in range(30)]
    rows[3] = rows[3] + ",7,8"            # one row with too many cells
    text = "time,lat,lon,heading\n" + "\n".join(rows) + "\n"
    assert looks_like_csv(text)
    p = tmp_path / "m.csv"
    p.write_text(text)
    res = import_file(p)
    assert res.report.format == "csv" and res.report.skipped == {"csv_malformed_row": 1}
    assert len(res.log["/gnss/fix"]) == 29


def test_csv_start_utc_is_the_first_sample(tmp_path):
    p = tmp_path / "rel.csv"
    p.write_text("t,heading\n" + "\n".join(f"{12.5 + 0.1 * i:.1f},{i}" for i in range(5)) + "\n")
    h = import_file(p, start_utc="2024-05-01T10:00:00Z").log["/compass/heading"]
    np.testing.assert_array_equal(h.index.to_numpy(), 1_714_557_600_000_000_000 + np.arange(5) * 100_000_000)


def test_csv_catalog_lists_columns_and_roles(tmp_path):
    p = tmp_path / "c.csv"
    p.write_text("time,Latitude,Longitude,heading,note\n1714557600,59.1,10.2,5,a\n1714557601,59.2,10.3,,b\n")
    cat = csv_catalog(p, ImportOptions(columns={"heading_deg": "heading"}))
    (t,) = cat.topics
    assert t.count == 2 and t.first_ns == 1_714_557_600 * 10**9 and t.last_ns == 1_714_557_601 * 10**9
    assert [(f.path, f.type, f.sample) for f in t.fields] == [
        ("time", "int", 1714557600), ("Latitude", "float", 59.1), ("Longitude", "float", 10.2),
        ("heading", "float", 5.0), ("note", "text", "a")]
    assert cat.mapping["lat_deg"] == "c.csv.Latitude" and "common name" in cat.reasons["lat_deg"]
    assert cat.reasons["heading_deg"].startswith("given") and cat.time_base == "utc"


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(i=st.integers(0, 39), how=st.sampled_from(["overflow", "nan", "missing", "truncated"]),
       col=st.integers(0, 3))
def test_one_damaged_csv_row_changes_only_its_own_samples(tmp_path, i, how, col):
    rows = [[f"{1714557600 + i}", f"59.{1000 + i}", f"10.{2000 + i}", f"{(5 * i) % 360}"] for i in range(40)]
    p = tmp_path / "c.csv"
    p.write_text("time,lat,lon,heading\n" + "\n".join(",".join(r) for r in rows) + "\n")
    a, _ = _samples(p)
    r = list(rows[i])
    if how == "overflow":
        r[col] = "1e300"
    elif how == "nan":
        r[col] = "nan"
    elif how == "missing":
        del r[col]
    text = ",".join(r)
    if how == "truncated":
        text = text[: max(1, len(text) // 2)]
    q = tmp_path / "d.csv"
    q.write_text("time,lat,lon,heading\n" + "\n".join(text if j == i else ",".join(x) for j, x in enumerate(rows))
                 + "\n")
    b, _ = _samples(q)
    changed = {key for key in a.keys() | b.keys() if a.get(key) != b.get(key)}
    assert all(t == (1714557600 + i) * 10**9 for _, t in changed), (text, changed)


def test_import_json_failure_prints_an_error_object(tmp_path, capsys):
    from usvlog.cli import main

    p = tmp_path / "e.nmea"
    p.write_text("nothing here\n")
    rc = main(["import", str(p), "--format", "nmea", "--out", str(tmp_path / "o.mcap"), "--json"])
    assert rc == 2
    out = json.loads(capsys.readouterr().out)
    assert "nothing imported" in out["error"] and out["kind"] == "InputError"


@settings(max_examples=200, deadline=None)
@given(text=st.text(st.sampled_from("0123456789-:T .,Ze+|[]abc"), max_size=40),
       fmt=st.sampled_from([None, "auto", "%Y-%m-%d %H:%M:%S.%f", "%H:%M:%S"]))
def test_prefix_time_reads_or_says_why(text, fmt):
    try:
        got = prefix_time(text, fmt)
    except PrefixTimeError:
        return
    assert got is None or (isinstance(got[0], int) and got[1] in ("utc", "local", "relative"))


def test_prefix_kinds():
    assert prefix_time("2024-05-01T10:00:00.5Z x") == (1_714_557_600_500_000_000, "utc")
    assert prefix_time("2024-05-01 12:00:00+0200 |") == (1_714_557_600_000_000_000, "utc")
    assert prefix_time("2024-05-01 10:00:00,25 INFO") == (1_714_557_600_250_000_000, "local")
    assert prefix_time("1714557600.5 ") == (1_714_557_600_500_000_000, "utc")
    assert prefix_time("12.5 ") == (12_500_000_000, "relative")
    assert prefix_time("[INFO] nmea: ") is None
    for bad in ("1e300 ", "-5 ", "2024-13-01 10:00:00 "):
        with pytest.raises(PrefixTimeError):
            prefix_time(bad)


def test_a_capture_with_many_logger_lines_is_nmea():
    lines = [f"2023-09-01 15:56:4{i}.000 | INFO | main - status {i}" for i in range(6)]
    lines += [f"2023-09-01 15:56:4{i}.500 | DEBUG | recv - " + _cs("GPHDT,10.0,T") for i in range(3)]
    assert looks_like_nmea("\n".join(lines))
    assert not looks_like_nmea("time,lat,lon\n1,2,3\n4,5,6\n")
