"""Closed-loop scenarios: the ``replay/*.toml`` files (see docs/replay.md) as :class:`Scenario` objects.

:func:`scenario_from_dict` checks a parsed document; :func:`load_scenario` reads a file (or a
name of a shipped scenario) through :mod:`usvlog.io.config`.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field, fields
from pathlib import Path as FilePath

import numpy as np

from ..control.gains import Gains, GuidanceSettings, gains_from_dict
from ..control.paths import Path, path_from_spec
from ..errors import ConfigError, StorageError
from ..io.config import load_vessel, read_toml
from ..model.vessel import Vessel, default_vessel, vessel_from_dict
from ..resources import replay_dir
from .simulate import (
    SensorSettings,
    SimSettings,
)

META_PATH = "usvlog.path"
RESERVED_SECTIONS = {"dataset", "stages", "baseline"}  # added by regression scenarios
SECTIONS = {"scenario", "simulation", "vessel", "path", "gains", "guidance", "speed", "initial", "metrics"}


@dataclass(frozen=True, kw_only=True)
class Scenario:
    """A closed-loop scenario (TOML in ``replay/``; see docs/replay.md).

    Usually built by :func:`load_scenario` or :func:`scenario_from_dict`.

    Attributes
    ----------
    name, description : str
    kind : str
        Always ``"closed-loop"``.
    sim : SimSettings
        Vessel, duration, step, current, initial state and sensors.
    seed : int
        Seed of the sensor noise.
    controller : {"full", "baseline"}
        Control law (9)-(10), or the paper's baseline PI/PID.
    controller_input : {"truth", "ekf"}
        The controller sees the true state or an online EKF's estimate.
    path_spec : dict
        The ``[path]`` table (see :func:`usvlog.control.paths.path_from_spec`).
    gains : Gains
    guidance : GuidanceSettings
    speed : tuple of tuple of float
        Speed schedule rows (t in s, u_d in m/s[, delta_theta in m]); times increasing.
    metrics_start_s : float
        Tracking metrics are computed from this time on, s.
    source : str
        File the scenario came from (for messages).
    doc : dict
        The parsed document.

    Raises
    ------
    usvlog.errors.ConfigError
        On an unknown controller or input, or an empty or invalid speed schedule.
    """

    name: str
    description: str = ""
    kind: str = "closed-loop"
    sim: SimSettings = field(default_factory=SimSettings)
    seed: int = 0
    controller: str = "full"              # "full" (9)-(10) or "baseline" PI/PID
    controller_input: str = "truth"       # "truth" or "ekf"
    path_spec: dict = field(default_factory=lambda: {"type": "circle", "radius_m": 4.0})
    gains: Gains = field(default_factory=Gains)
    guidance: GuidanceSettings = field(default_factory=GuidanceSettings)
    speed: tuple[tuple[float, ...], ...] = ((0.0, 0.5),)   # (t_s, u_d[, delta_theta])
    metrics_start_s: float = 0.0
    source: str = ""
    doc: dict = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self):
        if self.controller not in ("full", "baseline"):
            raise ConfigError(f"{self.source}: controller {self.controller!r} is not full or baseline")
        if self.controller_input not in ("truth", "ekf"):
            raise ConfigError(f"{self.source}: controller_input {self.controller_input!r} is not truth or ekf")
        if not self.speed:
            raise ConfigError(f"{self.source}: [speed] schedule is empty")
        for r in self.speed:
            if len(r) not in (2, 3) or not all(math.isfinite(a) for a in r):
                raise ConfigError(f"{self.source}: [speed] schedule row {list(r)} is not [t_s, u_d] or "
                                  "[t_s, u_d, delta_theta] of finite numbers")
            if len(r) == 3 and not r[2] > 0:
                raise ConfigError(f"{self.source}: [speed] delta_theta {r[2]} must be > 0")
        ts = [s[0] for s in self.speed]
        if ts != sorted(ts):
            raise ConfigError(f"{self.source}: [speed] schedule times must increase")

    @property
    def schedule(self) -> np.ndarray:
        """(K, 3) rows [t_s, u_d, delta_theta] (delta_theta from [guidance] where not given)."""
        return np.array([(r[0], r[1], r[2] if len(r) > 2 else self.guidance.delta_theta)
                         for r in self.speed], dtype=float)

    def path(self, datum=None) -> Path:
        """The compiled desired path.

        Parameters
        ----------
        datum : Datum, optional
            Datum for lat/lon waypoints (default the simulation's datum).

        Returns
        -------
        usvlog.control.paths.Path

        Raises
        ------
        usvlog.errors.ConfigError
            If the ``[path]`` table is invalid.
        """
        return path_from_spec(self.path_spec, datum=datum if datum is not None else self.sim.datum,
                              source=self.source or self.name)


def _check_keys(table: dict, allowed, where: str) -> None:
    unknown = set(table) - set(allowed)
    if unknown:
        raise ConfigError(f"{where} has unknown key(s) {', '.join(sorted(unknown))}")


def scenario_from_dict(doc: dict, *, source: str = "scenario", vessel: Vessel | None = None) -> Scenario:
    """Parsed scenario TOML -> :class:`Scenario`. ``vessel`` replaces ``[vessel] file = ...``.

    Parameters
    ----------
    doc : dict
        The parsed document (sections scenario, simulation, vessel, path, gains,
        guidance, speed, initial, metrics).
    source : str, default "scenario"
        Name of the document, for error messages.
    vessel : Vessel, optional
        Vessel to use instead of the document's ``[vessel]`` (default: that table, else
        the built-in vessel).

    Returns
    -------
    Scenario
        With the path already checked.

    Raises
    ------
    usvlog.errors.ConfigError
        On an unknown section or key, a missing ``[path]`` or ``[speed]``, an unresolved
        ``[vessel] file``, or an invalid value.
    """
    for k, v in doc.items():
        if k not in SECTIONS | RESERVED_SECTIONS:
            raise ConfigError(f"{source}: unknown section [{k}]")
        if not isinstance(v, dict):
            raise ConfigError(f"{source}: [{k}] must be a table")
    sc = doc.get("scenario", {})
    _check_keys(sc, {"name", "description", "kind"}, f"{source}: [scenario]")
    kind = sc.get("kind", "closed-loop")
    if kind != "closed-loop":
        raise ConfigError(f"{source}: [scenario] kind {kind!r} is not closed-loop")
    sim = dict(doc.get("simulation", {}))
    sim_keys = {f.name for f in fields(SimSettings)} - {"vessel", "sensors", "eta0", "nu0", "datum"}
    _check_keys(sim, sim_keys | {"seed", "controller", "controller_input", "sensors"}, f"{source}: [simulation]")
    sens = sim.pop("sensors", {})
    _check_keys(sens, {f.name for f in fields(SensorSettings)}, f"{source}: [simulation.sensors]")
    seed = sim.pop("seed", 0)
    controller = sim.pop("controller", "full")
    cinput = sim.pop("controller_input", "truth")
    if vessel is None:
        vdoc = doc.get("vessel")
        if vdoc is None:
            vessel = default_vessel()
        else:
            if "file" in vdoc:
                raise ConfigError(f"{source}: [vessel] file = ... must be resolved by the loader")
            _check_keys(vdoc, {"name", "model", "thrusters"}, f"{source}: [vessel]")
            vessel = vessel_from_dict(vdoc, source=f"{source} [vessel]")
    init = doc.get("initial", {})
    _check_keys(init, {"eta", "nu"}, f"{source}: [initial]")
    speed = doc.get("speed", {})
    _check_keys(speed, {"schedule", "u_d"}, f"{source}: [speed]")
    if "schedule" in speed:
        sched = speed["schedule"]
    elif "u_d" in speed:
        sched = [[0.0, speed["u_d"]]]
    else:
        raise ConfigError(f"{source}: [speed] needs schedule = [[t_s, u_d], ...] or u_d")
    try:
        sched_t = tuple(tuple(float(a) for a in row) for row in sched)
    except (TypeError, ValueError) as err:
        raise ConfigError(f"{source}: [speed] schedule must be a list of [t_s, u_d] rows") from err
    metrics = doc.get("metrics", {})
    _check_keys(metrics, {"start_s"}, f"{source}: [metrics]")
    if "path" not in doc:
        raise ConfigError(f"{source}: no [path] table")
    gains, guid = gains_from_dict(doc, source)
    try:
        st = SimSettings(vessel=vessel, sensors=SensorSettings(**{k: _tuples(v) for k, v in sens.items()}),
                         eta0=tuple(float(a) for a in init.get("eta", (0.0, 0.0, 0.0))),
                         nu0=tuple(float(a) for a in init.get("nu", (0.0, 0.0, 0.0))), **sim)
        if len(st.eta0) != 3 or len(st.nu0) != 3:
            raise ConfigError("[initial] eta and nu need 3 numbers each")
        scen = Scenario(name=str(sc.get("name", source)), description=str(sc.get("description", "")),
                        kind=kind, sim=st, seed=int(seed), controller=controller, controller_input=cinput,
                        path_spec=dict(doc["path"]), gains=gains, guidance=guid, speed=sched_t,
                        metrics_start_s=float(metrics.get("start_s", 0.0)), source=source, doc=doc)
    except (TypeError, ValueError) as err:
        if isinstance(err, ConfigError) and str(err).startswith(source):
            raise
        raise ConfigError(f"{source}: {err}") from err
    scen.path()  # validate the path now
    return scen


def _tuples(v):
    return tuple(tuple(x) for x in v) if isinstance(v, list) else v


def scenario_path(name_or_path) -> FilePath:
    """A scenario file path, or a name resolved to ``replay/<name>.toml`` of the package.

    Anything ending in ``.toml``, containing ``/`` or existing is taken as a path as is.

    Raises
    ------
    usvlog.errors.StorageError
        If a bare name is not a shipped scenario.
    """
    p = FilePath(name_or_path)
    if p.suffix == ".toml" or p.exists() or "/" in str(name_or_path):
        return p
    cand = replay_dir() / f"{name_or_path}.toml"
    if not cand.exists():
        have = ", ".join(closed_loop_scenarios()) or "none"
        raise StorageError(f"no scenario {name_or_path!r} (a file, or a name in replay/: {have})")
    return cand


def closed_loop_scenarios() -> list[str]:
    """Names of the shipped closed-loop scenarios (regression-only ones, ``[dataset]`` without ``[path]``, left out)."""
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
    """Read a closed-loop scenario TOML (``[vessel] file = ...`` is relative to the scenario).

    Parameters
    ----------
    name_or_path : str or os.PathLike
        A file, or the name of a shipped scenario (see :func:`closed_loop_scenarios`).
    vessel : Vessel, optional
        Replaces the scenario's vessel.

    Returns
    -------
    Scenario

    Raises
    ------
    usvlog.errors.StorageError
        If the file cannot be found or read.
    usvlog.errors.ConfigError
        If it is not a valid closed-loop scenario (e.g. a regression scenario).
    """
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
    """``[gains]`` + ``[guidance]`` from a gains file or a scenario file.

    Returns
    -------
    (Gains, GuidanceSettings)

    Raises
    ------
    usvlog.errors.StorageError
        If the file cannot be read.
    usvlog.errors.ConfigError
        If it is not valid TOML or the tables are invalid.
    """
    return gains_from_dict(read_toml(path), source=str(path))
