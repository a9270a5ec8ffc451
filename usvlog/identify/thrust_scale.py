"""Identification when the log's thrust has no known force scale.

Commands in ``counts``, ``normalized`` or PWM units become forces only through a thruster
map; when that map is missing or only a guess (the import's health record says
``force_scale = "unknown"``, or the vessel's ``thrusters.known`` is false), the forces are
known up to the thrust gain g: F = g_f s(c) for a forward command, g_r s(c) for a reverse
one, with s the map's shape (c or c|c|, c the normalized command). Dividing eq. (3) by
g_f,

    (M / g_f) nu_dot + (C(nu) / g_f) nu + (D / g_f) nu = s+(c) + rho s-(c),   rho = g_r / g_f,

shows what the log can tell: the model *per unit of command* (m / g_f, Iz / g_f, d / g_f;
xg is a length and unchanged) and the reverse-to-forward ratio rho. So the fit runs in
command units (a thruster map with forward_n = 1 and reverse_n = rho), and only ratios of
the physical parameters are identified. One physical value known (``--fix m=33``: a
weighed mass) fixes the scale: g_f = 33 / (m / g_f) and every per-unit value times g_f is
the physical one; the gains forward_n = g_f and reverse_n = rho g_f come out as well.

rho is estimated by equation error (the per-unit model is linear in it), where the model's
inertia terms, biased by the smoother, do not enter the ratio of the two input columns
much, and refined by output error; the output-error fit then runs with rho held. That search
is :mod:`usvlog.identify.thrust_ratio`.

PWM commands (every record in ``pwm_us``) also have their map identified first
(:mod:`usvlog.identify.thrust_map`): the deadband about the neutral pulse width, the shape's
quadratic share q and rho, by an equation-error profile over the deadband. When the data
determine the deadband the fit runs through that map (``map = "mixed"`` with
``deadband_us`` and ``quadratic_share``, written to the vessel TOML's ``[thrusters]``), rho
then refined as above; when they do not (the boat never came near neutral, a flat profile)
the vessel's own map is kept and the record says why.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import pandas as pd

from ..choices import EXTENDED_PARAM_NAMES
from ..errors import ConfigError, FitFailed
from ..log.fieldlog import FieldLog
from ..log.summary import health_from_provenance
from ..model.thrusters import SHAPED_MAPS
from ..model.vessel import PARAM_NAMES, ExtendedParams, Vessel, VesselParams
from .data import run_data
from .smooth import derivative, kinematic_states, smooth_like
from .thrust_map import ThrustMapFit, fit_thrust_map
from .thrust_ratio import (
    EE_ACC_S,
    SCALE_FREE,
    command_unit_vessel,
    profile_ratio,
    profile_ratio_ext,
    reverse_ratio,
    without_logged_forces,
)

EXT_ALIAS = {"m": "m11", "Iz": "m66"}
"""Paper symbols fixed with the extended model: the extended terms they stand for (as in
:meth:`usvlog.model.vessel.ExtendedParams.paper_terms`)."""

EXT_PROFILE_SEGMENT_S = 30.0   # shooting segments of the extended ratio search (longer ones stall more)

Z95 = 1.959963984540054


@dataclass(frozen=True, kw_only=True)
class ThrustScale:
    """Which thrust-scale case an identification is, and what it found about the gain.

    Attributes
    ----------
    case : {"known", "command units", "gain identified"}
        ``known``: forces in newtons (logged or through a known map); ``command units``:
        the model per unit of full forward command (only ratios identified);
        ``gain identified``: as ``command units``, scaled by a fixed physical value.
    ratio : float
        Reverse-to-forward gain ratio rho (NaN when known).
    ratio_from : str
        ``"equation error"`` or ``"vessel"`` (no reverse thrust in the log to tell).
    fixed_by : str or None
        The fixed parameter that set the scale (``gain identified``).
    forward_n, reverse_n : float
        Gains in N at full forward and reverse command (``gain identified``; NaN else).
    forward_stderr_n : float
        Standard error of ``forward_n`` in N (reverse: times ``ratio``).
    shape : {"linear", "quadratic", "mixed"}
        Map shape s(c) the commands went through (``mixed``: (1 - q) c + q c|c|).
    structure : {"paper", "extended"}
        The model the per-unit values are of (what the message names).
    deadband_us : float
        Half-width of the map's deadband about the neutral pulse width, us (the
        identified one, or the vessel's when the data did not determine it; NaN when the
        commands are not PWM).
    deadband_ci95_us : (float, float)
        Its 95 % profile-likelihood interval, us (NaN when not identified).
    quadratic_share : float
        q of the shape (NaN unless ``mixed``).
    map_from : str
        ``"equation error profile"`` (deadband, shape and ratio identified), ``"vessel"``
        (PWM commands whose deadband the data did not determine: the vessel's map kept) or
        "" (not PWM commands: no map identified).
    map_note : str
        Why the deadband was not determined ("" otherwise).
    """

    case: str = "known"
    ratio: float = float("nan")
    ratio_from: str = ""
    fixed_by: str | None = None
    forward_n: float = float("nan")
    reverse_n: float = float("nan")
    forward_stderr_n: float = float("nan")
    shape: str = "linear"
    structure: str = "paper"
    deadband_us: float = float("nan")
    deadband_ci95_us: tuple[float, float] = (float("nan"), float("nan"))
    quadratic_share: float = float("nan")
    map_from: str = ""
    map_note: str = ""

    @property
    def known(self) -> bool:
        """True when the forces were known in newtons."""
        return self.case == "known"

    def to_dict(self) -> dict:
        """JSON-ready: case, ratio, ratio_from, fixed_by, forward_n, reverse_n, forward_stderr_n, shape,
        structure, deadband_us, deadband_ci95_us, deadband_determined, quadratic_share, map_from,
        map_note (NaN written as None)."""
        def num(x):
            return None if x is None or not math.isfinite(x) else float(x)
        return {"case": self.case, "ratio": num(self.ratio), "ratio_from": self.ratio_from or None,
                "fixed_by": self.fixed_by, "forward_n": num(self.forward_n), "reverse_n": num(self.reverse_n),
                "forward_stderr_n": num(self.forward_stderr_n), "shape": self.shape,
                "structure": self.structure, "deadband_us": num(self.deadband_us),
                "deadband_ci95_us": [num(self.deadband_ci95_us[0]), num(self.deadband_ci95_us[1])],
                "deadband_determined": self.map_from == "equation error profile",
                "quadratic_share": num(self.quadratic_share), "map_from": self.map_from or None,
                "map_note": self.map_note or None}

    def map_message(self) -> str:
        """The identified thruster map in plain words ("" when the commands were not PWM)."""
        if self.map_from == "equation error profile":
            lo, hi = self.deadband_ci95_us
            return (f"thruster map identified from the PWM commands: no thrust within +-{self.deadband_us:.1f} us "
                    f"of neutral (95 % interval {lo:.1f}..{hi:.1f} us), shape {self.quadratic_share:.2f} quadratic "
                    f"and {1 - self.quadratic_share:.2f} linear beyond it")
        if self.map_from == "vessel":
            db = self.deadband_us if math.isfinite(self.deadband_us) else 0.0
            kept = f"the vessel's {self.shape} map kept" + (f" with its +-{db:g} us deadband" if db else
                                                             " (no deadband)")
            return f"thruster deadband not determined by the data ({self.map_note}): {kept}"
        return ""

    def message(self) -> str:
        """One plain line for the verdict ("" when known)."""
        text = self._scale_message()
        extra = self.map_message()
        return f"{text}; {extra}" if text and extra else text

    def _scale_message(self) -> str:
        if self.case == "command units":
            what, fix = (("m, Iz and the damping", "a weighed m") if self.structure == "paper" else
                         ("the extended model's inertias m11, m22, m26, m66 and its damping",
                          "m11, a weighed mass plus the surge added mass"))
            return (f"thrust scale unknown: identified in command units ({what} per unit of full "
                    f"forward command; only their ratios are physical; reverse/forward gain {self.ratio:.3g} "
                    f"from {self.ratio_from}); --fix one physical value (e.g. {fix}) to get the gain")
        if self.case == "gain identified":
            return (f"thrust scale unknown: gain identified from the fixed {self.fixed_by}: "
                    f"{self.forward_n:.4g} N forward, {self.reverse_n:.4g} N reverse at full command "
                    f"(+- {self.forward_stderr_n:.2g} N)")
        return ""


def thrust_scale_known(log: FieldLog, vessel: Vessel) -> bool:
    """Whether a log's thrust has a known force scale.

    Parameters
    ----------
    log : FieldLog
        Needs ``/thrust/command``.
    vessel : Vessel
        The vessel the identification uses (its thruster map).

    Returns
    -------
    bool
        False when some commands are not newtons and the import judged the force scale
        unknown, the vessel's thruster map is only a guess (``known = false``) or there
        is no map (``identity``) and no logged forces; True otherwise.
    """
    fr = log["/thrust/command"]
    units = set(fr["unit"].astype(str).unique()) if "unit" in fr else {"newton"}
    if units <= {"newton"}:
        return True
    if (health_from_provenance(log.provenance) or {}).get("thrust", {}).get("force_scale") == "unknown":
        return False
    if not vessel.thrusters.known:
        return False
    logged = ("thrust_left_n" in fr and "thrust_right_n" in fr
              and np.isfinite(fr["thrust_left_n"].to_numpy(float)).all()
              and np.isfinite(fr["thrust_right_n"].to_numpy(float)).all())
    return bool(logged or vessel.thrusters.map != "identity")


def pwm_commands(logs: list[FieldLog]) -> bool:
    """True when every ``/thrust/command`` record of every log is a pulse width (``pwm_us``)."""
    for log in logs:
        fr = log["/thrust/command"]
        if "unit" not in fr or len(fr) == 0 or set(fr["unit"].astype(str).unique()) != {"pwm_us"}:
            return False
    return True


def thrust_map_from_logs(logs: list[FieldLog], vessel: Vessel, *,
                         quadratic_share: float | None = None) -> ThrustMapFit:
    """The thruster map of PWM-commanded runs from the data (:func:`usvlog.identify.thrust_map.fit_thrust_map`).

    The smoothed states and their derivatives (the window of :func:`reverse_ratio`), and
    each thruster's pulse-width offset from the vessel's ``pwm_neutral_us`` as the thruster
    sees it (reversed channels flipped), held between records.

    Parameters
    ----------
    logs : list of FieldLog
        Runs whose ``/thrust/command`` is in ``pwm_us`` (:func:`pwm_commands`).
    vessel : Vessel
        Arm, PWM neutral and span, reversed channels; its ratio reverse_n / forward_n is the
        one held when the runs have too little reverse thrust.
    quadratic_share : float, optional
        Hold the shape's q (default: fitted).

    Returns
    -------
    ThrustMapFit

    Raises
    ------
    usvlog.errors.FitFailed
        Too few samples to smooth or fit.
    usvlog.errors.InputError
        A log lacks a channel the runs need.
    """
    thr = vessel.thrusters
    grids, nus, nuds, cmds = [], [], [], []
    for log in logs:
        log = without_logged_forces(log)
        r1 = run_data(log, command_unit_vessel(vessel, 1.0))
        ks = kinematic_states(log, r1, vessel)
        nu = ks.nu((0.0, 0.0))
        grids.append(ks.t)
        nus.append(smooth_like(ks.t, nu, EE_ACC_S))
        nuds.append(derivative(ks.t, nu, EE_ACC_S))
        fr = log["/thrust/command"]
        t_ns = np.asarray(fr.index, dtype=np.int64)
        left, right = fr["left"].to_numpy(float), fr["right"].to_numpy(float)
        ok = np.isfinite(left) & np.isfinite(right)   # a bad record is skipped: the one before stays in force
        t_ns, left, right = t_ns[ok], left[ok], right[ok]
        order = np.argsort(t_ns, kind="stable")
        t_ns, left, right = t_ns[order], left[order], right[order]
        keep = np.concatenate([[True], np.diff(t_ns) > 0])
        t_ns, left, right = t_ns[keep], left[keep], right[keep]
        span = thr.pwm_span_us
        cmds.append(((t_ns - r1.t0_ns) / 1e9, span * thr.normalize(left, "pwm_us", side="left"),
                     span * thr.normalize(right, "pwm_us", side="right")))
    return fit_thrust_map(grids, nus, nuds, cmds, arm_m=thr.arm_m, span_us=thr.pwm_span_us,
                          quadratic_share=quadratic_share, smooth=lambda t, y: smooth_like(t, y, EE_ACC_S),
                          ratio_prior=thr.reverse_n / thr.forward_n)


def with_identified_map(vessel: Vessel, tmap: ThrustMapFit) -> Vessel:
    """The vessel whose thrusters follow an identified map: ``mixed`` with its deadband and
    quadratic share (the gains as they were; :func:`command_unit_vessel` sets them)."""
    t = vessel.thrusters
    return replace(vessel, thrusters=replace(t, map="mixed", quadratic_share=float(tmap.quadratic_share),
                                             deadband_us=float(tmap.deadband_us)))


def scale_fix(fix: dict) -> tuple[dict, str | None]:
    """Split fixed values into those valid in command units and the one setting the scale.

    Parameters
    ----------
    fix : dict of str to float
        Fixed parameters by paper symbol, SI units.

    Returns
    -------
    per_unit_fix : dict
        Fixed values the command-unit fit can hold (``xg``, a length).
    scale_by : str or None
        The physical parameter that sets the thrust gain (``m`` preferred, then ``Iz``,
        ``d11``, ``d33``, ``d22``); None without one.
    """
    per_unit = {k: v for k, v in fix.items() if k in SCALE_FREE}
    for k in ("m", "Iz", "d11", "d33", "d22"):
        if k in fix:
            return per_unit, k
    return per_unit, None


def scale_results(theta, cov, names, fix: dict, scale_by: str, param_names=PARAM_NAMES, scale_free=SCALE_FREE):
    """Physical parameters, their covariance and the forward gain from a command-unit fit.

    With p_f fixed, g = p_f / q_f and p_k = g q_k for every parameter k the gain scales
    (q: per-unit values); the covariance by the delta method from the per-unit one.

    Parameters
    ----------
    theta : array_like, shape (6,) or (10,)
        Per-unit m, Iz, d11, d22, d33 and xg (``param_names`` order).
    cov : numpy.ndarray
        Covariance of the fitted quantities ``names`` (per-unit parameters, currents).
    names : sequence of str
        Row names of ``cov``.
    fix : dict
        The user's fixed values (physical).
    scale_by : str
        The fixed parameter that sets the scale.
    param_names : sequence of str, default PARAM_NAMES
        Names of ``theta`` (EXTENDED_PARAM_NAMES for the extended model).
    scale_free : sequence of str, default SCALE_FREE
        Those the gain does not scale (none of the extended model's).

    Returns
    -------
    theta : numpy.ndarray, shape (6,)
        Physical parameters (fixed ones at their values).
    cov : numpy.ndarray
        Covariance of the physical free quantities, rows ``names`` without ``scale_by``.
    names : tuple of str
    gain : float
        Forward thrust gain g (N at full forward command, per unit of the map shape).
    gain_se : float
        Its standard error, N.
    """
    theta = np.asarray(theta, float)
    names = list(names)
    q_f = theta[param_names.index(scale_by)]
    g = fix[scale_by] / q_f
    n = len(names)
    Jm = np.zeros((n, n))   # d(physical free quantities)/d(per-unit fitted ones)
    i_f = names.index(scale_by) if scale_by in names else None
    for i, k in enumerate(names):
        if k in param_names and k not in scale_free:
            Jm[i, i] = g
            if i_f is not None:
                Jm[i, i_f] = -g * theta[param_names.index(k)] / q_f
        else:
            Jm[i, i] = 1.0
    cov_p = Jm @ cov @ Jm.T
    gain_se = float(g / q_f * math.sqrt(max(cov[i_f, i_f], 0.0))) if i_f is not None else 0.0
    keep = [i for i, k in enumerate(names) if k != scale_by]
    out = theta.copy()
    for i, k in enumerate(param_names):
        if k not in scale_free:
            out[i] = g * theta[i]
    out[param_names.index(scale_by)] = fix[scale_by]
    return out, cov_p[np.ix_(keep, keep)], tuple(names[i] for i in keep), float(g), gain_se




def fit_in_command_units(ident, logs: list[FieldLog], vessel: Vessel):
    """:meth:`usvlog.identify.Identifier.fit` for runs whose thrust has no known force scale.

    For PWM commands the thruster map first (:func:`thrust_map_from_logs`: deadband, shape
    and ratio; used when the data determine the deadband, else the vessel's map is kept and
    ``thrust_scale_`` says why). The reverse-to-forward ratio (equation error, then refined
    by output error for that method: of the paper's model, or with ``model`` extended or
    both of the extended one, :func:`profile_ratio_ext`), then the identifier's own fit in
    command units through that map; with one
    physical value fixed, everything scaled to physical units and the gains found (the
    extended model: every term times the gain, ``m`` standing for m11 and ``Iz`` for m66).
    Sets the fitted attributes of ``ident`` (``thrust_scale_`` says which case it is and of
    which model) and returns it.

    Parameters
    ----------
    ident : usvlog.identify.Identifier
        The identifier (its settings; its fitted attributes are set).
    logs : list of FieldLog
    vessel : Vessel
        Arm and map shape (its forces are not trusted).

    Returns
    -------
    usvlog.identify.Identifier
        ``ident``, fitted.

    Raises
    ------
    usvlog.errors.ConfigError
        If more than one scale-carrying value (m, Iz, d11, d22, d33) is fixed.
    """
    import copy

    fix_all = dict(ident.fix)
    if ident.model == "paper":
        per_unit_fix, scale_by = scale_fix(fix_all)
        carrying = [k for k in fix_all if k not in SCALE_FREE]
        if len(carrying) > 1:
            raise ConfigError(f"with an unknown thrust scale fix one of m, Iz, d11, d22, d33 (it sets the thrust "
                              f"gain), not {len(carrying)} ({', '.join(carrying)})")
    else:   # the Identifier allows one scale-setting value (m, Iz, m11, m22, m66) and nothing else
        per_unit_fix, scale_by = {}, next(iter(fix_all), None)
    # PWM commands: the map (deadband, shape, ratio) from the data first, when they determine it
    map_rec = _identify_map(logs, vessel)
    tmap = map_rec["fit"]
    if tmap is not None and tmap.determined:
        vessel = with_identified_map(vessel, tmap)
    shape = vessel.thrusters.map if vessel.thrusters.map in SHAPED_MAPS else "linear"
    if tmap is not None and tmap.determined and tmap.ratio_fitted and tmap.ratio > 0:
        rho, how = tmap.ratio, "equation error"   # the map's own profile solved it at its deadband
    else:
        rho, how = reverse_ratio(logs, vessel)
    # the prior in command units: the vessel's values per newton of its (guessed) full forward force
    base = vessel.params.as_array()
    base[[PARAM_NAMES.index(k) for k in PARAM_NAMES if k not in SCALE_FREE]] /= vessel.thrusters.forward_n
    for k, v in per_unit_fix.items():
        base[PARAM_NAMES.index(k)] = v
    ext_prior = None
    if how == "equation error" and ident.method == "output-error" and ident.model != "paper":
        # the extended model's own ratio search (with "both" too: it nests the paper's model)
        rho, th_ext = profile_ratio_ext(logs, vessel, rho, fit_current=ident.current,
                                        max_current_mps=ident.max_current_mps, segment_s=EXT_PROFILE_SEGMENT_S)
        how = "output error of the extended model"
        try:
            ext_prior = ExtendedParams(**dict(zip(EXTENDED_PARAM_NAMES, map(float, th_ext))))
            base = ext_prior.paper_terms().as_array()
        except ConfigError:   # the search found no boat: the inner fit starts from equation error
            ext_prior = None
    elif how == "equation error" and ident.method == "output-error":
        free = np.array([k not in per_unit_fix for k in PARAM_NAMES])
        rho, base = profile_ratio(logs, vessel, rho, free_mask=free, fit_current=ident.current,
                                  segment_s=min(ident.segment_s, 120.0), fix_theta=base)
        how = "output error"
    inner = copy.copy(ident)
    inner.fix = per_unit_fix
    inner._command_units = True
    inner.thrust_scale_ = ThrustScale(case="command units", ratio=rho, ratio_from=how, shape=shape,
                                      structure="paper" if ident.model == "paper" else "extended",
                                      **map_rec["fields"])
    prior = VesselParams(**dict(zip(PARAM_NAMES, map(float, base))))
    vcmd = command_unit_vessel(replace(vessel, params=prior, extended=ext_prior), rho)
    inner.fit([without_logged_forces(lg) for lg in logs], vcmd)
    structure = "paper" if inner.extended_ is None else "extended"
    inner.thrust_scale_ = replace(inner.thrust_scale_, structure=structure)
    if structure != "paper":   # the verdict's message names the model returned
        inner.reasons_, inner.verdict_ = inner._verdict(inner.vessel_in_, inner.runs_, inner._kin)
        inner.usable_ = inner.verdict_ != "unusable"
    ident.__dict__.update(inner.__dict__)
    ident.fix = dict(fix_all)
    ident._command_units = False
    if scale_by is None:
        return ident
    if structure == "extended":
        g, g_se = _scale_extended(ident, inner, fix_all[scale_by], EXT_ALIAS.get(scale_by, scale_by))
    else:
        g, g_se = _scale_paper(ident, inner, fix_all, scale_by)
    ident.runs_ = [replace(r, tau_u=g * r.tau_u, tau_r=g * r.tau_r) for r in inner.runs_]
    ee = inner.equation_error_
    k_scale = np.array([1.0 if k in SCALE_FREE else g for k in PARAM_NAMES])
    ident.equation_error_ = replace(ee, theta=ee.theta * k_scale,
                                    stderr={k: v * (1.0 if k in SCALE_FREE else g) for k, v in ee.stderr.items()})
    t = vessel.thrusters
    ident.vessel_in_ = replace(vessel, thrusters=replace(t, map=shape, forward_n=g, reverse_n=g * rho, known=True,
                                                         scale="known"))
    ident.thrust_scale_ = ThrustScale(case="gain identified", ratio=rho, ratio_from=how, fixed_by=scale_by,
                                      forward_n=g, reverse_n=g * rho, forward_stderr_n=g_se, shape=shape,
                                      structure=structure, **map_rec["fields"])
    ident.reasons_, ident.verdict_ = ident._verdict(ident.vessel_in_, ident.runs_, ident._kin)
    ident.usable_ = ident.verdict_ != "unusable"
    return ident


def _identify_map(logs: list[FieldLog], vessel: Vessel) -> dict:
    """The thruster map of PWM-commanded runs (:func:`thrust_map_from_logs`) as ``{"fit":
    ThrustMapFit or None, "fields": the ThrustScale fields that report it}``; no fit for
    commands in other units or a vessel whose map has no shape (identity, catalogue)."""
    t = vessel.thrusters
    if not pwm_commands(logs):
        return {"fit": None, "fields": {}}
    try:
        fit = thrust_map_from_logs(logs, vessel)
    except FitFailed as err:   # too short to smooth or fit: the vessel's map, and why
        return {"fit": None, "fields": {"deadband_us": float(t.deadband_us), "map_from": "vessel",
                                        "map_note": f"no map could be fitted: {err}",
                                        "quadratic_share": _share(t)}}
    if fit.determined:
        return {"fit": fit, "fields": {"deadband_us": fit.deadband_us, "deadband_ci95_us": fit.ci95_us,
                                       "quadratic_share": fit.quadratic_share, "map_from": "equation error profile"}}
    return {"fit": fit, "fields": {"deadband_us": float(t.deadband_us), "map_from": "vessel", "map_note": fit.why,
                                   "quadratic_share": _share(t)}}


def _share(t) -> float:
    """The quadratic share of a shaped map, NaN for the others."""
    return t.share if t.map in SHAPED_MAPS else float("nan")


def _scale_paper(ident, inner, fix_all: dict, scale_by: str) -> tuple[float, float]:
    """Sets ``ident``'s paper-model results in physical units from ``inner``'s per-unit ones;
    returns the forward gain and its standard error (N)."""
    names = list(inner.corr_.index)
    theta, cov, names2, g, g_se = scale_results(inner.theta_, inner.cov_, names, fix_all, scale_by)
    se = np.sqrt(np.maximum(np.diag(cov), 0.0))
    stderr = {k: 0.0 for k in PARAM_NAMES}
    for i, k in enumerate(names2):
        if k in stderr:
            stderr[k] = float(se[i])
    ident.theta_ = theta
    ident.params_ = VesselParams(**{k: float(v) for k, v in zip(PARAM_NAMES, theta)})
    ident.stderr_ = stderr
    ident.ci95_ = {k: (float(v - Z95 * stderr[k]), float(v + Z95 * stderr[k])) for k, v in zip(PARAM_NAMES, theta)}
    ident.cov_ = cov
    sd = np.sqrt(np.maximum(np.diag(cov), 1e-300))
    ident.corr_ = pd.DataFrame(cov / np.outer(sd, sd), index=list(names2), columns=list(names2))
    return g, g_se


def _scale_extended(ident, inner, value: float, key: str) -> tuple[float, float]:
    """Sets ``ident``'s extended-model results in physical units from ``inner``'s per-unit ones
    (every extended term carries the gain: none is a pure length), ``key`` held at ``value``;
    returns the forward gain and its standard error (N)."""
    from .extended_oe import ExtendedOEResult  # local: only the extended scaling reads it

    cand = inner.final_
    fitted = cand.fitted
    if isinstance(fitted, ExtendedOEResult):
        names, cov = list(fitted.names), fitted.cov
    else:   # equation error: independent standard errors
        names = list(EXTENDED_PARAM_NAMES)
        cov = np.diag([fitted.stderr[k] ** 2 for k in names])
    theta, cov_p, names_p, g, g_se = scale_results(cand.theta, cov, names, {key: value}, key,
                                                   EXTENDED_PARAM_NAMES, ())
    se = np.sqrt(np.maximum(np.diag(cov_p), 0.0))
    stderr = {k: 0.0 for k in EXTENDED_PARAM_NAMES}
    stderr.update({k: float(x) for k, x in zip(names_p, se) if k in stderr})
    if isinstance(fitted, ExtendedOEResult):
        fitted = replace(fitted, theta=theta, cov=cov_p, names=list(names_p), stderr=stderr)
    else:
        fitted = replace(fitted, theta=theta, stderr=stderr)
    ident._set_ext_result(replace(cand, theta=theta, fitted=fitted), inner.runs_)
    return g, g_se


__all__ = ["ThrustScale", "fit_in_command_units", "pwm_commands", "scale_fix", "scale_results", "thrust_map_from_logs",
           "thrust_scale_known", "with_identified_map"]
