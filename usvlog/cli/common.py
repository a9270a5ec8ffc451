"""Helpers shared by the verbs: JSON output, progress (standard library only: the parser is built fast)."""

from __future__ import annotations

import json
import sys


def _default(o):
    """JSON form of what ``json`` does not know: result objects, numpy scalars and arrays."""
    if hasattr(o, "to_dict"):
        return o.to_dict()
    if hasattr(o, "tolist"):  # numpy integer/floating scalars -> int/float, arrays -> lists
        return o.tolist()
    return str(o)


def print_json(obj) -> None:
    json.dump(obj, sys.stdout, indent=2, default=_default, allow_nan=True)
    sys.stdout.write("\n")


def stage(msg: str) -> None:
    """A progress line on stderr (stdout stays clean for --json)."""
    print(msg, file=sys.stderr, flush=True)
