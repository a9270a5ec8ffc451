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
    stage("[4] identify: output error on the simulated run (true vs identified)")
    identify_stage(log, out)
    stage(f"done: results in {out}/")
    return 0


def identify_stage(log, out: Path) -> None:
    from ..identify import Identifier
    from ..vessel import PARAM_NAMES

    idf = Identifier("output-error").fit([log])
    (out / "identified.toml").write_text(idf.to_vessel().to_toml())
    true = log.vessel.params.to_dict()
    ee = idf.equation_error_.to_dict()
    print("parameter      true  identified   +-stderr   error %   (equation error)")
    for k in PARAM_NAMES:
        v = getattr(idf.params_, k)
        print(f"  {k:<5} {true[k]:9.4g} {v:11.5g} {idf.stderr_[k]:10.2g} {100 * (v / true[k] - 1):+8.2f}"
              f"   ({ee[k]:.4g})")
    cn, ce = idf.current_[0]
    print(f"  current north {cn:+.3f} east {ce:+.3f} m/s (true +0.100 +0.173)")
    for v in idf.verdict_:
        print(f"  - {v}")
