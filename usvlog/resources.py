"""Locate the data shipped with usvlog: channel schemas, replay scenarios and vessels.

In a wheel they live inside the package (``usvlog/_schemas``, ``usvlog/_replay``,
``usvlog/_vessels``); in a source checkout they are the top-level ``schemas/``,
``replay/`` and ``vessels/`` folders.
"""

from __future__ import annotations

from pathlib import Path

_PKG = Path(__file__).resolve().parent


def _find(packaged: str, top: str) -> Path:
    for cand in (_PKG / packaged, _PKG.parent / top):
        if cand.is_dir():
            return cand
    return _PKG.parent / top


def schemas_dir() -> Path:
    """The directory of the channel JSON Schemas (``usvlog/_schemas`` in a wheel, else ``schemas/``).

    The packaged directory wins when both exist; the path is returned even when neither
    does (the caller reports the missing file).
    """
    return _find("_schemas", "schemas")


def replay_dir() -> Path:
    """The directory of the shipped scenario TOML files (``usvlog/_replay`` in a wheel, else ``replay/``).

    The packaged directory wins when both exist; the path is returned even when neither
    does (the caller reports the missing file).
    """
    return _find("_replay", "replay")


def vessels_dir() -> Path:
    """The directory of the shipped vessel TOML files (``usvlog/_vessels`` in a wheel, else ``vessels/``).

    The packaged directory wins when both exist; the path is returned even when neither
    does (the caller reports the missing file).
    """
    return _find("_vessels", "vessels")
