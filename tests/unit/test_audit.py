"""Each check of the import health audit against hand-computed truth."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from usvlog.errors import ConfigError
from usvlog.io.importers.audit import (
    DUP_PAYLOAD_WINDOW_S,
    ChannelHealth,
    HealthAudit,
    TrackTurn,
    health_from_provenance,
    raw_topic,
)
from usvlog.io.importers.core import STREAMS, Assembler, ImportReport
from usvlog.io.importers.thrust_guess import guess_thrust
from usvlog.model.vessel import Thrusters

S = 1_000_000_000
T0 = 1_714_557_600 * S
TOPICS = {s: STREAMS[s][0] for s in STREAMS}


def _i64(x):
    return np.asarray(x, dtype=np.int64)


def test_republished_same_stamp_across_batches():
    ch = ChannelHealth("gnss", "/gnss/fix")
    # stamps 1,1,1,2,2,3 (record times all different), split after the 2nd sample
    t = T0 + _i64([0, 1, 2, 3, 4, 5]) * S // 10
    st = T0 - 5 * S + _i64([1, 1, 1, 2, 2, 3]) * S
    d1 = ch.republished(t[:2], st[:2], None)
    d2 = ch.republished(t[2:], st[2:], None)
    assert d1.tolist() == [False, True] and d2.tolist() == [True, False, True, False]
    assert ch.rep_stamp == 3


def test_same_stamp_rule_needs_own_stamps():
    ch = ChannelHealth("heading", "/compass/heading")
    t = T0 + _i64([0, 0, 1])
    assert not ch.republished(t, t.copy(), None).any()   # stamp == record time: the time filter's job
    assert not ch.own_stamps


def test_republished_same_payload_only_when_moving_and_within_window():
    ch = ChannelHealth("gnss", "/gnss/fix")
    d = 1e-4     # ~11 m of latitude
    lat = np.array([59.0, 59.0, 59.0 + d, 59.0 + d, 59.0 + d, 59.0 + 2 * d, 59.0 + 2 * d])
    lon = np.full(7, 10.0)
    alt = np.full(7, np.nan)
    w = int(DUP_PAYLOAD_WINDOW_S * S)
    t = T0 + _i64([0, 1, 2, 3, 4, 5, 5]) * (S // 10)
    t[6] = t[5] + w            # the last copy comes after the window: not a copy
    dup = ch.republished(t, t.copy(), [lat, lon, alt])
    # the first fix's copy is kept (no move seen before it); fixes 3, 4 are copies of 2
    assert dup.tolist() == [False, False, False, True, True, False, False]
    assert ch.rep_payload == 2


def test_still_receiver_repeats_are_kept():
    ch = ChannelHealth("gnss", "/gnss/fix")
    lat = np.full(10, 59.0)
    lon = np.full(10, 10.0)
    t = T0 + np.arange(10, dtype=np.int64) * (S // 10)
    assert not ch.republished(t, t.copy(), [lat, lon]).any()


def test_rate_jitter_gaps_after_collapse():
    ch = ChannelHealth("yaw_rate", "/imu/yaw_rate")
    # 10 Hz, intervals alternating 0.09 / 0.11 s, then one 1.0 s gap
    dts = [0.09, 0.11] * 20 + [1.0] + [0.09, 0.11] * 5
    t = T0 + np.round(np.cumsum([0.0] + dts) * S).astype(np.int64)
    v = np.arange(len(t), dtype=float)
    ch.observe(t[:13], t[:13], [v[:13]])
    ch.observe(t[13:], t[13:], [v[13:]])
    d = ch.to_dict()
    dt = np.array(dts)
    assert d["rate_hz"] == pytest.approx(1 / np.median(dt))      # 25 x 0.09, 25 x 0.11, 1 x 1.0: 0.11 s
    assert d["gaps"] == 1 and d["longest_gap_s"] == pytest.approx(1.0)
    assert d["jitter_s"] == pytest.approx(np.std(dt[dt < 0.5]), rel=1e-6)
    assert d["written"] == len(t)


def test_stamp_offset():
    ch = ChannelHealth("gnss", "/gnss/fix")
    t = T0 + np.arange(5, dtype=np.int64) * S
    off = _i64([-250, -250, -250, -200, -300]) * 1_000_000   # stamp - log time
    ch.observe(t, t + off, [np.linspace(59, 59.001, 5), np.full(5, 10.0)])
    d = ch.to_dict()
    assert d["own_stamps"] is False   # own_stamps comes from republished(); offsets from observe()
    assert d["stamp_offset_s"] == {"median": pytest.approx(-0.25), "min": pytest.approx(-0.3),
                                   "max": pytest.approx(-0.2)}


def test_longest_stuck_stretch_across_batches():
    ch = ChannelHealth("heading", "/compass/heading")
    v = np.array([0.1, 0.2, 0.2, 0.2, 0.2, 0.3, 0.3, 0.4])
    t = T0 + np.arange(len(v), dtype=np.int64) * S
    for a, b in ((0, 3), (3, 4), (4, 8)):
        ch.observe(t[a:b], t[a:b], [v[a:b]])
    assert ch.to_dict()["stuck_longest_s"] == pytest.approx(3.0)   # 0.2 from t=1 to t=4


def test_track_turn_of_a_square():
    tt = TrackTurn()
    m = 1 / 111_320.0
    c = math.cos(math.radians(59.0))
    # 20 m north, 20 m east, 20 m south, fixes every 1 m: turns 90 + 90 = 180 deg
    pts = [(k, 0) for k in range(21)] + [(20, k) for k in range(1, 21)] + [(20 - k, 20) for k in range(1, 21)]
    lat = np.array([59.0 + n * m for n, e in pts])
    lon = np.array([10.0 + e * m / c for n, e in pts])
    tt.add(lat[:30], lon[:30])
    tt.add(lat[30:], lon[30:])
    assert tt.turn_deg == pytest.approx(180.0, abs=1e-6)


class _QuadraticTrackTurn(TrackTurn):
    """The former TrackTurn.add, kept as the reference: every leg re-scans the rest of the batch."""

    def add(self, lat, lon):
        from usvlog.io.importers.audit import _M_PER_DEG, TRACK_LEG_M

        lat, lon = np.asarray(lat, float), np.asarray(lon, float)
        if not len(lat):
            return
        if self._anchor is None:
            self._anchor = (float(lat[0]), float(lon[0]))
            self._coslat = math.cos(math.radians(float(lat[0])))
        i, n = 0, len(lat)
        while i < n:
            a_lat, a_lon = self._anchor
            dn = (lat[i:] - a_lat) * _M_PER_DEG
            de = (lon[i:] - a_lon) * _M_PER_DEG * self._coslat
            far = np.flatnonzero(dn * dn + de * de >= TRACK_LEG_M ** 2)
            if not len(far):
                return
            j = int(far[0])
            course = math.atan2(float(de[j]), float(dn[j]))
            if self._course is not None:
                self.turn_rad += abs((course - self._course + math.pi) % (2 * math.pi) - math.pi)
            self._course = course
            self.legs += 1
            self._anchor = (float(lat[i + j]), float(lon[i + j]))
            i += j + 1


def _same_turn(lat, lon, cuts):
    new, ref = TrackTurn(), _QuadraticTrackTurn()
    for a, b in zip(cuts[:-1], cuts[1:]):
        new.add(lat[a:b], lon[a:b])
        ref.add(lat[a:b], lon[a:b])
    assert (new.legs, new.turn_rad, new._anchor, new._course) == (ref.legs, ref.turn_rad, ref._anchor, ref._course)
    return new


def test_track_turn_is_the_quadratic_scan_bit_for_bit():
    """A long track (drifting still, crawling, running straight and turning, NaN fixes) fed in batches
    of every size, and the real logs' fixes: the same legs, anchor, course and total turn to the bit."""
    from usvlog.io.importers import import_file

    rng = np.random.default_rng(7)
    n = 20_000
    speed = np.repeat(rng.choice([0.0, 0.3, 2.0, 8.0], size=n // 500), 500)   # m per fix
    course = np.cumsum(rng.normal(0.0, 0.05, n)) + np.repeat(rng.uniform(-3, 3, n // 2000), 2000)
    north = np.cumsum(speed * np.cos(course)) + rng.normal(0.0, 0.8, n)
    east = np.cumsum(speed * np.sin(course)) + rng.normal(0.0, 0.8, n)
    lat, lon = 59.0 + north / 111_320.0, 10.0 + east / 111_320.0 / math.cos(math.radians(59.0))
    lat[rng.integers(0, n, 50)] = np.nan
    cuts = np.unique(np.concatenate(([0, n], rng.integers(0, n, 40), [1, 2, 3])))
    tt = _same_turn(lat, lon, cuts)
    assert tt.legs > 500
    real = Path(__file__).resolve().parents[1] / "data" / "real"
    for name in ("ardusub_nmea_log.txt", "px4_sample_log_small.ulg"):
        fix = import_file(real / name).log["/gnss/fix"]
        la, lo = fix["lat_deg"].to_numpy(float), fix["lon_deg"].to_numpy(float)
        assert len(la) >= 30, name
        for cuts in ([0, len(la)], list(range(0, len(la), 7)) + [len(la)]):
            _same_turn(la, lo, cuts)


def test_heading_dead_only_when_the_track_turns():
    turning = HealthAudit(TOPICS)
    straight = HealthAudit(TOPICS)
    n = 60
    t = T0 + np.arange(n, dtype=np.int64) * S
    ang = np.radians(np.linspace(0, 270, n))
    lat_c = 59.0 + 50 * np.sin(ang) / 111_320.0
    lon_c = 10.0 + 50 * (1 - np.cos(ang)) / (111_320.0 * math.cos(math.radians(59)))
    lat_s = 59.0 + np.arange(n) * 10 / 111_320.0
    head = {"heading_rad": np.full(n, 1.0)}
    for audit, lat, lon in ((turning, lat_c, lon_c), (straight, lat_s, np.full(n, 10.0))):
        audit.observe("gnss", t, t, {"lat_deg": lat, "lon_deg": lon})
        audit.observe("heading", t, t, head)
    a, b = turning.finish(), straight.finish()
    assert a["dead"] == ["/compass/heading"] and a["track_turn_deg"] > 200
    assert a["channels"]["/compass/heading"]["written_as"] == raw_topic("/compass/heading")
    assert b["dead"] == [] and b["suspect"] == ["/compass/heading"] and b["track_turn_deg"] == pytest.approx(0.0)


def test_position_stuck_under_thrust():
    n = 100
    t = T0 + np.arange(n, dtype=np.int64) * S
    thr = {"left": np.full(n, 0.5), "right": np.full(n, 0.5)}
    exact, noisy, idle = HealthAudit(TOPICS), HealthAudit(TOPICS), HealthAudit(TOPICS)
    rng = np.random.default_rng(0)
    for audit, jitter, thrust in ((exact, 0.0, thr), (noisy, 2e-6, thr),
                                  (idle, 0.0, {"left": np.zeros(n), "right": np.zeros(n)})):
        audit.observe("thrust", t, t, thrust)
        audit.observe("gnss", t, t, {"lat_deg": 59.0 + jitter * rng.standard_normal(n), "lon_deg": np.full(n, 10.0)})
    a, b, c = exact.finish(), noisy.finish(), idle.finish()
    assert a["thrust_applied_s"] == pytest.approx(99.0)
    assert a["dead"] == ["/gnss/fix"]
    assert b["dead"] == [] and b["suspect"] == ["/gnss/fix"]
    assert c["dead"] == [] and c["suspect"] == [] and c["thrust_applied_s"] == 0.0


def test_assembler_holds_a_still_channel_and_releases_it_when_it_moves():
    rep = ImportReport()
    asm = Assembler(rep)
    t = T0 + np.arange(10, dtype=np.int64) * S
    out1 = asm.process({"heading": {"t_ns": t[:5], "heading_rad": np.full(5, 0.5)}})
    assert out1 == {}
    out2 = asm.process({"heading": {"t_ns": t[5:], "heading_rad": np.linspace(0.5, 1.5, 5)}})
    assert len(out2["/compass/heading"]) == 10 and rep.counts["/compass/heading"] == 10
    assert asm.finish() == {}
    assert asm.health["channels"]["/compass/heading"]["status"] == "ok"


@pytest.mark.parametrize("vals,unit,lo,hi", [
    ([1100, 1500, 1900, 1500], "pwm_us", 800, 2200),
    ([-0.5, 0.25, 1.0, -1.0], "normalized", -1 - 1e-9, 1 + 1e-9),
    ([-255, 0, 255, 17] * 300 + [-99360], "counts", -255, 255),
    ([0, 200, 150, 3] * 300, "counts", -200, 200),
    ([0, 1000, 1023, -1023], "counts", -1023, 1023),
    ([-12.5, 3.25, 20.0], "newton", -1e5, 1e5),
])
def test_guess_thrust(vals, unit, lo, hi):
    g = guess_thrust(np.array(vals, float), np.array(vals[::-1], float))
    assert (g.unit, g.lo, g.hi) == (unit, pytest.approx(lo), pytest.approx(hi))
    assert g.reason


def test_counts_thruster_map():
    thr = Thrusters(map="linear", forward_n=20.0, reverse_n=10.0)
    np.testing.assert_allclose(thr.normalize([-255, 0, 127.5, 300], "counts", full_scale=255), [-1, 0, 0.5, 1])
    np.testing.assert_allclose(thr.command_to_force([-255, 127.5], "counts", full_scale=255), [-10.0, 10.0])
    np.testing.assert_allclose(thr.force_to_command([-10.0, 10.0], "counts", full_scale=200), [-200, 100])
    with pytest.raises(ConfigError):
        thr.command_to_force([1.0], "counts")


def test_health_from_provenance_takes_the_last_import():
    recs = [{"producer": "usvlog import", "health": '{"version": 1, "dead": ["/a"]}'},
            {"producer": "usvlog estimate"},
            {"producer": "usvlog import", "health": '{"version": 1, "dead": []}'},
            {"producer": "x", "health": "not json"}]
    assert health_from_provenance(recs) == {"version": 1, "dead": []}
    assert health_from_provenance([]) is None
