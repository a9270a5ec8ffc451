"""Export file names: unique and reversible (``/a/b`` and ``/a__b`` are two files)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from usvlog.cli import main
from usvlog.io.export import channel_filename, filename_topic
from usvlog.io.mcap import write_log
from usvlog.log.fieldlog import FieldLog

# topics built from the characters that matter: separators, underscores, dots, escapes, non-ASCII
ALPHABET = st.sampled_from(list("/_/_.%-aZ9 é~\u00a0") + ["\U0001f6a4"])
TOPICS = st.one_of(st.text(ALPHABET, max_size=12), st.text(max_size=12))


@settings(max_examples=600, deadline=None)
@given(TOPICS, st.sampled_from(["csv", "parquet"]))
def test_round_trip(topic, fmt):
    name = channel_filename(topic, fmt)
    assert filename_topic(name) == topic
    assert name.endswith("." + fmt) and "/" not in name and "\\" not in name and not name.startswith(".")
    assert all(c.isascii() and (c.isalnum() or c in "%_-.") for c in name)


@settings(max_examples=600, deadline=None)
@given(st.text(ALPHABET, max_size=8), st.text(ALPHABET, max_size=8))
def test_distinct_topics_distinct_names(a, b):
    if a != b:
        assert channel_filename(a, "csv") != channel_filename(b, "csv")


def test_documented_names():
    # the canonical channels keep their plain names
    assert channel_filename("/gnss/fix", "csv") == "gnss__fix.csv"
    assert channel_filename("/replay/whatif/state", "csv") == "replay__whatif__state.csv"
    assert channel_filename("/a/b", "csv") == "a__b.csv"
    assert channel_filename("/a__b", "csv") == "a%5F%5Fb.csv"
    assert channel_filename("/imu/raw data", "parquet") == "imu__raw%20data.parquet"
    assert filename_topic("gnss__fix.csv") == "/gnss/fix"


@pytest.mark.parametrize("name", ["a___b.csv", "a b.csv", "x.txt", "%2e.csv", "a%5Fb.csv", ".csv", "%C3.csv"])
def test_names_not_written_by_export_are_refused(name):
    with pytest.raises(ValueError):
        filename_topic(name)


def _log(topics):
    log = FieldLog()
    t = np.arange(5, dtype=np.int64) * 100_000_000 + 1_700_000_000_000_000_000
    for k, topic in enumerate(topics):
        log.set(topic, pd.DataFrame({"x": np.arange(5.0) + 10 * k}, index=pd.Index(t, name="t_ns")))
    return log


def test_cli_export_keeps_slash_and_underscore_topics_apart(tmp_path, capsys):
    src = tmp_path / "two.mcap"
    write_log(_log(["/a/b", "/a__b"]), src)
    out = tmp_path / "csv"
    assert main(["export", str(src), "--out", str(out)]) == 0
    files = sorted(p.name for p in out.iterdir())
    assert files == ["a%5F%5Fb.csv", "a__b.csv"]
    assert sorted(capsys.readouterr().out.split()) == sorted(str(out / f) for f in files)
    for f in files:  # each file holds its own channel: /a/b is x = 0.., /a__b is x = 10..
        frame = pd.read_csv(out / f, index_col=0)
        first = {"/a/b": 0.0, "/a__b": 10.0}[filename_topic(f)]
        assert frame["x"].tolist() == [first + i for i in range(5)]
    # again without --force: refused before writing, naming a file that exists
    assert main(["export", str(src), "--out", str(out)]) == 2
    assert "output exists" in capsys.readouterr().err


def test_topics_differing_in_case_are_refused(tmp_path, capsys):
    src = tmp_path / "case.mcap"
    write_log(_log(["/imu", "/IMU"]), src)
    assert main(["export", str(src), "--out", str(tmp_path / "csv")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "letter case" in err[0]
    assert not (tmp_path / "csv").exists()
