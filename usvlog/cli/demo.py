"""``usvlog demo``: the whole pipeline on a built-in simulated run.

Every stage of usvlog adds itself here, so the demo always shows what the tool does.
"""

from __future__ import annotations

from pathlib import Path

from ..estimate import EstimateSettings, estimate
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
    est_path = out / "estimate.mcap"
    stage(f"[3] estimate: dynamic model + current, EKF + RTS smoother -> {est_path}")
    result = estimate(log, EstimateSettings(model="dynamic"))
    print(result.report.format())
    log = result.to_log(log)
    write_log(log, est_path, force=True)
    stage(f"[4] export -> {out / 'csv'}")
    export_log(log, out / "csv", fmt="csv", force=True)
    stage("[5] identify: output error on the simulated run (true vs identified)")
    identify_stage(log, out)
    _control_stages(out, first=6)
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


def _control_stages(out: Path, first: int) -> None:
    """Section IV closed loop, gain check, replay with a baseline what-if."""
    from ..control.gains import check_gains
    from ..io.config import load_scenario
    from ..replay import replay_log, simulate_scenario
    from .replay import format_metrics

    scen = load_scenario("paper-circle")
    circ = out / "paper-circle.mcap"
    stage(f"[{first}] simulate paper-circle: the paper's Section IV closed loop, {scen.sim.duration_s:.0f} s -> {circ}")
    log = simulate_scenario(scen)
    write_log(log, circ, force=True)
    stage(f"[{first + 1}] gains: Theorem 3.1 for the paper's gains")
    chk = check_gains(scen.sim.vessel.params, scen.gains)
    print(chk.verdict)
    print("eigenvalues of A_e: " + ", ".join(f"{z.real:.4f}{z.imag:+.4f}j" for z in chk.eigenvalues))
    rep = out / "paper-circle-replay.mcap"
    stage(f"[{first + 2}] replay paper-circle open loop, what-if with the PI/PID baseline -> {rep}")
    res = replay_log(read_log(circ), scen, whatif_controller="baseline")
    write_log(res.log, rep, force=True)
    print(format_metrics(res.metrics))
