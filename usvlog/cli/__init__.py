"""Command line: thin verbs over library calls.

Each verb lives in its own module here with ``register(subparsers)``; the module
sets ``func`` on its parser. Errors a user can cause are one line on stderr, exit 2.
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import signal
import sys
import threading

from .._jit import on_first_compile
from .._version import __version__
from ..errors import UsvlogError
from .common import one_blas_thread, stage

VERBS = [
    "simulate",
    "import_",
    "inspect",
    "check",
    "export",
    "estimate",
    "identify",
    "manoeuvres",
    "gains",
    "replay",
    "regress",
    "record",
    "demo",
    "view",
    "report",
    "campaign",
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


class Terminated(KeyboardInterrupt):
    """SIGTERM or SIGHUP turned into an exception, so ``finally`` blocks and clean-up code run.

    A KeyboardInterrupt subclass: whatever stops cleanly on Ctrl-C (temporary files removed,
    child processes stopped) does the same on these signals. ``signum`` is the signal number;
    the CLI exits with ``128 + signum`` (143 for SIGTERM, 129 for SIGHUP).
    """

    def __init__(self, signum: int):
        super().__init__(f"signal {signum}")
        self.signum = signum


CLEAN_EXIT_SIGNALS = ("SIGTERM", "SIGHUP")


def _raise_terminated(signum, frame):
    for name in CLEAN_EXIT_SIGNALS:  # a second signal during the clean-up ends the process at once
        sig = getattr(signal, name, None)
        if sig is not None and signal.getsignal(sig) is _raise_terminated:
            signal.signal(sig, signal.SIG_DFL)
    raise Terminated(signum)


def _install_signal_handlers() -> dict:
    """Turn SIGTERM and SIGHUP into :class:`Terminated` (not where they are ignored, e.g. under nohup).

    Returns the previous handlers, for :func:`_restore_signal_handlers`.
    """
    if threading.current_thread() is not threading.main_thread():  # only the main thread may set handlers
        return {}
    old = {}
    for name in CLEAN_EXIT_SIGNALS:
        sig = getattr(signal, name, None)  # Windows has no SIGHUP
        if sig is None or signal.getsignal(sig) is signal.SIG_IGN:
            continue
        old[sig] = signal.signal(sig, _raise_terminated)
    return old


def _restore_signal_handlers(old: dict) -> None:
    for sig, handler in old.items():
        signal.signal(sig, handler if handler is not None else signal.SIG_DFL)


def interrupted(err: BaseException) -> KeyboardInterrupt | None:
    """The KeyboardInterrupt (or :class:`Terminated`) that caused ``err``, directly or down its chain.

    Returns None when there is none (the result is truthy exactly when ``err`` was interrupted).
    """
    seen = set()
    cur: BaseException | None = err
    while cur is not None and id(cur) not in seen:
        if isinstance(cur, KeyboardInterrupt):
            return cur
        seen.add(id(cur))
        cur = cur.__cause__ or cur.__context__
    return None


def _stopped(verb: str, err: KeyboardInterrupt) -> int:
    """Report Ctrl-C (exit 130) or a terminating signal (exit 128 + signal number)."""
    if isinstance(err, Terminated):
        try:
            name = signal.Signals(err.signum).name
        except ValueError:
            name = f"signal {err.signum}"
        print(f"usvlog {verb}: terminated ({name})", file=sys.stderr)
        return 128 + err.signum
    print(f"usvlog {verb}: interrupted", file=sys.stderr)
    return 130


def _json_error(args, err: BaseException) -> None:
    """With ``--json``, a script reading stdout gets the failure as JSON too (the one line
    still goes to stderr, the exit code is the same)."""
    if getattr(args, "json", False):
        print(json.dumps({"error": " ".join(str(err).split()) or type(err).__name__, "kind": type(err).__name__,
                          "internal": not isinstance(err, UsvlogError)}), flush=True)


def _say_compiling(kernel: str, cache: str) -> None:
    """Say why a first run waits: a kernel is being compiled (see :func:`usvlog._jit.on_first_compile`)."""
    where = f"kept in {cache} for later runs" if cache else "not kept: the cache directory cannot be written"
    stage(f"compiling the numerical kernels for this machine (once after an install or upgrade, up to a minute; "
          f"{where})")


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the exit code.

    0 success, 1 a negative verdict (regress, inspect), 2 a user error (one line), 3 an
    internal error, 130 Ctrl-C, 128 + N when stopped by signal N (SIGTERM: 143, SIGHUP: 129):
    these signals are turned into an exception while the verb runs, so temporary files are
    removed and child processes stopped.
    """
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 0
    one_blas_thread()   # before numpy loads: every verb's linear algebra is small products
    on_first_compile(_say_compiling)
    old = _install_signal_handlers()
    try:
        rc = args.func(args)
        return int(rc or 0)
    except UsvlogError as err:
        _json_error(args, err)
        print(f"usvlog {args.verb}: error: {err}", file=sys.stderr)
        return int(getattr(err, "exit_code", 2))
    except KeyboardInterrupt as err:
        return _stopped(args.verb, err)
    except BrokenPipeError:
        return 0
    except Exception as err:  # a bug: one line, traceback on request
        cause = interrupted(err)
        if cause is not None:  # Ctrl-C inside compiled code arrives wrapped (numba: SystemError)
            return _stopped(args.verb, cause)
        _json_error(args, err)
        if os.environ.get("USVLOG_DEBUG"):
            raise
        print(f"usvlog {args.verb}: internal error: {type(err).__name__}: {err} "
              f"(set USVLOG_DEBUG=1 for a traceback)", file=sys.stderr)
        return 3
    finally:
        _restore_signal_handlers(old)


def run() -> None:
    sys.exit(main())
