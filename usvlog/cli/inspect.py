"""``usvlog inspect``: channels, counts, rates, time range, gaps and damage of a log."""

from __future__ import annotations

from .common import print_json, stage


def register(sub) -> None:
    p = sub.add_parser("inspect", help="channels, counts, rates, time range, gaps and damage of a log")
    p.add_argument("log", help="canonical MCAP log")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=run)


def run(args) -> int:
    """Print the summary (text or JSON); a damaged file's one-line report goes to stderr too.

    Exit 1 when the file is damaged and nothing could be recovered from it (a valid
    empty file exits 0).
    """
    from .. import api  # heavy: imported only when the verb runs
    from ..log.summary import format_summary

    s = api.inspect(args.log)
    if args.json:
        print_json(s.to_dict())
    else:
        print(format_summary(s))
    if s.recovery:
        stage(s.recovery["summary"])
        if s.recovery["nothing_recovered"]:
            return 1
    return 0
