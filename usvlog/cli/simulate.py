from __future__ import annotations

from dataclasses import replace as dc_replace
from pathlib import Path

from ..errors import ConfigError
from ..io.atomic import check_output
from ..io.config import load_vessel
from ..io.mcap import write_log
from ..resources import replay_dir
from ..sim.scenario import closed_loop_scenarios
from ..sim.simulate import SCENARIOS, SensorSettings, SimSettings, simulate
from .common import stage


def register(sub) -> None:
    p = sub.add_parser("simulate", help="simulate a scenario of the paper's plant into a canonical log")
    p.add_argument("scenario", help="built-in open-loop scenario (excitation, turns, straight), a closed-loop scenario name "
                                    "in replay/ (paper-circle, paper-sine) or a scenario TOML file; a "
                                    "closed-loop scenario takes its settings from the file (only --duration-s, "
                                    "--seed, --vessel, --controller and --truth-rate-hz override them)")
    p.add_argument("--out", required=True, help="output MCAP file")
    p.add_argument("--seed", type=int, default=None, help="random seed (same seed, same file; default 0, "
                                                          "or the closed-loop scenario's)")
    p.add_argument("--controller", choices=["full", "baseline"], default=None,
                   help="closed-loop scenarios: the paper's controller (9)-(10) or the PI/PID baseline")
    p.add_argument("--duration-s", type=float, default=None, help="run length in seconds")
    p.add_argument("--current-mps", type=float, default=0.0, help="water current speed")
    p.add_argument("--current-dir-deg", type=float, default=0.0,
                   help="direction the current flows towards, degrees clockwise from north")
    p.add_argument("--vessel", default=None, help="vessel TOML (default: the paper's Section IV vessel)")
    p.add_argument("--gps-noise-m", type=float, default=None, help="GPS noise, one sigma per axis")
    p.add_argument("--compass-noise-deg", type=float, default=None, help="compass noise, one sigma")
    p.add_argument("--gps-bias-m", type=float, default=None,
                   help="std of a slowly wandering GPS bias (Gauss-Markov, 300 s)")
    p.add_argument("--gps-jump", action="append", default=[], metavar="T_S:SIZE_M",
                   help="a single-fix GPS outlier of SIZE_M metres at T_S seconds (repeatable)")
    p.add_argument("--gps-dropout", action="append", default=[], metavar="START_S:DURATION_S",
                   help="no GPS fixes for DURATION_S from START_S (repeatable)")
    p.add_argument("--compass-bias-deg", type=float, default=None, help="constant compass bias")
    p.add_argument("--truth-rate-hz", type=float, default=None,
                   help="record /truth/state at this rate (default: every integration step)")
    p.add_argument("--force", action="store_true", help="overwrite an existing output")
    p.set_defaults(func=run)


def _pairs(values: list[str], flag: str) -> list[tuple[float, float]]:
    out = []
    for v in values:
        try:
            a, b = v.split(":")
            out.append((float(a), float(b)))
        except ValueError:
            raise ConfigError(f"{flag} {v!r}: expected two numbers as A:B") from None
    return out


def settings_from_args(args) -> SimSettings:
    sens = {}
    if args.gps_noise_m is not None:
        sens["gps_noise_m"] = args.gps_noise_m
    if args.compass_noise_deg is not None:
        sens["compass_noise_deg"] = args.compass_noise_deg
    if args.compass_bias_deg is not None:
        sens["compass_bias_deg"] = args.compass_bias_deg
    if args.gps_bias_m is not None:
        sens["gps_bias_sigma_m"] = args.gps_bias_m
    if args.truth_rate_hz is not None:
        sens["truth_rate_hz"] = args.truth_rate_hz
    sens["gps_jumps"] = tuple(_pairs(args.gps_jump, "--gps-jump"))
    sens["gps_dropouts"] = tuple(_pairs(args.gps_dropout, "--gps-dropout"))
    kw = dict(vessel=load_vessel(args.vessel), current_mps=args.current_mps,
              current_dir_deg=args.current_dir_deg, sensors=SensorSettings(**sens))
    if args.duration_s is not None:
        kw["duration_s"] = args.duration_s
    return SimSettings(**kw)


def run(args) -> int:
    check_output(args.out, args.force, parent=True)  # fail before the work, not after
    if args.scenario not in SCENARIOS:
        p = Path(args.scenario)
        if not (p.suffix == ".toml" or p.exists() or "/" in args.scenario
                or (replay_dir() / f"{args.scenario}.toml").exists()):
            raise ConfigError(f"no scenario {args.scenario!r} (open loop: {', '.join(SCENARIOS)}; closed loop: "
                              f"{', '.join(closed_loop_scenarios())}; or a scenario TOML file)")
        return run_closed_loop(args)
    settings = settings_from_args(args)
    seed = 0 if args.seed is None else args.seed
    stage(f"simulating {args.scenario} ({settings.duration_s:.0f} s, seed {seed})")
    log = simulate(args.scenario, settings, seed=seed)
    write_log(log, args.out, force=args.force)
    stage(f"wrote {args.out}")
    return 0


def run_closed_loop(args) -> int:
    """A closed-loop scenario (replay/<name>.toml or a file); the scenario holds the settings."""
    from ..sim.closed_loop import simulate_scenario
    from ..sim.scenario import load_scenario

    scen = load_scenario(args.scenario, vessel=load_vessel(args.vessel) if args.vessel else None)
    if args.truth_rate_hz is not None:
        sens = dc_replace(scen.sim.sensors, truth_rate_hz=args.truth_rate_hz)
        scen = dc_replace(scen, sim=dc_replace(scen.sim, sensors=sens))
    ctl = args.controller or scen.controller
    dur = args.duration_s or scen.sim.duration_s
    stage(f"simulating {scen.name} closed loop ({dur:.0f} s, controller {ctl}, "
          f"input {scen.controller_input})")
    log = simulate_scenario(scen, controller=ctl, seed=args.seed, duration_s=args.duration_s)
    write_log(log, args.out, force=args.force)
    stage(f"wrote {args.out}")
    return 0
