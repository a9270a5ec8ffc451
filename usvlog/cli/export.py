"""``usvlog export``: each channel of a log to CSV or Parquet."""

from __future__ import annotations

from .common import stage


def register(sub) -> None:
    p = sub.add_parser("export", help="export each channel of a log to CSV or Parquet")
    p.add_argument("log", help="canonical MCAP log")
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--format", choices=["csv", "parquet"], default="csv", help="file format (default csv)")
    p.add_argument("--force", action="store_true", help="overwrite existing files")
    p.set_defaults(func=run)


def run(args) -> int:
    from .. import api  # heavy: imported only when the verb runs

    for path in api.export(args.log, args.out, fmt=args.format, force=args.force, progress=stage):
        print(path)
    return 0
