"""``usvlog identify``: fit the paper's model (3) to field logs; write a vessel TOML."""

from __future__ import annotations

import math
import sys

from ..choices import EXT_SCALE_FIX, EXTENDED_PARAM_NAMES, IDENTIFY_METHODS, IDENTIFY_MODELS, PARAM_NAMES
from ..errors import ConfigError, UnusableResultError
from .common import print_json, stage


def register(sub) -> None:
    p = sub.add_parser("identify", help="identify m, Iz, d11, d22, d33, xg of the paper's model from logs")
    p.add_argument("logs", nargs="+", help="canonical MCAP logs (fitted jointly)")
    p.add_argument("--vessel", default=None, help="vessel TOML: thruster map and geometry, start values "
                                                  "(default: the vessel stored in the first log)")
    p.add_argument("--method", choices=IDENTIFY_METHODS, default="output-error",
                   help="output-error (accurate, default), equation-error (fast, biased), filter-error "
                        "(dynamic EKF likelihood; slower)")
    p.add_argument("--model", choices=IDENTIFY_MODELS, default="paper",
                   help="model structure: paper (default), extended (separate surge/sway inertia, linear plus "
                        "quadratic damping; written as an [extended] vessel), or both (compared on the validation; "
                        "the extended one is written only when it validates better by at least 1 point of the "
                        "validation score, else the simpler paper model)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--validate", default=None, metavar="LOG", help="validate on this log (not fitted)")
    g.add_argument("--holdout", type=float, default=None,
                   help="hold out this last fraction of each log for validation (default 0.3 of one log; "
                        "several logs: each left out in turn)")
    g.add_argument("--no-validate", action="store_true", help="no validation (the verdict says so)")
    p.add_argument("--fix", action="append", default=[], metavar="NAME=VALUE",
                   help=f"known parameter ({', '.join(PARAM_NAMES)}), e.g. --fix m=33.0 (repeatable); with "
                        "--model extended or both one inertia that sets an unknown thrust scale: m (the surge "
                        "inertia m11: a weighed mass leaves out the surge added mass) or Iz (m66), or for the "
                        "extended model m11, m22, m66")
    p.add_argument("--no-current", action="store_true", help="do not fit a water current")
    g2 = p.add_mutually_exclusive_group()
    g2.add_argument("--fit-lag", action="store_true",
                    help="identify a first-order thruster lag too (s; written to [thrusters] lag_s)")
    g2.add_argument("--lag-s", type=float, default=0.0, metavar="SECONDS",
                    help="a known first-order thruster lag (s) the thrust goes through before the fit")
    p.add_argument("--quadratic-surge", action="store_true",
                   help="also fit the paper model with a quadratic surge damping d11q (d11 u + d11q u|u|): "
                        "returned when it validates better, written as an [extended] vessel with one mass")
    p.add_argument("--gnss-delay-s", type=float, default=None, metavar="VALUE",
                   help="GNSS latency in s (a fix stamped t describes the boat at t - delay); default: the one "
                        "`usvlog estimate` stored in the log, else 0")
    p.add_argument("--max-current-mps", type=float, default=0.5,
                   help="bound on each component of a fitted current in m/s (default 0.5)")
    p.add_argument("--out", required=True, help="output vessel TOML with the identified parameters")
    p.add_argument("--out-log", default=None, help="copy of the first log with the /identify/fit channel")
    p.add_argument("--force", action="store_true",
                   help="overwrite existing outputs, and write the TOML even when the verdict is unusable "
                        "(it then says usable = false)")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=run)


def parse_fix(items: list[str]) -> dict[str, float]:
    """``["NAME=VALUE", ...]`` of --fix -> {name: value}, each a possible value of that parameter."""
    out = {}
    for it in items:
        name, sep, value = it.partition("=")
        name = name.strip()
        if not sep or name not in PARAM_NAMES + EXT_SCALE_FIX:
            raise ConfigError(f"--fix {it!r}: expected NAME=VALUE with NAME one of "
                              f"{', '.join(dict.fromkeys(PARAM_NAMES + EXT_SCALE_FIX))}")
        try:
            out[name] = float(value)
        except ValueError:
            raise ConfigError(f"--fix {it!r}: {value!r} is not a number") from None
        v = out[name]
        positive = name in ("m", "Iz") + EXT_SCALE_FIX
        if not math.isfinite(v) or (positive and v <= 0) or (name.startswith("d") and v < 0):
            bound = "> 0" if positive else ">= 0" if name.startswith("d") else "finite"
            raise ConfigError(f"--fix {it!r}: {name} must be {bound}")
    return out


def run(args) -> int:
    from .. import api  # heavy: imported only when the verb runs

    fix = parse_fix(args.fix)
    holdout = 0.0 if args.no_validate else args.holdout
    try:
        idf = api.identify(args.logs, args.out, vessel=args.vessel or None, method=args.method,
                           validate=args.validate or None, holdout=holdout, fix=fix,
                           current=not args.no_current, out_log=args.out_log or None, force=args.force,
                           progress=stage, max_current_mps=args.max_current_mps, gnss_delay_s=args.gnss_delay_s,
                           model=args.model, fit_lag=args.fit_lag, lag_s=args.lag_s,
                           quadratic_surge=args.quadratic_surge)
    except UnusableResultError as err:
        reasons = getattr(err, "reasons", None)
        if reasons is None:
            raise
        fitted = getattr(err, "identifier", None)
        d = fitted.to_dict() if fitted is not None else {"verdict": "unusable", "reasons": list(reasons),
                                                          "usable": False}
        if args.json:
            print_json({**d, "error": " ".join(str(err).split())})
        else:
            print(format_report(d) if fitted is not None else format_verdict(d))
        hint = " (--force writes it with usable = false)" if fitted is not None else ""
        print(f"usvlog identify: error: {err}; nothing written{hint}", file=sys.stderr)
        return int(err.exit_code)
    d = idf.to_dict()
    d["gnss_delay_s"] = [r.gnss_delay_s for r in idf.runs_]   # taken off the GNSS stamps of each run
    if args.json:
        print_json(d)
    else:
        print(format_report(d))
    stage(f"wrote {args.out}" + (f" and {args.out_log}" if args.out_log else ""))
    return 1 if not idf.usable_ else 0


def _num(x, digits: int = 5) -> str:
    return "n/a" if x is None or not math.isfinite(x) else f"{x:.{digits}g}"


def _pct(x) -> str:
    return "n/a" if x is None or not math.isfinite(x) else ("< -999" if x < -999 else f"{x:.1f}")


def format_verdict(d: dict) -> str:
    """The verdict line and its reasons, one per line."""
    lines = [f"verdict: {d['verdict']}"]
    lines += [f"  - {r}" for r in d.get("reasons", [])]
    return "\n".join(lines)


def _map_lines(ts: dict) -> list[str]:
    """The thruster map identified from PWM commands (``thrust_scale.map_from``), in plain words."""
    if ts.get("map_from") == "equation error profile":
        lo, hi = ts.get("deadband_ci95_us") or (None, None)
        q = ts.get("quadratic_share")
        return [f"thruster map from the PWM commands: no thrust within +-{_num(ts.get('deadband_us'), 3)} us of "
                f"neutral (95 % interval {_num(lo, 3)}..{_num(hi, 3)} us); beyond it force ~ "
                f"{_num(1 - q if q is not None else None, 2)} x + {_num(q, 2)} x|x| (x: the command past the edge, "
                f"1 at full command); reverse/forward gain {_num(ts.get('ratio'), 3)} "
                f"({ts.get('ratio_from') or 'n/a'})"]
    if ts.get("map_from") == "vessel":
        db = ts.get("deadband_us") or 0.0
        kept = f"the vessel's {ts.get('shape')} map kept" + (f" with its +-{db:g} us deadband" if db else
                                                             ", no deadband")
        return [f"thruster deadband not determined by the data: {ts.get('map_note')}; {kept}"]
    return []


def format_report(d: dict) -> str:
    """Text report of ``Identifier.to_dict()``: parameters, intervals, current, fit %, verdict.

    A standard error that is not finite or below 1e-9 of its value (a degenerate fit, not a
    precise one) is shown as ``n/a``, with no interval; fit % below -999 as ``< -999``."""
    lines = [f"method: {d['method']} (chosen: {d.get('chosen', d['method'])})",
             "parameter        value      stderr        95% interval    (equation error)"]
    for k in PARAM_NAMES:
        lo, hi = d["ci95"][k]
        v, se = d["params"][k], d["stderr"][k]
        fixed = k in d["fixed"] or {"m": "m11", "Iz": "m66"}.get(k) in d["fixed"]
        meaningful = se is not None and math.isfinite(se) and se > 1e-9 * max(abs(v), 1e-300)
        if fixed:
            interval, se_s = "(fixed)".center(26), "0"
        elif meaningful:
            interval, se_s = f"[{_num(lo):>10}, {_num(hi):>10}]", _num(se, 3)
        else:
            interval, se_s = "(not computable)".center(26), "n/a"
        lines.append(f"  {k:<5} {_num(v):>12} {se_s:>11}   {interval}   ({_num(d['equation_error']['params'][k], 4)})")
    if d.get("extended"):
        qs = d.get("structure") == "paper with quadratic surge damping"
        lines.append("the paper model with quadratic surge damping, in the extended form written (the parameters "
                     "above are its paper terms, d11 at 1 m/s):" if qs else
                     "extended model (the parameters above are its paper terms):")
        ext = d["extended"]
        held = {"m22": "(= m11)", "d22q": "(held)", "d33q": "(held)"} if qs else {}
        for k in EXTENDED_PARAM_NAMES:
            lines.append(f"  {k:<5} {_num(ext['params'][k]):>12} {_num(ext['stderr'].get(k), 3):>11}"
                         + (f"   {held[k]}" if k in held else ""))
    ts = d.get("thrust_scale") or {}
    if ts.get("case") == "command units":
        lines.append("thrust scale unknown: the values above are per unit of full forward command (only their "
                     "ratios are physical; xg in m)")
    elif ts.get("case") == "gain identified":
        lines.append(f"thrust gain from the fixed {ts['fixed_by']}: {_num(ts['forward_n'], 4)} N forward, "
                     f"{_num(ts['reverse_n'], 4)} N reverse at full command")
    lines += _map_lines(ts)
    lines.append(f"Iz - m xg^2 = {_num(d['Iz_minus_m_xg2'], 4)} (Theorem 3.1 condition 1 needs > 0)")
    if any(d.get("gnss_delay_s") or ()):
        lines.append("GNSS delay taken off the fix stamps: " + ", ".join(f"{x:.3f} s" for x in d["gnss_delay_s"]))
    for i, c in enumerate(d["current_ne_mps"]):
        lines.append(f"current run {i}: north {c[0]:+.3f} m/s, east {c[1]:+.3f} m/s")
    if d.get("condition_number") is not None:
        lines.append(f"condition number {_num(d['condition_number'], 3)}")
    lag = d.get("thruster_lag")
    if lag:
        hi = "inf" if lag["ci95"][1] is None else f"{lag['ci95'][1]:.2f}"
        lines.append(f"thruster lag identified: {lag['lag_s']:.2f} s (95 % {lag['ci95'][0]:.2f}..{hi} s)")
    elif d.get("thruster_lag_s"):
        lines.append(f"thruster lag {d['thruster_lag_s']:g} s (given, applied to the thrust)")
    fp = d["fit_percent"]
    quiet = {ch for ch, e in (d.get("excitation") or {}).items() if not e["excited"]}

    def fit(ch: str, v: dict) -> str:   # a channel the validation barely moves: its fit % is noise
        return f"{ch} not excited there" if ch in quiet else f"{ch} {_pct(v[ch])}"

    lines.append(f"fit % ({d['fit_percent_on']}): {fit('u', fp)}, {fit('v', fp)}, {fit('r', fp)}, "
                 f"track {_pct(fp['track'])}")
    for h, v in (d.get("fit_percent_ahead") or {}).items():   # k-step-ahead (re-started every h s)
        lines.append(f"fit % {h} s ahead: {fit('u', v)}, {fit('v', v)}, {fit('r', v)}")
    for ch, e in (d.get("excitation") or {}).items():
        if not e["excited"]:
            lines.append(f"{ch} not excited there: its spread {_num(e['spread'], 2)} against its noise "
                         f"{_num(e['noise'], 2)} (one sigma of the smoothed states)")
    mc = d.get("model_comparison")
    if mc:
        for m in ("paper", "extended"):
            if m in mc:
                f = mc[m]["fit_percent"]
                lines.append(f"{m} model on the validation ({mc[m]['candidate']}): track {_pct(f['track'])}, "
                             f"u {_pct(f['u'])}, v {_pct(f['v'])}, r {_pct(f['r'])}")
        if mc.get("winner"):
            by = f" by {mc['margin']:.1f} points of the validation score" if mc.get("margin") is not None else ""
            why = f" ({mc['why']})" if mc.get("why") else ""
            lines.append(f"better model on the validation: {mc['winner']}{by}; returned: {mc.get('returned')}{why}")
        if mc.get("rule"):
            lines.append(f"rule: {mc['rule']}")
    lines.append(format_verdict(d))
    return "\n".join(lines)
