"""Property: damage to one data record of a real ULog / DataFlash log changes that record's samples only.

The damage is done to the record's payload (its values and time stamp: random bytes, NaN,
infinity, all bits set), the framing (sizes, message ids, type bytes) is left alone: with
a damaged length the two formats lose their place in the file, which is a different
failure (covered by the truncation and garbage tests). Definition records (ULog formats
and subscriptions, DataFlash FMT/FMTU/UNIT/MULT) are not data records and are not damaged.

What is checked, per output channel: at most one sample of the original import is gone
and at most one new sample appears, and only channels fed by the damaged record's topic
change at all (or the import is refused with one line). The one exception, stated: the
first GNSS fix of a ULog sets the UTC offset of the log's clock, so damage to its UTC
time may shift every time stamp by the same amount (< 1 s; PX4 fixes agree within ~20 ms).
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from usvlog.errors import UsvlogError
from usvlog.io.importers import import_file

REAL = Path(__file__).resolve().parents[1] / "data" / "real"
ULG = REAL / "px4_sample_log_small.ulg"
BIN = REAL / "ardusub_small.BIN"
BIN_TOPICS = {"thrust_left": "RCOU.C1", "thrust_right": "RCOU.C2"}


# ----------------------------------------------------------------------------- record walkers
def ulog_data_records(data: bytes) -> list[tuple[int, int, str]]:
    """(payload start after msg_id, payload end, topic[.instance]) of every 'D' message (ULog spec layout)."""
    pos, subs, out = 16, {}, []
    while pos + 3 <= len(data):
        size, kind = struct.unpack_from("<HB", data, pos)
        body = pos + 3
        if body + size > len(data):
            break
        if kind == ord("A"):
            multi, mid = struct.unpack_from("<BH", data, body)
            name = data[body + 3: body + size].decode()
            subs[mid] = f"{name}.{multi}" if multi else name
        elif kind == ord("D"):
            (mid,) = struct.unpack_from("<H", data, body)
            out.append((body + 2, body + size, subs.get(mid, "?")))
        pos = body + size
    return out


def dataflash_data_records(data: bytes) -> list[tuple[int, int, str]]:
    """(payload start after the 3-byte header, end, message name) of every data message."""
    from pymavlink.DFReader import DFReader_binary

    fmts = {t: (f.len, f.name) for t, f in DFReader_binary(str(BIN), zero_time_base=True).formats.items()}
    pos, out = 0, []
    while pos + 3 <= len(data):
        assert data[pos:pos + 2] == b"\xa3\x95"
        length, name = fmts[data[pos + 2]]
        if name not in ("FMT", "FMTU", "UNIT", "MULT"):
            out.append((pos + 3, pos + length, name))
        pos += length
    return out


ULOG_RECORDS = ulog_data_records(ULG.read_bytes())
BIN_RECORDS = dataflash_data_records(BIN.read_bytes())
# channels fed by each source topic / message
ULOG_FEEDS = {"vehicle_gps_position": {"/gnss/fix", "/gnss/velocity"}, "vehicle_attitude": {"/compass/heading"},
              "vehicle_angular_velocity": {"/imu/yaw_rate"}, "actuator_outputs": {"/thrust/command"}}
BIN_FEEDS = {"ATT": {"/compass/heading"}, "IMU": {"/imu/yaw_rate"}, "RCOU": {"/thrust/command"}}


def _rows(frame: pd.DataFrame) -> set:
    f = frame.drop(columns=[c for c in ("thrust_left_n", "thrust_right_n") if c in frame])
    return {tuple([t] + ["nan" if isinstance(v, float) and np.isnan(v) else v for v in row])
            for t, row in zip(f.index.to_numpy(), f.itertuples(index=False, name=None), strict=True)}


@pytest.fixture(scope="module")
def baselines():
    return {"ulg": import_file(ULG).log, "bin": import_file(BIN, topics=BIN_TOPICS).log}


_damage = st.one_of(
    st.tuples(st.just("bytes"), st.integers(0, 10**6), st.binary(min_size=1, max_size=12)),
    st.tuples(st.just("nan"), st.integers(0, 10**6), st.sampled_from([b"\x00\x00\xc0\x7f", b"\x00\x00\x80\x7f",
                                                                     b"\x00\x00\x80\xff"])),
    st.tuples(st.just("ones"), st.integers(0, 10**6), st.binary(min_size=8, max_size=8).map(lambda _: b"\xff" * 8)),
)


def _damaged(src: Path, rec: tuple[int, int, str], damage, tmp: Path) -> Path:
    start, end, _ = rec
    kind, at, blob = damage
    data = bytearray(src.read_bytes())
    span = end - start
    off = start + at % max(span, 1)
    blob = blob[: end - off]
    data[off: off + len(blob)] = blob
    p = tmp / ("d" + src.suffix)
    p.write_bytes(bytes(data))
    return p


def _check(base, damaged, feeds: set, allow_shift: bool) -> None:
    for topic in set(base.topics) | set(damaged.topics):
        a = base.get(topic)
        b = damaged.get(topic)
        ra = _rows(a) if a is not None else set()
        rb = _rows(b) if b is not None else set()
        gone, new = ra - rb, rb - ra
        if topic not in feeds and not (allow_shift and gone):
            assert not gone and not new, (topic, sorted(gone)[:2], sorted(new)[:2])
        elif allow_shift and len(gone) > 1:
            shift = b.index.to_numpy()[: len(a)] - a.index.to_numpy()[: len(b)]
            assert len(set(shift[1:])) <= 1 and abs(int(shift[1])) < 1_000_000_000, topic
        else:
            assert len(gone) <= 1 and len(new) <= 1, (topic, len(gone), len(new))


def _pick(records, feeds):
    """Half the draws from the records that feed a channel (most records of a log feed none)."""
    fed = [i for i, r in enumerate(records) if r[2] in feeds]
    return st.one_of(st.sampled_from(fed), st.integers(0, len(records) - 1))


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(idx=_pick(ULOG_RECORDS, ULOG_FEEDS), damage=_damage)
def test_ulog_one_damaged_record_changes_only_its_samples(baselines, tmp_path_factory, idx, damage):
    rec = ULOG_RECORDS[idx]
    p = _damaged(ULG, rec, damage, tmp_path_factory.mktemp("ulg"))
    try:
        log = import_file(p).log
    except UsvlogError as err:
        assert "\n" not in str(err)
        return
    first_gps = next(r for r in ULOG_RECORDS if r[2] == "vehicle_gps_position")
    _check(baselines["ulg"], log, ULOG_FEEDS.get(rec[2], set()), allow_shift=rec == first_gps)


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(idx=_pick(BIN_RECORDS, BIN_FEEDS), damage=_damage)
def test_dataflash_one_damaged_record_changes_only_its_samples(baselines, tmp_path_factory, idx, damage):
    rec = BIN_RECORDS[idx]
    p = _damaged(BIN, rec, damage, tmp_path_factory.mktemp("bin"))
    try:
        log = import_file(p, topics=BIN_TOPICS).log
    except UsvlogError as err:
        assert "\n" not in str(err)
        return
    _check(baselines["bin"], log, BIN_FEEDS.get(rec[2], set()), allow_shift=False)


@pytest.mark.parametrize("topic", ["vehicle_attitude", "actuator_outputs", "vehicle_gps_position"])
def test_ulog_damaged_time_stamp_costs_one_sample(baselines, tmp_path, topic):
    """A time stamp set far ahead: that sample is dropped (counted), not every later one."""
    recs = [r for r in ULOG_RECORDS if r[2] == topic]
    rec = recs[len(recs) // 2]
    (ts,) = struct.unpack_from("<Q", ULG.read_bytes(), rec[0])
    p = _damaged(ULG, rec, ("bytes", 0, struct.pack("<Q", ts + 10**12)), tmp_path)   # 11.6 days ahead
    res = import_file(p)
    stream = {"vehicle_attitude": "heading", "actuator_outputs": "thrust", "vehicle_gps_position": "gnss"}[topic]
    assert res.report.skipped[f"{stream}_time_spike"] == 1
    for ch in ULOG_FEEDS[topic]:
        assert len(res.log[ch]) == len(baselines["ulg"][ch]) - 1


def test_dataflash_damaged_time_stamp_costs_one_sample(baselines, tmp_path):
    recs = [r for r in BIN_RECORDS if r[2] == "RCOU"]
    rec = recs[100]
    (ts,) = struct.unpack_from("<Q", BIN.read_bytes(), rec[0])
    p = _damaged(BIN, rec, ("bytes", 0, struct.pack("<Q", ts + 10**12)), tmp_path)   # 11.6 days ahead
    res = import_file(p, topics=BIN_TOPICS)
    assert res.report.skipped["thrust_time_spike"] == 1
    assert len(res.log["/thrust/command"]) == 236
