"""The compiled NMEA import against the per-line Python parser it speeds up (the reference).

Same samples (bit for bit), same lines counted and skipped with the same reasons and the
same first bad line, on the real logs and on generated ones that hold every kind of line
the importer meets: all sentence types, talkers, bad and lower-case checksums, missing
checksums, no-fix sentences, empty headings, unreadable and out-of-range fields, numbers
written as Python reads them but not plainly (`` 1.5``, ``+1``, ``1e1``, 16 digits), line
prefixes of every kind (epoch, relative, ISO with and without zone, broken), midnight
roll-overs, blank lines, CR LF, non-ASCII bytes.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from usvlog.io.importers import ImportOptions, nmea
from usvlog.io.importers.core import ImportReport
from usvlog.io.nmea import checksum

DATA = Path(__file__).parents[1] / "data"


def _read(path: Path, fast: bool, **kw):
    rep = ImportReport()
    parts: dict = {}
    for batch in nmea.read(path, ImportOptions(**kw), rep, fast=fast):
        for role, d in batch.items():
            parts.setdefault(role, []).append(d)
    out = {r: {k: np.concatenate([d[k] for d in ds]) for k in ds[0]} for r, ds in parts.items()}
    return out, rep


def _assert_same(path: Path, **kw):
    fast, rf = _read(path, True, **kw)
    ref, rr = _read(path, False, **kw)
    assert rf.records == rr.records
    assert dict(rf.skipped) == dict(rr.skipped)
    assert rf.first_bad == rr.first_bad
    assert rf.notes == rr.notes and rf.guesses == rr.guesses
    assert set(fast) == set(ref)
    for role in ref:
        for k, y in ref[role].items():
            x = fast[role][k]
            assert x.dtype == y.dtype, (role, k)
            if y.dtype.kind == "f":
                assert np.array_equal(x, y, equal_nan=True), (role, k, np.flatnonzero(x != y)[:5])
            else:
                assert np.array_equal(x, y), (role, k)
    return ref, rr


def _s(body: str, cs: str | None = "ok") -> str:
    if cs is None:
        return "$" + body
    return f"${body}*{checksum(body) if cs == 'ok' else cs}"


def _generated(rng: np.random.Generator, n_epochs: int, prefix: str, vtg: bool = True) -> str:
    """A receiver log: GGA/RMC/HDT(/VTG) epochs at 10 Hz across a midnight, with damage."""
    lines = []
    t = 86_400.0 - n_epochs * 0.05             # the epochs straddle midnight
    day = 19_000
    for i in range(n_epochs):
        t += 0.1
        tod = t % 86_400.0
        s = int(tod)
        hms = f"{s // 3600:02d}{s // 60 % 60:02d}{s % 60:02d}.{int(round((tod % 1) * 100)) % 100:02d}"
        d = day + int(t // 86_400)
        date = np.datetime64(d, "D").astype(object).strftime("%d%m%y")
        lat = f"{4700 + rng.uniform(0, 59.99):09.6f}"
        lon = f"{12200 + rng.uniform(0, 59.99):011.7f}"
        epoch_s = d * 86_400 + tod
        sents = [
            _s(f"GPGGA,{hms},{lat},N,{lon},W,{rng.choice([1, 1, 1, 2, 0])},12,0.9,8.378,M,-20.815,M,,"),
            _s(f"GNRMC,{hms},{rng.choice(['A', 'A', 'V'])},{lat},S,{lon},E,{rng.uniform(0, 9):.2f},"
               f"{rng.uniform(0, 360):.1f},{date},15.2,E,A"),
            _s(f"HEHDT,{rng.uniform(0, 360):.3f},T"),
        ]
        if vtg:
            sents.append(_s(f"GPVTG,{rng.uniform(0, 360):.1f},T,,M,{rng.uniform(0, 9):.3f},N,"
                            f"{rng.uniform(0, 20):.3f},K,A"))
        r = rng.uniform()
        if r < 0.02:
            sents[0] = sents[0][:-2] + "00"                                    # bad checksum
        elif r < 0.04:
            sents[1] = sents[1][:-2] + sents[1][-2:].lower()                   # lower-case checksum
        elif r < 0.05:
            sents[2] = sents[2].split("*")[0]                                  # no checksum
        elif r < 0.06:
            sents[2] = _s("GPHDT,,T")                                           # empty heading
        elif r < 0.07:
            sents[0] = _s(f"GPGGA,{hms},{lat},N,{lon},W,1,12, 0.9,8.378,M,,M,,")  # spaces: Python reads them
        elif r < 0.08:
            sents[0] = _s(f"GPGGA,{hms},{lat},X,{lon},W,1,12,0.9,8.378,M,,M,,")   # bad hemisphere
        elif r < 0.09 and vtg:
            sents[3] = _s("GPVTG,1e1,T,,M,+1.5,N,,K,A")                          # exponent, sign
        elif r < 0.10:
            sents[1] = _s(f"GPRMC,{hms},A,{lat},N,{lon},W,x,400.0,{date},,,A")    # bad speed/course kept as None
        elif r < 0.11:
            sents[2] = _s(f"HEHDT,{rng.uniform(0, 360):.16f},T")                # 16+ digits
        elif r < 0.12:
            sents.append(_s(f"GPGLL,{lat},N,{lon},W,{hms},A,A"))
        elif r < 0.13:
            sents.append(_s(f"GPZDA,{hms},{date[:2]},{date[2:4]},20{date[4:]},00,00"))
        elif r < 0.14:
            sents.append(_s(f"HCHDG,{rng.uniform(0, 360):.1f},1.5,E,3.0,W"))
            sents.append(_s(f"HCHDM,{rng.uniform(0, 360):.1f},M"))
        elif r < 0.15:
            sents.append(_s("GPGSA,A,3,04,05,,09,12,,,24,,,,,2.5,1.3,2.1"))
            sents.append(_s("PGRMZ,246,f,3"))
            sents.append("!AIVDM,1,1,,A,13aEOK?P00PD2wVMdLDRhgvL289?,0*26")
        elif r < 0.16:
            sents.append("some logger message without a sentence")
            sents.append("")
            sents.append("   ")
        elif r < 0.17:
            sents[0] = _s(f"GPGGA,{hms[:4]},{lat},N,{lon},W,1,12,0.9,8.378,M,-20.815,M,,")  # bad time
        elif r < 0.18:
            sents[1] = _s(f"GPRMC,{hms},A,{lat},N,{lon},W,1.0,90.0,310299,,,A")     # no such date
        elif r < 0.19:
            sents[0] = _s(f"GPGGA,{hms},9100.0000,N,{lon},W,1,12,0.9,8.378,M,-20.815,M,,")  # out of range
        elif r < 0.20:
            sents[2] = _s(f"HEHDT,{rng.uniform(0, 360):.2f},T") + " trailing"
        elif r < 0.21:
            sents[0] = "$$" + sents[0][1:]
        elif r < 0.22:
            sents[2] = _s(f"HEHDT,{rng.uniform(0, 360):.2f},T").replace("HDT", "HDT\xe9")
        for k, body in enumerate(sents):
            if prefix == "epoch":
                pre = f"{epoch_s + 0.001 * k:.3f} "
                if rng.uniform() < 0.01:
                    pre = rng.choice(["1e300 ", "-5 ", "12:30 ", "x ", "+1714557600.0 ", "[1714557600.5] "])
            elif prefix == "relative":
                pre = f"{i * 0.1 + 0.001 * k:.3f} "
                if rng.uniform() < 0.01:
                    pre = "1714557600.0 "                       # an epoch among relative ones
            elif prefix == "iso":
                ts = np.datetime64(int(round(epoch_s * 1000)), "ms").astype(object)
                pre = ts.strftime("%Y-%m-%d %H:%M:%S.%f")[:-3] + " | DEBUG | recv - "
            elif prefix == "isoz":
                ts = np.datetime64(int(round(epoch_s * 1000)), "ms").astype(object)
                pre = ts.strftime("%Y-%m-%dT%H:%M:%S.%f")[:-3] + "Z "
            else:
                pre = ""
            lines.append(pre + body if body.strip() else body)
    return "\r\n".join(lines[: len(lines) // 2]) + "\r\n" + "\n".join(lines[len(lines) // 2:]) + "\n"


@pytest.mark.parametrize("name", ["real/ardusub_nmea_log.txt", "sources/kingfisher.nmea"])
def test_fast_import_equals_reference_on_real_logs(name):
    ref, rep = _assert_same(DATA / name)
    assert rep.records > 200 and "gnss" in ref


@pytest.mark.parametrize("prefix,kw", [("", {}), ("epoch", {}), ("relative", {}), ("relative", {"prefix_time": "auto"}),
                                       ("iso", {}), ("iso", {"prefix_time": "auto"}), ("isoz", {}),
                                       ("epoch", {"prefix_time": "none"})])
def test_fast_import_equals_reference_on_generated_logs(tmp_path, prefix, kw):
    rng = np.random.default_rng(len(prefix) * 7 + len(kw))
    p = tmp_path / "gen.nmea"
    p.write_bytes(_generated(rng, 1500, prefix).encode("latin-1"))
    ref, rep = _assert_same(p, **kw)
    # the damage was there and was counted: the comparison covered the skip paths
    assert rep.skipped["nmea_bad_checksum"] > 0 and rep.skipped["gnss_no_fix"] > 0
    assert len(ref["gnss"]["t_ns"]) > 1000


@pytest.mark.parametrize("prefix", ["", "epoch"])
def test_fast_import_in_small_blocks_equals_reference(tmp_path, monkeypatch, prefix):
    """Blocks of a few lines: held fixes and untimed sentences carried from block to block."""
    monkeypatch.setattr(nmea, "_BLOCK_BYTES", 997)
    p = tmp_path / "gen.nmea"
    p.write_bytes(_generated(np.random.default_rng(5), 800, prefix).encode("latin-1"))
    ref, rep = _assert_same(p)
    assert rep.skipped["gnss_no_fix"] > 0 and len(ref["heading"]["t_ns"]) > 500


def test_fast_import_without_vtg_and_with_lone_cr(tmp_path):
    rng = np.random.default_rng(3)
    p = tmp_path / "rmc.nmea"
    p.write_text(_generated(rng, 600, "", vtg=False))
    ref, _ = _assert_same(p)
    assert len(ref["velocity"]["t_ns"]) > 100          # velocity from RMC
    q = tmp_path / "cr.nmea"
    q.write_bytes(p.read_bytes().replace(b"\r\n", b"\r"))   # old Mac line ends: the reference path
    _assert_same(q)
