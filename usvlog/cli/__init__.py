"""Command line: thin verbs over library calls.

Each verb lives in its own module here with ``register(subparsers)``; the module
sets ``func`` on its parser. Errors a user can cause are one line on stderr, exit 2.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys

from .._version import __version__
from ..errors import UsvlogError

VERBS = [
    "simulate",
    "import_",
    "inspect",
    "export",
    "estimate",
    "identify",
    "gains",
    "replay",
    "regress",
    "record",
    "demo",
    "view",
    "report",
]


class _Parser(argparse.ArgumentParser):
    """An argument parser whose usage errors are one line (the verb's usage is under --help)."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="usvlog",
        description="Field logs of small unmanned surface vessels: import, estimate, identify, replay, view.")
    parser.add_argument("--version", action="version", version=f"usvlog {__version__}")
    sub = parser.add_subparsers(dest="verb", metavar="VERB")
    for name in VERBS:
        importlib.import_module(f".{name}", __name__).register(sub)
    return parser


def interrupted(err: BaseException) -> bool:
    """True when ``err`` was caused by a KeyboardInterrupt (directly or down its chain)."""
    seen = set()
    while err is not None and id(err) not in seen:
        if isinstance(err, KeyboardInterrupt):
            return True
        seen.add(id(err))
        err = err.__cause__ or err.__context__
    return False


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 0
    try:
        rc = args.func(args)
        return int(rc or 0)
    except UsvlogError as err:
        print(f"usvlog {args.verb}: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"usvlog {args.verb}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return 0
    except Exception as err:  # a bug: one line, traceback on request
        if interrupted(err):  # Ctrl-C inside compiled code arrives wrapped (numba: SystemError)
            print(f"usvlog {args.verb}: interrupted", file=sys.stderr)
            return 130
        if os.environ.get("USVLOG_DEBUG"):
            raise
        print(f"usvlog {args.verb}: internal error: {type(err).__name__}: {err} "
              f"(set USVLOG_DEBUG=1 for a traceback)", file=sys.stderr)
        return 3


def run() -> None:
    sys.exit(main())
