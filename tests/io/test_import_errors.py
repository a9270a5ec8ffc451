"""Import errors: a bad file is a one-line UsvlogError chained from the parser's exception;
a bug in usvlog's own reader code is not mistaken for a bad file (internal error, exit 3)."""

from __future__ import annotations

import numpy as np
import pytest
from import_fixtures import build_dataflash, build_ulog
from test_import_bags import write_ros1, write_ros2
from test_import_text import merged_csv, nmea_lines

from usvlog.cli import main
from usvlog.errors import FormatError, InputError, UsvlogError
from usvlog.io.importers import import_file


def _bug(*_args, **_kwargs):
    raise IndexError("injected bug")


def _source(kind: str, tmp_path):
    """A good file of each format and a helper of its reader (module, name) to break."""
    if kind == "csv":
        p = tmp_path / "run.csv"
        merged_csv(p, n=50)
        return p, ("csvrows", "numeric_cells")
    if kind == "nmea":
        p = tmp_path / "run.nmea"
        p.write_text("\n".join(nmea_lines(10)) + "\n")
        return p, ("nmea", "_values")   # a small file: the Python parser
    if kind == "ros1":
        return write_ros1(tmp_path / "run.bag"), ("rosbag", "_number")
    if kind == "ros2":
        return write_ros2(tmp_path / "run2", "mcap"), ("rosbag", "_number")
    if kind == "dataflash":
        p = tmp_path / "run.bin"
        p.write_bytes(build_dataflash()[0])
        return p, ("dataflash", "_num")
    p = tmp_path / "run.ulg"
    p.write_bytes(build_ulog()[0])
    return p, ("ulog", "_time_ns")


@pytest.mark.parametrize("kind", ["csv", "nmea", "ros1", "ros2", "dataflash", "ulog"])
def test_injected_bug_is_not_a_bad_file(tmp_path, monkeypatch, capsys, kind):
    import importlib

    src, (module, helper) = _source(kind, tmp_path)
    assert import_file(src).log is not None      # the file itself is good
    monkeypatch.setattr(importlib.import_module(f"usvlog.io.importers.{module}"), helper, _bug)
    with pytest.raises(IndexError, match="injected bug"):
        import_file(src)
    out = tmp_path / "o.mcap"
    monkeypatch.delenv("USVLOG_DEBUG", raising=False)
    assert main(["import", str(src), "--out", str(out)]) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert "internal error: IndexError: injected bug" in err[-1] and "USVLOG_DEBUG" in err[-1]
    assert not out.exists()
    monkeypatch.setenv("USVLOG_DEBUG", "1")      # the traceback on request: the exception itself
    with pytest.raises(IndexError, match="injected bug"):
        main(["import", str(src), "--out", str(out)])


def test_truncated_bag_chained_from_rosbags(tmp_path):
    from rosbags.highlevel import AnyReaderError

    full = write_ros1(tmp_path / "full.bag")
    cut = tmp_path / "cut.bag"
    cut.write_bytes(full.read_bytes()[:3000])
    with pytest.raises(FormatError) as info:
        import_file(cut)
    err = info.value
    assert isinstance(err.__cause__, AnyReaderError)
    assert str(err).startswith(f"{cut}: not a readable ROS 1 bag (AnyReaderError: ") and "\n" not in str(err)


def test_damaged_ulog_chained_from_pyulog(tmp_path):
    from pyulog.core import ULogException

    data = bytearray(build_ulog()[0])
    data[16 + 3 + 8] = 0x02   # flag-bits message: an incompatible flag pyulog does not know
    p = tmp_path / "flags.ulg"
    p.write_bytes(bytes(data))
    with pytest.raises(FormatError, match=r"flags.ulg: not a readable ULog file \(ULogIncompatibleFlag") as info:
        import_file(p)
    assert isinstance(info.value.__cause__, ULogException)


def test_csv_parser_error_chained_from_pandas(tmp_path):
    import pandas as pd

    p = tmp_path / "quote.csv"
    p.write_text('time,lat,lon\n1714557600,"59.1,10\n1714557601,59.2,10.1\n')  # a quote never closed
    with pytest.raises(InputError, match="quote.csv") as info:
        import_file(p)
    assert isinstance(info.value.__cause__, pd.errors.ParserError) and "\n" not in str(info.value)


def test_iso_times_outside_int64_ns_are_bad_times(tmp_path):
    """pandas parses years 1 or 2262+ at a coarser resolution; they are counted, not a crash."""
    p = tmp_path / "iso.csv"
    p.write_text("utc,heading\n2024-05-01T10:00:00.123456Z,10\n2262-05-01T00:00:00Z,20\n"
                 "0001-01-01T00:00:00Z,30\n2024-05-01T10:00:01Z,40\n")
    res = import_file(p)
    h = res.log["/compass/heading"]
    np.testing.assert_array_equal(h.index.to_numpy(), [1_714_557_600_123_456_000, 1_714_557_601_000_000_000])
    assert res.report.skipped["csv_bad_time"] == 2


def test_dataflash_damaged_time_skipped(tmp_path):
    """A TimeUS too large for int64 ns (damaged bytes) is counted, the rest imported."""
    import struct

    data, tr = build_dataflash()
    gps = bytes([0xA3, 0x95, 65])
    i = data.index(gps, data.index(gps) + 1)          # the second GPS message
    bad = data[:i + 3] + struct.pack("<Q", 2**63 - 1) + data[i + 11:]
    p = tmp_path / "t.bin"
    p.write_bytes(bad)
    res = import_file(p)
    assert res.report.skipped["dataflash_bad_time"] == 1
    np.testing.assert_allclose(res.log["/gnss/fix"]["lat_deg"], np.delete(tr["lat_e7"], 1) * 1e-7, atol=1e-7)


def test_names_from_a_file_stay_on_one_line(tmp_path):
    p = tmp_path / "hdr.csv"
    p.write_text('"ti\nme",value\n1,2\n')
    with pytest.raises(UsvlogError) as info:
        import_file(p)
    assert "hdr.csv" in str(info.value) and "\n" not in str(info.value)


def test_a_library_message_with_raw_bytes_stays_one_printable_line():
    from usvlog.io.importers.core import foreign_error

    err = foreign_error("x.bag", "not a readable ROS 1 bag", ValueError("bad\x01\x02 def\nline two\x7f\x1b[31m"))
    msg = str(err)
    assert msg.isprintable() and "\n" not in msg
    assert msg == "x.bag: not a readable ROS 1 bag (ValueError: bad?? def line two??[31m)"
