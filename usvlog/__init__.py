"""usvlog: field logs of small unmanned surface vessels -> estimates, models, replays.

The package namespace is the Python API, one function per command line verb (see
:mod:`usvlog.api`): ``load``, ``save``, ``import_log``, ``inspect``, ``export``, ``simulate``,
``estimate``, ``identify``, ``gains``, ``replay``, ``to_rrd``, ``report``, ``regress``, ``campaign``, ``check``; plus
:class:`FieldLog` (one run in memory) and :class:`UsvlogError` (every error a user can cause).

Everything is imported on first use (PEP 562 module ``__getattr__``), so ``import usvlog``
loads neither numpy nor pandas. ``usvlog.estimate``, ``usvlog.identify``, ``usvlog.replay``
and ``usvlog.regress`` are the API functions even though subpackages of the same names
exist: reach those with ``from usvlog.estimate import EstimateSettings`` or
``importlib.import_module("usvlog.estimate")`` (``import usvlog.estimate as m`` binds the function).
"""

from __future__ import annotations

import importlib as _importlib
import sys as _sys
import types as _types

from ._version import __version__

_API = ("load", "save", "import_log", "inspect", "export", "simulate", "estimate", "identify", "gains",
        "replay", "to_rrd", "report", "regress", "campaign", "manoeuvres", "check")
_LAZY = {"FieldLog": "usvlog.log.fieldlog", "UsvlogError": "usvlog.errors", **{n: "usvlog.api" for n in _API}}

__all__ = ["FieldLog", "UsvlogError", "__version__", *_API]


def __getattr__(name: str):
    """Import an API name on first use and keep it in the namespace."""
    mod = _LAZY.get(name)
    if mod is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(_importlib.import_module(mod), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))


class _Package(_types.ModuleType):
    """The package module: importing a subpackage named like an API function (``usvlog.estimate``,
    ``usvlog.identify``, ``usvlog.replay``, ``usvlog.regress``) must not replace the function."""

    def __setattr__(self, name: str, value) -> None:
        if name in _API and isinstance(value, _types.ModuleType):
            return  # the import system binds a loaded submodule on its parent; it stays in sys.modules
        super().__setattr__(name, value)


_sys.modules[__name__].__class__ = _Package
