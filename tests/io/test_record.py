"""usvlog record: real sockets on 127.0.0.1, a pseudo-terminal for serial, real subprocess kills."""

from __future__ import annotations

import math
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

import usvlog
from usvlog.cli import main as cli_main
from usvlog.errors import InputError, OutputExistsError
from usvlog.io.mcap import read_log, read_logs
from usvlog.io.nmea import with_checksum
from usvlog.io.record import Recorder, record
from usvlog.io.record.loopback import LoopbackBoat, free_udp_port, udp_target
from usvlog.model.frames import Datum, ssa
from usvlog.model.vessel import default_vessel

ROOT = Path(__file__).resolve().parents[2]
T0 = 1_750_000_000 * 10**9


class TcpServer:
    """One-client TCP server on 127.0.0.1: ``send(bytes)`` writes to the connected client (drops before it connects)."""

    def __init__(self):
        self.sock = socket.create_server(("127.0.0.1", 0))
        self.port = self.sock.getsockname()[1]
        self.conn = None
        self.connected = threading.Event()
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self):
        self.sock.settimeout(20)
        try:
            self.conn, _ = self.sock.accept()
            self.connected.set()
        except OSError:
            pass

    def send(self, data: bytes) -> None:
        if self.conn is not None:
            self.conn.sendall(data)

    def close(self):
        for s in (self.conn, self.sock):
            if s is not None:
                s.close()


def wait_for(pred, timeout_s: float, what: str):
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout_s:
        if pred():
            return
        time.sleep(0.02)
    raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")


def _snapshot(path: Path, dest: Path) -> Path:
    """The file's bytes as they are on disk now (what a killed process leaves)."""
    shutil.copyfile(path, dest)
    return dest


# -----------------------------------------------------------------------------
# library
# -----------------------------------------------------------------------------

def test_recorder_api_round_trip(tmp_path):
    v = default_vessel()
    out = tmp_path / "api.mcap"
    with Recorder(out, vessel=v, flush_s=0.1) as rec:
        rec.thrust(0.2, -0.1, unit="normalized", t_ns=T0, stamp_ns=T0 - 5)
        rec.gnss(59.5, 10.25, alt_m=3.0, t_ns=T0 + 10, stamp_ns=T0 + 3, cov=(0.04, 0.09, 0.25))
        rec.gnss(59.6, 10.35, t_ns=T0 + 20)
        rec.heading(math.radians(350.0), reference="magnetic", t_ns=T0 + 30, std_rad=0.01)
        rec.thrust(12.0, 10.5, t_ns=T0 + 40)
        rec.event("start of the zig-zag", t_ns=T0 + 50)
    log = read_log(out)
    assert log.recovery is None
    assert log.vessel == v
    assert log.datum == Datum(lat_deg=59.5, lon_deg=10.25, alt_m=3.0)          # the first fix
    fix = log["/gnss/fix"]
    assert fix.index.tolist() == [T0 + 10, T0 + 20] and fix.stamp_ns.tolist() == [T0 + 3, T0 + 20]
    assert fix.lat_deg.tolist() == [59.5, 59.6] and fix.lon_deg.tolist() == [10.25, 10.35]
    assert fix.cov_type.tolist() == [2, 0]
    first = fix.iloc[0]
    assert (first.cov_ee_m2, first.cov_nn_m2, first.cov_uu_m2, first.cov_en_m2) == (0.04, 0.09, 0.25, 0.0)
    assert math.isnan(fix.alt_m.iloc[1]) and fix.cov_ee_m2.iloc[1] == 0.0   # unknown: zeros, type 0
    hd = log["/compass/heading"]
    assert hd.heading_rad.iloc[0] == pytest.approx(math.radians(-10.0)) and hd.reference.iloc[0] == "magnetic"
    th = log["/thrust/command"]
    assert th.unit.tolist() == ["normalized", "newton"] and th.left.tolist() == [0.2, 12.0]
    assert math.isnan(th.thrust_left_n.iloc[0]) and th.thrust_right_n.iloc[1] == 10.5
    assert th.stamp_ns.tolist() == [T0 - 5, T0 + 40]
    assert log["/events"].text.tolist() == ["start of the zig-zag"]
    prov = log.provenance[0]
    assert prov["producer"] == "usvlog record" and prov["closed"] == "true"
    with pytest.raises(InputError, match="/thrust/command.*unit"):
        Recorder(tmp_path / "x.mcap").thrust(1, 1, unit="volts")


def test_recorded_file_is_standard_mcap_and_every_message_validates(tmp_path):
    import json

    import jsonschema
    from mcap.reader import make_reader

    from usvlog.log.channels import schema_by_name

    out = tmp_path / "v.mcap"
    with Recorder(out, vessel=default_vessel()) as rec:
        rec.nmea(with_checksum("GPRMC,120000.00,A,5954.000,N,01042.000,E,1.0,90.0,010625,,"), source="gnss")
        rec.nmea(with_checksum("GPGGA,120000.10,5954.001,N,01042.001,E,1,07,1.2,3.0,M,40.0,M,,"), source="gnss")
        rec.nmea(with_checksum("GPGGA,120000.20,,,,,0,00,,,M,,M,,"), source="gnss")
        rec.nmea("$GPGGA,broken*00", source="gnss")
        rec.nmea(with_checksum("HCHDG,98.3,1.5,E,,"), source="compass")
        rec.json_line('{"left": 1500, "right": 1600, "unit": "pwm_us"}', source="thrust")
        rec.json_line("not json", source="thrust")
        rec.event("note")
    counts = {}
    with open(out, "rb") as fh:
        reader = make_reader(fh)                 # the mcap library's own reader, through the summary
        for schema, channel, message in reader.iter_messages():
            jsonschema.Draft202012Validator(schema_by_name(schema.name)).validate(json.loads(message.data))
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
        assert len(reader.get_summary().chunk_indexes) >= 1
    assert counts == {"/gnss/fix": 2, "/gnss/quality": 2, "/raw/nmea": 5, "/compass/heading": 1,
                      "/thrust/command": 1, "/raw/json": 1, "/events": 1, "/recorder/status": 3}
    fix = read_log(out)["/gnss/fix"]             # RMC first (no altitude), then GGA (with it)
    assert math.isnan(fix.alt_m.iloc[0]) and fix.alt_m.iloc[1] == pytest.approx(43.0)


def _epoch_sentences(i: int, lat_gga: float, lat_rmc: float, gga: str = "ok") -> tuple[str, str]:
    """GGA and RMC of epoch ``i`` (10 Hz from T0, 2025-06-15T15:06:40Z); ``gga``: ok, corrupt or nofix."""
    from usvlog.io.nmea import format_deg_min

    hms = f"1506{40 + i // 10:02d}.{i % 10}0"
    la, lh = format_deg_min(lat_gga, True)
    lr, lhr = format_deg_min(lat_rmc, True)
    g = with_checksum(f"GPGGA,{hms},{la},{lh},01042.000000,E,1,07,1.2,3.0,M,40.0,M,,")
    if gga == "corrupt":
        g = g[:-2] + ("00" if g[-2:] != "00" else "01")
    elif gga == "nofix":
        g = with_checksum(f"GPGGA,{hms},,,,,0,00,,,M,,M,,")
    return g, with_checksum(f"GPRMC,{hms},A,{lr},{lhr},01042.000000,E,1.0,90.0,150625,,")


@pytest.mark.parametrize("gga_first", [True, False])
def test_epoch_with_a_bad_gga_keeps_the_rmc_fix(tmp_path, gga_first):
    """One fix per epoch from its best valid sentence: GGA, else RMC (the importer's rule too).

    RMC reports each position 1e-5 deg north of its GGA, so the values show which sentence
    gave the fix. Epoch 3's GGA is corrupt, epoch 6's says "no fix", the last epoch's is
    corrupt too (its RMC fix is written when the recorder closes)."""
    out = tmp_path / "fix.mcap"
    n, bad = 10, {3: "corrupt", 6: "nofix", 9: "corrupt"}
    lat = 59.9 + 1e-4 * np.arange(n)
    with Recorder(out, flush_s=60.0) as rec:     # no background flush: only the rule decides
        for i in range(n):
            gga, rmc = _epoch_sentences(i, lat[i], lat[i] + 1e-5, bad.get(i, "ok"))
            first, second = (gga, rmc) if gga_first else (rmc, gga)
            t = T0 + i * 100_000_000
            rec.nmea(first, source="gnss", t_ns=t)
            rec.nmea(second, source="gnss", t_ns=t + 5_000_000)
    fix = read_log(out)["/gnss/fix"]
    from_rmc = np.isin(np.arange(n), list(bad))
    assert len(fix) == n                         # every epoch has its fix, once
    np.testing.assert_allclose(fix.lat_deg, lat + np.where(from_rmc, 1e-5, 0.0), atol=1e-8, rtol=0)
    assert np.isnan(fix.alt_m.to_numpy()[from_rmc]).all()
    np.testing.assert_allclose(fix.alt_m.to_numpy()[~from_rmc], 43.0)
    # the receive time of the sentence that gave the fix; the GPS time of its epoch
    t_gga = T0 + np.arange(n) * 100_000_000 + (0 if gga_first else 5_000_000)
    t_rmc = T0 + np.arange(n) * 100_000_000 + (5_000_000 if gga_first else 0)
    np.testing.assert_array_equal(fix.index.to_numpy(), np.where(from_rmc, t_rmc, t_gga))
    np.testing.assert_array_equal(fix.stamp_ns.to_numpy(), T0 + np.arange(n) * 100_000_000)


def test_held_rmc_fix_is_written_by_the_background_flush(tmp_path):
    out = tmp_path / "held.mcap"
    rec = Recorder(out, flush_s=0.1)
    try:
        for i, gga in enumerate(("ok", "corrupt")):
            g, r = _epoch_sentences(i, 59.9, 59.9 + 1e-5, gga)
            rec.nmea(g, source="gnss")
            rec.nmea(r, source="gnss")
        time.sleep(0.6)                          # > the epoch burst (0.25 s) + 2 flush intervals
        snap = read_log(_snapshot(out, tmp_path / "s.mcap"))
    finally:
        rec.close()
    np.testing.assert_allclose(snap["/gnss/fix"].lat_deg, [59.9, 59.9 + 1e-5], atol=1e-9, rtol=0)


def test_flushed_chunks_and_datum_survive_a_kill(tmp_path):
    out = tmp_path / "k.mcap"
    rec = Recorder(out, flush_s=60.0)          # only explicit flushes here
    for i in range(100):
        rec.thrust(float(i), -float(i), t_ns=T0 + i * 10**7)
    rec.gnss(60.0, 5.0, alt_m=1.0, t_ns=T0 + 10**9)   # the datum: written and fsynced at once
    rec.flush()
    for i in range(100, 150):                    # still in the open chunk (memory only)
        rec.thrust(float(i), -float(i), t_ns=T0 + i * 10**7)
    cut = read_log(_snapshot(out, tmp_path / "cut.mcap"))
    assert cut.recovery is not None              # no summary, no footer: recovered
    assert cut["/thrust/command"].left.tolist() == [float(i) for i in range(100)]
    assert cut.datum == Datum(lat_deg=60.0, lon_deg=5.0, alt_m=1.0)
    assert cut.provenance[0]["producer"] == "usvlog record"
    # cut the file in the middle of the last chunk as well: the complete chunks load
    data = out.read_bytes()
    (tmp_path / "half.mcap").write_bytes(data[:len(data) - 40])
    half = read_log(tmp_path / "half.mcap")
    assert half["/thrust/command"].left.tolist() == [float(i) for i in range(len(half["/thrust/command"]))]
    rec.close()
    assert read_log(out)["/thrust/command"].left.tolist() == [float(i) for i in range(150)]


def test_background_flush_bounds_the_loss(tmp_path):
    out = tmp_path / "b.mcap"
    rec = Recorder(out, flush_s=0.1)
    rec.thrust(1.0, 2.0)
    time.sleep(0.35)                             # > 2 flush intervals, no explicit flush
    snap = read_log(_snapshot(out, tmp_path / "s.mcap"))
    rec.close()
    assert snap["/thrust/command"].left.tolist() == [1.0]
    assert len(snap["/recorder/status"]) >= 1


def test_rotation_consecutive_files_load_as_one_run(tmp_path):
    out = tmp_path / "run.mcap"
    rec = Recorder(out, flush_s=0.05, rotate_mb=0.004)
    n = 0
    t_end = time.monotonic() + 1.0
    while time.monotonic() < t_end:
        for _ in range(20):
            rec.thrust(float(n), float(n % 7))
            n += 1
        rec.gnss(59.0 + n * 1e-6, 10.0) if n % 100 == 0 else None
        time.sleep(0.01)
    rec.close()
    paths = rec.paths
    assert len(paths) >= 3
    assert [p.name for p in paths] == [f"run_{k:03d}.mcap" for k in range(len(paths))]
    assert all(read_log(p).recovery is None for p in paths)
    # given in any order, the parts are put back in order and loaded as one run
    log = read_logs(list(reversed(paths)))
    assert usvlog.load(paths).equals(log)
    th = log["/thrust/command"]
    assert th.left.tolist() == [float(i) for i in range(n)]
    assert th.index.is_monotonic_increasing
    assert log.datum is not None and log.datum.lat_deg == pytest.approx(59.0001)
    with pytest.raises(InputError, match="missing"):
        read_logs([paths[0], paths[2]])
    other = Recorder(tmp_path / "other.mcap")
    other.thrust(1, 1)
    other.close()
    with pytest.raises(InputError, match="different recordings"):
        read_logs([paths[0], tmp_path / "other.mcap"])


def test_rotation_by_time_and_existing_parts_refused(tmp_path):
    out = tmp_path / "t.mcap"
    rec = Recorder(out, flush_s=0.05, rotate_min=0.15 / 60)
    for i in range(40):
        rec.thrust(float(i), 0.0)
        time.sleep(0.01)
    rec.close()
    assert len(rec.paths) >= 2
    assert read_logs(rec.paths)["/thrust/command"].left.tolist() == [float(i) for i in range(40)]
    with pytest.raises(OutputExistsError, match="t_000.mcap"):
        Recorder(out, rotate_min=1.0)


def test_json_lines_garbage_is_counted_and_kept(tmp_path):
    out = tmp_path / "j.mcap"
    with Recorder(out) as rec:
        assert rec.json_line('{"left": 1.5, "right": -2, "unit": "pwm_us", "t": 1750000000.25}', source="thrust")
        assert rec.json_line('{"event": "engine start"}', source="thrust")
        assert rec.json_line('{"topic": "/compass/heading", "heading_rad": 0.5, "reference": "true", "std_rad": null}',
                             source="thrust")
        bad = ['{"left": 1', '[1, 2]', '{"speed": 3}', '{"left": 1, "right": 2, "unit": "volts"}',
               '{"topic": "/raw/nmea", "text": "x"}', '{"topic": "/compass/heading", "heading_rad": 0.5}']
        assert not any([rec.json_line(b, source="thrust") for b in bad])
        st = {s.name: s for s in rec.status().sources}["thrust"]
        assert (st.messages, st.garbage) == (9, 6)
    log = read_log(out)
    assert log["/thrust/command"].stamp_ns.tolist() == [1_750_000_000_250_000_000]
    assert log["/thrust/command"].unit.tolist() == ["pwm_us"]
    assert log["/events"].text.tolist() == ["engine start"]
    assert log["/compass/heading"].heading_rad.tolist() == [0.5]
    raw = log["/raw/json"]
    assert raw.text.tolist() == bad and not raw.valid.any() and (raw.error != "").all()


# -----------------------------------------------------------------------------
# live sources: serial (pty) GNSS, TCP compass, UDP thrust
# -----------------------------------------------------------------------------

def _live(tmp_path, duration_s):
    out = tmp_path / "live.mcap"
    srv = TcpServer()
    master, slave = os.openpty()
    port = free_udp_port()
    stop = threading.Event()
    result = {}

    def go():
        result["summary"] = record(out, gnss=f"serial://{os.ttyname(slave)}?baud=115200",
                                   compass=f"tcp://127.0.0.1:{srv.port}", thrust=f"udp://127.0.0.1:{port}",
                                   stop=stop, flush_s=0.5)

    th = threading.Thread(target=go)
    th.start()
    try:
        assert srv.connected.wait(10), "recorder did not connect to the TCP compass"
        wait_for(lambda: out.exists(), 10, "the output file")
        boat = LoopbackBoat(gnss=lambda b: os.write(master, b), compass=srv.send,
                            thrust=udp_target(("127.0.0.1", port)), gps_lag_s=0.3, garbage_every=10)
        sent = boat.run(duration_s)
        time.sleep(0.4)
    finally:
        stop.set()
        th.join(15)
        srv.close()
        os.close(master)
        os.close(slave)
    return read_log(out), sent, result["summary"]


def check_live(log, sent, summary, duration_s):
    assert log.recovery is None and summary.stopped_by == "stop"
    # every message sent is in the log, in order, with its values
    fix = log["/gnss/fix"]
    assert len(fix) == len(sent.fixes) >= int(duration_s * 10) - 1
    assert np.abs(fix.lat_deg.to_numpy() - [f[2] for f in sent.fixes]).max() < 1e-7   # 6 decimals of minutes
    assert np.abs(fix.lon_deg.to_numpy() - [f[3] for f in sent.fixes]).max() < 1e-7
    assert np.abs(fix.alt_m.to_numpy() - [f[4] for f in sent.fixes]).max() < 1e-9
    assert fix.stamp_ns.tolist() == [f[1] for f in sent.fixes]                            # GPS time, ms
    hd = log["/compass/heading"]
    assert len(hd) == len(sent.headings)
    assert np.abs(ssa(hd.heading_rad.to_numpy() - np.radians([h[1] for h in sent.headings]))).max() < 1e-9
    th = log["/thrust/command"]
    assert th.left.tolist() == [x[1] for x in sent.thrust] and th.right.tolist() == [x[2] for x in sent.thrust]
    assert np.abs(th.stamp_ns.to_numpy() - [x[0] for x in sent.thrust]).max() <= 1000    # sender time kept
    # rates, from receive times
    for frame, hz in ((fix, 10.0), (hd, 20.0), (th, 100.0)):
        dt_s = np.diff(frame.index.to_numpy()) / 1e9
        assert np.median(dt_s) == pytest.approx(1 / hz, rel=0.15)
        assert (len(frame) - 1) / (dt_s.sum()) == pytest.approx(hz, rel=0.05)
    # malformed sentences: counted and kept raw; good ones too (GGA + RMC per epoch)
    raw = log["/raw/nmea"]
    gnss_raw = raw[raw.source == "gnss"]
    assert sorted(gnss_raw.text[~gnss_raw.valid].tolist()) == sorted(sent.garbage)
    assert int(gnss_raw.valid.sum()) == 2 * len(sent.fixes)
    assert (gnss_raw.error[~gnss_raw.valid].str.contains("checksum")).all()
    gn = {s.name: s for s in summary.status.sources}
    assert gn["gnss"].garbage == len(sent.garbage) and gn["compass"].garbage == 0
    assert len(log["/gnss/quality"]) == len(sent.fixes) and (log["/gnss/quality"].satellites == 9).all()
    # the GPS clock runs 0.3 s behind the sender's: the offset estimate finds it
    offsets = __import__("json").loads(log.provenance[0]["clock_offsets"])
    assert offsets["gnss"]["offset_ns"] / 1e9 == pytest.approx(0.3, abs=0.05)
    assert abs(offsets["thrust"]["offset_ns"]) / 1e9 < 0.05
    assert log.datum.lat_deg == pytest.approx(sent.fixes[0][2], abs=1e-7)
    assert log.datum.lon_deg == pytest.approx(sent.fixes[0][3], abs=1e-7)
    assert log.datum.alt_m == pytest.approx(sent.fixes[0][4])


def test_live_serial_tcp_udp_5s(tmp_path):
    log, sent, summary = _live(tmp_path, 5.0)
    check_live(log, sent, summary, 5.0)


@pytest.mark.slow   # a 30 s real-time soak; the 5 s run above checks the same in CI
def test_live_serial_tcp_udp_30s(tmp_path):
    log, sent, summary = _live(tmp_path, 30.0)
    check_live(log, sent, summary, 30.0)


# -----------------------------------------------------------------------------
# the CLI in a subprocess: kill -9, SIGTERM/SIGINT, disk full
# -----------------------------------------------------------------------------

def _start_cli(out: Path, ports, extra=(), preexec_fn=None):
    cmd = [sys.executable, "-m", "usvlog", "record", "--out", str(out),
           "--gnss", f"udp://127.0.0.1:{ports[0]}", "--compass", f"udp://127.0.0.1:{ports[0]}",
           "--thrust", f"udp://127.0.0.1:{ports[1]}", *extra]
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=preexec_fn)
    try:
        wait_for(lambda: out.exists() or proc.poll() is not None, 30, "the recorder to start")
    except AssertionError:
        proc.kill()
        raise
    return proc


def _stream(ports, seconds, **kw):
    boat = LoopbackBoat(gnss=udp_target(("127.0.0.1", ports[0])), compass=udp_target(("127.0.0.1", ports[0])),
                        thrust=udp_target(("127.0.0.1", ports[1])), **kw)
    return boat.run(seconds)


def check_kill_after(tmp_path, n_s):
    out = tmp_path / "killed.mcap"
    vt = tmp_path / "boat.toml"
    vt.write_text(default_vessel().to_toml())
    ports = (free_udp_port(), free_udp_port())
    proc = _start_cli(out, ports, ["--vessel", str(vt)])
    sent = _stream(ports, n_s)
    proc.send_signal(signal.SIGKILL)
    proc.wait(10)
    assert proc.returncode == -signal.SIGKILL
    log = read_log(out)
    assert log.recovery is not None                       # no footer: recovered
    assert log.vessel == default_vessel() and log.datum is not None
    assert log.datum.lat_deg == pytest.approx(sent.fixes[0][2], abs=1e-7)
    offsets = __import__("json").loads(log.provenance[0]["clock_offsets"])   # known, though never closed
    assert abs(offsets["gnss+compass"]["offset_ns"]) < 0.1e9 and offsets["gnss+compass"]["samples"] > 0
    for topic, hz, n_sent in (("/gnss/fix", 10, len(sent.fixes)), ("/compass/heading", 20, len(sent.headings)),
                              ("/thrust/command", 100, len(sent.thrust))):
        f = log[topic]
        span = (f.index[-1] - f.index[0]) / 1e9
        assert span >= n_s - 1.0 - 1.0 / hz, (topic, span)   # at most the last second lost
        assert (n_s - 1.0) * hz - 1 <= len(f) <= n_sent
    th = log["/thrust/command"]
    assert th.left.tolist() == [x[1] for x in sent.thrust[:len(th)]]   # a prefix of what was sent


def test_sigkill_loses_at_most_the_last_second(tmp_path):
    check_kill_after(tmp_path, 4.0)


def test_sigkill_after_20s_holds_19s(tmp_path):
    check_kill_after(tmp_path, 20.0)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_signal_finishes_the_file_cleanly(tmp_path, sig):
    out = tmp_path / "clean.mcap"
    ports = (free_udp_port(), free_udp_port())
    proc = _start_cli(out, ports, ["--json"])
    sent = _stream(ports, 1.5)
    time.sleep(0.2)
    proc.send_signal(sig)
    stdout, stderr = proc.communicate(timeout=20)
    assert proc.returncode == 0, stderr
    log = read_log(out, strict=True)                       # complete file: summary and footer
    assert log.provenance[0]["closed"] == "true"
    assert len(log["/thrust/command"]) == len(sent.thrust)
    assert len(log["/gnss/fix"]) == len(sent.fixes)
    summary = __import__("json").loads(stdout)
    assert summary["stopped_by"] == "stop" and summary["files"] == [str(out)]


def test_unwritable_output_exits_2_with_one_line(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    port = free_udp_port()
    for out, msg in ((blocker / "run.mcap", "does not exist"), ("/proc/run.mcap", "cannot create output"),
                     (blocker, "output exists")):
        rc = cli_main(["record", "--out", str(out), "--gnss", f"udp://127.0.0.1:{port}", "--duration-s", "1"])
        err = capsys.readouterr().err
        assert rc == 2 and err.count("\n") == 1 and msg in err, err
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as busy:     # another program has the port
        busy.bind(("127.0.0.1", 0))
        rc = cli_main(["record", "--out", str(tmp_path / "r.mcap"), "--gnss", f"udp://127.0.0.1:{busy.getsockname()[1]}"])
    err = capsys.readouterr().err
    assert rc == 2 and "cannot listen" in err and err.count("\n") == 1
    rc = cli_main(["record", "--out", str(tmp_path / "r.mcap"), "--gnss", "ftp://x:1"])
    err = capsys.readouterr().err
    assert rc == 2 and "unsupported scheme" in err and err.count("\n") == 1
    assert not (tmp_path / "r.mcap").exists()              # nothing created for a bad source


def _limit_file_size():
    import resource

    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)          # writes past the limit fail with EFBIG
    resource.setrlimit(resource.RLIMIT_FSIZE, (60_000, 60_000))


def test_disk_full_stops_with_one_line_and_keeps_what_was_written(tmp_path):
    out = tmp_path / "full.mcap"
    ports = (free_udp_port(), free_udp_port())
    proc = _start_cli(out, ports, ["--flush-s", "0.2"], preexec_fn=_limit_file_size)
    stop = threading.Event()
    boat = LoopbackBoat(gnss=udp_target(("127.0.0.1", ports[0])), thrust=udp_target(("127.0.0.1", ports[1])),
                        thrust_hz=1000.0)
    th = threading.Thread(target=boat.run, args=(20.0, stop))
    th.start()
    try:
        _, stderr = proc.communicate(timeout=30)
    finally:
        stop.set()
        th.join()
    lines = [ln for ln in stderr.splitlines() if "error" in ln]
    assert proc.returncode == 2, stderr
    assert len(lines) == 1 and "file too large" in lines[0] and str(out) in lines[0], stderr
    log = read_log(out)
    assert log.recovery is not None and len(log["/thrust/command"]) > 100
    left = log["/thrust/command"].left.to_numpy()
    assert np.isfinite(left).all()


def test_tcp_source_reconnects_after_the_link_drops(tmp_path):
    from usvlog.io.record import Source, parse_source

    server = socket.create_server(("127.0.0.1", 0))
    server.settimeout(10)
    rec = Recorder(tmp_path / "tcp.mcap", flush_s=0.1)
    src = Source("compass", parse_source(f"tcp://127.0.0.1:{server.getsockname()[1]}"), rec, "nmea")
    src.start()
    sent = []
    for link in range(2):                       # the cable is pulled after the first 5 headings
        conn, _ = server.accept()
        for i in range(5):
            h = 10.0 * (5 * link + i)
            sent.append(h)
            conn.sendall((with_checksum(f"HEHDT,{h:.1f},T") + "\r\n").encode())
        time.sleep(0.2)
        conn.close()
    wait_for(lambda: src.reconnects >= 2, 10, "the source to notice the second drop")
    src.stop()
    src.join(5)
    server.close()
    rec.close()
    log = read_log(tmp_path / "tcp.mcap")
    assert np.allclose(log["/compass/heading"].heading_rad, ssa(np.radians(sent)))
    ev = log["/events"].text.tolist()
    assert sum("connected" in e for e in ev) >= 2 and sum("reconnecting" in e for e in ev) == 2


# -----------------------------------------------------------------------------
# start-up: the loopback recipe of docs/recording.md, sender started without waiting
# -----------------------------------------------------------------------------

def _recipe(tmp_path, duration_s: float, gnss_hz: float):
    """``usvlog record ... &`` then at once the loopback boat, both as subprocesses (docs/recording.md
    "Recording live"); the boat does not wait for the recorder to be ready."""
    out = tmp_path / "run.mcap"
    p_nmea, p_json = free_udp_port(), free_udp_port()
    gnss, thrust = f"udp://127.0.0.1:{p_nmea}", f"udp://127.0.0.1:{p_json}"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    rec = subprocess.Popen([sys.executable, "-m", "usvlog", "record", "--out", str(out), "--gnss", gnss,
                            "--compass", gnss, "--thrust", thrust, "--duration-s", str(duration_s + 4)],
                           cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        boat = subprocess.run([sys.executable, "-m", "usvlog.io.record.loopback", "--gnss", gnss, "--compass", gnss,
                               "--thrust", thrust, "--duration-s", str(duration_s), "--gnss-hz", str(gnss_hz)],
                              cwd=ROOT, env=env, capture_output=True, text=True, timeout=duration_s + 60)
        _, err = rec.communicate(timeout=60)
    finally:
        if rec.poll() is None:
            rec.kill()
            rec.wait(10)
    assert rec.returncode == 0, err
    assert boat.returncode == 0, boat.stderr
    m = re.search(r"sent (\d+) fixes \(GGA\+RMC\), (\d+) headings, (\d+) thrust", boat.stdout)
    assert m is not None, boat.stdout
    sent = [int(x) for x in m.groups()]
    return read_log(out), sent


def _recipe_figures(log, sent) -> dict:
    """What the recipe's log kept of what the boat sent, and how late the first thrust
    receive times are (receive minus send time over the first 0.5 s of thrust, ms)."""
    th = log["/thrust/command"]
    late_ms = (th.index.to_numpy()[:50] - th.stamp_ns.to_numpy()[:50]) / 1e6
    return {"damaged": log.recovery is not None, "fixes_sent": sent[0], "fixes_kept": len(log["/gnss/fix"]),
            "thrust_sent": sent[2], "thrust_kept": len(th),
            "late_ms_median": float(np.median(late_ms)), "late_ms_min": float(late_ms.min())}


@pytest.mark.slow   # timing of three processes starting at once: kept out of the parallel suite, where the
#                    campaign's Dask workers load the 2 cores (294-297 of 300 kept at load 10+)
def test_loopback_recipe_started_at_once_keeps_299_of_300_fixes(tmp_path):
    fig = _recipe_figures(*_recipe(tmp_path, 6.0, 50.0))   # 300 fixes in 6 s: the start-up is the hard part
    assert not fig["damaged"] and fig["fixes_sent"] == 300
    assert fig["fixes_kept"] >= 299, fig                          # the target: >= 299 of 300
    assert fig["thrust_kept"] >= fig["thrust_sent"] - 10, fig      # < 0.1 s of thrust lost at the very start
    # what arrived while the recorder was importing is stamped when it arrived, not late
    assert fig["late_ms_median"] < 10.0 and fig["late_ms_min"] > -1.0, fig


@pytest.mark.slow
def test_readme_loopback_recipe_30s(tmp_path):
    fig = _recipe_figures(*_recipe(tmp_path, 30.0, 10.0))  # exactly the recipe's: 300 fixes at 10 Hz
    assert not fig["damaged"] and fig["fixes_sent"] == 300
    assert fig["fixes_kept"] >= 299, fig
    assert fig["thrust_kept"] >= fig["thrust_sent"] - 10, fig
    assert fig["late_ms_median"] < 10.0 and fig["late_ms_min"] > -1.0, fig


def test_sources_module_opens_sockets_with_the_standard_library_only():
    code = ("import sys, usvlog.io.record.sources as s; src = s.open_sources(thrust='udp://127.0.0.1:0'); "
            "[x.close() for x in src]; "
            "print(sorted({m.split('.')[0] for m in sys.modules} & {'numpy', 'pandas', 'numba', 'mcap', 'orjson'}))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT,
                       env=dict(os.environ, PYTHONPATH=str(ROOT)))
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "[]"


def test_backlog_read_before_attach_keeps_read_times_and_order(tmp_path):
    """A started source with no recorder yet keeps what it reads; attached, it hands it over in
    order, stamped with the time each datagram arrived, not when the recorder got it."""
    from usvlog.io.record.sources import open_sources, shutdown

    src = open_sources(thrust="udp://127.0.0.1:0")
    send = udp_target(src[0].address)
    src[0].start()
    sent_ns = []
    for k in range(20):
        sent_ns.append(time.time_ns())
        send(b'{"left": %d, "right": 0}\n' % k)
    time.sleep(0.5)                              # the recorder "imports": nothing attached yet
    out = tmp_path / "b.mcap"
    try:
        with Recorder(out, clock=src[0].opened_ns) as rec:
            src[0].attach(rec)
            wait_for(lambda: rec.status().messages_written >= 20, 5, "the backlog to be written")
            shutdown(src)
    finally:
        shutdown(src)
    th = read_log(out)["/thrust/command"]
    assert th.left.tolist() == list(range(20))
    late_ms = (th.index.to_numpy() - np.array(sent_ns)) / 1e6
    assert late_ms.max() < 100.0 and late_ms.min() > -1.0     # not the 500 ms the recorder was away


_PROBE_BIND_ORDER = r"""
import socket, sys, threading
port = int(sys.argv[1])
seen = {}

class Probe:
    def find_spec(self, name, path=None, target=None):
        if name == "numpy" and "numpy" not in seen:
            s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            try:
                s.bind(("127.0.0.1", port))
                seen["numpy"] = "port free"
            except OSError:
                seen["numpy"] = "port bound"
            finally:
                s.close()
            seen["readers"] = sorted(t.name for t in threading.enumerate() if t.name.startswith("usvlog-source"))
        return None

sys.meta_path.insert(0, Probe())
from usvlog.cli import main
rc = main(["record", "--out", sys.argv[2], "--thrust", f"udp://127.0.0.1:{port}", "--duration-s", "0.3"])
print(seen, rc)
"""


def test_record_binds_and_reads_its_sockets_before_numpy_is_imported(tmp_path):
    """When ``usvlog record`` first imports numpy its UDP port is already bound and its reader
    thread running (checked from an import hook, deterministically)."""
    port = free_udp_port()
    r = subprocess.run([sys.executable, "-c", _PROBE_BIND_ORDER, str(port), str(tmp_path / "p.mcap")],
                       capture_output=True, text=True, cwd=ROOT, env=dict(os.environ, PYTHONPATH=str(ROOT)),
                       timeout=60)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "{'numpy': 'port bound', 'readers': ['usvlog-source-thrust']} 0"
