"""Fault injection: damaged copies of a multi-chunk log, read back.

A 60 s excitation run is written in ~30 chunks; copies of the file get single-bit flips
at random offsets, random byte runs, zeroed 4 KB blocks, truncation at every chunk
boundary +- 1 byte, and garbage appended. For every case:

- no returned value differs from the original (every returned row equals the
  original row of its channel at the same ``t_ns``, column by column, bit for bit);
- every chunk the damage did not touch is recovered (which chunks a damage touches
  is computed from the clean file's chunk index, independently of the reader: a
  chunk is touched when the damaged bytes overlap its record);
- the loss is reported (``log.recovery`` is set whenever a row is missing).

The summary figures are printed (``pytest -s``). Seeded; a few seconds.
"""

import io

import numpy as np
import pandas as pd
import pytest
from mcap.reader import make_reader
from mcap.records import Chunk, Message
from mcap.stream_reader import StreamReader, breakup_chunk

from usvlog.io.mcap import read_log, write_log
from usvlog.io.mcap.reference import read_log_reference
from usvlog.log.fieldlog import FieldLog
from usvlog.sim.simulate import SimSettings, simulate

SEED = 16
CHUNK_SIZE = 64 * 1024


@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    """(original log, file bytes, chunks: [(start, end, {topic: row numbers})], path for copies)."""
    log = simulate("excitation", SimSettings(duration_s=60.0), seed=3)
    d = tmp_path_factory.mktemp("fault")
    path = d / "clean.mcap"
    write_log(log, path, chunk_size=CHUNK_SIZE)
    data = path.read_bytes()
    with open(path, "rb") as fh:
        summary = make_reader(fh).get_summary()
    topic_of = {c.id: c.topic for c in summary.channels.values()}
    index = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
    records = [r for r in StreamReader(io.BytesIO(data), emit_chunks=True).records if isinstance(r, Chunk)]
    assert len(records) == len(index)
    chunks = []
    for ci, rec in zip(index, records):
        rows: dict[str, list[int]] = {}
        for m in breakup_chunk(rec, validate_crc=True):
            if isinstance(m, Message):
                rows.setdefault(topic_of[m.channel_id], []).append(m.sequence)  # sequence = row number
        chunks.append((ci.chunk_start_offset, ci.chunk_start_offset + ci.chunk_length,
                       {t: np.array(v) for t, v in rows.items()}))
    for frame in log.channels.values():
        assert np.all(np.diff(frame.index.to_numpy()) > 0)  # t_ns identifies a row
    return log, data, chunks, d / "damaged.mcap"


def touched(chunks, ranges) -> set[int]:
    """Chunks whose record overlaps a damaged byte range [a, b)."""
    return {k for k, (s, e, _) in enumerate(chunks) for a, b in ranges if a < e and b > s}


def wrong_rows(got: pd.DataFrame, orig: pd.DataFrame) -> tuple[int, np.ndarray]:
    """(rows of ``got`` that differ from the original row at the same t_ns, row numbers found)."""
    t = got.index.to_numpy()
    ot = orig.index.to_numpy()
    pos = np.clip(np.searchsorted(ot, t), 0, len(ot) - 1)
    ok = ot[pos] == t
    if list(got.columns) != list(orig.columns) or list(got.dtypes) != list(orig.dtypes):
        return len(got), pos[ok]
    for c in got.columns:
        a, b = got[c].to_numpy(), orig[c].to_numpy()[pos]
        if a.dtype.kind == "f":
            ok &= a.view(np.int64) == b.view(np.int64)
        else:
            ok &= np.asarray(a == b, dtype=bool)
    return int((~ok).sum()), pos[ok]


class Tally:
    def __init__(self):
        self.cases = self.intact = self.intact_recovered = self.touched = self.touched_recovered = 0
        self.wrong_values = self.wrong_meta = self.unreported = self.rows_missing = 0
        self.by_kind: dict[str, int] = {}

    def line(self) -> str:
        return (f"{self.cases} cases ({', '.join(f'{k} {v}' for k, v in self.by_kind.items())}): "
                f"intact chunks recovered {self.intact_recovered}/{self.intact}, damaged chunks "
                f"recovered anyway {self.touched_recovered}/{self.touched} (their data checked out), "
                f"rows missing {self.rows_missing}, silent wrong values {self.wrong_values}, "
                f"metadata silently wrong {self.wrong_meta}, losses not reported {self.unreported}")


def check(clean, damaged: bytes, ranges, kind: str, tally: Tally, reference: bool = False) -> FieldLog:
    log, _data, chunks, path = clean
    path.write_bytes(damaged)
    got = read_log(path)
    if reference:  # the plain reader reads the same
        ref = read_log_reference(path)
        assert got.topics == ref.topics and got.meta == ref.meta
        for t in got.topics:
            pd.testing.assert_frame_equal(got[t], ref[t], check_exact=True)
        assert (got.recovery is None) == (ref.recovery is None)
        assert got.recovery is None or got.recovery.to_dict() == ref.recovery.to_dict()
    present = {t: np.zeros(len(f), bool) for t, f in log.channels.items()}
    wrong = 0
    for t in got.topics:
        if t not in log.channels:
            wrong += len(got[t])
            continue
        w, rows = wrong_rows(got[t], log[t])
        wrong += w
        present[t][rows] = True
    # metadata: what is returned must be the original; what is missing must be reported
    wrong_meta = sum(got.meta[k] != log.meta.get(k) for k in got.meta)
    hit = touched(chunks, ranges)
    missing = sum(int((~p).sum()) for p in present.values())
    recovered = {k for k, (_s, _e, rows) in enumerate(chunks) if all(present[t][r].all() for t, r in rows.items())}
    tally.cases += 1
    tally.by_kind[kind] = tally.by_kind.get(kind, 0) + 1
    tally.intact += len(chunks) - len(hit)
    tally.intact_recovered += len(recovered - hit)
    tally.touched += len(hit)
    tally.touched_recovered += len(recovered & hit)
    tally.wrong_values += wrong
    tally.wrong_meta += wrong_meta if got.recovery is None else 0
    tally.rows_missing += missing
    tally.unreported += (missing > 0 or got.meta.keys() != log.meta.keys()) and got.recovery is None
    assert wrong == 0, f"{kind} at {ranges}: {wrong} wrong values returned"
    assert wrong_meta == 0 or got.recovery is not None, f"{kind} at {ranges}: metadata silently wrong"
    assert set(range(len(chunks))) - hit <= recovered, f"{kind} at {ranges}: intact chunk(s) lost"
    assert missing == 0 or got.recovery is not None, f"{kind} at {ranges}: loss not reported"
    if got.recovery is not None and got.recovery.nothing_recovered:
        assert not any(len(f) for f in got.channels.values())
    return got


def library_count(data: bytes) -> int:
    """Messages the mcap library's sequential reader yields (CRCs checked) before it stops."""
    n = 0
    try:
        for rec in StreamReader(io.BytesIO(data), emit_chunks=True, validate_crcs=True).records:
            if isinstance(rec, Chunk):
                n += sum(isinstance(r, Message) for r in breakup_chunk(rec, validate_crc=True))
            elif isinstance(rec, Message):
                n += 1
    except Exception:  # noqa: BLE001 - the library stops on damage with many kinds of error (CRC, zstd, struct)
        return n
    return n


def test_fault_injection(clean):
    log, data, chunks, _path = clean
    n_rows = sum(len(f) for f in log.channels.values())
    assert 20 <= len(chunks) <= 40
    rng = np.random.default_rng(SEED)
    tally = Tally()
    ours_lib = [0, 0, 0]  # flips compared with the library: cases, our messages, the library's

    for i, at in enumerate(rng.integers(0, len(data), 200).tolist()):  # single-bit flips
        d = bytearray(data)
        d[at] ^= 1 << int(rng.integers(0, 8))
        got = check(clean, bytes(d), [(at, at + 1)], "bit flip", tally, reference=i % 20 == 0)
        if i % 20 == 0:
            ours_lib[0] += 1
            ours_lib[1] += sum(len(f) for f in got.channels.values())
            ours_lib[2] += library_count(bytes(d))
    for i in range(40):  # runs of random bytes, 2-64 bytes long
        at, n = int(rng.integers(8, len(data) - 64)), int(rng.integers(2, 65))
        d = bytearray(data)
        d[at:at + n] = rng.bytes(n)
        check(clean, bytes(d), [(at, at + n)], "byte run", tally, reference=i % 10 == 0)
    for i in range(20):  # zeroed 4 KB blocks
        at = int(rng.integers(0, len(data) - 4096))
        d = bytearray(data)
        d[at:at + 4096] = bytes(4096)
        check(clean, bytes(d), [(at, at + 4096)], "zeroed 4 KB", tally, reference=i % 10 == 0)
    for k, (s, e, _rows) in enumerate(chunks):  # truncation at every chunk boundary +- 1 byte
        for cut in (s - 1, s, s + 1, e - 1, e, e + 1):
            check(clean, data[:cut], [(cut, len(data))], "truncation", tally, reference=k % 10 == 0 and cut == s + 1)
    for n in (1, 37, 4096):  # garbage appended after the footer
        got = check(clean, data + rng.bytes(n), [], "garbage appended", tally, reference=n == 37)
        assert got.recovery is not None and got.recovery.trailing_bytes == n and got.recovery.bytes_lost == 0
        assert got.recovery.messages_recovered == n_rows
    got = check(clean, data + data, [], "garbage appended", tally)  # a second copy of the file
    assert got.recovery.trailing_bytes == len(data)

    print(f"\nfault injection on {len(data)} bytes, {len(chunks)} chunks, {n_rows} rows: {tally.line()}")
    print(f"bit flips, every 20th case also read by the mcap library (CRCs checked): {ours_lib[0]} cases, "
          f"usvlog returned {ours_lib[1]} rows, the library {ours_lib[2]} messages before stopping")
    assert tally.wrong_values == 0 and tally.unreported == 0
    assert tally.intact_recovered == tally.intact > 0


def test_nothing_recoverable_and_empty_files(tmp_path, clean):
    _log, data, chunks, _path = clean
    p = tmp_path / "x.mcap"
    p.write_bytes(data[:8])  # only the magic
    rec = read_log(p).recovery
    assert rec is not None and rec.nothing_recovered and "nothing recovered" in rec.one_line()
    p.write_bytes(data[:chunks[0][0] + 100])  # header and metadata, the first chunk cut
    got = read_log(p)
    assert got.recovery.nothing_recovered and got.meta == _log.meta
    assert got.recovery.lost_chunks[0].offset == chunks[0][0]
    write_log(FieldLog(), p, force=True)  # a valid file without messages is not damaged
    assert read_log(p).recovery is None


def test_lost_chunk_is_described(tmp_path, clean):
    """A chunk that fails its CRC: its offset, size, time range and channels are reported,
    from the chunk index, and from its header and message indexes when the summary is gone."""
    log, data, chunks, _path = clean
    s, e, rows = chunks[5]
    d = bytearray(data)
    d[s + 500] ^= 0x10
    p = tmp_path / "x.mcap"
    for cut in (len(d), chunks[-1][0] + 10):  # with the summary, then without it (cut short)
        p.write_bytes(bytes(d[:cut]))
        rec = read_log(p).recovery
        lost = rec.lost_chunks[0]
        t = np.concatenate([log[k].index.to_numpy()[r] for k, r in rows.items()])
        assert (lost.offset, lost.size, lost.start_ns, lost.end_ns) == (s, e - s, t.min(), t.max())
        assert lost.topics == tuple(sorted(rows)) and "CRC" in lost.reason
        assert rec.damaged_ranges[0] == (s, chunks[6][0] - s)
        assert rec.one_line().startswith(
            f"input damaged: {rec.bytes_lost} bytes / {len(rec.lost_chunks)} chunk(s) lost")


def _chunk_fields(data: bytes, start: int):
    """(offset of the CRC field, offset of the records, their length) of the chunk record at start."""
    import struct

    clen = struct.unpack_from("<I", data, start + 37)[0]
    rlen = struct.unpack_from("<Q", data, start + 41 + clen)[0]
    return start + 33, start + 49 + clen, rlen


def test_bad_message_in_a_good_chunk_costs_that_message(tmp_path, excitation_log):
    """An uncompressed file; one payload byte changed. With the chunk's CRC recomputed the
    chunk checks out and only that message is skipped (counted, by channel); with the old
    CRC kept the chunk is lost and reported, as the mcap library's reader refuses it."""
    import struct
    import zlib

    from mcap.stream_reader import CRCValidationError

    p = tmp_path / "plain.mcap"
    write_log(excitation_log, p, chunk_size=64 * 1024, compression="none")
    data = p.read_bytes()
    with open(p, "rb") as fh:
        summary = make_reader(fh).get_summary()
    fix = next(c.id for c in summary.channels.values() if c.topic == "/gnss/fix")
    index = sorted((c for c in summary.chunk_indexes if fix in c.message_index_offsets),
                   key=lambda c: c.chunk_start_offset)   # /gnss/fix's chunks
    start = index[len(index) // 2].chunk_start_offset
    crc_at, rec_at, rlen = _chunk_fields(data, start)
    records = data[rec_at:rec_at + rlen]
    # the first digit of a /gnss/fix message's latitude (a JSON channel: CDR's doubles have no invalid bytes)
    at = rec_at + records.index(b'"latitude":') + 11
    for fix_crc in (True, False):
        d = bytearray(data)
        d[at] = ord("x")
        if fix_crc:
            struct.pack_into("<I", d, crc_at, zlib.crc32(bytes(d[rec_at:rec_at + rlen])))
        p.write_bytes(bytes(d))
        got = read_log(p)
        rec = got.recovery
        for t in excitation_log.topics:
            w, _rows = wrong_rows(got[t], excitation_log[t])
            assert w == 0
        missing = {t: len(excitation_log[t]) - len(got[t]) for t in excitation_log.topics}
        if fix_crc:
            assert missing == {t: int(t == "/gnss/fix") for t in excitation_log.topics}
            assert rec.messages_skipped == 1 and rec.skipped_by_topic == {"/gnss/fix": 1}
            assert rec.lost_chunks == () and rec.bytes_lost == 0
            assert "1 message(s) unreadable" in rec.one_line()
        else:
            [lost] = rec.lost_chunks
            assert lost.offset == start and "CRC" in lost.reason and sum(missing.values()) > 100
            with open(p, "rb") as fh, pytest.raises(CRCValidationError):
                for _ in make_reader(fh, validate_crcs=True).iter_messages():
                    pass


def test_channels_defined_in_a_lost_first_chunk_come_from_the_summary(tmp_path, clean):
    log, data, chunks, _path = clean
    d = bytearray(data)
    d[chunks[0][0] + 300] ^= 0x04  # the first chunk holds every schema and channel record
    p = tmp_path / "x.mcap"
    p.write_bytes(bytes(d))
    got = read_log(p)
    assert got.topics == log.topics and got.recovery.lost_chunks[0].offset == chunks[0][0]
    for t in log.topics:
        w, rows = wrong_rows(got[t], log[t])
        want = np.setdiff1d(np.arange(len(log[t])), chunks[0][2].get(t, []))
        assert w == 0 and np.array_equal(np.sort(rows), want)
