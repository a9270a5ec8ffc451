"""``usvlog demo``: the whole pipeline on a built-in simulated run.

Every stage of usvlog adds itself here, so the demo always shows what the tool does.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..frames import ssa
from ..io.export import export_log
from ..io.importers import import_file
from ..io.mergedcsv import write_merged_csv
from ..io.mcapio import read_log, write_log
from ..simulate import SimSettings, simulate
from ..summary import format_summary, summarize
from .common import stage


def register(sub) -> None:
    p = sub.add_parser("demo", help="run the whole pipeline on a built-in simulated run")
    p.add_argument("--out", default="usvlog-demo", help="output directory (default: usvlog-demo)")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--duration-s", type=float, default=600.0)
    p.set_defaults(func=run)


def run(args) -> int:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    raw = out / "excitation.mcap"
    stage(f"[1] simulate: excitation run, {args.duration_s:.0f} s, 0.2 m/s current -> {raw}")
    settings = SimSettings(duration_s=args.duration_s, current_mps=0.2, current_dir_deg=60.0)
    write_log(simulate("excitation", settings, seed=args.seed), raw, force=True)
    stage("[2] inspect")
    log = read_log(raw)
    print(format_summary(summarize(log)))
    stage(f"[3] export -> {out / 'csv'}")
    export_log(log, out / "csv", fmt="csv", force=True)
    merged = out / "merged.csv"
    imported = out / "imported.mcap"
    stage(f"[4] import: the run as one merged logger CSV {merged} -> usvlog import -> {imported}")
    write_merged_csv(log, merged, force=True)
    thrust_unit = str(log["/thrust/command"]["unit"].iloc[0])
    res = import_file(merged, vessel=log.vessel, thrust_unit=thrust_unit, out=imported, force=True)
    back = read_log(imported)
    for topic, col in (("/gnss/fix", "lat_deg"), ("/gnss/fix", "lon_deg"), ("/compass/heading", "heading_rad"),
                       ("/thrust/command", "left")):
        a, b = log[topic], back[topic]
        same_t = len(a) == len(b) and bool((a.index == b.index).all())
        err = float(np.max(np.abs(ssa(b[col].to_numpy() - a[col].to_numpy())) if col == "heading_rad" else
                           np.abs(b[col].to_numpy() - a[col].to_numpy()))) if same_t else float("nan")
        print(f"import    {topic:<18} {col:<12} {len(b):>7} of {len(a):>7} samples, same times: {same_t}, "
              f"max |diff| {err:.3g}")
    print(f"import    skipped records: {dict(res.report.skipped) or 'none'}")
    stage(f"done: results in {out}/")
    return 0
