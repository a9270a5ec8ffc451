"""``usvlog estimate``: EKF + RTS smoother over a canonical log."""

from __future__ import annotations

import argparse
import sys

from .common import print_json, stage


def register(sub) -> None:
    p = sub.add_parser("estimate", help="estimate the state (EKF + RTS smoother) and add it to the log")
    p.add_argument("log", help="canonical MCAP log")
    p.add_argument("--out", required=True, help="output MCAP (every input channel plus /estimate/*)")
    p.add_argument("--model", choices=["kinematic", "dynamic"], default="kinematic",
                   help="kinematic (no vessel parameters) or dynamic (the paper's model, recorded thrust)")
    p.add_argument("--vessel", default=None,
                   help="vessel TOML for the dynamic model (default: the log's own vessel, else built-in)")
    p.add_argument("--current", action="store_true", default=None,
                   help="estimate the water current (default with --model dynamic)")
    p.add_argument("--no-current", dest="current", action="store_false", help="no current states")
    p.add_argument("--tune", action="store_true",
                   help="pick process noise by maximising the innovation likelihood")
    p.add_argument("--sway-damping", action=argparse.BooleanOptionalAction, default=None,
                   help="kinematic model in the body frame with an estimated sway damping (better u, v; "
                        "default: on for the kinematic model)")
    p.add_argument("--gate", type=float, default=0.9999, help="chi-square probability of the NIS gate (default 0.9999)")
    p.add_argument("--no-smoother", action="store_true", help="forward filter only")
    p.add_argument("--gps-only", action="store_true",
                   help="fuse no heading (a rough or doubtful compass); without a usable heading channel "
                        "the estimate is GNSS-only anyway")
    p.add_argument("--gnss-delay-s", type=delay_arg, default=0.0, metavar="auto|VALUE",
                   help="GNSS latency in s (a fix stamped t describes the boat at t - delay), or auto: estimated "
                        "from the data (needs the dynamic model and the recorded thrust), default 0")
    p.add_argument("--compass-delay-s", type=delay_arg, default=0.0, metavar="auto|VALUE",
                   help="compass latency in s, or auto (default 0)")
    p.add_argument("--heading-offset", type=offset_arg, default=None, metavar="auto|DEG",
                   help="heading mounting offset in deg, measured minus true (the heading fused is the measured one "
                        "minus it), or auto: detected against the course over ground on straight runs and applied "
                        "when found (default: the vessel file's [sensors] heading_offset_deg, else none). An estimate "
                        "with a detected offset not applied, or an implausible sideslip, is written flagged failed "
                        "and exits 1")
    p.add_argument("--force", action="store_true", help="overwrite an existing output")
    p.add_argument("--json", action="store_true", help="print the report as JSON")
    p.set_defaults(func=run)


def _auto_or_number(text: str, lo: float, hi: float, unit: str, symbol: str, what: str) -> float | str:
    """``auto``, or a number in [lo, hi] (argparse's error, naming ``what`` and the unit, otherwise)."""
    if text.strip().lower() == "auto":
        return "auto"
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is neither auto nor a number of {unit}") from None
    if not (lo <= v <= hi):  # also refuses nan
        raise argparse.ArgumentTypeError(f"{text!r}: {what} must be in [{lo:g}, {hi:g}] {symbol}")
    return v


def delay_arg(text: str) -> float | str:
    """``auto`` or a latency in s (a number in [-1, 5]) for --gnss-delay-s / --compass-delay-s."""
    return _auto_or_number(text, -1.0, 5.0, "seconds", "s", "a latency")


def offset_arg(text: str) -> float | str:
    """``auto`` or a heading mounting offset in degrees (a number in [-360, 360]) for --heading-offset."""
    return _auto_or_number(text, -360.0, 360.0, "degrees", "deg", "a heading offset")


def run(args) -> int:
    from .. import api  # heavy: imported only when the verb runs

    result = api.estimate(args.log, args.out, model=args.model, vessel=args.vessel or None, current=args.current,
                          tune=args.tune, sway_damping=args.sway_damping, gate=args.gate,
                          smoother=not args.no_smoother, gnss_delay_s=args.gnss_delay_s,
                          compass_delay_s=args.compass_delay_s, force=args.force, progress=stage,
                          gps_only=args.gps_only, heading_offset=args.heading_offset)
    stage(f"wrote {args.out}")
    if args.json:
        print_json(result.report.to_dict())
    else:
        print(result.report.format())
    if result.report.status == "failed":   # written, flagged failed: later stages refuse it
        print("usvlog estimate: error: the estimate is not usable: " + "; ".join(result.report.blocking),
              file=sys.stderr)
        return 1
    return 0
