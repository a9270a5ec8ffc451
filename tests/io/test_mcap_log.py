import json
import os

import jsonschema
import numpy as np
import pandas as pd
import pytest
from mcap.reader import make_reader

import usvlog
from usvlog.errors import FormatError, InputError, OutputExistsError
from usvlog.io.mcap import read_log, write_log
from usvlog.log.channels import BULK_TOPICS, registered_topics, schema_by_name, schema_for_topic, schema_names
from usvlog.log.fieldlog import FieldLog
from usvlog.resources import schemas_dir
from usvlog.sim.simulate import SimSettings, simulate


def test_schema_files_are_valid_json_schemas_with_versioned_names():
    files = sorted(schemas_dir().glob("*.json"))
    assert len(files) >= 4
    for f in files:
        s = json.loads(f.read_text())
        jsonschema.Draft202012Validator.check_schema(s)
        assert s["title"] == f.stem
        assert s["title"].startswith("foxglove.") or s["title"].rsplit(".", 1)[-1].startswith("v")
    topics = registered_topics()
    for t in ("/gnss/fix", "/compass/heading", "/thrust/command", "/truth/state"):
        assert t in topics


def test_round_trip_gives_identical_frames(excitation_log, excitation_file):
    back = usvlog.load(excitation_file)
    assert back.recovery is None
    assert set(back.topics) == set(excitation_log.topics)
    for topic in excitation_log.topics:
        a, b = excitation_log[topic], back[topic]
        assert list(a.columns) == list(b.columns)
        assert a.index.dtype == np.int64 and b.index.name == "t_ns"
        pd.testing.assert_frame_equal(a, b, check_exact=True)
    assert back.meta == excitation_log.meta
    assert back.datum == excitation_log.datum and back.vessel == excitation_log.vessel


def test_every_message_validates_against_its_schema(excitation_file):
    """Sensor channels are JSON with their JSON Schema; the bulk derived ones CDR whose
    messages, decoded by mcap-ros2-support, validate against the topic's JSON Schema."""
    from mcap_ros2.decoder import DecoderFactory

    validators = {n: jsonschema.Draft202012Validator(schema_by_name(n)) for n in schema_names()}
    ros2 = DecoderFactory()
    counts = {}
    with open(excitation_file, "rb") as fh:
        reader = make_reader(fh)
        for schema, channel, message in reader.iter_messages():
            if channel.topic in BULK_TOPICS:
                assert schema.encoding == "ros2msg" and channel.message_encoding == "cdr"
                o = ros2.decoder_for("cdr", schema)(message.data)
                msg = {k: None if isinstance(v, float) and v != v else v
                       for k in o.__slots__ for v in [getattr(o, k)]}
                validators[schema_for_topic(channel.topic)["title"]].validate(msg)
            else:
                assert schema.encoding == "jsonschema" and channel.message_encoding == "json"
                validators[schema.name].validate(json.loads(message.data))
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
        summary = reader.get_summary()
    assert counts["/gnss/fix"] == 1200 and counts["/compass/heading"] == 2400 and counts["/truth/state"] > 0
    # written with zstd chunks
    assert {c.compression for c in summary.chunk_indexes} == {"zstd"}


def test_location_fix_is_foxglove_layout(excitation_file):
    with open(excitation_file, "rb") as fh:
        schema, _channel, message = next(iter(make_reader(fh).iter_messages(topics=["/gnss/fix"])))
        msg = json.loads(message.data)
    assert schema.name == "foxglove.LocationFix"
    assert set(msg) == {"timestamp", "frame_id", "latitude", "longitude", "altitude",
                        "position_covariance", "position_covariance_type"}
    assert set(msg["timestamp"]) == {"sec", "nsec"} and len(msg["position_covariance"]) == 9


def test_same_seed_gives_identical_file_bytes(tmp_path):
    from usvlog.sim.simulate import SimSettings, simulate

    a, b = tmp_path / "a.mcap", tmp_path / "b.mcap"
    write_log(simulate("excitation", SimSettings(duration_s=20.0), seed=11), a)
    write_log(simulate("excitation", SimSettings(duration_s=20.0), seed=11), b)
    assert a.read_bytes() == b.read_bytes()


def test_truncated_file_recovers_complete_chunks(tmp_path, excitation_log):
    full = tmp_path / "full.mcap"
    write_log(excitation_log, full, chunk_size=64 * 1024)
    data = full.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(0.7 * len(data))])
    log = read_log(cut)
    rec = log.recovery
    assert rec is not None and rec.bytes_lost > 0
    assert rec.bytes_recovered + rec.bytes_lost == int(0.7 * len(data))
    # every recovered row equals the original, and a large share survived
    orig = excitation_log["/truth/state"]
    got = log["/truth/state"]
    assert 0.4 * len(orig) < len(got) < len(orig)
    pd.testing.assert_frame_equal(got, orig.loc[got.index], check_exact=True)
    assert rec.lost_from_ns == max(int(f.index.max()) for f in log.channels.values())
    assert log.datum == excitation_log.datum  # metadata written first survives
    assert "cut short" in rec.describe()
    with pytest.raises(InputError, match="damaged"):
        read_log(cut, strict=True)


def test_garbage_and_empty_files_are_format_errors(tmp_path):
    g = tmp_path / "garbage.mcap"
    g.write_bytes(os.urandom(5000))
    with pytest.raises(FormatError, match="garbage.mcap: not an MCAP file"):
        read_log(g)
    e = tmp_path / "empty.mcap"
    e.write_bytes(b"")
    with pytest.raises(FormatError):
        read_log(e)


def test_output_not_overwritten_without_force(tmp_path, excitation_log):
    p = tmp_path / "x.mcap"
    p.write_bytes(b"precious")
    with pytest.raises(OutputExistsError):
        write_log(excitation_log, p)
    assert p.read_bytes() == b"precious"
    write_log(excitation_log, p, force=True)
    assert read_log(p).equals(excitation_log)
    assert [f.name for f in tmp_path.iterdir()] == ["x.mcap"]  # no temporary files left


def test_unregistered_channel_round_trips_with_generated_schema(tmp_path):
    log = FieldLog()
    idx = pd.Index(np.array([3, 1, 2], dtype=np.int64) * 10**9, name="t_ns")  # goes backwards
    log.set("/my/sensor", pd.DataFrame({"depth_m": [1.5, np.nan, 2.0], "ok": [True, False, True],
                                        "count": [1, 2, 3], "label": ["a", "b", "c"]}, index=idx))
    p = tmp_path / "c.mcap"
    write_log(log, p)
    back = read_log(p)
    pd.testing.assert_frame_equal(back["/my/sensor"], log["/my/sensor"], check_exact=True)


def test_outputs_get_the_usual_file_mode(tmp_path, excitation_log):
    p = tmp_path / "mode.mcap"
    old = os.umask(0o022)
    try:
        write_log(excitation_log, p)
    finally:
        os.umask(old)
    assert (p.stat().st_mode & 0o777) == 0o644

@pytest.mark.parametrize("chunk_size, compression", [(1 << 20, "zstd"), (8192, "lz4"), (3000, "none")])
def test_write_log_is_the_mcap_writers_file(tmp_path, chunk_size, compression):
    """McapWriter (under write_log) writes the bytes the mcap library's Writer writes for the same log."""
    from usvlog.io.mcap.reference import _write_log_reference

    log = simulate("excitation", SimSettings(duration_s=15.0), seed=4)
    a, b = tmp_path / "a.mcap", tmp_path / "b.mcap"
    write_log(log, a, chunk_size=chunk_size, compression=compression, zstd_level=3)  # the library's level
    _write_log_reference(log, b, chunk_size=chunk_size, compression=compression)
    assert a.read_bytes() == b.read_bytes()


def test_writer_streamed_in_batches_reads_back_whole(tmp_path):
    """Batches of frames (with metadata after them, as the importer writes) read back as one log;
    sequence numbers run on over batches, so row order is kept."""
    from mcap.reader import make_reader

    from usvlog.io.mcap import McapWriter

    log = simulate("excitation", SimSettings(duration_s=15.0), seed=5)
    p = tmp_path / "s.mcap"
    with open(p, "wb") as fh:
        w = McapWriter(fh, chunk_size=16 * 1024)
        for k in range(4):
            w.add_frames({t: f.iloc[len(f) * k // 4:len(f) * (k + 1) // 4] for t, f in log.channels.items()})
            if k == 1:
                w.flush()
        for name in sorted(log.meta):
            w.add_metadata(name, log.meta[name])
        w.finish()
    back = read_log(p)
    for topic in log.topics:
        pd.testing.assert_frame_equal(back[topic], log[topic], check_dtype=False)
    assert back.meta == log.meta
    with open(p, "rb") as fh:
        summ = make_reader(fh).get_summary()
    assert summ.statistics.message_count == sum(len(f) for f in log.channels.values())
    assert len(summ.chunk_indexes) > 4


def test_missing_and_unreadable_inputs_are_one_line_storage_errors(tmp_path):
    """read_log, the importer's format detection and read_text share one mapping of read errors."""
    from usvlog.errors import StorageError
    from usvlog.io.config import read_text
    from usvlog.io.importers import detect_format

    for read in (read_log, detect_format, read_text):
        with pytest.raises(StorageError, match="nope.x: no such file"):
            read(tmp_path / "nope.x")
    with pytest.raises(StorageError, match=r"d.mcap: cannot read \(Is a directory\)"):
        read_log(tmp_path.joinpath("d.mcap").mkdir() or tmp_path / "d.mcap")
