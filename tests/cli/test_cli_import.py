"""``usvlog import`` end to end: outputs, one-line errors, no overwrite, no half-written file."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

from usvlog.cli import main
from usvlog.io.mcap import read_log

T0_S = 1_714_557_600.0


def _csv(path, n=1000, bad_every=0):
    k = np.arange(n)
    lat = np.where(k % 10 == 0, 59.1 + 1e-6 * k, np.nan).astype(object)
    if bad_every:
        lat[::bad_every] = "oops"
    df = pd.DataFrame({"time": T0_S + 0.01 * k, "lat": lat, "lon": np.where(k % 10 == 0, 10.2 + 1e-6 * k, np.nan),
                       "heading": np.where(k % 5 == 0, (0.3 * k) % 360, np.nan),
                       "left": 0.01 * (k % 50), "right": -0.01 * (k % 50)})
    df.to_csv(path, index=False, na_rep="")


def test_import_then_inspect_rates_and_skipped(tmp_path):
    src = tmp_path / "boat.csv"
    _csv(src, bad_every=100)
    out = tmp_path / "run.mcap"
    r = subprocess.run([sys.executable, "-m", "usvlog", "import", str(src), "--out", str(out)],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert "lat_deg" in r.stderr and "(guessed)" in r.stderr       # the mapping is shown
    assert "skipped" in r.stdout and "csv_bad_value 10" in r.stdout
    r = subprocess.run([sys.executable, "-m", "usvlog", "inspect", str(out), "--json"], capture_output=True, text=True)
    s = json.loads(r.stdout)
    assert s["channels"]["/gnss/fix"]["rate_hz"] == pytest.approx(10.0)
    assert s["channels"]["/compass/heading"]["rate_hz"] == pytest.approx(20.0)
    assert s["channels"]["/thrust/command"]["rate_hz"] == pytest.approx(100.0)
    assert s["skipped"] == {"csv_bad_value": 10, "gnss_incomplete": 10}
    r = subprocess.run([sys.executable, "-m", "usvlog", "inspect", str(out)], capture_output=True, text=True)
    assert "skipped records: csv_bad_value 10, gnss_incomplete 10" in r.stdout


def test_import_json_report_and_columns(tmp_path, capsys):
    src = tmp_path / "b.csv"
    _csv(src)
    out = tmp_path / "r.mcap"
    assert main(["import", str(src), "--out", str(out), "--json", "--column", "heading_deg=heading",
                 "--thrust-unit", "normalized"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["channels"] == {"/compass/heading": 200, "/gnss/fix": 100, "/thrust/command": 1000}
    assert rep["mapping"]["heading_deg"] == "heading" and "column heading_deg" not in rep["guesses"]
    log = read_log(out)
    assert set(log["/thrust/command"]["unit"]) == {"normalized"}


def test_no_overwrite_without_force(tmp_path, capsys):
    src = tmp_path / "b.csv"
    _csv(src, n=100)
    out = tmp_path / "r.mcap"
    out.write_bytes(b"keep me")
    assert main(["import", str(src), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "exists" in err[0] and out.read_bytes() == b"keep me"
    assert main(["import", str(src), "--out", str(out), "--force"]) == 0
    assert len(read_log(out)["/gnss/fix"]) == 10


def test_failed_import_leaves_no_output(tmp_path, capsys):
    src = tmp_path / "allbad.csv"
    src.write_text("time,lat,lon\n" + "\n".join(f"{T0_S + i},0,0" for i in range(3000)) + "\n")
    out = tmp_path / "r.mcap"
    assert main(["import", str(src), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert "allbad.csv: nothing imported" in err[-1] and "gnss_no_fix 3000" in err[-1]
    assert sorted(x.name for x in tmp_path.iterdir()) == ["allbad.csv"]  # no output, no temp file


@pytest.mark.parametrize("args, needle", [
    (["--column", "lat_deg=NOPE"], "column 'NOPE' for role lat_deg"),
    (["--column", "latdeg"], "is not ROLE=VALUE"),
    (["--column", "bogus=lat"], "unknown column role 'bogus'"),
    (["--start-utc", "yesterday-ish"], "not an ISO 8601 time"),
    (["--format", "ulog"], "not a PX4 ULog file"),
])
def test_bad_arguments_one_line(tmp_path, capsys, args, needle):
    src = tmp_path / "b.csv"
    _csv(src, n=50)
    out = tmp_path / "r.mcap"
    assert main(["import", str(src), "--out", str(out), *args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert needle in err[-1] and not out.exists()


def test_missing_and_empty_source(tmp_path, capsys):
    out = tmp_path / "r.mcap"
    assert main(["import", str(tmp_path / "nope.csv"), "--out", str(out)]) == 2
    assert "nope.csv: no such file" in capsys.readouterr().err
    e = tmp_path / "empty.log"
    e.write_bytes(b"")
    assert main(["import", str(e), "--out", str(out)]) == 2
    assert "empty.log: empty file" in capsys.readouterr().err
