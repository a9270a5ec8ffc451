"""Import speed and memory: CSV rows/s and NMEA lines/s of a 1-hour log, peak RSS.

The default files are one hour long: a 100 Hz merged-logger CSV (360,000 rows) and an
NMEA capture at 40 lines/s (144,000 lines: GGA, RMC and two HDT per 0.1 s, epoch-seconds
prefixes). ``--scales 1,10`` adds files 10x as long (memory should stay flat).

Each measurement runs in its own Python process (peak RSS = that process's ru_maxrss),
so the sizes do not share memory. Figures per file:

* ``parse``: reading + mapping + validating into canonical frames (the importer itself,
  timed inside the process after its imports; for NMEA this includes numba's import and
  the load of the cached kernels, ~0.7 CPU s, which an import to MCAP pays anyway for the
  writer's kernels);
* ``parse-py``: the same through the per-line Python NMEA parser (the reference the
  compiled one is tested against), for comparison;
* ``to mcap``: the same, streamed into an MCAP file (JSON encoding + mcap writer included),
  as ``usvlog import`` does, timed inside the process;
* ``cli``: ``python -m usvlog import SRC --out OUT`` end to end, start-up (imports, numba
  cache load) included: wall time from spawning the process to its exit;
* ``cli-tiny``: the same on the first 1,000 lines of the file: the fixed cost of one import
  (interpreter, imports, numba's load, the MCAP writer's set-up) that a file of any length
  pays; the line after it gives the rate of the rest (``records beyond the tiny file`` per
  extra CPU second).

``--stages`` adds, per file, the CPU seconds of each stage of one import in one process
(interpreter start-up, the imports ``usvlog import`` does, numba's import, the source
read, the assembly into canonical frames (audit included), the MCAP writing, the source's
sha256), which is where the end-to-end figure goes.

Records/s is given per wall-clock second and per CPU second of the process (the second
is the fairer figure on a machine shared with other work).

Start-up depends on whether usvlog's modules have bytecode caches (``__pycache__``): an
installed package has them, a checkout run with ``PYTHONDONTWRITEBYTECODE=1`` compiles every
usvlog module it imports from source in every process (~0.1-0.2 CPU s of each import's
start-up). The first line says which; ``--compile`` writes them first (``compileall``), as
an installation does.

Run:  python benchmarks/bench_import.py [--rows 360000] [--lines 144000] [--scales 1,10] [--stages] [--compile]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

import numpy as np
from _proc import timed_run  # noqa: E402  (benchmarks/ is the script's directory)

ROOT = Path(__file__).resolve().parents[1]
T0_S = 1_714_557_600.0


def make_csv(path: Path, rows: int) -> None:
    """100 Hz merged-logger rows: thrust every row, heading every 5th, lat/lon every 10th."""
    with open(path, "w") as fh:
        fh.write("time,lat,lon,heading,left,right\n")
        step = 100_000
        for a in range(0, rows, step):
            k = np.arange(a, min(rows, a + step))
            t = T0_S + 0.01 * k
            lat = np.char.mod("%.8f", 59.1 + 1e-7 * k)
            lon = np.char.mod("%.8f", 10.2 + 1e-7 * k)
            hd = np.char.mod("%.3f", (0.01 * k) % 360)
            lat = np.where(k % 10 == 0, lat, "")
            lon = np.where(k % 10 == 0, lon, "")
            hd = np.where(k % 5 == 0, hd, "")
            left = np.char.mod("%d", 1500 + k % 300)
            right = np.char.mod("%d", 1500 - k % 300)
            tt = np.char.mod("%.2f", t)
            lines = [",".join(r) for r in zip(tt, lat, lon, hd, left, right)]
            fh.write("\n".join(lines) + "\n")


def _cs(body: str) -> str:
    c = 0
    for ch in body:
        c ^= ord(ch)
    return f"${body}*{c:02X}"


def make_nmea(path: Path, lines: int) -> None:
    """10 Hz GGA + 20 Hz HDT with an epoch-seconds prefix (4 lines per 0.1 s: GGA, RMC, 2x HDT)."""
    with open(path, "w") as fh:
        out = []
        for i in range(lines // 4):
            t = T0_S + 0.1 * i
            s = int(t) % 86400
            hms = f"{s // 3600:02d}{s // 60 % 60:02d}{s % 60:02d}.{int(round((t % 1) * 100)) % 100:02d}"
            lat = f"5906.{i % 10000:04d}000"
            out.append(f"{t:.2f} " + _cs(f"GPGGA,{hms},{lat},N,01012.0000000,E,1,10,0.8,5.0,M,20.0,M,,"))
            out.append(f"{t:.2f} " + _cs(f"GPRMC,{hms},A,{lat},N,01012.0000000,E,3.9,90.0,010524,,,A"))
            out.append(f"{t + 0.02:.2f} " + _cs(f"HEHDT,{(i * 0.1) % 360:.2f},T"))
            out.append(f"{t + 0.07:.2f} " + _cs(f"HEHDT,{(i * 0.1 + 0.05) % 360:.2f},T"))
            if len(out) >= 40_000:
                fh.write("\n".join(out) + "\n")
                out = []
        if out:
            fh.write("\n".join(out) + "\n")


CHILD = textwrap.dedent("""
    import json, resource, sys, time
    sys.path.insert(0, {root!r})
    from usvlog.io.importers import import_file, ImportOptions, ImportReport
    from usvlog.io.importers.core import Assembler
    import importlib
    src, mode, out = sys.argv[1], sys.argv[2], sys.argv[3]
    t0 = time.perf_counter()
    c0 = time.process_time()
    if mode in ("parse", "parse-py"):
        from usvlog.io.importers import detect_format, _MODULES
        fmt = detect_format(src)
        mod = importlib.import_module("usvlog.io.importers." + _MODULES[fmt])
        rep = ImportReport()
        asm = Assembler(rep)
        n_out = 0
        kw = {{"fast": False}} if mode == "parse-py" else {{}}
        for batch in mod.read(__import__("pathlib").Path(src), ImportOptions(), rep, fmt=fmt, **kw):
            n_out += sum(len(f) for f in asm.process(batch).values())
        n_out += sum(len(f) for f in asm.finish().values())
        records = rep.records
    else:
        res = import_file(src, out=out, force=True)
        records = res.report.records
        n_out = sum(res.report.counts.values())
    dt = time.perf_counter() - t0
    cpu = time.process_time() - c0
    print(json.dumps({{"records": records, "samples": n_out, "seconds": dt, "cpu_seconds": cpu,
                      "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}}))
""").format(root=str(ROOT))


STAGES = textwrap.dedent("""
    import time
    c = time.process_time
    marks = [("start-up", c())]
    import importlib, json, sys
    sys.path.insert(0, {root!r})
    from pathlib import Path
    import usvlog.api  # noqa: F401  (what the import verb imports)
    from usvlog.io.importers import ImportOptions, ImportReport, detect_format, file_identity, _MODULES
    from usvlog.io.importers.core import Assembler
    from usvlog.io.importers.sink import McapSink
    src = Path(sys.argv[1])
    fmt = detect_format(src)
    mod = importlib.import_module("usvlog.io.importers." + _MODULES[fmt])
    marks.append(("imports", c()))
    import numba  # noqa: F401  (loaded by the first compiled kernel: the reader's or the MCAP writer's)
    marks.append(("numba import", c()))
    rep = ImportReport()
    asm = Assembler(rep)
    t = dict(read=0.0, assemble=0.0, write=0.0)
    with open(sys.argv[2], "wb") as fh:
        a = c()
        sink = McapSink(fh)
        t["write"] += c() - a
        it = mod.read(src, ImportOptions(), rep, fmt=fmt)
        while True:
            a = c()
            batch = next(it, None)
            b = c()
            t["read"] += b - a
            if batch is None:
                break
            frames = asm.process(batch)
            a = c()
            t["assemble"] += a - b
            sink.write(frames)
            t["write"] += c() - a
        a = c()
        frames = asm.finish()
        b = c()
        sink.write(frames)
        sink.finish({{}})
        t["assemble"] += b - a
        t["write"] += c() - b
    a = c()
    file_identity(src)
    t["sha256"] = c() - a
    out = {{k: v - marks[i - 1][1] if i else v for i, (k, v) in enumerate(marks)}}
    out.update(t)
    out["records"] = rep.records
    print(json.dumps(out))
""").format(root=str(ROOT))


def measure_stages(src: Path, out: Path) -> dict:
    """CPU seconds per stage of one import in a fresh process (see the module docstring)."""
    r = subprocess.run([sys.executable, "-c", STAGES, str(src), str(out)], capture_output=True, text=True)
    if r.returncode != 0:
        raise SystemExit(r.stderr)
    return json.loads(r.stdout.strip().splitlines()[-1])


def head_lines(src: Path, dst: Path, n: int) -> None:
    """The first ``n`` lines of ``src`` into ``dst``."""
    with open(src, "rb") as fi, open(dst, "wb") as fo:
        for i, line in enumerate(fi):
            if i >= n:
                break
            fo.write(line)


def measure(src: Path, mode: str, out: Path) -> dict:
    if mode == "cli":
        return measure_cli(src, out)
    r = subprocess.run([sys.executable, "-c", CHILD, str(src), mode, str(out)], capture_output=True, text=True)
    if r.returncode != 0:
        raise SystemExit(r.stderr)
    return json.loads(r.stdout.strip().splitlines()[-1])


def measure_cli(src: Path, out: Path) -> dict:
    """``usvlog import`` as a user runs it: wall from spawn to exit, the child's CPU and peak RSS."""
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    r = timed_run([sys.executable, "-m", "usvlog", "import", str(src), "--out", str(out), "--force", "--json"], env)
    if r.returncode != 0:
        raise SystemExit(r.stderr.decode(errors="replace"))
    rep = json.loads(r.stdout)
    return {"records": rep["records"], "samples": sum(rep["channels"].values()), "seconds": r.wall_s,
            "cpu_seconds": r.cpu_s, "peak_rss_mb": r.peak_rss_mb}


def bytecode_status() -> tuple[int, int]:
    """(usvlog modules with an up-to-date bytecode cache, usvlog modules) in this checkout."""
    import importlib.util

    have = total = 0
    for src in (ROOT / "usvlog").rglob("*.py"):
        total += 1
        pyc = Path(importlib.util.cache_from_source(str(src)))
        have += pyc.exists() and pyc.stat().st_mtime >= src.stat().st_mtime
    return have, total


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=360_000, help="CSV rows of the 1x file (1 hour at 100 Hz)")
    ap.add_argument("--lines", type=int, default=144_000, help="NMEA lines of the 1x file (1 hour at 40 lines/s)")
    ap.add_argument("--scales", default="1", help="file lengths to run, comma-separated multiples of 1x")
    ap.add_argument("--skip-mcap", action="store_true", help="only the parse figures")
    ap.add_argument("--stages", action="store_true", help="also the CPU seconds per stage of one import")
    ap.add_argument("--compile", action="store_true",
                    help="write usvlog's bytecode caches first (compileall), as an installed package has them")
    args = ap.parse_args()
    if args.compile:
        import compileall

        compileall.compile_dir(str(ROOT / "usvlog"), quiet=1)
    have, total = bytecode_status()
    try:
        load = " ".join(f"{x:.2f}" for x in os.getloadavg())
    except OSError:
        load = "?"
    print(f"load average {load}; usvlog bytecode cached for {have} of {total} modules"
          + ("" if have == total else " (the others are compiled from source in every process)"))
    with tempfile.TemporaryDirectory(prefix="usvlog-bench-") as d:
        d = Path(d)
        print(f"{'file':<20} {'MB':>6} {'records':>9} {'mode':>8} {'wall s':>7} {'records/s':>10} "
              f"{'CPU s':>7} {'rec/CPU-s':>10} {'peak RSS MB':>12}")
        for kind, n, make in (("csv", args.rows, make_csv), ("nmea", args.lines, make_nmea)):
            for scale in (int(x) for x in args.scales.split(",")):
                src = d / f"{kind}_{scale}x.{kind}"
                make(src, n * scale)
                mb = src.stat().st_size / 1e6
                modes = ("parse",) + (("parse-py",) if kind == "nmea" else ()) + \
                    (() if args.skip_mcap else ("to mcap", "cli"))
                for mode in modes:
                    m = measure(src, "mcap" if mode == "to mcap" else mode, d / "out.mcap")
                    row(src.name, mb, m, mode)
                if "cli" in modes:
                    tiny = d / f"{kind}_tiny.{kind}"
                    head_lines(src, tiny, 1000)
                    m0 = measure_cli(tiny, d / "out.mcap")
                    row(tiny.name, tiny.stat().st_size / 1e6, m0, "cli")
                    extra = m["records"] - m0["records"]
                    print(f"{'':<20} {'':>6} {extra:>9} {'cli-rest':>8} {m['seconds'] - m0['seconds']:>7.2f} "
                          f"{extra / max(1e-9, m['seconds'] - m0['seconds']):>10,.0f} "
                          f"{m['cpu_seconds'] - m0['cpu_seconds']:>7.2f} "
                          f"{extra / max(1e-9, m['cpu_seconds'] - m0['cpu_seconds']):>10,.0f}", flush=True)
                    tiny.unlink()
                if args.stages:
                    st = measure_stages(src, d / "out.mcap")
                    parts = {k: v for k, v in st.items() if k != "records"}
                    print(f"{'':<20} stages (CPU s): " + ", ".join(f"{k} {v:.2f}" for k, v in parts.items())
                          + f"; sum {sum(parts.values()):.2f}", flush=True)
                src.unlink()


def row(name: str, mb: float, m: dict, mode: str) -> None:
    """One line of the table."""
    print(f"{name:<20} {mb:>6.1f} {m['records']:>9} {mode:>8} {m['seconds']:>7.2f} "
          f"{m['records'] / m['seconds']:>10,.0f} {m['cpu_seconds']:>7.2f} "
          f"{m['records'] / m['cpu_seconds']:>10,.0f} {m['peak_rss_mb']:>12.0f}", flush=True)


if __name__ == "__main__":
    main()
