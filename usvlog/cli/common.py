"""Helpers shared by the verbs: JSON output, progress, ROLE=VALUE options (standard library and usvlog's
errors only: the parser is built fast)."""

from __future__ import annotations

import json
import sys

from ..errors import ConfigError


def _default(o):
    """JSON form of what ``json`` does not know: result objects, numpy scalars and arrays."""
    if hasattr(o, "to_dict"):
        return o.to_dict()
    if hasattr(o, "tolist"):  # numpy integer/floating scalars -> int/float, arrays -> lists
        return o.tolist()
    return str(o)


def parse_pairs(items, what: str) -> dict:
    """``["ROLE=VALUE", ...]`` -> {role: value} (for --column / --topic)."""
    out = {}
    for it in items or []:
        role, sep, val = str(it).partition("=")
        if not sep or not role.strip() or not val.strip():
            raise ConfigError(f"{what} {it!r} is not ROLE=VALUE")
        out[role.strip()] = val.strip()
    return out


def print_json(obj) -> None:
    json.dump(obj, sys.stdout, indent=2, default=_default, allow_nan=True)
    sys.stdout.write("\n")


def stage(msg: str) -> None:
    """A progress line on stderr (stdout stays clean for --json)."""
    print(msg, file=sys.stderr, flush=True)


BLAS_THREAD_VARS = ("OPENBLAS_NUM_THREADS", "GOTO_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def one_blas_thread() -> None:
    """Ask the BLAS numpy loads for one thread, unless the user chose a number (one of
    :data:`BLAS_THREAD_VARS` set) or numpy is loaded already (then it has no effect).

    Called for every verb (their linear algebra is many small products, a few thousand rows
    by ~10 columns): OpenBLAS's extra threads spin-wait between them, ~25 % of ``identify``'s
    CPU time on a 1-hour log, for no shorter wall time on 2 cores. Products summed in one
    thread may round differently in the last bit."""
    import os

    if "numpy" in sys.modules or any(os.environ.get(v) for v in BLAS_THREAD_VARS):
        return
    os.environ["OPENBLAS_NUM_THREADS"] = "1"
