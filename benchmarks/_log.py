"""The canonical 1-hour log the benchmarks use, built once per source tree and cached in benchmarks/out/
(the file's name carries the hash of the package's kernel-reachable source, which covers the
simulator and the MCAP writer: a change to either builds the file again, in the new layout)."""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "out"
sys.path.insert(0, str(ROOT))


def hour_log():
    """GPS 36k + compass 72k + thrust 360k = 468k messages (``/truth/state`` dropped)."""
    from usvlog.sim.simulate import SimSettings, simulate

    log = simulate("excitation", SimSettings(duration_s=3600.0), seed=1)
    log.channels.pop("/truth/state", None)
    return log


def hour_file() -> Path:
    from usvlog._jit import source_hash
    from usvlog.io.mcap import write_log

    hour = OUT / f"hour-{source_hash()[:12]}.mcap"
    if not hour.exists():
        OUT.mkdir(parents=True, exist_ok=True)
        for old in OUT.glob("hour*.mcap"):   # written by an older tree
            old.unlink()
        print(f"building {hour} (simulating 1 h) ...", flush=True)
        write_log(hour_log(), hour)
    return hour
