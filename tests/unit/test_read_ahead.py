"""The verbs read their logs on a second thread while they import their modules and check their
options (:func:`usvlog.api._read_ahead`): the same logs, the same damage notes in the same
order, and the same errors in the same order as reading them on the main thread, with and
without a spare CPU."""

import subprocess
import sys

import pandas as pd
import pytest

import usvlog
from usvlog import api
from usvlog.errors import ConfigError
from usvlog.io.mcap import write_log
from usvlog.io.mcap.format import OP_CHUNK
from usvlog.sim.simulate import SimSettings, simulate


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    """A 30 s run, its file, and a copy with one chunk's CRC broken (read with a damage note)."""
    d = tmp_path_factory.mktemp("ahead")
    run = simulate("excitation", SimSettings(duration_s=30.0), seed=3)
    good = d / "good.mcap"
    write_log(run, good, chunk_size=16 * 1024)
    data = bytearray(good.read_bytes())
    offs, off = [], 8 + 9 + int.from_bytes(data[9:17], "little")
    while data[off] != 0x0F:   # the chunk records, up to Data End
        if data[off] == OP_CHUNK:
            offs.append(off)
        off += 9 + int.from_bytes(data[off + 1:off + 9], "little")
    data[offs[len(offs) // 2] + 9 + 24] ^= 0xFF   # a chunk's uncompressed CRC
    bad = d / "bad.mcap"
    bad.write_bytes(bytes(data))
    return run, good, bad


def test_read_topics_are_the_verbs_own():
    from usvlog.estimate.core import INPUT_TOPICS as estimate_reads
    from usvlog.identify.data import INPUT_TOPICS as identify_reads

    assert api._ESTIMATE_READS == tuple(estimate_reads)
    assert api._IDENTIFY_READS == tuple(identify_reads)


def _same(a, b):
    assert list(a.channels) == list(b.channels)
    for t in a.channels:
        pd.testing.assert_frame_equal(a.channels[t], b.channels[t])
    assert a.recovery == b.recovery
    assert a.meta == b.meta and a.source == b.source


@pytest.mark.parametrize("threads", ["1", "2"])
def test_read_ahead_gives_what_read_gives(monkeypatch, logs, threads):
    monkeypatch.setenv("USVLOG_THREADS", threads)
    run, good, bad = logs
    topics = list(api._IDENTIFY_READS)
    said, said_ahead = [], []
    want = [api._read(good, said.append, topics), api._read(bad, said.append), run]
    got = api._read_ahead([(good, topics), (bad, None), (run, topics)])(said_ahead.append)
    assert said_ahead == said and len(said) == 1 and "damaged" in said[0]
    for a, b in zip(got, want):
        _same(a, b)
    assert got[2] is run   # a log given in memory is the caller's own


@pytest.mark.parametrize("threads", ["1", "2"])
def test_a_read_error_comes_after_the_notes_of_the_logs_before_it(monkeypatch, logs, tmp_path, threads):
    monkeypatch.setenv("USVLOG_THREADS", threads)
    _run, _good, bad = logs
    missing = tmp_path / "missing.mcap"
    with pytest.raises(Exception) as direct:
        api._read(missing)
    said = []
    take = api._read_ahead([(bad, None), (missing, None)])
    with pytest.raises(type(direct.value)) as ahead:
        take(said.append)
    assert str(ahead.value) == str(direct.value)
    assert len(said) == 1 and str(bad) in said[0]


@pytest.mark.parametrize("threads", ["1", "2"])
def test_a_bad_option_is_reported_before_a_bad_file(monkeypatch, tmp_path, threads):
    monkeypatch.setenv("USVLOG_THREADS", threads)
    missing = tmp_path / "missing.mcap"
    with pytest.raises(ConfigError, match="method"):
        usvlog.identify(missing, method="bogus")
    with pytest.raises(ConfigError, match="model"):
        usvlog.estimate(missing, model="bogus")
    with pytest.raises(ConfigError, match="holdout"):
        usvlog.identify(missing, holdout=2.0)


IMPORT_ERROR = """
import io, os, sys, contextlib
sys.modules["scipy.optimize"] = None     # the fit's module cannot be imported
from usvlog.cli import main
out = []
for threads in ("1", "2"):
    os.environ["USVLOG_THREADS"] = threads
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        try:
            code = main(["identify", sys.argv[1], "--json", "--out", sys.argv[2]])
        except SystemExit as e:
            code = e.code
    out.append((code, err.getvalue()))
print(repr(out))
"""


def test_an_import_error_reaches_the_user_as_without_the_thread(logs, tmp_path):
    _run, good, _bad = logs
    r = subprocess.run([sys.executable, "-c", IMPORT_ERROR, str(good), str(tmp_path / "fit.json")],
                       capture_output=True, text=True, check=True)
    (code1, err1), (code2, err2) = eval(r.stdout.strip().splitlines()[-1])   # noqa: S307 - our own repr
    assert code1 == code2 == 3
    assert err1 == err2 and "scipy.optimize" in err1
    assert not (tmp_path / "fit.json").exists()
