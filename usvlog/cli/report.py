"""``usvlog report``: a log (and optionally a baseline) -> HTML page with the paper's figures."""

from __future__ import annotations

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
    from .. import api  # heavy: imported only when the verb runs (matplotlib only when drawing)

    print(api.report(args.log, args.out, args.baseline or None, axes=args.axes, force=args.force, progress=stage))
    return 0
