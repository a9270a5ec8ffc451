"""``usvlog manoeuvres``: the standard manoeuvres of a run (turning circle, zig-zag, speed steps,
stop, pivot turn) with their metrics and one-sigmas."""

from __future__ import annotations

from .common import print_json, stage


def register(sub) -> None:
    p = sub.add_parser("manoeuvres", help="find the standard manoeuvres of a run and measure them",
                       description="Find turning circles, zig-zags, speed steps, stops and pivot turns from the "
                                   "thrust commands and the estimate (the log's /estimate/state, else an estimate "
                                   "made with the default settings); times in s from the log's start; every "
                                   "metric with its one-sigma. Definitions: docs/manoeuvres.md.")
    p.add_argument("log", help="canonical MCAP log")
    p.add_argument("--json", action="store_true", help="print the manoeuvres as JSON")
    p.set_defaults(func=run)


def run(args) -> int:
    from .. import api  # heavy: imported only when the verb runs

    result = api.manoeuvres(args.log, progress=stage)
    if args.json:
        print_json(result.to_dict())
    else:
        print(result.format())
    return 0
