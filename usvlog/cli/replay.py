"""``usvlog replay``: open-loop replay of a recorded run through the controller, plus a what-if run."""

from __future__ import annotations

from dataclasses import replace

from ..io.atomic import check_output
from ..io.config import load_vessel_or_scenario_vessel, read_toml
from ..io.mcap import read_log, write_log
from ..replay import replay_log
from ..sim.scenario import load_gains, load_scenario
from .common import print_json, stage


def register(sub) -> None:
    p = sub.add_parser("replay", help="replay a recorded run through guidance + controller, and a what-if run")
    p.add_argument("log", help="recorded run (canonical MCAP)")
    p.add_argument("--scenario", required=True, help="closed-loop scenario: a TOML file (path, gains, guidance, speed) or "
                        "a shipped name (paper-circle, paper-sine)")
    p.add_argument("--gains", default=None,
                   help="gains TOML overriding the scenario's [gains] (and [guidance] when it has one)")
    p.add_argument("--vessel", default=None,
                   help="vessel TOML for the controller's model and the what-if plant "
                        "(default: the scenario's [vessel], else the log's)")
    p.add_argument("--controller", choices=["full", "baseline"], default=None,
                   help="controller replayed open loop (default: the scenario's)")
    p.add_argument("--whatif-controller", choices=["full", "baseline"], default=None,
                   help="controller of the what-if run (default: as --controller)")
    p.add_argument("--no-whatif", action="store_true", help="skip the what-if simulation")
    p.add_argument("--out", required=True, help="output MCAP: the input log plus /replay/* channels")
    p.add_argument("--force", action="store_true", help="overwrite an existing output")
    p.add_argument("--json", action="store_true", help="print the metrics as JSON")
    p.set_defaults(func=run)


def run(args) -> int:
    check_output(args.out, args.force, parent=True)
    scen = load_scenario(args.scenario)
    gains = None
    if args.gains:
        gains, guidance = load_gains(args.gains)
        if "guidance" in read_toml(args.gains):  # a [guidance] table there overrides the scenario's
            scen = replace(scen, guidance=guidance)
    vessel = load_vessel_or_scenario_vessel(args.vessel) if args.vessel else None
    stage(f"reading {args.log}")
    log = read_log(args.log)
    stage(f"replaying with scenario {scen.name}")
    res = replay_log(log, scen, vessel=vessel, gains=gains, controller=args.controller,
                     whatif=not args.no_whatif, whatif_controller=args.whatif_controller)
    write_log(res.log, args.out, force=args.force)
    stage(f"wrote {args.out}")
    m = res.metrics
    if args.json:
        print_json(m.to_dict())
    else:
        print(format_metrics(m))
    return 0


def format_metrics(m) -> str:
    lines = [f"state source: {m.state_source}; controller: {m.controller}"]

    def block(name, t):
        lines.append(f"{name}: {t.n_ticks} ticks, {t.duration_s:.1f} s from t = {t.start_s:g} s")
        lines.append(f"  cross-track RMS {t.cross_track_rms_m:.4f} m, p95 {t.cross_track_p95_m:.4f} m, "
                     f"max {t.cross_track_max_m:.4f} m")
        lines.append(f"  heading error RMS {t.heading_error_rms_rad:.5f} rad, surge error RMS "
                     f"{t.surge_error_rms_mps:.5f} m/s, saturated {t.time_saturated_s:.1f} s")

    block("replay (recorded states)", m.replay)
    if m.command_rms is not None:
        lines.append(f"  replayed vs recorded commands ({m.command_unit}, {m.n_commands_compared} ticks): "
                     f"RMS {m.command_rms:.3g}, max {m.command_max_abs:.3g}"
                     + (f"; forces RMS {m.force_rms_n:.3g} N" if m.force_rms_n is not None else ""))
    if m.decisions_max_abs is not None:
        lines.append(f"  replayed vs recorded /control/state ({m.decisions_compared} ticks): "
                     f"max |difference| of forces {m.decisions_max_abs:.3g}")
    if m.whatif is not None:
        block(f"what-if ({m.whatif_controller})", m.whatif)
    return "\n".join(lines)
