"""A vessel: its name, model parameters and thrusters, read from and written to a vessel TOML.

:class:`Vessel` holds the paper's parameters (:mod:`usvlog.model.dynamics`), the extended
model when the vessel has that structure (:mod:`usvlog.model.extended`) and the thrusters
(:mod:`usvlog.model.thrusters`); :func:`vessel_from_toml` / :meth:`Vessel.to_toml` read and
write its file, :meth:`Vessel.to_dict` / :meth:`Vessel.from_dict` its MCAP metadata record.

The model's names are re-exported here, where the rest of usvlog imports them from
(``from usvlog.model.vessel import VesselParams, nu_dot_terms, Thrusters, ...``).
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import asdict, dataclass, field, fields, replace
from typing import Any

from ..choices import EXTENDED_PARAM_NAMES, PARAM_NAMES, THRUST_UNITS
from ..errors import ConfigError
from .dynamics import (
    VesselParams,
    check_finite,
    coriolis_matrix,
    damping_matrix,
    eta_dot,
    euler_step,
    mass_matrix,
    model_residual,
    nu_dot,
    nu_dot_jacobian,
    nu_dot_jacobian_terms,
    nu_dot_tau_matrix,
    nu_dot_terms,
    plant_jacobian,
    plant_rhs,
    require_finite,
    rk4_step,
)
from .extended import ExtendedParams, nu_dot_ext, nu_dot_ext_terms
from .thrusters import CATALOGUE_MAPS, THRUSTER_MAPS, THRUSTER_SIDES, Thrusters

__all__ = [
    "CATALOGUE_MAPS", "EXTENDED_PARAM_NAMES", "PARAM_NAMES", "THRUST_UNITS", "THRUSTER_MAPS", "THRUSTER_SIDES",
    "ExtendedParams", "Thrusters", "Vessel", "VesselParams", "check_finite", "coriolis_matrix", "damping_matrix",
    "default_vessel", "eta_dot", "euler_step", "extended_vessel", "mass_matrix", "model_residual", "nu_dot",
    "nu_dot_ext", "nu_dot_ext_terms", "nu_dot_jacobian", "nu_dot_jacobian_terms", "nu_dot_tau_matrix",
    "nu_dot_terms", "plant_jacobian", "plant_rhs", "require_finite", "rk4_step", "vessel_from_dict",
    "vessel_from_toml",
]


@dataclass(frozen=True, kw_only=True)
class Vessel:
    """A vessel: its name, model parameters and thrusters, as read from a vessel TOML.

    Parameters
    ----------
    name : str, default "paper-section-iv"
        Name stored in logs and reports.
    params : VesselParams, default VesselParams()
        Model parameters of eq. (3) (the paper's Section IV vessel by default). For a vessel
        of the extended structure: the paper terms of ``extended``
        (:meth:`ExtendedParams.paper_terms`), which the paper's controller and the
        estimator use.
    thrusters : Thrusters, default Thrusters()
        Thruster geometry and command-to-force map.
    extended : ExtendedParams or None, default None
        The extended model, when the vessel has that structure; the simulated plant
        then follows it (see :func:`extended_vessel`).
    heading_offset_deg : float or None, default None
        Heading sensor mounting offset, deg in [-360, 360], measured minus true (the
        estimator fuses the measured heading minus it); ``[sensors] heading_offset_deg``
        in the vessel TOML. None: not stated.

    See Also
    --------
    vessel_from_toml, vessel_from_dict, default_vessel
    """

    name: str = "paper-section-iv"
    params: VesselParams = field(default_factory=VesselParams)
    thrusters: Thrusters = field(default_factory=Thrusters)
    extended: ExtendedParams | None = None
    heading_offset_deg: float | None = None

    def __post_init__(self):
        h = self.heading_offset_deg
        if h is not None and not (math.isfinite(h) and -360.0 <= h <= 360.0):
            raise ConfigError(f"[sensors] heading_offset_deg = {h} must be an angle in [-360, 360] deg")

    @property
    def structure(self) -> str:
        """``"extended"`` when the vessel has an extended model, else ``"paper"``."""
        return "paper" if self.extended is None else "extended"

    def plant_params(self) -> ExtendedParams:
        """The model the simulated plant follows, in the extended form.

        Returns
        -------
        ExtendedParams
            ``extended``, or the paper's parameters written in the extended form.
        """
        return self.extended if self.extended is not None else ExtendedParams.from_paper(self.params)

    def to_toml(self) -> str:
        """The vessel as a TOML document that :func:`vessel_from_toml` reads back exactly.

        Returns
        -------
        str
            ``name``, a ``[model]`` table (paper symbols, SI units) or, for the extended
            structure, ``structure = "extended"`` and an ``[extended]`` table, and a
            ``[thrusters]`` table; floats are written with ``repr`` (no rounding),
            infinities as ``inf``. Thruster fields at their defaults (``lag_s``,
            ``scale``, ``supply_v``, the reversed flags, ``deadband_us``,
            ``quadratic_share``) are left out, and so are a
            catalogue map's ``forward_n``/``reverse_n`` (written as a comment: the map
            sets them from ``supply_v``).
        """
        p, t = self.params, self.thrusters
        lines = [f'name = "{self.name}"']
        if self.extended is None:
            lines += ["", "[model]"] + [f"{k} = {_toml_float(v)}" for k, v in p.to_dict().items()]
        else:
            lines += ['structure = "extended"', "", "[extended]"]
            lines += [f"{k} = {_toml_float(v)}" for k, v in self.extended.to_dict().items()]
        lines += ["", "[thrusters]"]
        for f in fields(Thrusters):
            v = getattr(t, f.name)
            if _thruster_default(f.name, v):
                continue  # the defaults: files of vessels without them stay as they were
            if t.catalogue and f.name in ("forward_n", "reverse_n"):
                lines.append(f"# {f.name} = {_toml_float(v)}  (the {t.map} map's own maximum at supply_v)")
                continue
            if isinstance(v, bool):
                lines.append(f"{f.name} = {'true' if v else 'false'}")
            elif isinstance(v, str):
                lines.append(f'{f.name} = "{v}"')
            else:
                lines.append(f"{f.name} = {_toml_float(v)}")
        if self.heading_offset_deg is not None:
            lines += ["", "[sensors]", f"heading_offset_deg = {_toml_float(self.heading_offset_deg)}"]
        return "\n".join(lines) + "\n"

    def to_dict(self) -> dict[str, str]:
        """Flat string map (MCAP metadata record).

        Returns
        -------
        dict of str to str
            ``name``, ``model.<symbol>`` (the paper terms), ``extended.<field>`` (extended
            structure only) and ``thrusters.<field>`` entries (``lag_s``, ``scale``,
            ``supply_v``, the reversed flags, ``deadband_us`` and ``quadratic_share``
            only when not the default);
            read back by :meth:`from_dict`.
        """
        d = {"name": self.name}
        d.update({f"model.{k}": repr(v) for k, v in self.params.to_dict().items()})
        if self.extended is not None:
            d.update({f"extended.{k}": repr(v) for k, v in self.extended.to_dict().items()})
        d.update({f"thrusters.{k}": str(v) for k, v in asdict(self.thrusters).items()
                  if not _thruster_default(k, v)})
        if self.heading_offset_deg is not None:
            d["sensors.heading_offset_deg"] = repr(self.heading_offset_deg)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, str]) -> Vessel:
        """Vessel from the flat string map written by :meth:`to_dict`.

        Parameters
        ----------
        d : mapping of str to str
            ``name`` (default ``"vessel"``), ``model.<symbol>`` and ``thrusters.<field>``
            entries; missing ones take the defaults of :class:`VesselParams` and
            :class:`Thrusters`.

        Returns
        -------
        Vessel

        Raises
        ------
        usvlog.errors.ConfigError
            If a value is out of range.
        ValueError
            If a numeric entry is not a number.
        """
        model = {k.split(".", 1)[1]: float(v) for k, v in d.items() if k.startswith("model.")}
        thr: dict = {}
        for f in fields(Thrusters):
            key = f"thrusters.{f.name}"
            if key in d:
                v = d[key]
                thr[f.name] = v if f.type == "str" else (v == "True") if f.type == "bool" else float(v)
        ext = {k.split(".", 1)[1]: float(v) for k, v in d.items() if k.startswith("extended.")}
        off = float(d["sensors.heading_offset_deg"]) if "sensors.heading_offset_deg" in d else None
        if ext:
            return replace(extended_vessel(d.get("name", "vessel"), ExtendedParams(**ext), Thrusters(**thr)),
                           heading_offset_deg=off)
        return cls(name=d.get("name", "vessel"), params=VesselParams(**model), thrusters=Thrusters(**thr),
                   heading_offset_deg=off)

    def with_params(self, **changes) -> Vessel:
        """A copy with some model parameters replaced.

        Parameters
        ----------
        **changes : float
            New values by paper symbol (``m``, ``Iz``, ``d11``, ``d22``, ``d33``, ``xg``),
            SI units as in :class:`VesselParams`.

        Returns
        -------
        Vessel
            The same name and thrusters with the new parameters (checked again). An
            extended model is dropped: the copy is a vessel of the paper's structure.
        """
        return replace(self, params=replace(self.params, **changes), extended=None)


def extended_vessel(name: str, ext: ExtendedParams, thrusters: Thrusters | None = None) -> Vessel:
    """A vessel of the extended structure, its paper terms derived from the extended model.

    Parameters
    ----------
    name : str
        Vessel name.
    ext : ExtendedParams
        The extended model (the simulated plant follows it).
    thrusters : Thrusters, optional
        Default ``Thrusters()``.

    Returns
    -------
    Vessel
        ``params`` = :meth:`ExtendedParams.paper_terms` (what the paper's controller and
        the estimator use), ``extended`` = ``ext``.
    """
    return Vessel(name=str(name), params=ext.paper_terms(), thrusters=thrusters or Thrusters(), extended=ext)


_THRUSTER_DEFAULTS = (("lag_s", 0.0), ("scale", "known"), ("supply_v", None), ("reversed_left", False),
                      ("reversed_right", False), ("deadband_us", 0.0), ("quadratic_share", None))


def _thruster_default(name: str, value) -> bool:
    """A thruster field a vessel file or metadata record leaves out when it has this value."""
    for k, d in _THRUSTER_DEFAULTS:
        if name == k:
            return value is d if (d is None or isinstance(d, bool)) else value == d
    return False


def _toml_float(v: float) -> str:
    if math.isinf(v):
        return "inf" if v > 0 else "-inf"
    return repr(float(v))


def vessel_from_toml(text: str, source: str = "<vessel>") -> Vessel:
    """Parse a vessel TOML document (see docs/vessels.md) into a :class:`Vessel`.

    Parameters
    ----------
    text : str
        The TOML document: ``name``, ``[model]`` (paper symbols, SI units) or, for the
        extended structure, ``[extended]`` (fields of :class:`ExtendedParams`; optionally
        ``structure = "extended"``), and ``[thrusters]`` (fields of :class:`Thrusters`);
        missing keys take the defaults.
    source : str, default "<vessel>"
        Name of the document (usually its path), for error messages.

    Returns
    -------
    Vessel

    Raises
    ------
    usvlog.errors.ConfigError
        If the text is not valid TOML, has an unknown key or a value out of range.
    """
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"{source}: not valid TOML: {err}") from err
    return vessel_from_dict(doc, source)


def vessel_from_dict(doc: dict, source: str = "<vessel>") -> Vessel:
    """A parsed vessel document ({name, model: {...}, thrusters: {...}}) -> :class:`Vessel`.

    Parameters
    ----------
    doc : dict
        The parsed document; see :func:`vessel_from_toml`.
    source : str, default "<vessel>"
        Name of the document, for error messages.

    Returns
    -------
    Vessel

    Raises
    ------
    usvlog.errors.ConfigError
        On an unknown key or a value that is not a number or out of range, or a
        structure that does not match the tables given.
    """
    structure = doc.get("structure", "extended" if "extended" in doc else "paper")
    if structure not in ("paper", "extended"):
        raise ConfigError(f"{source}: structure {structure!r} is not paper or extended")
    offset = _heading_offset_from_dict(doc.get("sensors", {}), source)
    if structure == "extended":
        return replace(_extended_from_dict(doc, source), heading_offset_deg=offset)
    if "extended" in doc:
        raise ConfigError(f"{source}: an [extended] table needs structure = \"extended\"")
    model = doc.get("model", {})
    known_m = set(PARAM_NAMES)
    for k in model:
        if k not in known_m:
            raise ConfigError(f"{source}: [model] has unknown key {k!r} (expected {', '.join(PARAM_NAMES)})")
    thrusters = _thrusters_from_dict(doc.get("thrusters", {}), source)
    try:
        params = VesselParams(**{k: float(v) for k, v in model.items()})
    except (ConfigError, TypeError, ValueError) as err:
        raise ConfigError(f"{source}: {err}") from err
    return Vessel(name=str(doc.get("name", "vessel")), params=params, thrusters=thrusters, heading_offset_deg=offset)


def _heading_offset_from_dict(sensors: dict, source: str) -> float | None:
    """``[sensors] heading_offset_deg`` (deg, in [-360, 360]) or None; no other key is known."""
    if not isinstance(sensors, dict):
        raise ConfigError(f"{source}: sensors must be a table ([sensors])")
    for k in sensors:
        if k != "heading_offset_deg":
            raise ConfigError(f"{source}: [sensors] has unknown key {k!r} (expected heading_offset_deg)")
    v = sensors.get("heading_offset_deg")
    if v is None:
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and -360.0 <= v <= 360.0):
        raise ConfigError(f"{source}: [sensors] heading_offset_deg = {v!r} must be an angle in [-360, 360] deg")
    return float(v)


def _thrusters_from_dict(thr: dict, source: str) -> Thrusters:
    known_t = {f.name for f in fields(Thrusters)}
    for k in thr:
        if k not in known_t:
            raise ConfigError(f"{source}: [thrusters] has unknown key {k!r}")
    try:
        tvals: dict[str, Any] = {k: (v if isinstance(v, (str, bool)) else float(v)) for k, v in thr.items()}
        t = Thrusters(**tvals)
    except (ConfigError, TypeError, ValueError) as err:
        raise ConfigError(f"{source}: {err}") from err
    if t.catalogue:   # a catalogue map sets its own limits: a file may omit them, not contradict them
        for k in ("forward_n", "reverse_n"):
            if k in tvals and not (isinstance(tvals[k], float) and math.isclose(tvals[k], getattr(t, k), rel_tol=1e-9)):
                raise ConfigError(f"{source}: [thrusters] {k} = {tvals[k]!r} N contradicts the {t.map} map's "
                                  f"{getattr(t, k):.4g} N at supply_v = {t.supply_v:g} V (leave {k} out)")
    return t


def _extended_from_dict(doc: dict, source: str) -> Vessel:
    """A vessel of the extended structure from its parsed document (``[extended]``, no ``[model]``)."""
    if "model" in doc:
        raise ConfigError(f"{source}: an extended vessel takes [extended], not [model] (its paper terms are "
                          "derived from the extended model)")
    ext = doc.get("extended")
    if not isinstance(ext, dict):
        raise ConfigError(f"{source}: structure = \"extended\" needs an [extended] table")
    known = {f.name for f in fields(ExtendedParams)}
    for k in ext:
        if k not in known:
            raise ConfigError(f"{source}: [extended] has unknown key {k!r} (expected {', '.join(sorted(known))})")
    for k in ("m11", "m22", "m26", "m66", "d11", "d22", "d33"):
        if k not in ext:
            raise ConfigError(f"{source}: [extended] lacks {k}")
    try:
        params = ExtendedParams(**{k: float(v) for k, v in ext.items()})
    except (ConfigError, TypeError, ValueError) as err:
        raise ConfigError(f"{source}: {err}") from err
    return extended_vessel(str(doc.get("name", "vessel")), params, _thrusters_from_dict(doc.get("thrusters", {}),
                                                                                        source))


def default_vessel() -> Vessel:
    """The paper's Section IV vessel: m = 33 kg, Iz = 10 kg m^2, d = 5, xg = 0.1 m.

    Returns
    -------
    Vessel
        ``Vessel()``: the default :class:`VesselParams` and :class:`Thrusters`
        (identity map, 0.3 m arm, 20 N forward / 12 N reverse).
    """
    return Vessel()
