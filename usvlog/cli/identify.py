"""``usvlog identify``: fit the paper's model (3) to field logs; write a vessel TOML."""

from __future__ import annotations

import math

from ..choices import IDENTIFY_METHODS, PARAM_NAMES
from ..errors import ConfigError
from .common import print_json, stage


def register(sub) -> None:
    p = sub.add_parser("identify", help="identify m, Iz, d11, d22, d33, xg of the paper's model from logs")
    p.add_argument("logs", nargs="+", help="canonical MCAP logs (fitted jointly)")
    p.add_argument("--vessel", default=None, help="vessel TOML: thruster map and geometry, start values "
                                                  "(default: the vessel stored in the first log)")
    p.add_argument("--method", choices=IDENTIFY_METHODS, default="output-error",
                   help="output-error (accurate, default), equation-error (fast, biased), filter-error "
                        "(dynamic EKF likelihood; slower)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--validate", default=None, metavar="LOG", help="validate on this log (not fitted)")
    g.add_argument("--holdout", type=float, default=0.0, help="hold out this last fraction of each log")
    p.add_argument("--fix", action="append", default=[], metavar="NAME=VALUE",
                   help=f"known parameter ({', '.join(PARAM_NAMES)}), e.g. --fix m=33.0 (repeatable)")
    p.add_argument("--no-current", action="store_true", help="do not fit a water current")
    p.add_argument("--gnss-delay-s", type=float, default=None, metavar="VALUE",
                   help="GNSS latency in s (a fix stamped t describes the boat at t - delay); default: the one "
                        "`usvlog estimate` stored in the log, else 0")
    p.add_argument("--out", required=True, help="output vessel TOML with the identified parameters")
    p.add_argument("--out-log", default=None, help="copy of the first log with the /identify/fit channel")
    p.add_argument("--force", action="store_true", help="overwrite existing outputs")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=run)


def parse_fix(items: list[str]) -> dict[str, float]:
    """``["NAME=VALUE", ...]`` of --fix -> {name: value}, each a possible value of that parameter."""
    out = {}
    for it in items:
        name, sep, value = it.partition("=")
        name = name.strip()
        if not sep or name not in PARAM_NAMES:
            raise ConfigError(f"--fix {it!r}: expected NAME=VALUE with NAME one of {', '.join(PARAM_NAMES)}")
        try:
            out[name] = float(value)
        except ValueError:
            raise ConfigError(f"--fix {it!r}: {value!r} is not a number") from None
        v = out[name]
        if not math.isfinite(v) or (name in ("m", "Iz") and v <= 0) or (name.startswith("d") and v < 0):
            bound = "> 0" if name in ("m", "Iz") else ">= 0" if name.startswith("d") else "finite"
            raise ConfigError(f"--fix {it!r}: {name} must be {bound}")
    return out


def run(args) -> int:
    from .. import api  # heavy: imported only when the verb runs

    fix = parse_fix(args.fix)
    idf = api.identify(args.logs, args.out, vessel=args.vessel or None, method=args.method,
                       validate=args.validate or None, holdout=args.holdout, fix=fix, current=not args.no_current,
                       out_log=args.out_log or None, force=args.force, progress=stage,
                       gnss_delay_s=args.gnss_delay_s)
    d = idf.to_dict()
    d["gnss_delay_s"] = [r.gnss_delay_s for r in idf.runs_]   # taken off the GNSS stamps of each run
    if args.json:
        print_json(d)
    else:
        print(format_report(d))
    stage(f"wrote {args.out}" + (f" and {args.out_log}" if args.out_log else ""))
    return 0


def format_report(d: dict) -> str:
    lines = [f"method: {d['method']}", "parameter        value      stderr        95% interval    (equation error)"]
    for k in PARAM_NAMES:
        lo, hi = d["ci95"][k]
        fixed = "  (fixed)" if k in d["fixed"] else ""
        lines.append(f"  {k:<5} {d['params'][k]:12.5g} {d['stderr'][k]:11.3g}   [{lo:10.5g}, {hi:10.5g}]"
                     f"   ({d['equation_error']['params'][k]:.4g}){fixed}")
    lines.append(f"Iz - m xg^2 = {d['Iz_minus_m_xg2']:.4g} (Theorem 3.1 condition 1 needs > 0)")
    if any(d.get("gnss_delay_s") or ()):
        lines.append("GNSS delay taken off the fix stamps: " + ", ".join(f"{x:.3f} s" for x in d["gnss_delay_s"]))
    for i, c in enumerate(d["current_ne_mps"]):
        lines.append(f"current run {i}: north {c[0]:+.3f} m/s, east {c[1]:+.3f} m/s")
    if d.get("condition_number") is not None:
        lines.append(f"condition number {d['condition_number']:.3g}")
    fp = d["fit_percent"]
    lines.append(f"fit % ({d['fit_percent_on']}): u {fp['u']:.1f}, v {fp['v']:.1f}, r {fp['r']:.1f}, "
                 f"track {fp['track']:.1f}")
    if d["verdict"]:
        lines.append("verdict:")
        lines += [f"  - {v}" for v in d["verdict"]]
    else:
        lines.append("verdict: all parameters well determined")
    return "\n".join(lines)
