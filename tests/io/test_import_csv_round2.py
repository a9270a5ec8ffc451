"""CSV import, round 2 (issue 30): time columns in any unit, heading/yaw-rate units from the data,
sample-and-hold GNSS, never a mostly-empty log with exit 0, gzipped CSV.

Every CSV is written here from a simulated track whose truth the tests compare against.
"""

from __future__ import annotations

import gzip
import json

import numpy as np
import pandas as pd
import pytest

from usvlog.cli import main
from usvlog.errors import FormatError, UnusableResultError
from usvlog.io.importers import catalog_file, detect_format, import_file
from usvlog.io.importers.csvlog import time_like
from usvlog.io.importers.held import detect_held, held_mask
from usvlog.io.importers.infer import angle_unit, judge_time, rate_scale
from usvlog.io.mcap import read_log
from usvlog.io.nmea import format_deg_min
from usvlog.io.nmea import with_checksum as _cs
from usvlog.model.frames import ssa

EPOCH_MS = 1_703_025_363_629          # 2023-12-19T22:36:03.629Z
START_UTC_NS = 1_714_557_600_000_000_000   # 2024-05-01T10:00:00Z
M_PER_DEG = 111_320.0


def track(t, lat0=59.43, lon0=10.47, speed=1.2, still=None):
    """Heading (rad), yaw rate (rad/s), lat/lon (deg) of a boat turning back and forth at ``speed``
    (m/s), at rest between the times ``still`` = (t0, t1)."""
    psi = 1.5 * np.sin(2 * np.pi * t / 40.0) + 0.04 * t
    r = 1.5 * 2 * np.pi / 40.0 * np.cos(2 * np.pi * t / 40.0) + 0.04
    dt = np.diff(t, prepend=t[0])
    v = np.full(len(t), speed)
    if still is not None:
        v[(t >= still[0]) & (t < still[1])] = 0.0
    n = np.cumsum(v * np.cos(psi) * dt)
    e = np.cumsum(v * np.sin(psi) * dt)
    lat = lat0 + n / M_PER_DEG
    lon = lon0 + e / (M_PER_DEG * np.cos(np.radians(lat0)))
    return psi, r, np.round(lat, 8), np.round(lon, 8)


# -- the pure decisions ---------------------------------------------------------------------------
def test_time_unit_from_magnitude_and_step():
    k = np.arange(500.0)
    ms_epoch = judge_time(EPOCH_MS + 100.0 * k, "unix_timestamp")
    assert ms_epoch.ok and ms_epoch.unit == "ms" and ms_epoch.epoch and ms_epoch.step_s == pytest.approx(0.1)
    boot = judge_time(4959442.825 + 100.0 * k, "original_timestamp")
    assert boot.ok and boot.unit == "ms" and not boot.epoch and boot.step_s == pytest.approx(0.1)
    assert judge_time(1.7e9 + 0.01 * k, "time").unit == "s"
    assert judge_time(12.0 + 0.01 * k, "time").unit == "s"
    assert judge_time(3.0e6 + 10_000.0 * k, "timeus").unit == "us"      # the name says us
    assert judge_time(1.7e18 + 1e8 * k, "t").unit == "ns"
    garbled = np.random.default_rng(1).uniform(0, 86400, 500)
    bad = judge_time(garbled, "time")
    assert not bad.ok and "not monotonic" in bad.why
    assert not judge_time(np.full(50, 7.0), "time").ok
    names = ["t", "t_s", "t_water", "Unix Timestamp", "original_timestamp", "TimeUS", "Date", "speed_ms", "yaw"]
    assert [h for h in names if time_like(h)] == ["t", "t_s", "Unix Timestamp", "original_timestamp", "TimeUS",
                                                  "Date"]


def test_angle_and_rate_units_from_the_data():
    t = np.arange(0, 120, 0.1)
    psi, r, _, _ = track(t)
    wrapped = np.asarray(ssa(psi))
    assert angle_unit(np.degrees(wrapped), "deg")[0] == "deg"
    assert angle_unit(wrapped, "deg")[0] == "rad"
    assert angle_unit(np.full(10, 2.0), "deg")[0] == "deg"           # cannot tell: the name's unit
    k_rad, corr = rate_scale(t, wrapped, t, r)
    assert k_rad == pytest.approx(1.0, abs=0.03) and corr > 0.99
    k_deg, _ = rate_scale(t, wrapped, t, np.degrees(r))
    assert k_deg == pytest.approx(180 / np.pi, rel=0.03)
    assert rate_scale(t, np.zeros_like(t), t, r) is None               # a heading that never turns


def test_held_detection_and_a_still_receiver():
    t = np.arange(0, 300, 0.1)
    _, _, lat, lon = track(t, still=(100, 130))
    k = np.arange(len(t))
    hold = 2 * (k // 2)                                 # 5 Hz updates held on a 10 Hz grid
    t_ns = np.round(t * 1e9).astype(np.int64)
    h = detect_held(t_ns, lat[hold], lon[hold])
    assert h is not None and h.rate_hz == pytest.approx(5.0, rel=1e-3) and h.row_rate_hz == pytest.approx(10.0)
    mask = np.concatenate([held_mask(t_ns[a:a + 337], [lat[hold][a:a + 337], lon[hold][a:a + 337]],
                                     h.update_s, st)[0] for a, st in _states(t_ns, lat[hold], lon[hold], h)])
    moving = (t < 99.9) | (t >= 130)
    np.testing.assert_array_equal(mask[moving], k[moving] % 2 == 1)   # one row per update, the first
    assert (~mask).sum() == len(t) // 2                 # every real update kept, at rest too (0.1 s later)
    # the same receiver without resampling: 10 Hz fixes, identical while at rest -> not held
    assert detect_held(t_ns, lat, lon) is None
    # a fix republished 3 times 0.1 s apart each second: copies, not a resampled grid
    tr = np.concatenate([s + np.array([0.0, 0.1, 0.2]) for s in range(100)])
    rep = np.repeat(np.arange(100.0), 3)
    assert detect_held(np.round(tr * 1e9).astype(np.int64), 59 + rep * 1e-5, 10 + rep * 1e-5) is None


def test_held_with_a_jittery_receiver():
    """5 Hz fixes arriving +-40 ms late or early, held on a 10 Hz grid: runs of 1, 2 and 3 rows;
    one row per update kept (the row where it arrived), none of the held rows."""
    rng = np.random.default_rng(5)
    t_fix = np.arange(0, 200, 0.2) + rng.uniform(-0.04, 0.04, 1000)
    _, _, lat, lon = track(t_fix)
    t = np.arange(0.1, 200, 0.1)
    j = np.searchsorted(t_fix, t, side="right") - 1     # the last fix at or before each row
    t_ns = np.round(t * 1e9).astype(np.int64)
    h = detect_held(t_ns, lat[j], lon[j])
    assert h is not None and h.rate_hz == pytest.approx(5.0, rel=0.01)
    held, _ = held_mask(t_ns, [lat[j], lon[j]], h.update_s)
    first = np.ones(len(t), bool)
    first[1:] = j[1:] != j[:-1]
    np.testing.assert_array_equal(~held, first)


def _states(t_ns, lat, lon, h):
    """(start, state) of batches of 337 rows, the state carried from batch to batch."""
    st = None
    for a in range(0, len(t_ns), 337):
        yield a, st
        _, st = held_mask(t_ns[a:a + 337], [lat[a:a + 337], lon[a:a + 337]], h.update_s, st)


# -- survey boat: ms since 1970, garbled Date/Time, Yaw in degrees ------------------------------
def survey_csv(path, n=1758):
    rng = np.random.default_rng(7)
    t_ms = EPOCH_MS + 100 * np.arange(n) + rng.integers(-3, 4, n)
    t = (t_ms - t_ms[0]) / 1e3
    psi, _, lat, lon = track(t)
    yaw = np.round(np.degrees(psi) % 360.0, 3)
    date = np.array(["2023-12-19"] + [f"20{rng.integers(10, 30)}-0{rng.integers(1, 9)}-1{rng.integers(0, 9)}"
                                      for _ in range(n - 1)])
    tod = np.concatenate([[81363.629], np.round(rng.uniform(0, 86400, n - 1), 3)])
    pd.DataFrame({"Date": date, "Time": tod, "Unix Timestamp": t_ms, "Latitude": lat, "Longitude": lon,
                  "Yaw": yaw}).to_csv(path, index=False)
    return dict(t_ns=t_ms * 1_000_000, lat=lat, lon=lon, psi=psi)


def test_ms_since_epoch_beats_a_garbled_time_column(tmp_path):
    tr = survey_csv(tmp_path / "survey.csv")
    res = import_file(tmp_path / "survey.csv", chunk_rows=500)
    rep, log = res.report, res.log
    assert rep.mapping["time_ms"] == "Unix Timestamp" and "time_s" not in rep.mapping
    assert "ms since 1970" in rep.guesses["time_column"]
    assert "'Time': not monotonic" in rep.guesses["time_rejected"]
    assert "'Date': not monotonic" in rep.guesses["time_rejected"]
    g, h = log["/gnss/fix"], log["/compass/heading"]
    assert len(g) == len(tr["t_ns"]) and len(h) == len(tr["t_ns"])          # every fix kept
    assert np.max(np.abs(g.index.to_numpy() - tr["t_ns"])) < 1_000_000      # times to 1 ms
    np.testing.assert_allclose(g["lat_deg"], tr["lat"], atol=1e-9, rtol=0)
    assert rep.mapping["heading_deg"] == "Yaw" and rep.guesses["heading_unit"].startswith("'Yaw' in deg")
    assert np.max(np.abs(ssa(h["heading_rad"].to_numpy() - tr["psi"]))) < np.radians(0.001)
    assert sum(rep.skipped.values()) == 0 and rep.unusable is None


# -- resampled ArduPilot boat: ms since boot, held GNSS, yaw deg, yaw_rate rad/s -----------------
def ardupilot_csv(path, n=3098):
    k = np.arange(n)
    boot_ms = 4959442.825 + 100.0 * k
    t = k * 0.1
    psi, r, lat, lon = track(t, still=(150, 180))
    hold = 2 * (k // 2)                                 # 5 Hz fixes held on the 10 Hz grid
    pd.DataFrame({"original_timestamp": np.char.mod("%.3f", boot_ms), "lat": lat[hold], "lon": lon[hold],
                  "yaw": np.round(np.degrees(psi) % 360.0, 4), "yaw_rate": np.round(r, 6)}
                 ).to_csv(path, index=False)
    return dict(t_ns=START_UTC_NS + 100_000_000 * k, lat=lat, lon=lon, psi=psi, r=r, n=n)


def test_ms_since_boot_held_gnss_and_rad_per_s_yaw_rate(tmp_path):
    tr = ardupilot_csv(tmp_path / "boat.csv")
    res = import_file(tmp_path / "boat.csv", start_utc="2024-05-01T10:00:00Z", chunk_rows=337)
    rep, log = res.report, res.log
    assert rep.mapping["time_ms"] == "original_timestamp" and "ms since boot" in rep.guesses["time_column"]
    g = log["/gnss/fix"]
    even = np.arange(0, tr["n"], 2)
    assert rep.guesses["gnss_rate_hz"] == pytest.approx(5.0, rel=1e-3)
    assert "5 Hz" in rep.guesses["gnss_held"] and "10 Hz rows" in rep.guesses["gnss_held"]
    assert rep.skipped["gnss_held_repeat"] == tr["n"] - len(even)
    assert len(g) == len(even)                          # one fix per real update, at rest too
    kept = (g.index.to_numpy() - START_UTC_NS) // 100_000_000
    moving = (kept < 1500) | (kept >= 1800)
    np.testing.assert_array_equal(kept[moving], np.concatenate([even[even < 1500], even[even >= 1800]]))
    np.testing.assert_allclose(g["lat_deg"], tr["lat"][kept], atol=1e-9, rtol=0)
    np.testing.assert_allclose(g["lon_deg"], tr["lon"][kept], atol=1e-9, rtol=0)
    assert rep.mapping["heading_deg"] == "yaw"
    h = log["/compass/heading"]
    assert np.max(np.abs(ssa(h["heading_rad"].to_numpy() - tr["psi"]))) < 1e-5
    assert rep.mapping["yaw_rate_radps"] == "yaw_rate" and "yaw_rate_degps" not in rep.mapping
    assert rep.guesses["yaw_rate_unit"].startswith("'yaw_rate' in rad/s")
    scale = float(rep.guesses["yaw_rate_unit"].split("scale ")[1].split()[0])
    assert scale == pytest.approx(1.0, abs=0.05)
    r = log["/imu/yaw_rate"]
    np.testing.assert_array_equal(r.index.to_numpy(), tr["t_ns"])
    np.testing.assert_allclose(r["r_radps"], tr["r"], atol=1e-6, rtol=0)
    assert rep.unusable is None
    cat = catalog_file(tmp_path / "boat.csv")           # inspect shows the same decisions
    assert cat.mapping["time_ms"] == "boat.csv.original_timestamp" and "yaw_rate_radps" in cat.mapping
    assert "ms since boot" in cat.reasons["time_ms"] and any("5 Hz" in n for n in cat.notes)


# -- a garbled time column and nothing else: exit 1, or flagged with --force ----------------------
def garbled_csv(path, n=600):
    rng = np.random.default_rng(3)
    t = 0.1 * np.arange(n)
    _, _, lat, lon = track(t)
    tod = np.concatenate([[36000.0], np.round(rng.uniform(0, 86400, n - 1), 3)])
    pd.DataFrame({"Time": tod, "lat": lat, "lon": lon}).to_csv(path, index=False)


def test_a_mostly_empty_import_is_unusable(tmp_path, capsys):
    src = tmp_path / "garbled.csv"
    garbled_csv(src)
    with pytest.raises(UnusableResultError) as exc:
        import_file(src)
    msg = str(exc.value)
    assert "\n" not in msg and "garbled.csv" in msg and "/gnss/fix" in msg
    kept, of = (int(x) for x in msg.split("kept ")[1].split(" samples")[0].split(" of "))
    assert of == 600 and kept < 300 and "gnss_time_backwards" in msg
    assert "--column time_ms=" in msg and "--force" in msg
    out = tmp_path / "g.mcap"
    assert main(["import", str(src), "--out", str(out)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert "kept" in err[-1] and not out.exists()
    assert main(["import", str(src), "--out", str(out), "--force", "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["unusable"].startswith(str(src)) and any(n.startswith("UNUSABLE") for n in rep["notes"])
    prov = read_log(out).provenance[-1]
    assert "kept" in prov["unusable"] and len(read_log(out)["/gnss/fix"]) == kept


# -- gzipped CSV ---------------------------------------------------------------------------------
def otter_rows(n=2000):
    k = np.arange(n)
    t = 0.01 * k
    psi, _, lat, lon = track(t)
    fix = k % 10 == 0
    return pd.DataFrame({"t": np.char.mod("%.3f", t),
                         "lat_deg": np.where(fix, np.char.mod("%.8f", lat), ""),
                         "lon_deg": np.where(fix, np.char.mod("%.8f", lon), ""),
                         "heading_deg": np.where(k % 5 == 0, np.char.mod("%.2f", np.degrees(psi) % 360), ""),
                         "thrust_cmd_left_N": np.char.mod("%.4f", 20 + 5 * np.sin(t)),
                         "thrust_cmd_right_N": np.char.mod("%.4f", 20 - 5 * np.sin(t)),
                         "n_cmd_left_radps": np.char.mod("%.4f", 50 + np.sin(t))}), dict(t=t, lat=lat, fix=fix)


def test_gzipped_csv_imports_like_the_plain_file(tmp_path):
    df, tr = otter_rows()
    plain = tmp_path / "otter.csv"
    df.to_csv(plain, index=False)
    zipped = tmp_path / "otter_sensor.csv.gz"
    with gzip.open(zipped, "wt") as fh:
        df.to_csv(fh, index=False)
    args = ["--column", "time_s=t", "--column", "lat_deg=lat_deg", "--column", "lon_deg=lon_deg",
            "--column", "heading_deg=heading_deg", "--column", "thrust_left=thrust_cmd_left_N",
            "--column", "thrust_right=thrust_cmd_right_N", "--thrust-unit", "newton",
            "--start-utc", "2026-06-01T12:00:00Z"]
    logs = []
    for src in (zipped, plain):
        out = tmp_path / (src.name + ".mcap")
        assert main(["import", str(src), "--out", str(out), *args]) == 0
        logs.append(read_log(out))
    lz, lp = logs
    g = lz["/gnss/fix"]
    t0 = 1_780_315_200_000_000_000   # 2026-06-01T12:00:00Z
    np.testing.assert_array_equal(g.index.to_numpy(), t0 + np.round(tr["t"][tr["fix"]] * 1e9).astype(np.int64))
    np.testing.assert_allclose(g["lat_deg"], tr["lat"][tr["fix"]], atol=1e-8, rtol=0)
    assert len(lz["/thrust/command"]) == len(df) and len(lz["/compass/heading"]) == len(df) // 5
    for topic in ("/gnss/fix", "/compass/heading", "/thrust/command"):
        assert lz[topic].equals(lp[topic]), topic
    res = import_file(zipped)                           # detected and mapped without help too
    assert res.report.format == "csv" and len(res.log["/gnss/fix"]) == int(tr["fix"].sum())


def test_gzipped_nmea_is_detected_and_read(tmp_path):
    t = np.arange(0, 60, 1.0)
    _, _, lat, lon = track(t, lat0=59.43, lon0=10.47)
    lines = []
    for k, tk in enumerate(t):
        la, lh = format_deg_min(lat[k], True)
        lo, oh = format_deg_min(lon[k], False)
        hms = f"1000{int(tk):02d}.00"
        lines.append(_cs(f"GPRMC,{hms},A,{la},{lh},{lo},{oh},2.3,90.0,010524,,,A"))
    src = tmp_path / "capture.nmea.gz"
    with gzip.open(src, "wt") as fh:
        fh.write("\r\n".join(lines) + "\r\n")
    assert detect_format(src) == "nmea"
    g = import_file(src).log["/gnss/fix"]
    np.testing.assert_array_equal(g.index.to_numpy(), START_UTC_NS + np.round(t * 1e9).astype(np.int64))
    np.testing.assert_allclose(g["lat_deg"], lat, atol=1e-6, rtol=0)


def test_a_damaged_gzip_is_one_format_error(tmp_path):
    df, _ = otter_rows(300)
    src = tmp_path / "cut.csv.gz"
    with gzip.open(src, "wt") as fh:
        df.to_csv(fh, index=False)
    src.write_bytes(src.read_bytes()[:-40])             # cut short: the end of the stream is missing
    for fmt in ("auto", "csv", "nmea"):
        with pytest.raises(FormatError, match="damaged gzip file") as exc:
            import_file(src, fmt)
        assert "\n" not in str(exc.value) and "cut.csv.gz" in str(exc.value)
