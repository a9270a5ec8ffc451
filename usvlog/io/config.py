"""Read settings files (TOML): vessels, scenarios, gains."""

from __future__ import annotations

import tomllib
from pathlib import Path

from ..errors import ConfigError, StorageError
from ..vessel import Vessel, default_vessel, vessel_from_toml
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


def scenario_path(name_or_path) -> Path:
    """A scenario file path, or a name resolved to ``replay/<name>.toml`` of the package."""
    from ..resources import replay_dir

    p = Path(name_or_path)
    if p.suffix == ".toml" or p.exists() or "/" in str(name_or_path):
        return p
    cand = replay_dir() / f"{name_or_path}.toml"
    if not cand.exists():
        have = ", ".join(closed_loop_scenarios()) or "none"
        raise StorageError(f"no scenario {name_or_path!r} (a file, or a name in replay/: {have})")
    return cand


def closed_loop_scenarios() -> list[str]:
    """Names of the shipped closed-loop scenarios (regression-only ones, ``[dataset]`` without ``[path]``, left out)."""
    from ..resources import replay_dir

    names = []
    for q in sorted(replay_dir().glob("*.toml")):
        try:
            doc = tomllib.loads(q.read_text())
            if "path" in doc or "dataset" not in doc:
                names.append(q.stem)
        except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
            continue
    return names


def load_scenario(name_or_path, *, vessel=None):
    """Read a closed-loop scenario TOML (``[vessel] file = ...`` is relative to the scenario)."""
    from ..replay import scenario_from_dict

    path = scenario_path(name_or_path)
    doc = read_toml(path)
    if "dataset" in doc and "path" not in doc:
        raise ConfigError(f"{path}: a regression scenario ([dataset]): run it with usvlog regress; closed-loop "
                          f"scenarios: {', '.join(closed_loop_scenarios())} or a file like them")
    vdoc = doc.get("vessel")
    if vessel is None and isinstance(vdoc, dict) and "file" in vdoc:
        extra = set(vdoc) - {"file"}
        if extra:
            raise ConfigError(f"{path}: [vessel] file = ... cannot be combined with {', '.join(sorted(extra))}")
        vessel = load_vessel(path.parent / vdoc["file"])
    return scenario_from_dict(doc, source=str(path), vessel=vessel)


def load_gains(path):
    """``[gains]`` + ``[guidance]`` from a gains file or a scenario file."""
    from ..control.gains import gains_from_dict

    return gains_from_dict(read_toml(path), source=str(path))


def load_vessel_or_scenario_vessel(path) -> Vessel:
    """A vessel file, or the ``[vessel]`` of a scenario file."""
    from ..vessel import vessel_from_dict

    doc = read_toml(path)
    if "model" in doc or "thrusters" in doc:
        return vessel_from_toml(read_text(path), source=str(path))
    v = doc.get("vessel")
    if isinstance(v, dict):
        if "file" in v:
            return load_vessel(Path(path).parent / v["file"])
        return vessel_from_dict(v, source=f"{path} [vessel]")
    raise ConfigError(f"{path}: neither a vessel file ([model]) nor a scenario with [vessel]")
