"""Read settings files (TOML): vessels, scenarios, gains."""

from __future__ import annotations

import tomllib
from pathlib import Path

from ..errors import ConfigError
from ..model.vessel import Vessel, default_vessel, vessel_from_toml
from .atomic import reading


def read_text(path) -> str:
    p = Path(path)
    try:
        with reading(p):
            return p.read_text()
    except UnicodeDecodeError as err:
        raise ConfigError(f"{p}: not a text file") from err


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


def load_vessel_or_scenario_vessel(path) -> Vessel:
    """A vessel file, or the ``[vessel]`` of a scenario file."""
    from ..model.vessel import vessel_from_dict

    doc = read_toml(path)
    if "model" in doc or "thrusters" in doc:
        return vessel_from_toml(read_text(path), source=str(path))
    v = doc.get("vessel")
    if isinstance(v, dict):
        if "file" in v:
            return load_vessel(Path(path).parent / v["file"])
        return vessel_from_dict(v, source=f"{path} [vessel]")
    raise ConfigError(f"{path}: neither a vessel file ([model]) nor a scenario with [vessel]")
