"""The canonical 1-hour log the benchmarks use, built once and cached in benchmarks/out/."""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "out"
HOUR = OUT / "hour.mcap"
sys.path.insert(0, str(ROOT))


def hour_log():
    """GPS 36k + compass 72k + thrust 360k = 468k messages (``/truth/state`` dropped)."""
    from usvlog.sim.simulate import SimSettings, simulate

    log = simulate("excitation", SimSettings(duration_s=3600.0), seed=1)
    log.channels.pop("/truth/state", None)
    return log


def hour_file() -> Path:
    from usvlog.io.mcap import write_log

    if not HOUR.exists():
        OUT.mkdir(parents=True, exist_ok=True)
        print(f"building {HOUR} (simulating 1 h) ...", flush=True)
        write_log(hour_log(), HOUR)
    return HOUR
