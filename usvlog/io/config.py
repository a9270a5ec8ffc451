"""Read settings files (TOML): vessels, scenarios, gains."""

from __future__ import annotations

import tomllib
from pathlib import Path

from ..errors import ConfigError
from ..model.vessel import Vessel, default_vessel, vessel_from_dict, vessel_from_toml
from ..resources import vessels_dir
from .atomic import reading


def read_text(path) -> str:
    """The text of a settings file.

    Raises
    ------
    usvlog.errors.StorageError
        If the file is missing or unreadable.
    usvlog.errors.ConfigError
        If it is not text (not UTF-8).
    """
    p = Path(path)
    try:
        with reading(p):
            return p.read_text()
    except UnicodeDecodeError as err:
        raise ConfigError(f"{p}: not a text file") from err


def read_toml(path) -> dict:
    """A TOML file parsed into a dict.

    Raises
    ------
    usvlog.errors.StorageError
        If the file is missing or unreadable.
    usvlog.errors.ConfigError
        If it is not text or not valid TOML.
    """
    try:
        return tomllib.loads(read_text(path))
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"{path}: not valid TOML: {err}") from err


def load_vessel(path=None) -> Vessel:
    """A vessel TOML file, or the paper's Section IV vessel when ``path`` is None.

    Parameters
    ----------
    path : str or os.PathLike, optional
        Vessel file (``name``, ``[model]`` or ``[extended]``, ``[thrusters]``; see docs/vessels.md),
        or the name of a vessel shipped with usvlog (``catamaran`` or ``catamaran.toml``)
        when no such file exists.

    Returns
    -------
    Vessel

    Raises
    ------
    usvlog.errors.StorageError
        If the file is missing or unreadable.
    usvlog.errors.ConfigError
        If it is not a valid vessel document.
    """
    if path is None:
        return default_vessel()
    return vessel_from_toml(read_text(shipped_vessel(path)), source=str(path))


def shipped_vessel(path) -> Path:
    """``path`` itself, or the shipped vessel file of that name when ``path`` does not exist.

    Parameters
    ----------
    path : str or os.PathLike
        A vessel file, or a bare name (``catamaran``, ``catamaran.toml``) of a file in
        :func:`usvlog.resources.vessels_dir`.

    Returns
    -------
    pathlib.Path
        The file to read (``path`` unchanged when it exists, has a directory part or no
        shipped file has its name; reading it then reports the missing file).
    """
    p = Path(path)
    if p.exists() or p.parent != Path("."):
        return p
    for cand in (vessels_dir() / p.name, vessels_dir() / f"{p.name}.toml"):
        if cand.is_file():
            return cand
    return p


def load_vessel_or_scenario_vessel(path) -> Vessel:
    """A vessel file, or the ``[vessel]`` of a scenario file.

    A scenario's ``[vessel] file = ...`` is read relative to the scenario.

    Returns
    -------
    Vessel

    Raises
    ------
    usvlog.errors.StorageError
        If a file is missing or unreadable.
    usvlog.errors.ConfigError
        If the file is neither a vessel file nor a scenario with ``[vessel]``, or invalid.
    """
    path = shipped_vessel(path)
    doc = read_toml(path)
    if "model" in doc or "extended" in doc or "thrusters" in doc:
        return vessel_from_toml(read_text(path), source=str(path))
    v = doc.get("vessel")
    if isinstance(v, dict):
        if "file" in v:
            return load_vessel(Path(path).parent / v["file"])
        return vessel_from_dict(v, source=f"{path} [vessel]")
    raise ConfigError(f"{path}: neither a vessel file ([model]) nor a scenario with [vessel]")
