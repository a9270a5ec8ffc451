"""``usvlog inspect``: what a log holds (canonical MCAP) or what a foreign source holds and how it would map."""

from __future__ import annotations

from .common import parse_pairs, print_json, stage


def register(sub) -> None:
    p = sub.add_parser("inspect", help="what a log holds: channels, counts, rates, gaps and damage of an MCAP log; "
                                       "topics, field paths and the role mapping of any other source")
    p.add_argument("log", metavar="SOURCE",
                   help="canonical MCAP log, or a field log to import (ROS 1/2 bag, .ulg, .bin, NMEA, CSV)")
    p.add_argument("--format", default="auto", help="format of a field log (default: detected from the content)")
    p.add_argument("--topic", action="append", default=[], metavar="ROLE=SOURCE[.field.path[i]]",
                   help="check a mapping as `usvlog import --topic` would; repeatable")
    p.add_argument("--msg-dir", action="append", default=[], metavar="DIR",
                   help="ROS bags without stored message definitions: every .msg file under DIR "
                        "(<pkg>/msg/<Name>.msg) defines the type <pkg>/msg/<Name>; repeatable")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=run)


def run(args) -> int:
    """Print the summary or the catalog (text or JSON); a damaged file's one-line report goes to stderr too.

    Exit 1 when an MCAP file is damaged and nothing could be recovered from it (a valid
    empty file exits 0).
    """
    from .. import api  # heavy: imported only when the verb runs
    from ..log.summary import LogSummary, format_summary

    topics = parse_pairs(args.topic, "--topic")
    s = api.inspect(args.log, fmt=args.format, topics=topics, msg_dirs=getattr(args, "msg_dir", None) or ())
    if not isinstance(s, LogSummary):   # a foreign source's catalog
        from ..io.importers.catalog import format_catalog  # heavy: the importers

        print_json(s.to_dict()) if args.json else print(format_catalog(s))
        return 0
    if args.json:
        print_json(s.to_dict())
    else:
        print(format_summary(s))
    if s.recovery:
        stage(s.recovery["summary"])
        if s.recovery["nothing_recovered"]:
            return 1
    return 0
