"""Helpers shared by the verbs: JSON output, progress."""

from __future__ import annotations

import json
import sys

import numpy as np


def _default(o):
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.floating,)):
        return float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    if hasattr(o, "to_dict"):
        return o.to_dict()
    return str(o)


def print_json(obj) -> None:
    json.dump(obj, sys.stdout, indent=2, default=_default, allow_nan=True)
    sys.stdout.write("\n")


def stage(msg: str) -> None:
    """A progress line on stderr (stdout stays clean for --json)."""
    print(msg, file=sys.stderr, flush=True)
