"""``usvlog check``: one table of findings about a log (severity, channel, time range, evidence, action)."""

from __future__ import annotations

from .common import print_json, stage


def register(sub) -> None:
    p = sub.add_parser("check", help="is this log sound, and what is wrong with the sensors? findings with severity, "
                                     "channel, time range, evidence in numbers and what to do (exit 1 on an error)")
    p.add_argument("log", metavar="SOURCE",
                   help="canonical MCAP log, or a field log to import in memory first (ROS 1/2 bag, .ulg, .bin, "
                        "NMEA, CSV), with the import's own guesses")
    p.add_argument("--vessel", default=None, help="vessel TOML or shipped vessel (thruster limits, heading offset)")
    p.add_argument("--format", default="auto", help="format of a field log (default: detected from the content)")
    p.add_argument("--msg-dir", action="append", default=[], metavar="DIR",
                   help="ROS bags without stored message definitions: .msg files under DIR; repeatable")
    p.add_argument("--json", action="store_true", help="the findings as JSON on stdout")
    p.add_argument("--junit", default=None, metavar="FILE",
                   help="also write JUnit XML: one testcase per check, a failure for an error; warnings and infos "
                        "in the testcase's system-out (the check passed; not 'skipped': it ran)")
    p.add_argument("--force", action="store_true", help="overwrite an existing --junit file")
    p.set_defaults(func=run)


def run(args) -> int:
    """Print the findings (table or JSON), write the JUnit file; exit 1 when any finding is an error."""
    from .. import api  # heavy: imported only when the verb runs
    from ..io.atomic import check_output, write_text_atomic  # light: os and pathlib

    if args.junit:   # a bad --junit fails before the work
        check_output(args.junit, args.force, parent=True)
    res = api.check(args.log, vessel=args.vessel, fmt=args.format, msg_dirs=args.msg_dir, progress=stage)
    if args.junit:
        write_text_atomic(args.junit, res.junit(), force=args.force)
    if args.json:
        print_json(res.to_dict())
    else:
        print(f"{res.source}:")
        print(res.table())
    return res.exit_code
