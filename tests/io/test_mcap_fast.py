"""The fast read/write paths against the plain reference paths and the mcap library.

Independent truth here is the mcap library (its Writer writes the files our writer
must reproduce byte for byte; its readers give the records our reader must find)
and the stdlib ``json`` module (the values our decoder must produce).
"""

import io
import json
import math
import os

import numpy as np
import orjson
import pandas as pd
import pytest
from mcap.reader import make_reader
from mcap.records import Chunk, Message
from mcap.stream_reader import StreamReader, breakup_chunk
from mcap.writer import CompressionType, Writer

from usvlog.errors import InputError
from usvlog.io.mcap import read_log, write_log
from usvlog.io.mcap.codec import Codec, codec_for_topic, writer_codec
from usvlog.io.mcap.json_layout import _decode_layout
from usvlog.io.mcap.reference import _write_log_reference, read_log_reference
from usvlog.log.channels import StrCodes, auto_schema, concat_columns, frame_from_columns
from usvlog.log.fieldlog import FieldLog

T0 = 1_780_000_000 * 10**9
TRIALS = int(os.environ.get("USVLOG_FUZZ_TRIALS", "25"))


def tricky_log(n: int = 700) -> FieldLog:
    """A log with NaN/null, negative numbers, exponents, big integers, booleans, strings
    with unicode, quotes and escapes, an empty channel and an unregistered channel."""
    rng = np.random.default_rng(5)
    log = FieldLog()
    idx = pd.Index(T0 + np.arange(n, dtype=np.int64) * 10_000_000, name="t_ns")
    x = rng.standard_normal(n) * 10.0 ** rng.integers(-30, 30, n)
    x[::7] = np.nan
    x[3] = -0.0
    x[4] = 5e-324
    x[5] = 1.7976931348623157e308
    x[6] = -2.2250738585072014e-308
    labels = np.array(["plain", "Ünïcødé ✓ 🚤", 'quote " and \\ back', "new\nline\ttab", "", "\u0001ctl"],
                      dtype=object)
    log.set("/my/tricky", pd.DataFrame({
        "value": x,
        "neg_m": -np.abs(rng.standard_normal(n)),
        "count": rng.integers(-2**62, 2**62, n),
        "ok": rng.random(n) < 0.5,
        "label": pd.array(labels[rng.integers(0, len(labels), n)], dtype="str"),
    }, index=idx))
    std = np.full(n, 0.01)
    std[::3] = np.nan
    heading = pd.DataFrame({"stamp_ns": idx.to_numpy() - 5, "heading_rad": rng.uniform(-3.1, 3.1, n),
                            "reference": pd.array(["magnetic"] * n, dtype="str"), "std_rad": std}, index=idx)
    log.set("/compass/heading", heading)
    empty = codec_for_topic("/thrust/command")
    log.set("/thrust/command", pd.DataFrame({c: pd.Series([], dtype="str" if d == "str" else d)
                                             for c, d in empty.dtypes().items()},
                                            index=pd.Index([], dtype=np.int64, name="t_ns")))
    log.meta["usvlog.datum"] = {"lat_deg": "59.1", "lon_deg": "10.5", "alt_m": "0.0"}
    log.meta["note"] = {"text": "Ünïcødé ✓"}
    return log


def assert_logs_equal(a: FieldLog, b: FieldLog) -> None:
    assert a.topics == b.topics
    for t in a.topics:
        pd.testing.assert_frame_equal(a[t], b[t], check_exact=True)
    assert a.meta == b.meta
    assert (a.recovery is None) == (b.recovery is None)
    if a.recovery is not None:
        assert a.recovery.to_dict() == b.recovery.to_dict()


def library_messages(data: bytes) -> list[tuple[str, int, int, bytes]]:
    """(topic, log time, sequence, payload) of every message in complete chunks, read
    sequentially by the mcap library (stops at the first damaged record)."""
    out, channels = [], {}
    try:
        for rec in StreamReader(io.BytesIO(data), emit_chunks=True).records:
            recs = breakup_chunk(rec, validate_crc=True) if isinstance(rec, Chunk) else [rec]
            for r in recs:
                if hasattr(r, "topic"):
                    channels.setdefault(r.id, r.topic)
                elif isinstance(r, Message) and r.channel_id in channels:
                    out.append((channels[r.channel_id], r.log_time, r.sequence, r.data))
    except Exception:
        pass
    return out


def our_messages(log: FieldLog) -> list:
    """The messages a read log holds, re-encoded, in the library's record order."""
    out = []
    for topic in log.topics:
        codec = writer_codec(topic, log.schemas[topic])
        payloads = codec.encode_reference(log[topic], topic)
        out += [(topic, t, i, p) for i, (t, p) in enumerate(zip(log[topic].index.tolist(), payloads))]
    return out


@pytest.mark.parametrize("compression", ["zstd", "lz4", "none"])
def test_writer_gives_the_mcap_writers_bytes(tmp_path, excitation_log, compression):
    for log in (excitation_log, tricky_log()):
        ref = tmp_path / "ref.mcap"
        _write_log_reference(log, ref, chunk_size=32 * 1024, compression=compression, force=True)
        ours = tmp_path / "ours.mcap"
        # the library compresses at zstd level 3; written in slices of 1000 messages or whole
        for slice_messages in (1000, 1 << 30):
            write_log(log, ours, chunk_size=32 * 1024, compression=compression, force=True, zstd_level=3,
                      slice_messages=slice_messages)
            assert ours.read_bytes() == ref.read_bytes()


def test_written_file_reads_back_through_the_library_seeking_reader(tmp_path, excitation_log):
    """JSON channels decoded by the stdlib json module, CDR ones by mcap-ros2-support's decoder."""
    from mcap_ros2.decoder import DecoderFactory

    p = tmp_path / "x.mcap"
    write_log(excitation_log, p, chunk_size=64 * 1024)
    ros2 = DecoderFactory()
    with open(p, "rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        got = {}
        for schema, channel, msg in reader.iter_messages():
            if channel.message_encoding == "cdr":
                o = ros2.decoder_for("cdr", schema)(msg.data)
                value = {k: getattr(o, k) for k in o.__slots__}
            else:
                value = json.loads(msg.data)
            got.setdefault(channel.topic, []).append((msg.log_time, msg.sequence, value))
        metas = {m.name: m.metadata for m in reader.iter_metadata()}
    assert {t for t in got if excitation_log[t].shape[0]} >= {"/truth/state", "/gnss/fix"}
    assert summary.statistics.message_count == sum(len(f) for f in excitation_log.channels.values())
    assert len(summary.chunk_indexes) > 5
    assert metas == excitation_log.meta
    back = read_log(p)
    for topic, rows in got.items():
        frame = excitation_log[topic]
        assert [r[0] for r in rows] == frame.index.tolist() == back[topic].index.tolist()
        assert [r[1] for r in rows] == list(range(len(frame)))
        codec = codec_for_topic(topic)
        # values decoded by the stdlib json module equal the frame read by usvlog
        cols = codec.decode_objects([r[2] for r in rows], topic)
        for c, v in cols.items():
            np.testing.assert_array_equal(back[topic][c].to_numpy(), v)


@pytest.mark.parametrize("compression", ["zstd", "lz4", "none"])
def test_fast_read_matches_reference_and_library(tmp_path, compression):
    log = tricky_log()
    p = tmp_path / "t.mcap"
    write_log(log, p, chunk_size=16 * 1024, compression=compression)
    fast, ref = read_log(p), read_log_reference(p)
    assert_logs_equal(fast, ref)
    assert fast.recovery is None
    for t in log.topics:
        pd.testing.assert_frame_equal(fast[t], log[t], check_exact=True)
    lib = library_messages(p.read_bytes())
    assert sorted(our_messages(fast)) == sorted(lib)


def test_tricky_values_equal_the_stdlib_json_reading(tmp_path):
    log = tricky_log()
    p = tmp_path / "t.mcap"
    write_log(log, p)
    back = read_log(p)
    rows = [(t, json.loads(d)) for topic, t, _s, d in library_messages(p.read_bytes()) if topic == "/my/tricky"]
    frame = back["/my/tricky"]
    assert len(rows) == len(frame)
    for (t, obj), (ti, row) in zip(rows, frame.iterrows()):
        assert t == ti
        assert row["label"] == obj["label"] and row["ok"] == obj["ok"] and row["count"] == obj["count"]
        v = obj["value"]
        assert (math.isnan(row["value"]) and v is None) or row["value"] == v
        assert math.copysign(1, row["value"]) == math.copysign(1, v) if v is not None else True


@pytest.mark.parametrize("cut", [0.3, 0.7, 0.93])
def test_truncated_file_fast_equals_reference_and_library(tmp_path, excitation_log, cut):
    full = tmp_path / "full.mcap"
    write_log(excitation_log, full, chunk_size=64 * 1024)
    data = full.read_bytes()
    p = tmp_path / "cut.mcap"
    p.write_bytes(data[: int(cut * len(data))])
    fast, ref = read_log(p), read_log_reference(p)
    assert_logs_equal(fast, ref)
    rec = fast.recovery
    assert rec is not None and rec.bytes_recovered + rec.bytes_lost == len(p.read_bytes())
    if data[rec.bytes_recovered] == 0x06:  # cut inside a chunk: its header names the lost time range
        assert rec.lost_to_ns is not None and rec.lost_to_ns > rec.lost_from_ns
    else:                                  # cut in the index records after a chunk: nothing more known
        assert rec.lost_to_ns is None
    lib = library_messages(p.read_bytes())
    assert len(lib) == rec.messages_recovered > 0
    assert sorted(our_messages(fast)) == sorted(lib)


def test_corrupt_chunk_fast_equals_reference(tmp_path, excitation_log):
    """Zeros inside one chunk: that chunk alone is lost and reported (offset, size, time
    range and channels from the chunk index); every other chunk loads."""
    full = tmp_path / "full.mcap"
    write_log(excitation_log, full, chunk_size=64 * 1024)
    clean = full.read_bytes()
    data = bytearray(clean)
    with open(full, "rb") as fh:
        summary = make_reader(fh).get_summary()
    chunks, topic_of = summary.chunk_indexes, {c.id: c.topic for c in summary.channels.values()}
    k = len(chunks) // 2
    bad, after = chunks[k], chunks[k + 1]
    mid = bad.chunk_start_offset + bad.chunk_length // 2
    data[mid:mid + 64] = bytes(64)
    p = tmp_path / "bad.mcap"
    p.write_bytes(bytes(data))
    fast, ref = read_log(p), read_log_reference(p)
    assert_logs_equal(fast, ref)
    rec = fast.recovery
    assert "corrupt" in rec.reason and rec.messages_skipped == 0
    start, nxt = bad.chunk_start_offset, after.chunk_start_offset
    assert rec.damaged_ranges == ((start, nxt - start),) and rec.bytes_lost == nxt - start
    [lost] = rec.lost_chunks
    assert (lost.offset, lost.size, lost.start_ns, lost.end_ns) == (
        start, bad.chunk_length, bad.message_start_time, bad.message_end_time)
    assert lost.topics == tuple(sorted(topic_of[c] for c in bad.message_index_offsets))
    assert (rec.lost_from_ns, rec.lost_to_ns) == (bad.message_start_time, bad.message_end_time)
    # every other chunk: the library's messages of the clean file with the bad chunk cut out
    others = library_messages(clean[:start] + clean[nxt:])
    assert 0 < len(others) == rec.messages_recovered < len(library_messages(clean))
    # (topic, time, payload): row numbers after the gap differ from the sequence numbers
    assert sorted((a, b, d) for a, b, _, d in our_messages(fast)) == sorted((a, b, d) for a, b, _, d in others)


def _plain_writer_file(compression, use_chunking=True) -> bytes:
    """A file written by the mcap Writer directly: out-of-order rows, a message on an
    unknown channel, whitespace in the JSON, a channel defined after some messages."""
    buf = io.BytesIO()
    w = Writer(buf, chunk_size=2000, compression=compression, use_chunking=use_chunking)
    w.start()
    schema = json.dumps({"title": "test.Sample", "type": "object",
                         "properties": {"x": {"type": ["number", "null"]}, "name": {"type": "string"},
                                        "n": {"type": "integer"}, "flag": {"type": "boolean"}}}).encode()
    sid = w.register_schema("test.Sample", "jsonschema", schema)
    cid = w.register_channel("/a", "json", sid)
    rows = [(5, {"x": 1.5e-7, "name": "ä", "n": -3, "flag": True}),
            (2, {"x": None, "name": "b\\\"", "n": 7, "flag": False})]
    rows += [(i, {"x": -float(i) * 1.1e200, "name": "r", "n": i, "flag": i % 2 == 0}) for i in range(6, 200)]
    for seq, obj in rows:
        w.add_message(cid, T0 + seq, json.dumps(obj).encode(), T0 + seq, sequence=seq)
    w.add_message(99, T0, b'{"x": 1}', T0)  # no such channel: skipped
    cid2 = w.register_channel("/b", "json", sid)
    for i in range(50):
        w.add_message(cid2, T0 + i, json.dumps({"x": i, "name": "q", "n": i, "flag": True}).encode(), T0 + i, i)
    w.finish()
    return buf.getvalue()


@pytest.mark.parametrize("compression,chunked", [(CompressionType.LZ4, True), (CompressionType.NONE, True),
                                                 (CompressionType.ZSTD, True), (CompressionType.NONE, False)])
def test_files_from_the_plain_mcap_writer(tmp_path, compression, chunked):
    p = tmp_path / "plain.mcap"
    data = _plain_writer_file(compression, chunked)
    p.write_bytes(data)
    fast, ref = read_log(p), read_log_reference(p)
    assert_logs_equal(fast, ref)
    assert fast.recovery is None
    a = fast["/a"]
    assert a.index.tolist() == [T0 + 2, T0 + 5] + [T0 + i for i in range(6, 200)]  # sequence order
    assert math.isnan(a["x"].iloc[0]) and a["x"].iloc[1] == 1.5e-7 and a["name"].iloc[0] == 'b\\"'
    assert a["n"].iloc[1] == -3 and a["x"].iloc[-1] == -199 * 1.1e200
    lib = library_messages(data)
    assert len(lib) == len(a) + len(fast["/b"])
    # every value equals the stdlib json reading of the library's messages (in sequence order)
    for topic in ("/a", "/b"):
        msgs = sorted((seq, t, json.loads(d)) for top, t, seq, d in lib if top == topic)
        frame = fast[topic]
        assert frame.index.tolist() == [t for _, t, _ in msgs]
        for c in ("x", "name", "n", "flag"):
            want = [np.nan if o[c] is None else o[c] for _, _, o in msgs]
            assert frame[c].tolist() == want or np.array_equal(frame[c].to_numpy(), want, equal_nan=True)
    # truncated versions too
    for cut in (0.45, 0.8):
        p.write_bytes(data[: int(cut * len(data))])
        assert_logs_equal(read_log(p), read_log_reference(p))


# -- the JSON codec -----------------------------------------------------------------

def _spans(payloads):
    lens = np.array([len(x) for x in payloads], dtype=np.int64)
    ends = np.cumsum(lens)
    return np.frombuffer(b"".join(payloads), dtype=np.uint8), ends - lens, ends


def _same_columns(a, b):
    assert list(a) == list(b)
    for k in a:
        assert a[k].dtype == b[k].dtype, k
        if a[k].dtype.kind == "f":
            np.testing.assert_array_equal(a[k], b[k])
            assert np.array_equal(np.signbit(a[k]), np.signbit(b[k]))
        else:
            assert a[k].tolist() == b[k].tolist(), k
    return True


SCHEMA = {"title": "t", "properties": {
    "stamp": {"type": "object", "x-usvlog-time": True, "x-usvlog-column": "stamp_ns"},
    "x": {"type": ["number", "null"]}, "n": {"type": "integer"}, "flag": {"type": "boolean"},
    "s": {"type": "string"}, "v": {"type": "array", "maxItems": 3}}}


def _msg(i, **kw):
    o = {"stamp": {"sec": 1_780_000_000 + i, "nsec": i * 7}, "x": i * -1.25e-5, "n": -i, "flag": i % 3 == 0,
         "s": "é✓" if i % 2 else "plain", "v": [i, None, 1e300]}
    o.update(kw)
    return orjson.dumps(o)


def test_decode_in_blocks_with_the_cached_layout_equals_reference(monkeypatch):
    """Blocks of messages decoded against the channel's cached layout; a block laid out
    otherwise (keys reordered, spaces) is matched on its own layout, a mixed one falls back
    to the reference: every way gives the reference's columns."""
    from usvlog.io.mcap import json_codec

    monkeypatch.setattr(json_codec, "_DECODE_BLOCK", 8)
    codec = Codec(SCHEMA)
    plain = [_msg(i) for i in range(20)]
    spaced = [json.dumps(json.loads(_msg(i)), indent=1).encode() for i in range(20, 36)]
    mixed = plain[:5] + spaced[:3] + plain[5:]
    for msgs in (plain, plain + spaced, spaced + plain, mixed, plain):
        buf, s, e = _spans(msgs)
        got = codec.decode_spans(buf, s, e)
        assert all(len(col) == len(msgs) for col in got.values())   # every message decoded, in blocks of 8
        assert _same_columns(got, codec.decode_reference(msgs))
        # coded (as a reader asks): string columns as distinct values + codes, the same strings
        coded = codec.decode_spans(buf, s, e, coded=True)
        assert _same_columns({k: v.objects() if isinstance(v, StrCodes) else v for k, v in coded.items()}, got)
        if msgs is plain:   # one layout throughout: the fast path in every block, so the string column is coded
            assert isinstance(coded["s"], StrCodes) and len(coded["s"].uniques) <= 3 * 3


def test_coded_strings_build_the_frame_the_strings_build():
    """A str column from StrCodes (Arrow strings gathered from the distinct values) is the column
    built from one Python string per row: values, dtype, missing rows none; its parts concatenate
    and reorder as arrays do."""
    rng = np.random.default_rng(3)
    values = ["newton", "normalized", "é✓", "", "a" * 200]
    parts = [StrCodes.of(values, rng.integers(0, len(values), n)) for n in (0, 1, 500, 37)]
    whole = concat_columns(parts)
    objects = np.concatenate([p.objects() for p in parts])
    assert isinstance(whole, StrCodes) and whole.objects().tolist() == objects.tolist()
    order = rng.permutation(len(objects))
    mixed = concat_columns([parts[2], parts[3].objects()])   # an object array among them: objects
    assert not isinstance(mixed, StrCodes) and mixed.tolist() == objects[1:].tolist()
    t = np.arange(len(objects), dtype=np.int64)
    for col, ref in ((whole, objects), (whole[order], objects[order]), (StrCodes.repeat("gnss", 7), ["gnss"] * 7)):
        n = len(ref)
        got = frame_from_columns({"s": col, "x": np.zeros(n)}, t[:n])
        want = frame_from_columns({"s": np.array(ref, dtype=object), "x": np.zeros(n)}, t[:n])
        pd.testing.assert_frame_equal(got, want, check_exact=True)
        assert got["s"].tolist() == list(ref)


@pytest.mark.parametrize("case", [
    "plain", "null", "exponents", "spaces", "key_order", "missing", "big_int", "escape", "extra_key",
    "array_len", "float_in_int", "null_string"])
def test_decode_fast_path_equals_reference(case):
    codec = Codec(SCHEMA)
    msgs = [_msg(i) for i in range(40)]
    if case == "null":
        msgs[3] = _msg(3, x=None)
    elif case == "exponents":
        msgs = [m.replace(b'"x":-', b'"x":-1.5E+2') if j % 2 else m for j, m in enumerate(msgs)]
        msgs = [m if b"E+2" not in m else _msg(0, x=None).replace(b'"x":null', b'"x":-1.5E+2') for m in msgs]
        msgs.append(_msg(1, x=None).replace(b'"x":null', b'"x":2e-310'))
        msgs.append(_msg(1, x=None).replace(b'"x":null', b'"x":-0.0'))
        msgs.append(_msg(1, x=None).replace(b'"x":null', b'"x":12345678901234567890123'))
        msgs.append(_msg(1, x=None).replace(b'"x":null', b'"x":-0'))
        msgs.append(_msg(1, x=None).replace(b'"x":null', b'"x":-2e-400'))
        msgs.append(_msg(1, x=None).replace(b'"x":null', b'"x":9007199254740993'))
    elif case == "spaces":
        msgs = [json.dumps(json.loads(m), indent=1, ensure_ascii=True).encode() for m in msgs]
    elif case == "key_order":
        msgs[5] = orjson.dumps(dict(reversed(list(json.loads(msgs[5]).items()))))
    elif case == "missing":
        o = json.loads(msgs[2])
        del o["x"]
        msgs[2] = orjson.dumps(o)
    elif case == "big_int":
        msgs[1] = _msg(1, n=-9223372036854775807)
        msgs[2] = _msg(2, n=9223372036854775807)
    elif case == "escape":
        msgs[4] = _msg(4, s='tab\t"q"\\ \u2028')
    elif case == "extra_key":
        msgs = [_msg(i, extra="ignored") for i in range(10)]
    elif case == "array_len":
        msgs[0] = _msg(0, v=[1, 2])
    elif case == "float_in_int":
        msgs[0] = _msg(0, n=2.0)
    elif case == "null_string":
        msgs[3] = _msg(3, s=None)
    buf, s, e = _spans(msgs)
    if case == "array_len":  # an array of the wrong length is an error either way
        for decode in (codec.decode_reference, codec.decode):
            with pytest.raises(InputError, match="field 'v'"):
                decode(msgs, "/t")
        return
    ref = codec.decode_reference(msgs)
    _same_columns(codec.decode_spans(buf, s, e), ref)
    _same_columns(codec.decode(msgs), ref)
    if case in ("plain", "null", "exponents", "spaces", "big_int", "escape", "extra_key"):
        assert _decode_layout(codec, buf, s, e) is not None  # the fast path was taken


def test_decode_errors_are_the_reference_errors():
    codec = Codec(SCHEMA)
    for bad in (b'{"x": nan}', b"[1, 2]", b'{"stamp": 3}', _msg(1)[:-1],
                _msg(1, x=None).replace(b'"x":null', b'"x":1e400'),
                _msg(1, x=None).replace(b'"x":null', b'"x":01'), _msg(1, x=None).replace(b'"x":null', b'"x":1.')):
        msgs = [_msg(0), bad]
        with pytest.raises(InputError):
            codec.decode_reference(msgs, "/t")
        with pytest.raises(InputError):
            codec.decode(msgs, "/t")


def test_random_numbers_parse_exactly():
    rng = np.random.default_rng(1)
    x = np.concatenate([rng.standard_normal(3000) * 10.0 ** rng.integers(-300, 300, 3000),
                        rng.integers(-2**53, 2**53, 500).astype(float),
                        np.frombuffer(rng.bytes(8 * 2000), dtype=np.float64)])
    x = x[np.isfinite(x)]
    codec = Codec({"title": "t", "properties": {"x": {"type": "number"}}})
    msgs = [orjson.dumps({"x": v}) for v in x.tolist()]
    got = codec.decode(msgs)["x"]
    assert got.tobytes() == x.tobytes()
    # written with Python's float repr instead of orjson's
    msgs = [('{"x":%r}' % v).encode() for v in x.tolist()]
    assert codec.decode(msgs)["x"].tobytes() == x.tobytes()
    # decimal texts that are not shortest forms: rounding from 1 to 25 digits, half-way
    # cases, the edges of the exponent range, subnormals; truth is Python's float()
    y = np.frombuffer(rng.bytes(8 * 20000), dtype=np.float64)
    y = y[np.isfinite(y)]
    texts = ["%.*e" % (int(d), v) for d, v in zip(rng.integers(0, 25, len(y)), y.tolist())]
    texts += ["9007199254740993", "9007199254740995", "1e23", "8.98846567431158e307", "2.2250738585072011e-308",
              "4.9406564584124654e-324", "1.7976931348623157e308", "0.1", "1E-5", "123456789012345678901",
              "1.00000000000000011102230246251565404236316680908203125", "7.4109846876186982e-323",
              "-0.000000000000000000000000000000000000000000001", "1e-342", "1e-343", "9e307"]
    # short mantissas with small exponents (one exact multiplication or division)
    mans, exps = rng.integers(-2**54, 2**54, 3000).tolist(), rng.integers(-25, 26, 3000).tolist()
    texts += [f"{m}e{q}" for m, q in zip(mans, exps)]
    texts += [f"{m / 1000}" for m in rng.integers(-10**6, 10**6, 1000).tolist()]
    texts += ["-0.0", "-0e3", "0.000", "9007199254740992e22"]
    msgs = [b'{"x":' + t.encode() + b"}" for t in texts]
    want = np.array([float(t) for t in texts])
    got = codec.decode(msgs)["x"]
    assert got.tobytes() == want.tobytes()
    buf, s, e = _spans(msgs)
    fast = _decode_layout(codec, buf, s, e)
    assert fast is not None and fast["x"].tobytes() == want.tobytes()


def test_encode_packed_equals_reference():
    log = tricky_log(300)
    for topic in log.topics:
        frame = log[topic]
        codec = codec_for_topic(topic) or Codec(auto_schema(topic, frame))
        ref = codec.encode_reference(frame, topic)
        assert codec.encode(frame, topic) == ref
        buf, starts, ends = codec.encode_spans(frame, topic, 31)   # spaced for the record headers
        assert [buf[a:b].tobytes() for a, b in zip(starts.tolist(), ends.tolist())] == ref
    codec = Codec(SCHEMA)
    frame = pd.DataFrame({"stamp_ns": [T0 + 3, T0 - 1], "x": [np.inf, -1e-300], "n": [0, -5],
                          "flag": [True, False], "s": ["", "ü"], "v_0": [np.nan, 1.0], "v_1": [2.0, 3.0],
                          "v_2": [0.1, -0.0]})
    assert codec.encode(frame) == codec.encode_reference(frame)


@pytest.mark.parametrize("compression,chunked", [(CompressionType.LZ4, True), (CompressionType.NONE, True),
                                                 (CompressionType.NONE, False)])
def test_damaged_bytes_read_the_same_both_ways(tmp_path, compression, chunked):
    """Random damage anywhere in a file: the fast reader and the reference reader give
    the same frames and the same report, or the same error."""
    data = _plain_writer_file(compression, chunked)
    rng = np.random.default_rng(7)
    p = tmp_path / "damaged.mcap"
    for trial in range(TRIALS):
        d = bytearray(data)
        for _ in range(int(rng.integers(1, 4))):
            at = int(rng.integers(8, len(d)))
            d[at:at + int(rng.integers(1, 9))] = rng.bytes(8)[: int(rng.integers(1, 9))]
        if trial % 3 == 0:
            d = d[: int(rng.integers(9, len(d)))]
        p.write_bytes(bytes(d))
        outcomes = []
        for fast in (True, False):
            try:
                outcomes.append((read_log if fast else read_log_reference)(p))
            except InputError as err:
                outcomes.append(type(err))
        if isinstance(outcomes[0], FieldLog) and isinstance(outcomes[1], FieldLog):
            assert_logs_equal(outcomes[0], outcomes[1])
        else:
            assert outcomes[0] == outcomes[1]


def test_topics_skip_the_chunks_that_hold_none_of_them(tmp_path):
    """read_log(topics=...) loads what the full read loads for those topics, and does not read
    a chunk the chunk index shows holds none of them: damage there is not met."""
    data = bytearray(_plain_writer_file(CompressionType.ZSTD))
    chunks = []   # (offset of the chunk's compressed records, their length, topics of its messages)
    with io.BytesIO(bytes(data)) as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        topic_of = {c.id: c.topic for c in summary.channels.values()}
        for ci in summary.chunk_indexes:
            rec = data[ci.chunk_start_offset:ci.chunk_start_offset + ci.chunk_length]
            chunks.append((ci.chunk_start_offset + len(rec) - ci.compressed_size, ci.compressed_size,
                           {topic_of.get(c, "?") for c in ci.message_index_offsets}))
    a_only = [c for c in chunks if c[2] == {"/a"}]
    assert a_only and any("/b" in c[2] for c in chunks)
    p = tmp_path / "plain.mcap"
    p.write_bytes(bytes(data))
    full, only_b = read_log(p), read_log(p, topics=["/b"])
    assert list(only_b.channels) == ["/b"] and only_b.recovery is None
    pd.testing.assert_frame_equal(only_b["/b"], full["/b"], check_exact=True)
    at, size, _ = a_only[0]
    data[at + size // 2] ^= 0xFF          # damage inside a chunk of /a messages only
    p.write_bytes(bytes(data))
    full = read_log(p)
    assert full.recovery is not None and len(full.recovery.lost_chunks) == 1
    only_b = read_log(p, topics=["/b"])
    assert not (only_b.recovery and only_b.recovery.lost_chunks)   # the damaged chunk was not read
    pd.testing.assert_frame_equal(only_b["/b"], full["/b"], check_exact=True)


def test_the_readers_crc_is_zlibs():
    # the reader's CRC-32 (fastcrc's when installed) against zlib's: whole, chained as the
    # data section's check runs it window by window, and over memoryview slices of a larger buffer
    import zlib

    from usvlog.io.mcap.format import crc32 as _crc32

    rng = np.random.default_rng(3)
    data = rng.integers(0, 256, 100_003, dtype=np.uint8).tobytes()
    mv = memoryview(data)
    assert _crc32(b"") == zlib.crc32(b"") == 0
    assert _crc32(data) == zlib.crc32(data)
    chained = 0
    for off in range(0, len(data), 4096):
        chained = _crc32(mv[off:off + 4096], chained)
    assert chained == zlib.crc32(data)
    assert _crc32(mv[7:90_001]) == zlib.crc32(data[7:90_001])
