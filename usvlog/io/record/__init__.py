"""Live recording: sources (serial, UDP, TCP) -> power-loss-safe canonical MCAP log.

Names are imported on first use (PEP 562 module ``__getattr__``): ``usvlog record``
imports :mod:`.sources` (standard library only) to open its sockets before numpy,
pandas and the MCAP writer are loaded, and importing that module must not load them.
"""

from __future__ import annotations

import importlib as _importlib

_LAZY = {"check_outputs": ".output", "part_path": ".output", "Recorder": ".recorder",
         "RecordSummary": ".session", "record": ".session", "Source": ".sources", "SourceSpec": ".sources",
         "open_sources": ".sources", "parse_source": ".sources", "RecorderStatus": ".status",
         "SourceStatus": ".status", "META_RECORDING": ".topics"}

__all__ = ["META_RECORDING", "RecordSummary", "Recorder", "RecorderStatus", "Source", "SourceSpec", "SourceStatus",
           "check_outputs", "open_sources", "parse_source", "part_path", "record"]


def __getattr__(name: str):
    """Import a name of this package on first use and keep it in the namespace."""
    mod = _LAZY.get(name)
    if mod is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(_importlib.import_module(mod, __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
