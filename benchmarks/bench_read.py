"""Read speed: usvlog.read_log (every CRC checked) vs the mcap library's own loop, on a 1-hour log.

    python benchmarks/bench_read.py

The library loop is the fastest one the mcap library has: ``NonSeekingReader(f)
.iter_messages(log_time_order=False)`` (records in file order, no log-time sort) +
``orjson.loads`` per message (nothing else: no columns, no frames; it checks no CRC).
``make_reader(f).iter_messages()`` with its default log-time heap merge is printed too,
for reference only. Best of 3 each, ours and the library loop run in turn (so a change of
the machine's load weighs on both alike), wall and CPU time; ours is timed
after one warm-up load (numba compiles its loops once and caches them on disk).
``read_log`` checks every chunk's CRC and the data section CRC; the cost of that check
is timed on its own (the same CRC-32 calls over the same bytes) and printed.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time

import orjson
from _log import hour_file


def best_of(fn, n=3):
    best = float("inf")
    for _ in range(n):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out


def best_interleaved(fns, n=3):
    """Best wall and best CPU time (s) of each of ``fns``, run in turn n times (so a change
    of the machine's load weighs on all of them alike), and each one's last result."""
    wall = [float("inf")] * len(fns)
    cpu = [float("inf")] * len(fns)
    outs = [None] * len(fns)
    for _ in range(n):
        for i, fn in enumerate(fns):
            t, c = time.perf_counter(), time.process_time()
            outs[i] = fn()
            wall[i] = min(wall[i], time.perf_counter() - t)
            cpu[i] = min(cpu[i], time.process_time() - c)
    return wall, cpu, outs


def mcap_loop(path):
    """The fastest mcap-library loop: records in file order, one orjson.loads per message."""
    from mcap.reader import NonSeekingReader

    n = 0
    with open(path, "rb") as fh:
        for _schema, _channel, message in NonSeekingReader(fh).iter_messages(log_time_order=False):
            orjson.loads(message.data)
            n += 1
    return n


def mcap_sorted_loop(path):
    """``make_reader().iter_messages()``: the library's default, sorted by log time."""
    from mcap.reader import make_reader

    n = 0
    with open(path, "rb") as fh:
        for _schema, _channel, message in make_reader(fh).iter_messages():
            orjson.loads(message.data)
            n += 1
    return n


PEAK = """
import resource, sys
sys.path.insert(0, sys.argv[1])
from usvlog.io.mcap import read_log
import numba, pyarrow.compute
if sys.argv[3] == "load":
    log = read_log(sys.argv[2])
try:  # this process's own high-water mark (ru_maxrss may carry the parent's peak over exec)
    hwm = [l for l in open("/proc/self/status") if l.startswith("VmHWM")][0].split()[1]
except OSError:
    hwm = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(hwm)
"""


def crc_seconds(path) -> float:
    """Time of the CRC checks read_log makes: crc32 of every chunk's uncompressed records
    and of the data section (best of 3; the decompression is not timed)."""
    import zstandard
    from mcap.records import Chunk
    from mcap.stream_reader import StreamReader

    data = path.read_bytes()
    chunks = []
    with open(path, "rb") as fh:
        for rec in StreamReader(fh, emit_chunks=True).records:
            if isinstance(rec, Chunk):
                assert rec.compression == "zstd"
                chunks.append(zstandard.decompress(rec.data, rec.uncompressed_size))
    data_end = data.rfind(b"\x0f\x04\x00\x00\x00\x00\x00\x00\x00")  # the Data End record

    from usvlog.io.mcap.format import crc32 as _crc32  # the reader's own CRC-32 (fastcrc's, or zlib's)

    def run():
        for c in chunks:
            _crc32(c)
        _crc32(memoryview(data)[:data_end])

    return best_of(run)[0]


def peak_rss_mb(path, load: bool) -> float:
    """Peak resident memory of a fresh process that imports usvlog (and loads ``path``)."""
    from _log import ROOT

    out = subprocess.run([sys.executable, "-c", PEAK, str(ROOT), str(path), "load" if load else "-"],
                         check=True, capture_output=True, text=True).stdout
    return int(out.split()[-1]) / 1024


def topics_read(path, log) -> None:
    """``read_log(path, topics=[one channel])`` per channel: time (best of 3) and the chunks
    it decompresses (a chunk holding none of the channel is skipped by the chunk index)."""
    from usvlog.io.mcap import read_log
    from usvlog.io.mcap.reader import chunk_spans, chunks_decompressed

    n_chunks = len(chunk_spans(path) or [])
    for topic in log.topics:
        before = chunks_decompressed()
        read_log(path, topics=[topic])
        used = chunks_decompressed() - before
        t, _ = best_of(lambda topic=topic: read_log(path, topics=[topic]))
        print(f"read_log(topics=[{topic}]): {t:7.3f} s, {used} of {n_chunks} chunks decompressed")


def main() -> None:
    from usvlog.io.mcap import read_log

    path = hour_file()
    base, peak = peak_rss_mb(path, False), peak_rss_mb(path, True)
    size_mb = path.stat().st_size / 1e6
    read_log(path)  # warm-up (compiles or loads the cached compiled loops)
    (t_ours, t_lib), (c_ours, c_lib), (log, n_lib) = best_interleaved([lambda: read_log(path), lambda: mcap_loop(path)])
    n = sum(len(f) for f in log.channels.values())
    t_sorted, _ = best_of(lambda: mcap_sorted_loop(path))
    assert n == n_lib, (n, n_lib)
    print(f"file: {path.name}, {size_mb:.1f} MB, {n} messages "
          + ", ".join(f"{t} {len(f)}" for t, f in log.channels.items()))
    print(f"mcap NonSeekingReader (unsorted) + orjson.loads: {t_lib:7.3f} s  {n / t_lib:12,.0f} msg/s")
    print(f"(mcap make_reader iter_messages, log-time sorted: {t_sorted:7.3f} s, not the comparison)")
    print(f"usvlog read_log (to frames, every CRC checked):  {t_ours:7.3f} s  {n / t_ours:12,.0f} msg/s")
    print(f"speed-up over the fastest library loop: {t_lib / t_ours:.1f}x (target >= 5x); "
          f"in CPU time {c_lib:.3f} / {c_ours:.3f} s = {c_lib / c_ours:.1f}x")
    t_crc = crc_seconds(path)
    print(f"of which CRC checks (every chunk + data section): {t_crc:.3f} s ({100 * t_crc / t_ours:.1f} % of read_log)")
    topics_read(path, log)
    print(f"load average during the run: {os.getloadavg()[0]:.2f} (1 min), {os.cpu_count()} CPUs")
    print(f"peak RSS (VmHWM/ru_maxrss) of a fresh process loading the log: {peak:.0f} MB "
          f"({base:.0f} MB after imports alone, so {peak - base:.0f} MB for the load)")


if __name__ == "__main__":
    main()
