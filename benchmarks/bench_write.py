"""Write speed: usvlog.write_log vs the mcap library Writer (one add_message per message)
on the 1-hour log (468k messages).

    python benchmarks/bench_write.py

Both are timed the same way: one warm-up write each, then best of 3. The library Writer
compresses at zstd level 3, usvlog at level 1 (smaller and faster on these logs), so the
files differ in their chunks' compressed bytes only; written at level 3 ours is the
library's file byte for byte (checked here, and in tests/io).
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

from _log import hour_file


def best_of(fn, n=3):
    best = float("inf")
    for _ in range(n):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def main() -> None:
    from usvlog.io.mcap import _write_log_reference, read_log, write_log

    log = read_log(hour_file())
    n = sum(len(f) for f in log.channels.values())
    with tempfile.TemporaryDirectory() as d:
        ours, ref = Path(d) / "ours.mcap", Path(d) / "ref.mcap"
        write_log(log, ours, force=True)  # warm-up
        t_ours = best_of(lambda: write_log(log, ours, force=True))
        size = ours.stat().st_size / 1e6
        _write_log_reference(log, ref, force=True)  # warm-up
        t_ref = best_of(lambda: _write_log_reference(log, ref, force=True))
        ref_size = ref.stat().st_size / 1e6
        t_ours3 = best_of(lambda: write_log(log, ours, force=True, zstd_level=3))
        same = ours.read_bytes() == ref.read_bytes()
    print(f"{n} messages; load average {os.getloadavg()[0]:.2f} (1 min), {os.cpu_count()} CPUs")
    print(f"mcap Writer, add_message per message (zstd 3): {t_ref:7.3f} s  {n / t_ref:12,.0f} msg/s  {ref_size:.1f} MB")
    print(f"usvlog write_log (zstd 1, default):            {t_ours:7.3f} s  {n / t_ours:12,.0f} msg/s  {size:.1f} MB")
    print(f"usvlog write_log (zstd 3):                     {t_ours3:7.3f} s  {n / t_ours3:12,.0f} msg/s")
    print(f"speed-up: {t_ref / t_ours:.1f}x (same level: {t_ref / t_ours3:.1f}x); "
          f"identical bytes at level 3: {same}")


if __name__ == "__main__":
    main()
