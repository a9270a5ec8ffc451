"""``usvlog inspect``: channels, counts, rates, time range, gaps and damage of a log."""

from __future__ import annotations

from .common import print_json


def register(sub) -> None:
    p = sub.add_parser("inspect", help="channels, counts, rates, time range, gaps and damage of a log")
    p.add_argument("log", help="canonical MCAP log")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=run)


def run(args) -> int:
    from .. import api  # heavy: imported only when the verb runs
    from ..log.summary import format_summary

    s = api.inspect(args.log)
    if args.json:
        print_json(s.to_dict())
    else:
        print(format_summary(s))
    return 0
