"""Read settings files (TOML): vessels, scenarios, gains."""

from __future__ import annotations

import tomllib
from pathlib import Path

from ..errors import ConfigError, StorageError
from ..vessel import Vessel, default_vessel, vessel_from_toml


def read_text(path) -> str:
    p = Path(path)
    try:
        return p.read_text()
    except FileNotFoundError as err:
        raise StorageError(f"{p}: no such file") from err
    except UnicodeDecodeError as err:
        raise ConfigError(f"{p}: not a text file") from err
    except OSError as err:
        raise StorageError(f"{p}: cannot read ({err.strerror})") from err


def read_toml(path) -> dict:
    try:
        return tomllib.loads(read_text(path))
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"{path}: not valid TOML: {err}") from err


def load_vessel(path=None) -> Vessel:
    """A vessel TOML file, or the paper's Section IV vessel when ``path`` is None."""
    if path is None:
        return default_vessel()
    return vessel_from_toml(read_text(path), source=str(path))
