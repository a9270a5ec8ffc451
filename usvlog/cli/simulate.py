"""``usvlog simulate``: a scenario of the paper's plant (open loop, or a closed-loop scenario) into a log."""

from __future__ import annotations

from ..errors import ConfigError
from .common import stage


def register(sub) -> None:
    p = sub.add_parser("simulate", help="simulate a scenario of the paper's plant into a canonical log")
    p.add_argument("scenario", help="built-in open-loop scenario (excitation, turns, straight), a closed-loop "
                                    "scenario name in replay/ (paper-circle, paper-sine) or a scenario TOML file; a "
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


def run(args) -> int:
    from .. import api  # heavy: imported only when the verb runs

    api.simulate(args.scenario, args.out, seed=args.seed, controller=args.controller, duration_s=args.duration_s,
                 current_mps=args.current_mps, current_dir_deg=args.current_dir_deg, vessel=args.vessel or None,
                 gps_noise_m=args.gps_noise_m, compass_noise_deg=args.compass_noise_deg, gps_bias_m=args.gps_bias_m,
                 gps_jumps=_pairs(args.gps_jump, "--gps-jump"), gps_dropouts=_pairs(args.gps_dropout, "--gps-dropout"),
                 compass_bias_deg=args.compass_bias_deg, truth_rate_hz=args.truth_rate_hz, force=args.force,
                 progress=stage)
    return 0
