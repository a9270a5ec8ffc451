"""``usvlog report``: a log (and optionally a baseline) -> HTML page with the paper's figures."""

from __future__ import annotations

from ..io.mcap import read_log
from .common import stage


def register(sub) -> None:
    p = sub.add_parser("report", help="write an HTML report with PNG figures in the style of the paper")
    p.add_argument("log", help="canonical MCAP log")
    p.add_argument("baseline", nargs="?", default=None,
                   help="optional second log (e.g. the baseline PI/PID run) compared in Fig. 2")
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--axes", choices=["paper", "map"], default="paper",
                   help="plane figures as in the paper (X = north to the right, Y = east up; default) "
                        "or as a map (north up)")
    p.add_argument("--force", action="store_true", help="overwrite existing files")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..view.report import check_report_outputs, write_report

    check_report_outputs(args.out, args.force)  # fail before the work, not after
    log = read_log(args.log)
    base = read_log(args.baseline) if args.baseline else None
    stage(f"writing report to {args.out}")
    page = write_report(log, args.out, baseline=base, force=args.force, axes=args.axes)
    print(page)
    return 0
