"""Kernels that only read a byte buffer have one compiled signature, whatever buffer the caller holds.

numba compiles, caches and loads a kernel once per argument signature, and it types a read-only
array apart from a writable one. A decoded buffer is read-only when it is ``np.frombuffer`` of
bytes (one decompressed chunk, a block of a text file) and writable when it was assembled (an
arena, a concatenation, an empty array), which depends on the file: a first short log after long
ones compiled the JSON decoder again (3.4 s of a 36 s log's ``usvlog view``), and every NMEA import
loaded the line scanner twice. Every call site passes the buffer through ``usvlog._jit.readonly``.

Independent truth: numba's own list of each kernel's signatures, and the same messages decoded
from a writable and from a read-only buffer giving the same columns.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from usvlog._jit import readonly
from usvlog.io.importers import ImportOptions, nmea
from usvlog.io.importers import nmea_fast as nf
from usvlog.io.importers.core import ImportReport
from usvlog.io.mcap import kernels as K
from usvlog.io.mcap.codec import writer_codec
from usvlog.log.channels import channel_spec, frame_from_columns, schema_for_topic

DATA = Path(__file__).parents[1] / "data"
T0 = 1_780_000_000 * 10**9


def _signatures(kernel) -> list:
    """The argument types numba holds compiled (or loaded) for ``kernel`` in this process."""
    return list(kernel.signatures)


def _frame(topic: str, n: int = 200):
    rng = np.random.default_rng(4)
    spec = channel_spec(topic)
    cols = {}
    for f in spec.fields:
        for c in f.columns:
            cols[c] = (rng.random(n) < 0.5 if f.kind == "bool" else rng.integers(-2**40, 2**40, n)
                       if f.kind in ("int", "time") else np.array(["a", "bé"] * (n // 2), dtype=object)
                       if f.kind == "str" else rng.standard_normal(n) * 10.0 ** rng.integers(-8, 8, n))
    return frame_from_columns(cols, T0 + np.arange(n) * 10**8, spec)


def _spans(payloads: list[bytes]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    lens = np.array([len(p) for p in payloads], dtype=np.int64)
    ends = np.cumsum(lens)
    return np.frombuffer(b"".join(payloads), dtype=np.uint8), ends - lens, ends


def _assert_same_columns(a: dict, b: dict) -> None:
    assert list(a) == list(b)
    for c in a:
        if a[c].dtype == object:
            assert a[c].tolist() == b[c].tolist(), c
        else:
            np.testing.assert_array_equal(a[c], b[c], err_msg=c)


@pytest.mark.parametrize("topic,kernel", [("/gnss/fix", "match_template"), ("/thrust/command", "match_template"),
                                          ("/estimate/state", "gather_fields")])
def test_decoding_kernel_has_one_signature_for_writable_and_readonly_buffers(topic, kernel):
    codec = writer_codec(topic, schema_for_topic(topic))   # JSON for sensor channels, CDR for the bulk ones
    frame = _frame(topic)
    buf, starts, ends = _spans(codec.encode(frame, topic))
    assert not buf.flags.writeable
    writable = buf.copy()
    got_ro = codec.decode_spans(buf, starts, ends, topic)
    got_rw = codec.decode_spans(writable, starts, ends, topic)
    _assert_same_columns(got_ro, got_rw)
    _assert_same_columns(got_ro, {c: frame[c].to_numpy(dtype=object if got_ro[c].dtype == object else None)
                                  for c in frame.columns})   # the values encoded
    sigs = _signatures(getattr(K, kernel))
    assert sigs, f"{kernel} was not called"
    assert all(not s[0].mutable for s in sigs), sigs   # the buffer: read-only in every signature
    assert len({s[0] for s in sigs}) == 1


def test_nmea_scanner_has_one_signature():
    """An NMEA import calls the line scanner on an empty array first (the carried columns' shape)
    and then on each block of the file: the same signature for both."""
    rep = ImportReport()
    n = sum(len(d.get("t_ns", ())) for batch in nmea.read(DATA / "sources" / "kingfisher.nmea", ImportOptions(), rep,
                                                          fast=True) for d in batch.values())
    assert n > 100
    sigs = _signatures(nf.scan_lines)
    assert sigs and all(not s[0].mutable for s in sigs), sigs
    assert len(sigs) == 1


def test_readonly_is_a_view_not_a_copy():
    a = np.arange(10, dtype=np.uint8)
    r = readonly(a)
    assert not r.flags.writeable and a.flags.writeable   # the caller's array stays writable
    assert np.shares_memory(a, r)
    a[3] = 99
    assert r[3] == 99
    assert readonly(r) is r
