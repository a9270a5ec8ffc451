"""Range checks shared by the parameter dataclasses (vessel model, controller gains)."""

from __future__ import annotations

import math

from .errors import ConfigError


def require_finite(obj, names, kind: str) -> None:
    """Every field in ``names`` of ``obj`` is a finite number (not a bool), else ConfigError."""
    for f in names:
        v = getattr(obj, f)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ConfigError(f"{kind} {f} = {v!r} is not a finite number")
