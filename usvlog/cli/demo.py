"""``usvlog demo``: the whole pipeline on a built-in simulated run.

Every stage of usvlog adds itself here, so the demo always shows what the tool does.
"""

from __future__ import annotations

from pathlib import Path

from ..io.export import export_log
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
    stage(f"[4] view -> {out / 'demo.rrd'} (open it with: rerun {out / 'demo.rrd'})")
    from ..viz import to_rrd

    to_rrd(log, out / "demo.rrd", names=["demo"], force=True)
    stage(f"[5] report -> {out / 'report' / 'report.html'}")
    from ..report import write_report

    write_report(log, out / "report", force=True)
    stage(f"done: results in {out}/")
    return 0
