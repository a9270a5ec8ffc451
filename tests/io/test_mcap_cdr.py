"""The bulk derived channels as CDR (ros2msg): bit-for-bit round trips, files read by the
mcap library + mcap-ros2-support and by Rerun's MCAP loader, and older files whose derived
channels are JSON still read.

Independent truth: the values put in (compared as bit patterns), the mcap library's Writer
and readers, mcap-ros2-support's CDR decoder, Rerun's ``mcap convert``, stdlib ``json``.
"""

import json
import shutil
import subprocess

import numpy as np
import pandas as pd
import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from usvlog.errors import InputError
from usvlog.io.mcap import read_log, write_log
from usvlog.io.mcap.codec import CdrCodec, codec_for_topic, writer_codec
from usvlog.log.channels import BULK_TOPICS, channel_spec, frame_from_columns, schema_for_topic
from usvlog.log.fieldlog import FieldLog

T0 = 1_780_000_000 * 10**9
SPECIAL = np.array([np.nan, np.inf, -np.inf, -0.0, 5e-324, 1.7976931348623157e308, -2.2250738585072014e-308])


def bulk_log(n: int = 300, seed: int = 1, special: bool = True) -> FieldLog:
    """Every bulk topic with random values; with ``special`` NaN, +-inf, -0.0 and extremes too."""
    rng = np.random.default_rng(seed)
    log = FieldLog()
    for k, topic in enumerate(sorted(BULK_TOPICS)):
        spec = channel_spec(topic)
        cols = {}
        for f in spec.fields:
            for c in f.columns:
                if f.kind == "bool":
                    cols[c] = rng.random(n) < 0.5
                elif f.kind == "int":
                    cols[c] = rng.integers(-2**62, 2**62, n)
                else:
                    x = rng.standard_normal(n) * 10.0 ** rng.integers(-30, 30, n)
                    if special:
                        x[rng.integers(0, n, 20)] = rng.choice(SPECIAL, 20)
                    else:
                        x[::11] = np.nan
                    cols[c] = x
        t = T0 + np.sort(rng.integers(0, 60 * 10**9, n)) + k
        log.channels[topic] = frame_from_columns(cols, t, spec)
    return log


def assert_bits_equal(a: pd.DataFrame, b: pd.DataFrame) -> None:
    assert list(a.columns) == list(b.columns)
    np.testing.assert_array_equal(a.index.to_numpy(), b.index.to_numpy())
    for c in a.columns:
        x, y = a[c].to_numpy(), b[c].to_numpy()
        assert x.dtype == y.dtype, c
        if x.dtype == np.float64:
            np.testing.assert_array_equal(x.view(np.uint64), y.view(np.uint64), err_msg=c)
        else:
            np.testing.assert_array_equal(x, y, err_msg=c)


def test_bulk_channels_round_trip_bit_for_bit(tmp_path):
    log = bulk_log()
    p = tmp_path / "b.mcap"
    write_log(log, p, chunk_size=16 * 1024)
    with open(p, "rb") as fh:
        summary = make_reader(fh).get_summary()
    encodings = {c.topic: (c.message_encoding, summary.schemas[c.schema_id].encoding)
                 for c in summary.channels.values()}
    assert encodings == {t: ("cdr", "ros2msg") for t in BULK_TOPICS}
    back = read_log(p)
    assert back.recovery is None and set(back.topics) == BULK_TOPICS
    for topic in BULK_TOPICS:
        assert_bits_equal(back[topic], log[topic])
        assert back.schemas[topic] == schema_for_topic(topic)   # the registered columns, not a stand-in
        # the whole-block numpy paths equal the per-message struct reference
        codec = writer_codec(topic, schema_for_topic(topic))
        assert isinstance(codec, CdrCodec)
        data, offs = codec.encode_packed(log[topic], topic)
        ref = codec.encode_reference(log[topic], topic)
        assert data.tobytes() == b"".join(ref) and np.all(np.diff(offs) == codec.size)
        # with room for the record headers (the writer's path): the same messages, spaced
        buf, starts, ends = codec.encode_spans(log[topic], topic, 31)
        assert [buf[a:b].tobytes() for a, b in zip(starts.tolist(), ends.tolist())] == ref
        fast = codec.decode_spans(data, offs[:-1], offs[1:], topic)
        slow = codec.decode_reference(ref, topic)
        for c in codec.columns:
            assert fast[c].dtype == slow[c].dtype
            np.testing.assert_array_equal(fast[c].view(np.uint8), slow[c].view(np.uint8))


def test_cdr_messages_decode_with_mcap_ros2_support(tmp_path):
    """Every field mcap-ros2-support decodes equals the frame's value, bit for bit."""
    from mcap_ros2.decoder import DecoderFactory

    log = bulk_log(n=60, seed=2)
    p = tmp_path / "r.mcap"
    write_log(log, p)
    got: dict = {}
    with open(p, "rb") as fh:
        for _schema, channel, _msg, obj in make_reader(fh, decoder_factories=[DecoderFactory()]) \
                .iter_decoded_messages(log_time_order=False):
            got.setdefault(channel.topic, []).append(obj)
    for topic in BULK_TOPICS:
        frame, spec = log[topic], channel_spec(topic)
        assert len(got[topic]) == len(frame)
        for f in spec.fields:
            vals = np.array([getattr(o, f.prop) for o in got[topic]], dtype=frame[f.columns[0]].dtype)
            want = frame[f.columns[0]].to_numpy()
            if vals.dtype == np.float64:
                np.testing.assert_array_equal(vals.view(np.uint64), want.view(np.uint64))
            else:
                np.testing.assert_array_equal(vals, want)


@pytest.mark.skipif(shutil.which("rerun") is None, reason="the rerun CLI of rerun-sdk is not on PATH")
def test_cdr_channels_open_in_rerun(tmp_path):
    """Rerun's MCAP loader (``rerun mcap convert``, its ros2 reflection decoder) reads the
    CDR channels: the .rrd it writes holds every message's fields with the values written."""
    from rerun.chunk import RrdReader

    log = bulk_log(n=40, seed=3, special=False)
    p, out = tmp_path / "v.mcap", tmp_path / "v.rrd"
    write_log(log, p)
    run = subprocess.run(["rerun", "mcap", "convert", str(p), "-o", str(out), "--disable-raw-fallback"],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr[-2000:]
    rows: dict = {}
    for c in RrdReader(out).stream().to_chunks():
        for k, v in c.to_record_batch().to_pydict().items():
            if k.endswith(":message"):
                rows.setdefault(c.entity_path, []).extend(v)
    for topic in BULK_TOPICS:
        frame = log[topic]
        msgs = [m[0] if isinstance(m, list) else m for m in rows[topic]]
        assert len(msgs) == len(frame)
        for f in channel_spec(topic).fields:
            vals = np.array([m[f.prop] for m in msgs], dtype=float)
            np.testing.assert_array_equal(vals, frame[f.columns[0]].to_numpy(dtype=float))


def _write_json_file(path, log: FieldLog) -> None:
    """``log`` as older usvlog wrote it: every channel JSON with its JSON Schema, through
    the mcap library's Writer (whose bytes the older writer reproduced)."""
    with open(path, "wb") as fh:
        w = Writer(fh, compression=CompressionType.ZSTD)
        w.start()
        for topic in log.topics:
            schema = schema_for_topic(topic)
            sid = w.register_schema(schema["title"], "jsonschema", json.dumps(schema).encode())
            cid = w.register_channel(topic, "json", sid)
            frame = log[topic]
            for i, (t, data) in enumerate(zip(frame.index.tolist(), codec_for_topic(topic).encode(frame, topic))):
                w.add_message(cid, log_time=t, data=data, publish_time=t, sequence=i)
        w.finish()


def test_older_files_with_json_derived_channels_still_read(tmp_path):
    log = bulk_log(n=200, seed=4, special=False)   # JSON has no inf: NaN (null) only
    old, new = tmp_path / "old.mcap", tmp_path / "new.mcap"
    _write_json_file(old, log)
    back = read_log(old)
    assert back.recovery is None
    with open(old, "rb") as fh:
        msgs = {}
        for _s, ch, m in make_reader(fh).iter_messages(log_time_order=False):
            assert ch.message_encoding == "json"
            msgs.setdefault(ch.topic, []).append(json.loads(m.data))
    for topic in BULK_TOPICS:
        assert_bits_equal(back[topic], log[topic])
        # the values stdlib json reads from the old file
        for f in channel_spec(topic).fields:
            vals = np.array([np.nan if o[f.prop] is None else o[f.prop] for o in msgs[topic]],
                            dtype=back[topic][f.columns[0]].dtype)
            np.testing.assert_array_equal(vals, back[topic][f.columns[0]].to_numpy())
    # written again, the same log comes back with its derived channels as CDR
    write_log(back, new)
    again = read_log(new)
    for topic in BULK_TOPICS:
        assert_bits_equal(again[topic], log[topic])


def test_damaged_cdr_message_is_skipped_and_foreign_cdr_left_alone(tmp_path):
    """A message of the wrong size costs that message only (reported; strict raises); a
    CDR channel of another program's type (not usvlog/msg/...) is not loaded."""
    topic = "/estimate/state"
    log = bulk_log(n=30, seed=5, special=False)
    codec = writer_codec(topic, schema_for_topic(topic))
    frame = log[topic]
    payloads = codec.encode(frame, topic)
    payloads[7] = payloads[7][:-3]
    p = tmp_path / "d.mcap"
    with open(p, "wb") as fh:
        w = Writer(fh)
        w.start()
        sid = w.register_schema(codec.schema_name, "ros2msg", codec.schema_data)
        cid = w.register_channel(topic, "cdr", sid)
        fid = w.register_channel("/other/value", "cdr",
                                 w.register_schema("std_msgs/msg/Float64", "ros2msg", b"float64 data\n"))
        for i, (t, data) in enumerate(zip(frame.index.tolist(), payloads)):
            w.add_message(cid, log_time=t, data=data, publish_time=t, sequence=i)
            w.add_message(fid, log_time=t, data=b"\x00\x01\x00\x00" + bytes(8), publish_time=t, sequence=i)
        w.finish()
    back = read_log(p)
    assert back.topics == [topic]
    assert back.recovery is not None and back.recovery.skipped_by_topic == {topic: 1}
    assert_bits_equal(back[topic], frame.drop(frame.index[7]))
    with pytest.raises(InputError, match="damaged"):
        read_log(p, strict=True)
    with pytest.raises(InputError, match=r"/estimate/state: message 0 is 129 bytes"):
        codec.decode([payloads[7]], topic)
