"""``usvlog replay``: open-loop replay of a recorded run through the controller, plus a what-if run."""

from __future__ import annotations

from .common import print_json, stage


def register(sub) -> None:
    p = sub.add_parser("replay", help="replay a recorded run through guidance + controller, and a what-if run")
    p.add_argument("log", help="recorded run (canonical MCAP)")
    p.add_argument("--scenario", required=True,
                   help="closed-loop scenario: a TOML file (path, gains, guidance, speed) or "
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
    from .. import api  # heavy: imported only when the verb runs

    res = api.replay(args.log, args.scenario, args.out, gains=args.gains or None, vessel=args.vessel or None,
                     controller=args.controller, whatif=not args.no_whatif,
                     whatif_controller=args.whatif_controller, force=args.force, progress=stage)
    m = res.metrics
    if args.json:
        for w in m.warnings:   # the JSON carries them too; a person reading the terminal sees them here
            stage(f"warning: {w}")
        print_json(m.to_dict())
    else:
        print(format_metrics(m))
    return 0


def format_metrics(m) -> str:
    """The replay metrics as console lines: each with its window (``[t>60s]``), angles in degrees
    (``--json`` keeps the stored radians); the replay's warnings first."""
    lines = [f"warning: {w}" for w in m.warnings]
    lines.append(f"state source: {m.state_source}; controller: {m.controller}")

    def block(name, t):
        lines.append(f"{name}: {t.n_ticks} ticks, {t.duration_s:.1f} s, metrics over [{t.window}]")
        lines.extend(f"  {k:<32} {v:>10} {u}" for k, v, u in t.display())

    block("replay (recorded states)" + ("  [NOT on the scenario's path]" if not m.follows_path else ""), m.replay)
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
