"""Identifier: scikit-learn style fitter of the paper's model (3) from field logs."""

from __future__ import annotations

import math
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from .._cpu import spare_cpu
from ..choices import EXT_SCALE_FIX, EXTENDED_PARAM_NAMES, IDENTIFY_METHODS, IDENTIFY_MODELS
from ..errors import ConfigError, FitFailed, InputError, UnusableResultError
from ..estimate import EstimateSettings, estimate
from ..estimate.latency import stored_delays, with_settings_delays
from ..log.fieldlog import FieldLog
from ..log.summary import health_from_provenance, propulsion_from_provenance
from ..model.frames import ssa
from ..model.stats import fit_percent
from ..model.vessel import PARAM_NAMES, ExtendedParams, Vessel, VesselParams, default_vessel, extended_vessel
from .ahead import excited_channels, fit_percent_ahead
from .data import RunData, run_data
from .equation import EquationErrorResult, fit_equation_error
from .output import (
    OutputErrorResult,
    fit_initial_state,
    fit_output_error,
    predict_segments,
    simulate_run,
    velocity_samples,
)
from .signs import channel_signs, surge_sign, thrust_yaw_sign
from .smooth import KinStates, derivative, kinematic_states, smooth_like, thrust_on_grid
from .surge import SurgeFit, fit_surge
from .thrust_scale import EXT_PROFILE_SEGMENT_S, ThrustScale, fit_in_command_units, thrust_scale_known
from .velocity import VelocityFitResult, data_scales, fit_velocity_error

if TYPE_CHECKING:   # the extended model and filter error are imported where used (start-up of the default fit)
    from .extended import ExtendedFit

METHODS = IDENTIFY_METHODS
Z95 = 1.959963984540054
# equation-error smoothing (s): positions, heading, accelerations (thrust filtered alike)
EE_POS_S, EE_PSI_S, EE_ACC_S = 16.0, 6.0, 6.0
DEFAULT_HOLDOUT = 0.3       # one log: the last 30 % validates
MAX_CURRENT_MPS = 0.5       # default bound on each current component (m/s)
VEL_WEIGHT = 1.0            # weight of the smoothed velocities against GPS + compass (robust start)
PREFER_WITHIN = 1.0         # fit % points: a preferred candidate this close to the best is taken
# the surge equation's own m (fit_surge) this factor away from the full fit's: a candidate holding it
SURGE_MASS_RATIO = 1.5
VERDICTS = ("usable", "usable with caveats", "unusable")
# verdict thresholds: validation fit % of u and r; relative standard error of m, Iz, d11, d33
FIT_UNUSABLE, FIT_CAVEAT = 0.0, 50.0
U_FIT_UNUSABLE = -50.0      # u: its measurement noise alone can cost tens of points
REL_SE_CAVEAT, REL_SE_UNUSABLE = 0.10, 0.3
COND_CAVEAT = 1e5
EXT_SEGMENT_S = 120.0       # extended output error: shooting segment length (s)
EXT_REFIT_ITER = 20         # extended output error: iterations of the refit on all data (it starts converged)
AHEAD_S = (5.0, 10.0, 30.0)  # k-step-ahead validation horizons (s): a path follower's prediction horizons


@dataclass(frozen=True, kw_only=True)
class Validation:
    """Free run of the identified model through a run's recorded thrust.

    Attributes
    ----------
    fit_percent : dict of str to float
        NRMSE fit in % after the initial window, 100 (1 - |y - yhat| / |y - mean y|), for
        ``u``, ``v``, ``r`` and ``track`` (north and east together); 100 is perfect.
    t : numpy.ndarray, shape (N,)
        Time in s from the run's first thrust sample (smoothed-state grid).
    measured : numpy.ndarray, shape (N, 6)
        n (m), e (m), psi (rad), u (m/s), v (m/s), r (rad/s) from the smoothed
        measurements (u, v relative to the water for ``current``).
    simulated : numpy.ndarray, shape (N, 6)
        The model's free run, same columns.
    current : (float, float)
        Current north, east in m/s used (fitted with the initial state).
    init_window_s : float
        Initial state (and current) fitted on [0, init_window_s] s of the run.
    """

    fit_percent: dict            # "u", "v", "r", "track": 100 (1 - |y - yhat| / |y - mean y|)
    t: np.ndarray                # s from the run's start (smoothed-state grid)
    measured: np.ndarray         # (N, 6) n, e, psi, u, v, r from the smoothed measurements
    simulated: np.ndarray        # (N, 6) the model's free run
    current: tuple[float, float]  # current used (fitted with the initial state)
    init_window_s: float         # initial state (and current) fitted on [0, init_window_s]

    def to_dataframe(self) -> pd.DataFrame:
        """Measured and simulated states side by side, indexed by ``t_s`` (s).

        Columns n_m, n_sim_m, e_m, e_sim_m, psi_rad, psi_sim_rad, u_mps, u_sim_mps, v_mps,
        v_sim_mps, r_radps, r_sim_radps.
        """
        cols = {}
        for i, (name, unit) in enumerate((("n", "m"), ("e", "m"), ("psi", "rad"), ("u", "mps"),
                                          ("v", "mps"), ("r", "radps"))):
            cols[f"{name}_{unit}"] = self.measured[:, i]
            cols[f"{name}_sim_{unit}"] = self.simulated[:, i]
        return pd.DataFrame(cols, index=pd.Index(self.t, name="t_s"))

    @property
    def diverged(self) -> bool:
        """True when the free run left the finite range (a failed model, not a fit %)."""
        return bool(not np.all(np.isfinite(self.simulated)) or
                    np.any(np.abs(self.simulated[:, 3:]) > 1e3))

    @property
    def score(self) -> float:
        """The figure candidates are compared by: mean fit % of the track and of r (-inf when
        diverged). The track (smoothed GPS positions, whose errors are small beside the
        track's extent) judges u and v: a free run's position error integrates their errors.
        The smoothed u and v themselves carry errors of the smoother that are partly
        systematic, so a candidate fitted to them would be favoured for copying them."""
        if self.diverged:
            return -math.inf
        s = 0.5 * (self.fit_percent["track"] + self.fit_percent["r"])
        return float(s) if math.isfinite(s) else -math.inf

    def to_dict(self) -> dict:
        """JSON-ready summary: fit_percent, current_ne_mps, init_window_s, duration_s, diverged."""
        return {"fit_percent": _finite_dict(self.fit_percent), "current_ne_mps": list(self.current),
                "init_window_s": self.init_window_s, "duration_s": float(self.t[-1] - self.t[0]),
                "diverged": self.diverged}


MODEL_RULE = (f"the extended model is returned only when its best candidate validates better than the paper "
              f"model's by at least {PREFER_WITHIN:g} point (score: mean fit % of the held-out track and r); "
              f"never a fit that validates worse than equation error")


def _returned(mc: dict, chosen) -> dict:
    """``returned`` (the chosen candidate's model), ``why`` in plain words and the ``rule`` of
    ``--model both`` for a model comparison ``mc`` (:meth:`Identifier._compare_models`)."""
    model, winner, margin = chosen.start.model, mc.get("winner"), mc.get("margin")
    if chosen.start.kind == "equation-error":
        why = "equation error validates better than the output-error fits"
    elif model == winner:
        why = "it validates better" if margin is None else f"it validates better by {margin:.1f} points"
    elif winner == "extended" and margin is not None and margin < PREFER_WITHIN:
        why = (f"the simpler paper model: the extended one validates better by only {margin:.1f} points "
               f"(less than {PREFER_WITHIN:g})")
    else:
        why = "preferred candidate within the tie margin"
    return {"returned": model, "why": why, "rule": MODEL_RULE}


def _mean_score(vals: list) -> float:
    """Mean :attr:`Validation.score` of a list (a None, a fit that was not a boat, counts -inf)."""
    return float(np.mean([v.score if v is not None else -math.inf for v in vals])) if vals else -math.inf


def _finite_dict(d: dict) -> dict:
    """Values as floats, None where not finite (JSON has no NaN)."""
    return {k: (float(v) if v is not None and math.isfinite(v) else None) for k, v in d.items()}


@dataclass(frozen=True, kw_only=True)
class Start:
    """One candidate of the fit: how it is fitted and from where.

    Attributes
    ----------
    name : str
        Plain-words name (``"output error from equation error"``).
    kind : {"equation-error", "output-error", "filter-error"}
        The fit that makes it (``"equation-error"``: the equation-error values as they are).
    theta : numpy.ndarray, shape (6,)
        Starting m (kg), Iz (kg m^2), d11, d22 (kg/s), d33 (kg m^2/s), xg (m).
    vel_weight : float
        Output error: weight of the smoothed velocities against GPS and compass (0: none).
    model : {"paper", "extended"}
        The model structure fitted (``theta`` then has 6 or 10 values, EXTENDED_PARAM_NAMES
        order for the extended model).
    surge_mass : bool
        Output error with m held at the surge equation's own fit (:func:`~usvlog.identify.surge.fit_surge`,
        made again on the data each fit uses) instead of fitted with the coupled sway and yaw.
    """

    name: str
    kind: str
    theta: np.ndarray
    vel_weight: float = 0.0
    model: str = "paper"
    surge_mass: bool = False


@dataclass(frozen=True, kw_only=True)
class Candidate:
    """A fitted candidate and how it validates.

    Attributes
    ----------
    start : Start
        What was fitted.
    theta : numpy.ndarray, shape (6,)
        Fitted m (kg), Iz (kg m^2), d11, d22 (kg/s), d33 (kg m^2/s), xg (m).
    currents : numpy.ndarray, shape (n_runs, 2)
        Fitted current north, east per run, m/s (zeros when not fitted).
    fitted : object
        The fit's result (EquationErrorResult, OutputErrorResult or FilterErrorResult).
    validations : list of Validation
        Free runs it was judged on (held-out parts, or the fitted runs without validation).
    failed : str
        Why it failed (diverged, impossible values), empty when it did not.
    held_stderr : dict of str to float
        Standard errors of parameters held in the fit but estimated elsewhere (``m`` of a
        ``surge_mass`` start: the surge fit's).
    """

    start: Start
    theta: np.ndarray
    currents: np.ndarray
    fitted: object
    validations: list
    failed: str = ""
    held_stderr: dict = field(default_factory=dict)

    @property
    def fit_percent(self) -> dict:
        """Mean fit % of u, v, r and track over the validations (NaN when failed)."""
        if self.failed or not self.validations:
            return {k: float("nan") for k in ("u", "v", "r", "track")}
        return {k: float(np.mean([v.fit_percent[k] for v in self.validations])) for k in ("u", "v", "r", "track")}

    @property
    def score(self) -> float:
        """Mean over the validations of :attr:`Validation.score` (-inf when failed)."""
        if self.failed or not self.validations:
            return -math.inf
        return float(np.mean([v.score for v in self.validations]))

    def to_dict(self) -> dict:
        """JSON-ready: name, model, params, fit_percent, score, failed."""
        names = EXTENDED_PARAM_NAMES if self.start.model == "extended" else PARAM_NAMES
        return {"name": self.start.name, "model": self.start.model,
                "params": dict(zip(names, map(float, self.theta))),
                "fit_percent": _finite_dict(self.fit_percent),
                "score": self.score if math.isfinite(self.score) else None, "failed": self.failed}


def physical_problem(theta) -> str:
    """Why a parameter vector is not a boat (empty when it is): m, Iz, d.. > 0, finite, Iz - m xg^2 > 0."""
    th = np.asarray(theta, float)
    if not np.all(np.isfinite(th)):
        return "parameters not finite"
    bad = [k for k, v in zip(PARAM_NAMES[:5], th[:5]) if v <= 0]
    if bad:
        return f"{', '.join(bad)} not positive"
    if th[1] - th[0] * th[5] ** 2 <= 0:
        return "Iz - m xg^2 not positive"
    return ""


def _ee_inputs(run: RunData, ks: KinStates, current=(0.0, 0.0)):
    nu = ks.nu(current)
    tu, tr = thrust_on_grid(run, ks.t)
    tu = smooth_like(ks.t, smooth_like(ks.t, tu, EE_POS_S), EE_ACC_S)
    tr = smooth_like(ks.t, smooth_like(ks.t, tr, EE_PSI_S), EE_ACC_S)
    return smooth_like(ks.t, nu, EE_ACC_S), derivative(ks.t, nu, EE_ACC_S), tu, tr


def _log_before(log: FieldLog, t_ns: int) -> FieldLog:
    """The part of a log before ``t_ns`` (every channel)."""
    out = log.copy()
    for topic, frame in log.channels.items():
        out.channels[topic] = frame[np.asarray(frame.index, dtype=np.int64) < t_ns]
    return out


def _ekf_current(log: FieldLog, vessel: Vessel, theta, current: bool) -> tuple[float, float]:
    """Mean water current the dynamic EKF estimates with the identified parameters."""
    if not current:
        return (0.0, 0.0)
    v = Vessel(name=vessel.name, params=VesselParams(**dict(zip(PARAM_NAMES, map(float, theta)))),
               thrusters=vessel.thrusters)
    settings = with_settings_delays(EstimateSettings(model="dynamic", current=True, output_step_s=0.1),
                                    stored_delays(log))   # the latency an earlier estimate found
    st = estimate(log, settings, v).state
    return (float(np.nanmean(st["current_n_mps"])), float(np.nanmean(st["current_e_mps"])))


def fmt_num(x: float, digits: int = 4) -> str:
    """A number for people: ``digits`` significant digits, no endless digit strings."""
    if x is None or not math.isfinite(x):
        return "n/a"
    return f"{x:.{digits}g}"


def fmt_pct(x: float) -> str:
    """A fit % for people: one decimal; below -999 only ``< -999`` (the figure means nothing
    more); ``n/a`` when not finite."""
    if x is None or not math.isfinite(x):
        return "n/a"
    return "< -999" if x < -999 else f"{x:.1f}"


def _rel_pct(rel: float) -> str:
    """A relative standard error for people: whole percent, ``> 999 %`` beyond (it means nothing more)."""
    return "> 999 %" if not math.isfinite(rel) or rel > 9.99 else f"{100 * rel:.0f} %"


def _why_dead(health: dict, topic: str) -> str:
    why = ((health.get("channels") or {}).get(topic) or {}).get("why") or ""
    return why or "no reason recorded"


def _refuse_dead_channels(logs: list[FieldLog], health: list[dict]) -> None:
    """A channel the import judged dead and left out cannot be identified from: unusable, in plain words."""
    for log, h in zip(logs, health):
        dead = [t for t in (h.get("dead") or []) if t in ("/compass/heading", "/gnss/fix")
                and log.get(t) is None]
        if not dead:
            continue
        reasons = [f"{t} was judged dead at import ({_why_dead(h, t)}) and left out" for t in dead]
        if (h.get("thrust") or {}).get("force_scale") == "unknown":
            unit = (h.get("thrust") or {}).get("unit") or "unknown units"
            reasons.append(f"the thrust has no known force scale ({unit})")
        err = UnusableResultError(f"{log.source or 'log'}: identification unusable: " + "; ".join(reasons))
        err.reasons = reasons      # type: ignore[attr-defined]
        raise err


def _refuse_outside_model(logs: list[FieldLog]) -> None:
    """A log whose import found a propeller and rudder (or one thruster) is not the paper's
    twin-thruster boat: the model (3) with differential thrust cannot be fitted to it."""
    for log in logs:
        prop = propulsion_from_provenance(log.provenance)
        if prop is None:
            continue
        reasons = [str(prop["reason"])]
        err = UnusableResultError(f"{log.source or 'log'}: identification refused: " + reasons[0])
        err.reasons = reasons      # type: ignore[attr-defined]
        raise err


def _refuse_wrong_signs(runs: list[RunData], kin: list[KinStates], arm_m: float) -> list:
    """Sign checks of each run (:mod:`usvlog.identify.signs`) before any fit: the yaw rate against
    the differential thrust and the surge speed against the total thrust. A yaw response of the
    wrong sign is refused with the fix (a fit would find negative inertias, or a boat that does not
    exist, and say nothing of why). The surge check is recorded only: the sway-yaw coupling in the
    surge equation makes it far less certain (t ~ 6 against ~ 21 for yaw on a simulated run), and it
    was wrong on a short run of the paper's vessel."""
    checks = []
    for run, ks in zip(runs, kin):
        tu, tr = thrust_on_grid(run, ks.t)
        nu = ks.nu()
        yaw, surge = thrust_yaw_sign(ks.t, tr, nu[:, 2]), surge_sign(ks.t, tu, nu[:, 0])
        fl, fr = 0.5 * (tu + tr / arm_m), 0.5 * (tu - tr / arm_m)   # each channel's force again
        ch = channel_signs(ks.t, fl, fr, nu[:, 0], nu[:, 2])
        checks.append({"source": run.source, "yaw": yaw.to_dict(), "surge": surge.to_dict(),
                       "channels": ch.to_dict()})
        reasons = []
        if ch.verdict.endswith("reversed"):
            side = {"left reversed": "reversed_left = true", "right reversed": "reversed_right = true",
                    "both reversed": "reversed_left = true and reversed_right = true"}[ch.verdict]
            reasons.append(f"{ch.message}: set {side} in the vessel's [thrusters] (commands in PWM, counts or "
                           f"normalized) or negate that channel's recorded forces")
        elif yaw.sign < 0:
            reasons.append(f"{yaw.message}: map the channel named right to thrust_left and the one named left to "
                           f"thrust_right when importing (--column/--topic thrust_left=... thrust_right=...), or "
                           f"set the vessel's arm sign right")
        if reasons:
            err = UnusableResultError(f"{run.source or 'log'}: identification refused: " + "; ".join(reasons))
            err.reasons = reasons      # type: ignore[attr-defined]
            raise err
    return checks


def _excitation_warnings(kin: list[KinStates], force: bool = False) -> list[str]:
    r_rms = math.sqrt(np.mean(np.concatenate([k.r for k in kin]) ** 2))
    psi_span = max(float(np.ptp(k.psi)) for k in kin)
    if r_rms > math.radians(90.0):   # not a boat turning: the heading itself is bad
        return [f"yaw rate rms {math.degrees(r_rms):.0f} deg/s is no boat's: the heading record is bad "
                f"(a dead or noisy compass); Iz, d33, d22 and xg cannot be trusted"]
    if r_rms < math.radians(2.0) or psi_span < math.radians(30.0) or (
            force and (r_rms < math.radians(5.0) or psi_span < math.radians(90.0))):
        return [f"yaw barely excited (yaw rate rms {math.degrees(r_rms):.2f} deg/s, heading span "
                f"{math.degrees(psi_span):.0f} deg): Iz, d33, d22 and xg are not determined; "
                f"add a zig-zag run"]
    return []


class Identifier:
    """Identify m, Iz, d11, d22, d33, xg of eq. (3) from field logs.

    ``method``: ``"output-error"`` (simulate from the recorded thrust, fit GPS and compass;
    the accurate one), ``"equation-error"`` (least squares on smoothed states; fast, biased),
    ``"filter-error"`` (the estimator's dynamic EKF with candidate parameters, maximising the
    innovation likelihood; slower, wider intervals). ``fix``: known values by name (e.g. a weighed
    mass). ``current``: fit a constant water current per run (two nuisance parameters).
    ``segment_s``: multiple-shooting segment length of the final output-error fit.

    Output error fits several candidates and keeps the one that validates best: the
    equation-error result itself (always a candidate: the answer never validates worse than
    it), output error from it fitted to GPS and compass, and output error fitted to GPS,
    compass and the smoothed velocities u, v, r together (a wrong current then cannot buy a
    better position fit with absurd dynamics), from the equation-error values and from the
    given vessel's; and, when the surge equation fitted alone to the GPS track
    (:func:`~usvlog.identify.surge.fit_surge`) puts m more than SURGE_MASS_RATIO away from the
    full fit's, output error with m held at that surge mass (the full fit's m then carries a
    sway or yaw mismatch through the couplings; m's standard error is the surge fit's). A
    candidate whose simulation diverges, or whose values are not a boat's, has failed.
    Validation: one run, the last ``holdout`` of it (default 30 %) is held out; several runs,
    each is left out in turn.

    Follows the scikit-learn contract: :meth:`fit` returns the identifier, and what it
    fitted is in attributes ending in ``_``.

    Parameters
    ----------
    method : {"output-error", "equation-error", "filter-error"}, default "output-error"
        Identification method (see above).
    fix : dict of str to float, optional
        Known parameters by paper symbol, SI units (e.g. ``{"m": 31.5}`` kg); they are
        held at these values and get standard error 0. With ``model`` extended or both only
        one value, and only to set an unknown thrust scale (the fit is in command units and
        this value scales it, :mod:`usvlog.identify.thrust_scale`): ``m`` or ``Iz`` (both
        models), or for the extended model ``m11``, ``m22``, ``m66``. ``m`` is the surge
        inertia in either model (the paper's m, the extended m11 = m - X_udot) and ``Iz``
        the yaw inertia (m66): a weighed mass leaves out the surge added mass, so the
        gain comes out low by that fraction (about 6 % on the shipped catamaran); fix
        ``m11`` with an added-mass estimate to do better.
    current : bool, default True
        Fit a constant water current (north, east) per run. Equation error never fits it.
    segment_s : float, default 300.0
        Output error: segment length in s of the final multiple-shooting fit, > 0.
    warm_segment_s : float, default 60.0
        Output error: a warm-up fit with segments this long (s) on the first 900 s of each
        run precedes the final one when 0 < warm_segment_s < segment_s; 0 turns it off.
    holdout : float, optional
        Fraction in [0, 0.9) of each run's end kept out of the fit and validated on; 0: no
        validation. Default (None): 0.3 for one run; several runs are validated by leaving
        each out in turn. The parameters returned are then refitted on all the data from
        the chosen candidate (kept only if they validate as well).
    max_current_mps : float, default 0.5
        Bound on each component of a fitted current, m/s (> 0).
    model : {"paper", "extended", "both"}, default "paper"
        The model structure: the paper's model (3), the extended model
        (:class:`~usvlog.model.vessel.ExtendedParams`: separate surge and sway inertia, linear
        plus quadratic damping), or both, each fitted by its candidates and the one that
        validates better returned (``model_comparison_`` says by how much). The extended
        model is fitted by output error (multiple shooting from the smoothed states, finite-
        difference Jacobian) from its equation-error fit and from the paper's fit written in
        the extended form; its equation-error fit is its floor.

    Attributes
    ----------
    params_ : VesselParams
        Identified parameters: m (kg), Iz (kg m^2), d11, d22 (kg/s), d33 (kg m^2/s), xg (m).
    theta_ : numpy.ndarray, shape (6,)
        The same as an array in the order m, Iz, d11, d22, d33, xg.
    stderr_ : dict of str to float
        One-sigma standard error of each parameter, in its unit (0 for fixed ones).
    ci95_ : dict of str to (float, float)
        95 % confidence interval of each parameter (value +- 1.96 stderr).
    cov_ : numpy.ndarray
        Covariance of the fitted quantities named in ``corr_`` (free parameters, and for
        output error the currents ``current_n_<i>``, ``current_e_<i>`` in m/s).
    corr_ : pandas.DataFrame
        Correlation matrix of those quantities, labelled by name.
    cond_ : float
        Condition number of the (scaled) estimation problem; NaN for equation error.
    current_ : list of (float, float)
        Water current north, east in m/s per run ((0, 0) when not fitted; filter error:
        the mean current its EKF estimates).
    current_stderr_ : list of (float, float)
        Standard errors of ``current_`` in m/s (NaN where not computed).
    residual_rms_ : dict of str to float
        Output error: RMS of the noise-weighted residuals per sensor (``gps``,
        ``compass``; about 1 when the stated noise is right). Equation error: RMS
        equation error ``surge_n`` (N), ``sway_n`` (N), ``yaw_nm`` (N m). Filter error: empty.
    verdict_ : str
        ``"usable"``, ``"usable with caveats"`` or ``"unusable"``.
    reasons_ : list of str
        Why, in plain words (what makes it less than usable first); notes that do not
        change the verdict follow.
    usable_ : bool
        False when the verdict is unusable.
    candidates_ : list of Candidate
        Every candidate fitted, with its validation; ``chosen_`` is the one returned.
    chosen_ : Candidate
        The candidate the parameters come from.
    thrust_scale_ : ThrustScale
        Whether the thrust had a known force scale; if not, the fit is in command units
        (per unit of full forward command) or, with one physical value fixed, scaled to
        physical units with the thrust gains found (:mod:`usvlog.identify.thrust_scale`).
    equation_error_ : EquationErrorResult
        The equation-error fit (always computed: the output-error start and a candidate).
    oe_ : OutputErrorResult or None
        Full output-error result of the returned parameters (None for the other methods).
    fe_ : FilterErrorResult
        Full filter-error result (only set by that method).
    validation_ : Validation or None
        Free run of the model fitted without it on the held-out data (the first held-out
        run), None without validation.
    validations_ : list of Validation
        All of them (one per held-out run or left-out log).
    validation_mode_ : str
        ``"holdout"``, ``"leave-one-out"`` or ``"none"``.
    loo_switch_ : dict or None
        Leave-one-out only: set when the left-out logs validated equation error (of the same
        model) better than the candidate picked, which is then returned instead (never worse
        than equation error): ``from`` (the candidate's name), ``score`` and
        ``equation_error_score`` (mean :attr:`Validation.score` over the left-out logs).
    vessel_in_ : Vessel
        Vessel given to :meth:`fit` (thruster map and starting values).
    runs_ : list of RunData
        The runs the returned parameters were fitted on.
    extended_ : ExtendedParams or None
        The extended model when it was returned (``params_`` are then its paper terms,
        :meth:`ExtendedParams.paper_terms`, with standard errors by the delta method).
    extended_stderr_ : dict of str to float
        Standard errors of ``extended_`` (empty for the paper's model).
    model_comparison_ : dict or None
        With ``model="both"``: per model the best candidate's name, validation fit % and
        score, the ``winner`` (better score) and its ``margin`` in score points (mean fit % of
        track and r), the model ``returned`` (the paper's when the extended one is better by
        less than PREFER_WITHIN points, or equation error's when that validates better), ``why``
        in plain words and the ``rule`` (MODEL_RULE).

    Raises
    ------
    usvlog.errors.ConfigError
        On an unknown method, an unknown or non-finite fixed parameter, or segment
        lengths, ``holdout`` or ``max_current_mps`` out of range.

    Examples
    --------
    >>> ident = Identifier(fix={"m": 33.0}).fit(log)        # doctest: +SKIP
    >>> ident.params_, ident.stderr_["d11"], ident.verdict_  # doctest: +SKIP
    >>> vessel = ident.to_vessel("my-boat")                  # doctest: +SKIP
    """

    extended_: ExtendedParams | None = None     # set by fit (class defaults: the paper's model)
    extended_stderr_: dict = {}
    model_comparison_: dict | None = None
    model = "paper"

    def __init__(self, method: str = "output-error", *, fix: dict | None = None, current: bool = True,
                 segment_s: float = 300.0, warm_segment_s: float = 60.0, holdout: float | None = None,
                 max_current_mps: float = MAX_CURRENT_MPS, model: str = "paper"):
        if method not in METHODS:
            raise ConfigError(f"method {method!r} is not one of {', '.join(METHODS)}")
        fix = dict(fix or {})
        for k, v in fix.items():
            if k not in PARAM_NAMES and (model == "paper" or k not in EXT_SCALE_FIX):
                raise ConfigError(f"cannot fix {k!r}: not one of {', '.join(PARAM_NAMES)}")
            if not (isinstance(v, (int, float)) and math.isfinite(v)):
                raise ConfigError(f"fixed value {k} = {v!r} is not a finite number")
        if not (segment_s > 0 and warm_segment_s >= 0):
            raise ConfigError("segment_s must be > 0 and warm_segment_s >= 0")
        if holdout is not None and not (0.0 <= holdout < 0.9):
            raise ConfigError(f"holdout = {holdout} must be in [0, 0.9)")
        if not (max_current_mps > 0 and math.isfinite(max_current_mps)):
            raise ConfigError(f"max_current_mps = {max_current_mps} must be a positive number (m/s)")
        if model not in IDENTIFY_MODELS:
            raise ConfigError(f"model {model!r} is not one of {', '.join(IDENTIFY_MODELS)}")
        if model != "paper" and method == "filter-error":
            raise ConfigError("the extended model is fitted by output error or equation error, not filter error")
        scale_keys = EXT_SCALE_FIX if model == "extended" else ("m", "Iz")
        if model != "paper" and fix and (len(fix) > 1 or next(iter(fix)) not in scale_keys):
            raise ConfigError(f"with --model {model} --fix only sets an unknown thrust scale: one of "
                              f"{', '.join(scale_keys)} (m is the surge inertia m11, Iz the yaw inertia m66)")
        self.model = model
        self.method = method
        self.fix = fix
        self.current = current
        self.segment_s = float(segment_s)
        self.warm_segment_s = float(warm_segment_s)
        self.holdout = None if holdout is None else float(holdout)
        self.max_current_mps = float(max_current_mps)

    # ------------------------------------------------------------------------------
    def fit(self, logs: list[FieldLog] | FieldLog, vessel: Vessel | None = None) -> Identifier:
        """Fit the model parameters to one or more runs.

        Each log needs ``/thrust/command`` (forces in N, or commands through the
        vessel's thruster map), ``/gnss/fix`` and ``/compass/heading``. Runs share the
        model parameters; each has its own current and initial states.

        Parameters
        ----------
        logs : FieldLog or list of FieldLog
            The runs to fit (better: a zig-zag or other yaw-exciting manoeuvre).
        vessel : Vessel, optional
            Thruster map and geometry, and a starting point; default the first log's
            vessel, else the built-in :func:`~usvlog.model.vessel.default_vessel`.

        Returns
        -------
        Identifier
            ``self``, with the fitted attributes (``params_``, ``stderr_``, ...) set.

        Raises
        ------
        usvlog.errors.InputError
            If there are no logs, a log lacks a channel or has too few samples.
        usvlog.errors.UnusableResultError
            If a log's import found a propulsion outside the twin-thruster model (a
            propeller and rudder, or one thruster), a log's compass was judged dead at
            import (and left out), or every
            candidate failed (diverged or physically impossible values).
        """
        if isinstance(logs, FieldLog):
            logs = [logs]
        if not logs:
            raise InputError("no logs to identify from")
        self._prior_given = vessel is not None
        vessel = vessel or logs[0].vessel or default_vessel()
        self.vessel_in_ = vessel
        self.health_ = [health_from_provenance(lg.provenance) or {} for lg in logs]
        _refuse_outside_model(logs)
        _refuse_dead_channels(logs, self.health_)
        # thrust without a known force scale: the model in command units (and the gain from a fixed value)
        if not getattr(self, "_command_units", False):
            if not all(thrust_scale_known(lg, vessel) for lg in logs):
                return fit_in_command_units(self, logs, vessel)
            if self.model != "paper" and self.fix:
                raise ConfigError(f"--fix with --model {self.model} only sets an unknown thrust scale, and these "
                                  "logs' thrust is in newtons (or through a known thruster map)")
            self.thrust_scale_ = ThrustScale()
        all_runs = [run_data(lg, vessel) for lg in logs]
        all_kin = [kinematic_states(lg, r, vessel) for lg, r in zip(logs, all_runs)]
        self.sign_checks_ = _refuse_wrong_signs(all_runs, all_kin, vessel.thrusters.arm_m)
        holdout = self.holdout if self.holdout is not None else (DEFAULT_HOLDOUT if len(logs) == 1 else None)
        if holdout is None:
            self.validation_mode_ = "leave-one-out"
        else:
            self.validation_mode_ = "holdout" if holdout > 0 else "none"
        runs, kin, held, fit_logs = [], [], [], []
        for log, run, ks in zip(logs, all_runs, all_kin):
            if holdout is not None and holdout > 0:
                t_cut = run.t_thrust[0] + (1 - holdout) * run.duration_s
                held.append((run.window(t_cut, run.t_thrust[-1]), ks.window(t_cut, np.inf)))
                run, ks = run.window(-np.inf, t_cut), ks.window(-np.inf, t_cut)
                if self.method == "filter-error":   # the only fit that reads the logs themselves
                    log = _log_before(log, run.t0_ns + int(t_cut * 1e9))
            fit_logs.append(log)
            runs.append(run)
            kin.append(ks)
        # -- candidates, fitted on the fit part, judged on the held-out part ---------------
        self._data_scales = data_scales(runs, kin)
        ee = self._equation_error(runs, kin)
        self.equation_error_ = ee
        self._ext_ee = self._ext_equation_error(runs, kin) if self.model != "paper" else None
        # the surge equation's own fit needs only equation error's start: made while the candidates are fitted
        surge = _Once(lambda: self._surge(runs, kin, self._start(ee, vessel))) if self._surge_wanted() else None
        cands = self._fit_candidates(self.candidate_starts(ee, vessel), runs, kin, fit_logs, vessel, held,
                                     meanwhile=surge)
        sc = self._surge_candidate(cands, runs, kin, fit_logs, vessel, held, surge)
        if sc is not None:   # preferred in a tie: its m also agrees with the surge's own evidence
            cands.insert(0, sc)
        if self.model == "both" and self.method == "output-error":   # the paper's fit in the extended form
            ok = [c for c in cands if not c.failed and c.start.model == "paper"]
            if ok:
                best = max(ok, key=lambda c: c.score)
                th = ExtendedParams.from_paper(VesselParams(**dict(zip(PARAM_NAMES, map(float, best.theta)))))
                cands.append(self._fit_candidate(Start(name="extended output error from the paper's fit",
                                                       kind="output-error", model="extended",
                                                       theta=th.as_array()), runs, kin, fit_logs, vessel, held))
        self.candidates_ = cands
        self.model_comparison_ = self._compare_models(cands) if self.model == "both" else None
        try:
            chosen = self._pick(cands)
        except UnusableResultError as err:   # say what would help
            hint = _excitation_warnings(kin)
            if hint:
                err.reasons = list(getattr(err, "reasons", [])) + hint    # type: ignore[attr-defined]
                err.args = (f"{err}; {'; '.join(hint)}",)
            raise
        if self.model_comparison_ is not None:   # the simpler paper model is kept within PREFER_WITHIN
            self.model_comparison_.update(_returned(self.model_comparison_, chosen))
        self.validations_ = list(chosen.validations) if self.validation_mode_ == "holdout" else []
        # -- the returned parameters: refitted on all the data from the chosen candidate --
        if self.validation_mode_ == "holdout":
            try:
                final = self._refit(chosen, all_runs, all_kin, logs, vessel, held)
            except UnusableResultError:   # the refit on all the data could not proceed: the validated one stands
                final = chosen
            if final is not chosen:
                runs, kin = all_runs, all_kin
        else:
            final = chosen
        self.loo_switch_ = None
        if self.validation_mode_ == "leave-one-out":
            mine, floor = self._leave_one_out(chosen, cands, all_runs, all_kin, logs, vessel)
            s_mine, s_floor = _mean_score(mine), _mean_score(floor)
            ee_c = [c for c in cands if c.start.kind == "equation-error" and c.start.model == chosen.start.model
                    and not c.failed]
            if chosen.start.kind != "equation-error" and s_floor > s_mine and ee_c:
                # never worse than equation error: the rule of the single-log case, on the left-out logs
                self.loo_switch_ = {"from": chosen.start.name, "score": s_mine, "equation_error_score": s_floor}
                chosen = final = ee_c[0]
                mine = floor
                if self.model_comparison_ is not None:
                    self.model_comparison_.update(_returned(self.model_comparison_, chosen))
                    self.model_comparison_["why"] = "equation error validates better on the left-out logs"
            self._loo_prefers_ee = s_floor > s_mine and chosen.start.kind != "equation-error"
            self.validations_ = [v for v in mine if v is not None]
        self.chosen_ = chosen
        self.runs_ = runs
        self._kin = kin
        self._set_result(final, runs)
        self.validation_ = self.validations_[0] if self.validations_ else None
        self._held = held
        try:
            self.fit_percent_ahead_, self.excited_ = self._ahead(held)
        except FitFailed:   # too short a held-out part to predict ahead: the free run alone judges
            self.fit_percent_ahead_, self.excited_ = {}, {}
        self.reasons_, self.verdict_ = self._verdict(vessel, runs, kin)
        self.usable_ = self.verdict_ != "unusable"
        return self

    def _ahead(self, held) -> tuple[dict, dict]:
        """k-step-ahead fit % (:func:`~usvlog.identify.ahead.fit_percent_ahead`, H = AHEAD_S) of the
        returned model on the held-out parts (mean over them), and which of u, v, r those parts
        excite at all; empty without held-out data."""
        if not held:
            return {}, {}
        simulate = None
        theta = self.theta_
        if self.extended_ is not None:
            from .extended_oe import free_run_full  # lazy: the extended model only

            simulate, theta = free_run_full, self.extended_.as_array()
        per = []
        for i, (r, k) in enumerate(held):
            cur = self.current_[i] if i < len(self.current_) else (0.0, 0.0)
            if simulate is not None:
                per.append(fit_percent_ahead(r, k, theta, cur, AHEAD_S, simulate=simulate))
            else:
                per.append(fit_percent_ahead(r, k, theta, cur, AHEAD_S))
        ahead = {h: {c: float(np.mean([p[h][c] for p in per])) for c in ("u", "v", "r")} for h in per[0]}
        nu = np.concatenate([k.nu(self.current_[i] if i < len(self.current_) else (0.0, 0.0))
                             for i, (_, k) in enumerate(held)])
        return ahead, excited_channels(nu)

    # -- the candidate list, one fit, the pick by validation -------------------------
    def candidate_starts(self, ee: EquationErrorResult, vessel: Vessel) -> list[Start]:
        """The candidates to fit, most preferred first (a tie in validation goes to the first).

        Parameters
        ----------
        ee : EquationErrorResult
            The equation-error fit on the fit part of the runs.
        vessel : Vessel
            The vessel (its values are a start of their own when it was given to :meth:`fit`
            and they differ by more than 10 %).

        Returns
        -------
        list of Start
            Equation error is always among them.
        """
        ee_start = Start(name="equation error", kind="equation-error", theta=self._ee_theta(ee, vessel))
        th = self._start(ee, vessel)
        if self.model != "paper":
            ext = self._extended_starts(th)
            if getattr(self, "_command_units", False) and vessel.extended is not None and self.method == "output-error":
                # the thrust-scale search's extended fit at the ratio it found (a start from its optimum)
                ext.insert(0, Start(name="extended output error from the thrust-ratio search", kind="output-error",
                                    model="extended", theta=vessel.extended.as_array()))
            if self.model == "extended":
                return ext if self.method == "output-error" else ext[-1:]
            if self.method == "equation-error":
                return [ee_start] + ext[-1:]
            return self.candidate_starts_paper(ee, vessel, th) + ext
        if self.method == "equation-error":
            return [ee_start]
        return self.candidate_starts_paper(ee, vessel, th)

    def _extended_starts(self, th_paper) -> list[Start]:
        """Extended-model candidates: output error from the paper's equation-error start in the
        extended form (preferred: the extended equation-error fit is biased by the noise of its
        regressors, m11 a third of the truth on a noisy run) and from the extended
        equation-error fit, then that fit itself."""
        from .extended_oe import ext_physical_problem  # lazy: the extended model only

        ext_ee = getattr(self, "_ext_ee", None)
        assert ext_ee is not None
        paper = ExtendedParams.from_paper(VesselParams(**dict(zip(PARAM_NAMES, map(float, th_paper))))).as_array()
        th_ee = ext_ee.theta
        return [Start(name="extended output error from the paper's equation error", kind="output-error",
                      model="extended", theta=paper),
                Start(name="extended output error from extended equation error", kind="output-error",
                      model="extended", theta=th_ee if not ext_physical_problem(th_ee) else paper),
                Start(name="extended equation error", kind="equation-error", model="extended", theta=th_ee)]

    def candidate_starts_paper(self, ee: EquationErrorResult, vessel: Vessel, th) -> list[Start]:
        """The paper model's candidates (output or filter error), equation error last.

        Parameters
        ----------
        ee : EquationErrorResult
            The equation-error fit on the fit part of the runs.
        vessel : Vessel
            The vessel (its values are a start of their own, see :meth:`candidate_starts`).
        th : numpy.ndarray, shape (6,)
            The output-error start made from ``ee``.

        Returns
        -------
        list of Start
        """
        ee_start = Start(name="equation error", kind="equation-error", theta=self._ee_theta(ee, vessel))
        if self.method == "filter-error":
            return [Start(name="filter error from equation error", kind="filter-error", theta=th), ee_start]
        out = [Start(name="output error from equation error", kind="output-error", theta=th),
               Start(name="output error with velocities from equation error", kind="output-error", theta=th,
                     vel_weight=VEL_WEIGHT)]
        prior = vessel.params.as_array().copy()
        for i, k in enumerate(PARAM_NAMES):
            if k in self.fix:
                prior[i] = self.fix[k]
        if getattr(self, "_prior_given", True) and np.max(np.abs(prior[:5] / th[:5] - 1)) > 0.1:
            out.append(Start(name="output error with velocities from the vessel's values", kind="output-error",
                             theta=prior, vel_weight=VEL_WEIGHT))
        # velocity output error (:mod:`usvlog.identify.velocity`): starts from the data's own scales,
        # whatever the vessel file says, so the answer does not hang on the user's guess
        scales = getattr(self, "_data_scales", None)
        if scales is not None:
            out.append(Start(name="velocity output error from the data's scales", kind="velocity-error",
                             theta=self._with_fixed(scales)))
        return out + [ee_start]

    def _with_fixed(self, theta) -> np.ndarray:
        """``theta`` with the fixed parameters set to their values."""
        th = np.array(theta, float)
        for i, k in enumerate(PARAM_NAMES):
            if k in self.fix:
                th[i] = self.fix[k]
        return th

    def _free(self, st: Start) -> np.ndarray:
        """Which of the paper model's parameters a candidate's output or filter error fits."""
        return np.array([k not in self.fix and not (k == "m" and st.surge_mass) for k in PARAM_NAMES])

    def _surge(self, runs, kin, theta) -> SurgeFit:
        """m and d11 of the surge equation alone (output error to the GPS track), from ``theta``."""
        return fit_surge(runs, kin, float(theta[0]), float(theta[2]), float(theta[5]), fit_current=self.current,
                         max_current_mps=self.max_current_mps)

    def _surge_wanted(self) -> bool:
        """Whether :meth:`_surge_candidate` fits the surge equation (not for the extended model
        alone, equation or filter error, a fixed m)."""
        return not (self.model == "extended" or self.method != "output-error" or "m" in self.fix)

    def _surge_candidate(self, cands, runs, kin, fit_logs, vessel, held, surge: _Once | None = None
                         ) -> Candidate | None:
        """Output error with m held at the surge equation's own fit, when that m is more than
        SURGE_MASS_RATIO away from the full output-error fit's (None otherwise, and for the
        extended model alone, equation or filter error, a fixed m). It is the most preferred
        candidate: when it and the full fit validate alike (within PREFER_WITHIN), the data's
        surge evidence decides for its m (the held-out track and r barely see the surge time
        constant; the smoothed u lags and cannot judge it).

        The paper's model has one mass for surge, sway and the yaw coupling (m xg); on a boat
        whose sway and yaw are of another form the full fit can move m far from the surge's to
        absorb that mismatch (the track barely sees the surge time constant), and its surge
        speed is then wrong. The validation judges the two. ``surge``: the surge fit from
        equation error's start, when made already (:meth:`_fit_candidates`' ``meanwhile``)."""
        if not self._surge_wanted():
            return None
        full = [c for c in cands if c.start.model == "paper" and c.start.kind == "output-error"
                and c.start.vel_weight == 0]
        th = self._start(self.equation_error_, vessel)
        sf = surge.get() if surge is not None else self._surge(runs, kin, th)
        if full and not full[0].failed and 1 / SURGE_MASS_RATIO < sf.m / full[0].theta[0] < SURGE_MASS_RATIO:
            return None
        th[0] = sf.m
        st = Start(name="output error with the surge equation's mass", kind="output-error", theta=th,
                   surge_mass=True)
        return self._fit_candidate(st, runs, kin, fit_logs, vessel, held, held_stderr={"m": sf.stderr["m"]})

    def _fit_candidates(self, starts: list[Start], runs, kin, fit_logs, vessel, held,
                        meanwhile: _Once | None = None) -> list[Candidate]:
        """:meth:`_fit_candidate` of each start, in their order. With a spare CPU the paper
        model's output-error candidates are fitted two at a time in threads (the shooting
        kernel runs without the GIL, and so does much of the arithmetic around it), each
        integrating its segments in one thread while another fit runs and in two once it is the
        last; the others here meanwhile, and then ``meanwhile`` (a computation the caller needs
        next, made here while the threads run). The same numbers as one by one."""
        par = [i for i, st in enumerate(starts) if st.kind == "output-error" and st.model == "paper"]
        if len(par) < 2 or not spare_cpu():
            return [self._fit_candidate(st, runs, kin, fit_logs, vessel, held) for st in starts]
        unfinished = [len(par)]
        lock = threading.Lock()

        def fit_one(st: Start) -> Candidate:
            try:
                return self._fit_candidate(st, runs, kin, fit_logs, vessel, held, threads=lambda: unfinished[0] == 1)
            finally:
                with lock:
                    unfinished[0] -= 1

        out: list[Candidate | None] = [None] * len(starts)
        with ThreadPoolExecutor(max_workers=2) as pool:
            futures = {i: pool.submit(fit_one, starts[i]) for i in par}
            for i, st in enumerate(starts):
                if i not in futures:
                    out[i] = self._fit_candidate(st, runs, kin, fit_logs, vessel, held)
            if meanwhile is not None:
                meanwhile.run()
            for i, f in futures.items():
                out[i] = f.result()
        return [c for c in out if c is not None]

    def _fit_candidate(self, st: Start, runs, kin, fit_logs, vessel, held, held_stderr=None,
                       threads: bool | Callable[[], bool] | None = None) -> Candidate:
        """Fit one candidate and validate it (a failure is a result: ``failed`` says why, also when
        its fit could not proceed, :class:`~usvlog.errors.FitFailed`); ``threads``: an output-error
        fit's (:func:`fit_output_error`)."""
        try:
            return self._fit_candidate_raw(st, runs, kin, fit_logs, vessel, held, held_stderr, threads)
        except UnusableResultError as err:   # FitFailed, or an estimate inside the fit that diverged
            return Candidate(start=st, theta=np.asarray(st.theta, float), currents=np.zeros((len(runs), 2)),
                             fitted=None, validations=[], failed=str(err))

    def _fit_candidate_raw(self, st: Start, runs, kin, fit_logs, vessel, held, held_stderr=None,
                           threads: bool | Callable[[], bool] | None = None) -> Candidate:
        """:meth:`_fit_candidate` without the catch."""
        if st.model == "extended":
            return self._fit_ext_candidate(st, runs, kin, held)
        free = self._free(st)
        zeros = np.zeros((len(runs), 2))
        fitted: object
        if st.kind == "equation-error":
            theta, cur, fitted = st.theta, zeros, self.equation_error_
        elif st.kind == "filter-error":
            from .filter import fit_filter_error  # lazy: filter error only (scipy's minimize)

            fitted = fit_filter_error(fit_logs, vessel, st.theta, free_mask=free, current=self.current)
            theta = fitted.theta
            cur = np.array([_ekf_current(lg, vessel, theta, self.current) for lg in fit_logs])
        elif st.kind == "velocity-error":
            fitted = fit_velocity_error(runs, kin, st.theta, free_mask=free, fit_current=self.current,
                                        max_current_mps=self.max_current_mps)
            theta, cur = fitted.theta, np.asarray(fitted.currents, float)
        else:
            vel = [velocity_samples(k.t, k.vn, k.ve, k.r) for k in kin] if st.vel_weight > 0 else None
            fitted = fit_output_error(runs, st.theta, lambda i, t: kin[i].at(t), free_mask=free,
                                      fit_current=self.current, segment_s=self.segment_s,
                                      warm_segment_s=self.warm_segment_s, warm_span_s=900.0, velocities=vel,
                                      vel_weight=st.vel_weight, max_current_mps=self.max_current_mps,
                                      threads=threads)
            theta, cur = fitted.theta, np.asarray(fitted.currents, float)
        failed = physical_problem(theta)
        if not failed and isinstance(fitted, (OutputErrorResult, VelocityFitResult)) and fitted.diverged:
            failed = "its simulation diverged"
        vals = []
        if not failed:
            # the same runs: their fitted current held (equation error's model has none: zero)
            if held:
                vals = [self._validate_run(r, k, theta, cur[i]) for i, (r, k) in enumerate(held)]
            else:   # without held-out data: free runs of the fitted runs judge it
                vals = [self._validate_run(r, k, theta, cur[i]) for i, (r, k) in enumerate(zip(runs, kin))]
            if any(v.diverged for v in vals):
                failed = "its free run diverged"
        return Candidate(start=st, theta=np.asarray(theta, float), currents=np.asarray(cur, float),
                         fitted=fitted, validations=vals, failed=failed, held_stderr=dict(held_stderr or {}))

    def _fit_ext_candidate(self, st: Start, runs, kin, held, currents0=None) -> Candidate:
        """An extended-model candidate fitted (output error) or taken (equation error) and validated."""
        # lazy: the extended model only
        from .extended_oe import ExtendedOEResult, ext_physical_problem, fit_extended_output_error

        fitted: object
        if st.kind == "equation-error":
            theta, cur, fitted = np.asarray(st.theta, float), np.zeros((len(runs), 2)), self._ext_ee
        else:
            # in command units the ratio search's short segments (its optimum stalls with long ones)
            seg = EXT_PROFILE_SEGMENT_S if getattr(self, "_command_units", False) else EXT_SEGMENT_S
            fitted = fit_extended_output_error(runs, kin, st.theta, fit_current=self.current, currents0=currents0,
                                               max_current_mps=self.max_current_mps, segment_s=seg)
            theta, cur = fitted.theta, fitted.currents
        failed = ext_physical_problem(theta)
        if not failed and isinstance(fitted, ExtendedOEResult) and fitted.diverged:
            failed = "its simulation diverged"
        vals = []
        if not failed:
            pairs = held if held else list(zip(runs, kin))
            vals = [self._validate_run(r, k, theta, cur[i]) for i, (r, k) in enumerate(pairs)]
            if any(v.diverged for v in vals):
                failed = "its free run diverged"
        return Candidate(start=st, theta=np.asarray(theta, float), currents=np.asarray(cur, float),
                         fitted=fitted, validations=vals, failed=failed)

    def _compare_models(self, cands: list[Candidate]) -> dict:
        """Best candidate of each model on the validation, the winner and its margin (score points)."""
        out: dict = {}
        for model in ("paper", "extended"):
            ok = [c for c in cands if c.start.model == model and not c.failed]
            if ok:
                b = max(ok, key=lambda c: c.score)
                out[model] = {"candidate": b.start.name, "fit_percent": _finite_dict(b.fit_percent),
                              "score": b.score if math.isfinite(b.score) else None}
        if "paper" in out and "extended" in out:
            sp, se = out["paper"]["score"], out["extended"]["score"]
            sp, se = (-math.inf if sp is None else sp), (-math.inf if se is None else se)
            out["winner"] = "extended" if se > sp else "paper"
            out["margin"] = abs(se - sp) if math.isfinite(se - sp) else None
        else:
            out["winner"] = "paper" if "paper" in out else ("extended" if "extended" in out else None)
            out["margin"] = None
        return out

    def _pick(self, cands: list[Candidate]) -> Candidate:
        """The best candidate by validation; a preferred one (earlier) within PREFER_WITHIN
        points of the best is taken, but never one that validates worse than equation error."""
        ok = [c for c in cands if not c.failed]
        if not ok:
            why = [f"{c.start.name}: {c.failed}" for c in cands]
            err = UnusableResultError(f"identification failed: every candidate failed ({'; '.join(why)})")
            err.reasons = why      # type: ignore[attr-defined]
            raise err
        best = max(c.score for c in ok)
        ee = [c.score for c in ok if c.start.kind == "equation-error"]
        floor = max(best - PREFER_WITHIN, max(ee) if ee else -math.inf)
        return next(c for c in ok if c.score >= floor)

    def _refit(self, chosen: Candidate, runs, kin, logs, vessel, held) -> Candidate:
        """The chosen candidate fitted again on all the data from its values; kept only if it
        validates (now in-sample) at least as well as the candidate did, less PREFER_WITHIN."""
        st = chosen.start
        fitted: object
        held_se = chosen.held_stderr
        if st.model == "extended":
            # lazy: the extended model only
            from .extended_oe import ext_physical_problem, fit_extended_output_error

            if st.kind == "equation-error":
                ext_ee = self._ext_equation_error(runs, kin)
                theta, cur, fitted = ext_ee.theta, np.zeros((len(runs), 2)), ext_ee
            else:
                fitted = fit_extended_output_error(runs, kin, chosen.theta, fit_current=self.current,
                                                   currents0=chosen.currents, max_current_mps=self.max_current_mps,
                                                   segment_s=EXT_SEGMENT_S, max_iter=EXT_REFIT_ITER)
                theta, cur = fitted.theta, fitted.currents
                if fitted.diverged:
                    return chosen
            if ext_physical_problem(theta):
                return chosen
        elif st.kind == "filter-error":
            from .filter import fit_filter_error  # lazy: filter error only (scipy's minimize)

            fe = fit_filter_error(logs, vessel, chosen.theta, current=self.current,
                                  free_mask=np.array([k not in self.fix for k in PARAM_NAMES]))
            theta, fitted = fe.theta, fe
            cur = np.array([_ekf_current(lg, vessel, theta, self.current) for lg in logs])
        elif st.kind == "equation-error":
            ee = self._equation_error(runs, kin)
            theta, cur, fitted = self._ee_theta(ee, vessel), np.zeros((len(runs), 2)), ee
        elif st.kind == "velocity-error":
            vf = fit_velocity_error(runs, kin, chosen.theta, free_mask=self._free(st), fit_current=self.current,
                                    currents0=chosen.currents, max_current_mps=self.max_current_mps,
                                    horizons_s=(120.0,))
            theta, cur, fitted = vf.theta, vf.currents, vf
            if vf.diverged:
                return chosen
        else:
            vel = [velocity_samples(k.t, k.vn, k.ve, k.r) for k in kin] if st.vel_weight > 0 else None
            th0 = chosen.theta.copy()
            if st.surge_mass:   # the surge equation's m from all the data too
                sf = self._surge(runs, kin, th0)
                th0[0], held_se = sf.m, {"m": sf.stderr["m"]}
            oe = fit_output_error(runs, th0, lambda i, t: kin[i].at(t),
                                  free_mask=self._free(st),
                                  fit_current=self.current, currents0=chosen.currents,
                                  segment_s=self.segment_s, warm_segment_s=0.0, velocities=vel,
                                  vel_weight=st.vel_weight, max_current_mps=self.max_current_mps)
            theta, cur, fitted = oe.theta, np.asarray(oe.currents, dtype=np.float64), oe
            if oe.diverged:
                return chosen
        if st.model == "paper" and physical_problem(theta):
            return chosen
        vals = [self._validate_run(r, k, theta, cur[i]) for i, (r, k) in enumerate(held)]
        again = Candidate(start=st, theta=np.asarray(theta, float), currents=cur, fitted=fitted, validations=vals,
                          held_stderr=held_se)
        if again.score < chosen.score - PREFER_WITHIN:
            return chosen
        return again

    def _leave_one_out(self, chosen: Candidate, cands, runs, kin, logs, vessel) -> tuple[list, list]:
        """Each log left out in turn: the chosen candidate's fit on the others, validated on it,
        and the same for equation error of the chosen's model (the floor). Returns both lists
        of Validation, None where the fit was not a boat."""
        out, ee_out = [], []
        for i in range(len(runs)):
            rest = [j for j in range(len(runs)) if j != i]
            r_, k_ = [runs[j] for j in rest], [kin[j] for j in rest]
            st = chosen.start
            if st.model == "extended":
                # lazy: the extended model only
                from .extended_oe import ext_physical_problem, fit_extended_output_error

                th_ee = self._ext_equation_error(r_, k_).theta
                ee_out.append(self._validate_run(runs[i], kin[i], th_ee, None) if not ext_physical_problem(th_ee)
                              else None)
            else:
                th_ee = self._ee_theta(self._equation_error(r_, k_), vessel)
                ee_out.append(self._validate_run(runs[i], kin[i], th_ee, None) if not physical_problem(th_ee)
                              else None)
            if st.model == "extended":
                if st.kind == "equation-error":
                    out.append(ee_out[-1])
                    continue
                theta = fit_extended_output_error(r_, k_, chosen.theta, fit_current=self.current,
                                                  max_current_mps=self.max_current_mps,
                                                  segment_s=EXT_SEGMENT_S).theta
                out.append(self._validate_run(runs[i], kin[i], theta, None) if not ext_physical_problem(theta)
                           else None)
                continue
            if st.kind == "equation-error":
                out.append(ee_out[-1])
                continue
            if st.kind == "velocity-error":
                theta = fit_velocity_error(r_, k_, chosen.theta, free_mask=self._free(st), fit_current=self.current,
                                           max_current_mps=self.max_current_mps).theta
            elif st.kind == "filter-error":
                from .filter import fit_filter_error  # lazy: filter error only (scipy's minimize)

                fe = fit_filter_error([logs[j] for j in rest], vessel, chosen.theta,
                                      free_mask=np.array([k not in self.fix for k in PARAM_NAMES]),
                                      current=self.current)
                theta = fe.theta
            else:
                vel = [velocity_samples(k.t, k.vn, k.ve, k.r) for k in k_] if st.vel_weight > 0 else None
                th0 = chosen.theta.copy()
                if st.surge_mass:
                    th0[0] = self._surge(r_, k_, th0).m
                oe = fit_output_error(r_, th0, lambda q, t, k_=k_: k_[q].at(t),
                                      free_mask=self._free(st),
                                      fit_current=self.current, segment_s=self.segment_s, warm_segment_s=0.0,
                                      velocities=vel, vel_weight=st.vel_weight,
                                      max_current_mps=self.max_current_mps)
                theta = oe.theta
            out.append(self._validate_run(runs[i], kin[i], theta, None) if not physical_problem(theta) else None)
        return out, ee_out

    def _ee_theta(self, ee: EquationErrorResult, vessel: Vessel) -> np.ndarray:
        """Equation error's values as a candidate: d22 at its bound 0 (not determined by it)
        taken from the vessel, so that the candidate is a boat that can be simulated."""
        th = ee.theta.copy()
        if th[3] <= 0 and "d22" not in self.fix:
            th[3] = vessel.params.d22
        return th

    def _equation_error(self, runs, kin) -> EquationErrorResult:
        parts = [_ee_inputs(r, k) for r, k in zip(runs, kin)]
        return fit_equation_error(np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts]),
                                  np.concatenate([p[2] for p in parts]), np.concatenate([p[3] for p in parts]),
                                  fix=self.fix)

    def _ext_equation_error(self, runs, kin) -> ExtendedFit:
        from .extended import fit_extended_equation_error  # lazy: the extended model only

        parts = [_ee_inputs(r, k) for r, k in zip(runs, kin)]
        return fit_extended_equation_error(*(np.concatenate([p[i] for p in parts]) for i in range(4)))

    def _set_ext_result(self, cand: Candidate, runs) -> None:
        """The fitted attributes from an extended-model candidate: ``extended_`` and its paper
        terms as ``params_`` (standard errors by the delta method)."""
        from .extended import ExtendedFit  # lazy: the extended model only
        from .extended_oe import ExtendedOEResult

        fitted = cand.fitted
        ext = ExtendedParams(**dict(zip(EXTENDED_PARAM_NAMES, map(float, cand.theta))))
        self.extended_ = ext
        self.oe_: OutputErrorResult | None = None
        ne = len(EXTENDED_PARAM_NAMES)
        ix = {k: i for i, k in enumerate(EXTENDED_PARAM_NAMES)}
        if isinstance(fitted, ExtendedOEResult):
            names = list(fitted.names)
            cov = fitted.cov
            cov_ext = np.zeros((ne, ne))
            pos = [ix[k] for k in names if k in ix]
            cov_ext[np.ix_(pos, pos)] = cov[:len(pos), :len(pos)]
            d = np.sqrt(np.maximum(np.diag(cov), 0))
            self.current_: list[tuple[float, ...]] = [tuple(float(x) for x in c) for c in fitted.currents]
            self.current_stderr_: list[tuple[float, ...]] = [
                tuple(float(d[names.index(f"current_{ax}_{i}")]) for ax in ("n", "e"))
                if self.current else (0.0, 0.0) for i in range(len(runs))]
            self.cond_ = fitted.cond
            self.residual_rms_ = dict(fitted.rms)
        else:
            assert isinstance(fitted, ExtendedFit)
            names = list(EXTENDED_PARAM_NAMES)
            cov_ext = np.diag([fitted.stderr[k] ** 2 for k in EXTENDED_PARAM_NAMES])
            cov = cov_ext
            self.current_ = [(0.0, 0.0)] * len(runs)
            self.current_stderr_ = [(float("nan"), float("nan"))] * len(runs)
            self.cond_ = float("nan")
            self.residual_rms_ = {"surge_n": fitted.rms[0], "sway_n": fitted.rms[1], "yaw_nm": fitted.rms[2]}
        self.extended_stderr_ = {k: float(math.sqrt(max(cov_ext[i, i], 0.0)))
                                 for i, k in enumerate(EXTENDED_PARAM_NAMES)}
        # paper terms: m = m11, Iz = m66, xg = m26 / m11, d.. = d.. + d..q typical speed
        G = np.zeros((6, ne))
        G[0, ix["m11"]] = 1.0
        G[1, ix["m66"]] = 1.0
        G[2, ix["d11"]], G[2, ix["d11q"]] = 1.0, ext.map_u_mps
        G[3, ix["d22"]], G[3, ix["d22q"]] = 1.0, ext.map_v_mps
        G[4, ix["d33"]], G[4, ix["d33q"]] = 1.0, ext.map_r_radps
        G[5, ix["m26"]], G[5, ix["m11"]] = 1.0 / ext.m11, -ext.m26 / ext.m11 ** 2
        se = np.sqrt(np.maximum(np.diag(G @ cov_ext @ G.T), 0.0))
        self.params_ = ext.paper_terms()
        self.theta_ = self.params_.as_array()
        self.stderr_ = {k: float(x) for k, x in zip(PARAM_NAMES, se)}
        self.ci95_ = {k: (float(v - Z95 * x), float(v + Z95 * x)) for k, v, x in zip(PARAM_NAMES, self.theta_, se)}
        sd = np.sqrt(np.maximum(np.diag(cov), 1e-300))
        self.corr_ = pd.DataFrame(cov / np.outer(sd, sd), index=names, columns=names)
        self.cov_ = cov
        self.final_ = cand

    def _set_result(self, cand: Candidate, runs) -> None:
        """The fitted attributes from the returned candidate."""
        self.extended_ = None
        self.extended_stderr_ = {}
        if cand.start.model == "extended":
            self._set_ext_result(cand, runs)
            return
        fitted = cand.fitted
        theta = cand.theta
        self.oe_ = fitted if isinstance(fitted, OutputErrorResult) else None
        se = np.zeros(6)
        if isinstance(fitted, EquationErrorResult):
            se = np.array([fitted.stderr[k] for k in PARAM_NAMES])
            names = [k for k in PARAM_NAMES if k not in self.fix]
            cov = np.diag([fitted.stderr[k] ** 2 for k in names])
            self.current_ = [(0.0, 0.0)] * len(runs)
            self.current_stderr_ = [(float("nan"), float("nan"))] * len(runs)
            self.cond_ = float("nan")
            self.residual_rms_ = {"surge_n": fitted.rms[0], "sway_n": fitted.rms[1], "yaw_nm": fitted.rms[2]}
        elif isinstance(fitted, (OutputErrorResult, VelocityFitResult)):
            names, cov = list(fitted.names), fitted.cov
            d = np.sqrt(np.maximum(np.diag(cov), 0))
            for i, k in enumerate(names):
                if k in PARAM_NAMES:
                    se[PARAM_NAMES.index(k)] = d[i]
            for k, x in cand.held_stderr.items():   # held in this fit, estimated by another (not in cov_)
                se[PARAM_NAMES.index(k)] = x
            self.current_ = [tuple(float(x) for x in c) for c in fitted.currents]
            self.current_stderr_ = [tuple(float(d[names.index(f"current_{ax}_{i}")]) for ax in ("n", "e"))
                                    if self.current else (0.0, 0.0) for i in range(len(runs))]
            self.cond_ = fitted.cond
            self.residual_rms_ = dict(fitted.rms)
        else:   # filter error
            from .filter import FilterErrorResult  # lazy: filter error only (scipy's minimize)

            assert isinstance(fitted, FilterErrorResult)
            self.fe_ = fitted
            names, cov = list(fitted.free), fitted.cov
            d = np.sqrt(np.maximum(np.diag(cov), 0))
            for i, k in enumerate(names):
                se[PARAM_NAMES.index(k)] = d[i]
            self.current_ = [tuple(float(x) for x in c) for c in cand.currents]
            self.current_stderr_ = [(float("nan"), float("nan"))] * len(runs)   # not computed
            corr = cov / np.outer(np.maximum(d, 1e-300), np.maximum(d, 1e-300))
            self.cond_ = float(np.sqrt(np.linalg.cond(corr)))
            self.residual_rms_ = {}
        self.params_ = VesselParams(**{k: float(v) for k, v in zip(PARAM_NAMES, theta)})
        self.theta_ = np.asarray(theta, float)
        self.stderr_ = {k: float(s) for k, s in zip(PARAM_NAMES, se)}
        self.ci95_ = {k: (float(v - Z95 * s), float(v + Z95 * s)) for k, v, s in zip(PARAM_NAMES, theta, se)}
        sd = np.sqrt(np.maximum(np.diag(cov), 1e-300))
        self.corr_ = pd.DataFrame(cov / np.outer(sd, sd), index=names, columns=names)
        self.cov_ = cov
        self.final_ = cand

    def _start(self, ee: EquationErrorResult, vessel: Vessel) -> np.ndarray:
        """Output-error start: the equation-error values where plausible, else the vessel's."""
        prior = vessel.params.as_array()
        th = ee.theta.copy()
        for i, k in enumerate(PARAM_NAMES):
            if k in self.fix:
                th[i] = self.fix[k]
                continue
            v = th[i]
            if k == "xg":
                ok = math.isfinite(v) and abs(v) < 1.0
            else:
                ok = math.isfinite(v) and v > 0 and (1 / 3) < v / prior[i] < 3
            if not ok:
                th[i] = prior[i]
        if th[1] - th[0] * th[5] ** 2 <= 0.05 * th[1]:
            th[5] = 0.0 if "xg" not in self.fix else th[5]
        return th

    # ------------------------------------------------------------------------------
    def _held_names(self) -> set:
        """Names held at a fixed value: the fixed ones, and for the extended model the paper terms
        they are (m11 is m, m66 is Iz; ``--fix m`` holds m11)."""
        held = set(self.fix)
        for paper, ext in (("m", "m11"), ("Iz", "m66")):
            if paper in held or ext in held:
                held |= {paper, ext}
        return held

    def _ext_term_findings(self, add) -> None:
        """The extended model's own terms judged by their standard errors (the paper-term checks
        see only their combinations): m22 poorly determined is a caveat (sway barely excited);
        the split of linear and quadratic damping, and m26, are notes (their combination at the
        typical speed, the paper term, is what the checks above judge)."""
        ext = self.extended_
        assert ext is not None
        vals = ext.to_dict()
        for k in EXTENDED_PARAM_NAMES:
            v, se = vals[k], self.extended_stderr_.get(k, math.nan)
            if k in ("m11", "m66") or (k.endswith("q") and v <= 0) or k in self.fix:   # m, Iz: judged above;
                continue                                                         # q at its bound 0; fixed
            if not (math.isfinite(se) and se > 1e-9 * max(abs(v), 1e-300)):
                add(1 if k == "m22" else 0, f"extended term {k} = {fmt_num(v)}: standard error not computable")
                continue
            rel = se / abs(v) if v else math.inf
            if rel > REL_SE_CAVEAT:
                add(1 if k == "m22" else 0, f"extended term {k} poorly determined: {fmt_num(v)} +- {fmt_num(se, 2)}"
                                            f" ({_rel_pct(rel)})")

    def _verdict(self, vessel, runs, kin) -> tuple[list[str], str]:
        """(reasons, verdict): each finding with its level, the worst level the verdict."""
        found: list[tuple[int, str]] = []   # (0 note, 1 caveat, 2 unusable, text)

        def add(level: int, text: str) -> None:
            found.append((level, text))

        p = self.params_
        # -- validation ------------------------------------------------------------
        if self.validations_:
            fp = self.validation_fit_percent_()
            on = {"holdout": "the held-out data", "leave-one-out": "the left-out logs"}.get(
                self.validation_mode_, "the validation log(s)")
            fu = fp["u"] if math.isfinite(fp["u"]) else -math.inf
            fr = fp["r"] if math.isfinite(fp["r"]) else -math.inf
            excited: dict = {}   # which channels are excited there: not judged yet (the noise floor is not calibrated)
            txt = f"validation fit on {on}: u {fmt_pct(fp['u'])} %, r {fmt_pct(fp['r'])} %"
            ahead = (getattr(self, "fit_percent_ahead_", {}) or {}).get("30")
            # the measured u, v, r are smoothed GPS and compass: their own noise caps the fit %
            # of u (slow, small changes) far below 100 even for the true model; r is the sharp test.
            # The free run over the whole held-out part is judged first; a model that fails it but
            # predicts 30 s ahead (re-started from the smoothed state, a path follower's horizon)
            # is usable with that caveat, not refused
            ok_ahead = ahead is not None and all(
                excited.get(ch) is False or (math.isfinite(ahead[ch]) and ahead[ch] >= FIT_CAVEAT) for ch in ("u", "r"))
            if fr < FIT_UNUSABLE or fu < U_FIT_UNUSABLE:
                if ok_ahead and ahead is not None:
                    add(1, f"{txt} in a free run, but {fmt_pct(ahead['u'])} % and {fmt_pct(ahead['r'])} % predicted "
                           f"30 s ahead (judged at that horizon: a path follower needs the model over its "
                           f"prediction horizon, not over minutes of disturbances)")
                else:
                    add(2, f"{txt}: the model predicts worse than a constant; it does not describe this boat")
            elif fr < FIT_CAVEAT or fu < FIT_UNUSABLE:
                add(1, f"{txt}: the model explains only part of the motion")
            sw = getattr(self, "loo_switch_", None)
            if sw:
                add(0, f"left out in turn, the logs validate equation error better (score "
                       f"{fmt_pct(sw['equation_error_score'])}) than {sw['from']} ({fmt_pct(sw['score'])}): "
                       f"equation error returned")
            elif getattr(self, "_loo_prefers_ee", False):
                add(1, "left out in turn, the logs validate equation error better than the fit returned")
        else:
            add(1, "not validated (--no-validate): nothing checks the model on data it was not fitted on")
        # -- the parameters -----------------------------------------------------------
        held = self._held_names()
        se_bad = [k for k in PARAM_NAMES if k not in held and k != "xg" and
                  not (math.isfinite(self.stderr_[k]) and self.stderr_[k] > 1e-9 * abs(getattr(p, k)))]
        if se_bad and self.method != "filter-error":
            add(2, f"standard errors of {', '.join(se_bad)} could not be computed (degenerate fit): "
                   "the intervals mean nothing")
        rel = {k: self.stderr_[k] / abs(getattr(p, k)) if getattr(p, k) else math.inf for k in PARAM_NAMES}
        ex = _excitation_warnings(kin, force=rel["Iz"] > 0.2 or rel["d33"] > 0.2)
        for w in ex:
            add(1, w)
        for k in PARAM_NAMES:
            if k in held or k in se_bad:
                continue
            if rel[k] > REL_SE_CAVEAT and not (k == "xg" and abs(p.xg) < 0.05):
                level = 2 if rel[k] > REL_SE_UNUSABLE and k in ("m", "Iz", "d11", "d33") else 1
                add(level, f"{k} poorly determined: {fmt_num(getattr(p, k))} +- {fmt_num(self.stderr_[k], 2)} "
                           f"({_rel_pct(rel[k])})")
        names = list(self.corr_.index)
        C = self.corr_.to_numpy()
        for i in range(len(names)):
            for j in range(i + 1, len(names)):
                wide = [n for n in (names[i], names[j]) if rel.get(n, 0.0) > REL_SE_CAVEAT]
                if abs(C[i, j]) >= 0.95 and wide:   # correlated and therefore uncertain
                    add(1, f"{names[i]} and {names[j]} correlated at {C[i, j]:.2f}, so {', '.join(wide)} "
                           f"uncertain: excite the run differently or --fix one of them")
        if math.isfinite(self.cond_) and self.cond_ > COND_CAVEAT:
            add(1, f"condition number {fmt_num(self.cond_, 2)}: parameters nearly unidentifiable together")
        if self.extended_ is not None:
            self._ext_term_findings(add)
        iz_eff = p.Iz_eff
        if iz_eff <= 0:
            add(1, f"Theorem 3.1 condition 1 fails: Iz - m xg^2 = {fmt_num(iz_eff)} <= 0")
        # -- the current -----------------------------------------------------------------
        for i, c in enumerate(self.current_):
            speed = math.hypot(*c)
            if max(abs(c[0]), abs(c[1])) >= 0.98 * self.max_current_mps:
                add(1, f"current of run {i} at its bound ({speed:.2f} m/s, bound {self.max_current_mps:g} m/s "
                       "per axis): the fit wanted more current than allowed; a model mismatch or a real strong "
                       "current (--max-current-mps)")
        # -- the data -------------------------------------------------------------------
        for lg_h, run in zip(self.health_, runs):
            dead = [t for t in (lg_h.get("dead") or []) if t in ("/compass/heading", "/gnss/fix", "/thrust/command")]
            for t in dead:
                add(2, f"{run.source}: {t} was judged dead at import ({_why_dead(lg_h, t)}): what it recorded "
                       "is not the boat's motion")
        unknown = [run.source for run, h in zip(runs, self.health_)
                   if (h.get("thrust") or {}).get("force_scale") == "unknown"]
        guessed = not vessel.thrusters.known and any(r.thrust_source != "logged newtons" for r in runs)
        if not self.thrust_scale_.known:   # identified in command units (and the gain from a fixed value)
            add(1 if self.thrust_scale_.case == "command units" else 0, self.thrust_scale_.message())
        elif unknown or guessed:
            scale_fixed = any(k in self.fix for k in ("m", "Iz", "d11", "d22", "d33"))
            src = ", ".join(unknown) if unknown else "the thruster map"
            what = ("thrust has no known force scale" if unknown else
                    "thruster map is only a guess (thrusters.known = false)")
            if scale_fixed:
                add(0, f"{what} ({src}): the scale comes from the fixed value(s)")
            else:
                add(1, f"{what} ({src}): m, Iz and the damping are known only up to the unknown thrust "
                       "gain; --fix a known value (e.g. a weighed mass)")
        skipped = sum(r.thrust_skipped for r in runs)
        if skipped:
            add(0, f"{skipped} thrust record(s) not finite: skipped (the command before each held)")
        if self.oe_ is not None and self.oe_.outliers:
            o = self.oe_.outliers
            if o["gps"] or o["compass"]:
                add(0, f"{o['gps']} GNSS fix(es) and {o['compass']} compass reading(s) beyond "
                       f"5 sigma of the fitted model dropped as outliers")
        if self.oe_ is not None:
            for s in ("gps", "compass"):
                v = self.residual_rms_.get(s, 0.0)
                if v > 2.0:
                    add(1, f"{s} residuals {v:.1f} times their stated noise: model mismatch or sensor trouble")
        if self.final_.start.kind == "equation-error":
            add(1 if self.method == "equation-error" else 0,
                "equation error is biased by measurement noise in its regressors (inertia terms and d22 "
                "typically tens of percent off)" + ("" if self.method == "equation-error" else
                                                     ": it validated better than the output-error fits here"))
            if self.final_.start.model == "paper" and self.equation_error_.theta[3] <= 0.0 and "d22" not in self.fix:
                add(1, f"d22 at its bound 0 in equation error (not determined): the vessel's value "
                       f"{fmt_num(p.d22)} kept")
        if not self.current and self.method == "output-error":
            add(0, "current not fitted: a real current biases d11 and d22")
        level = max((lv for lv, _ in found), default=0)
        order = sorted(found, key=lambda x: -x[0])
        return [t for _, t in order], VERDICTS[min(level, 2)] if level else VERDICTS[0]

    def validation_fit_percent_(self) -> dict:
        """Mean validation fit % of u, v, r and track over ``validations_`` (NaN without)."""
        if not self.validations_:
            return {k: float("nan") for k in ("u", "v", "r", "track")}
        return {k: float(np.mean([v.fit_percent[k] for v in self.validations_])) for k in ("u", "v", "r", "track")}

    def use_validation(self, validations: list[Validation]) -> None:
        """Judge the fit by these validations (e.g. on logs it was not fitted on) and redo the verdict.

        Parameters
        ----------
        validations : list of Validation
            From :meth:`validate`.

        Raises
        ------
        usvlog.errors.ConfigError
            If the identifier is not fitted.
        """
        self._check_fitted()
        self.validations_ = list(validations)
        self.validation_ = self.validations_[0] if self.validations_ else None
        self.validation_mode_ = "logs" if self.validations_ else "none"
        self.reasons_, self.verdict_ = self._verdict(self.vessel_in_, self.runs_, self._kin)
        self.usable_ = self.verdict_ != "unusable"

    def raise_if_unusable(self) -> None:
        """Raise :class:`~usvlog.errors.UnusableResultError` naming the reasons when the verdict is unusable.

        Raises
        ------
        usvlog.errors.UnusableResultError
            If ``verdict_`` is ``"unusable"``.
        """
        self._check_fitted()
        if self.verdict_ == "unusable":
            err = UnusableResultError("identification unusable: " + "; ".join(self.reasons_[:3]))
            err.reasons = list(self.reasons_)      # type: ignore[attr-defined]
            err.identifier = self                  # type: ignore[attr-defined]
            raise err

    # ------------------------------------------------------------------------------
    def _check_fitted(self):
        if not hasattr(self, "params_"):
            raise ConfigError("Identifier is not fitted: call fit() first")

    def to_vessel(self, name: str | None = None) -> Vessel:
        """The identified vessel: the fitted parameters with the input vessel's thrusters.

        Parameters
        ----------
        name : str, optional
            Name of the new vessel (default ``"<input vessel name>-identified"``).

        Returns
        -------
        Vessel
            Write it with :meth:`Vessel.to_toml` to use it in simulation or estimation.

        Raises
        ------
        usvlog.errors.ConfigError
            If the identifier is not fitted.
        """
        self._check_fitted()
        v = self.vessel_in_
        if self.extended_ is not None:   # the extended structure: its TOML has an [extended] table
            return extended_vessel(name or f"{v.name}-identified", self.extended_, v.thrusters)
        return Vessel(name=name or f"{v.name}-identified", params=self.params_, thrusters=v.thrusters)

    def validate(self, log: FieldLog, *, init_window_s: float = 60.0) -> Validation:
        """Free run of the identified model from ``log``'s thrust (a run it was not fitted on).

        The initial state (and the current, if the identifier fits currents) is fitted to
        the first ``init_window_s`` seconds with the parameters held; the fit % is scored
        after that window.

        Parameters
        ----------
        log : FieldLog
            A run with the same channels as for :meth:`fit`.
        init_window_s : float, default 60.0
            Length in s of the initial-state window (at most half the run).

        Returns
        -------
        Validation
            Measured and simulated states and the fit % of u, v, r and the track.

        Raises
        ------
        usvlog.errors.ConfigError
            If the identifier is not fitted.
        usvlog.errors.InputError
            If the log lacks a channel or has too few samples.
        """
        self._check_fitted()
        run = run_data(log, self.vessel_in_)
        return self._validate_run(run, kinematic_states(log, run, self.vessel_in_), init_window_s=init_window_s)

    def _validate_run(self, run: RunData, ks: KinStates, theta=None, current=None,
                      init_window_s: float = 60.0) -> Validation:
        """Free run of ``theta`` (default ``theta_``) through a run: the initial state (and,
        when ``current`` is None and currents are fitted, the current, within its bound)
        fitted on the first ``init_window_s``; ``current`` (north, east, m/s) given: held."""
        if theta is None:
            theta = self.theta_ if self.extended_ is None else self.extended_.as_array()
        theta = np.asarray(theta, float)
        t0 = max(run.t_thrust[0], ks.t[0])
        t_init = t0 + min(init_window_s, 0.5 * (run.t_thrust[-1] - t0))
        if len(theta) == len(EXTENDED_PARAM_NAMES):
            return self._validate_ext(run, ks, theta, current, t0, t_init)
        if current is None:
            x0, cur = fit_initial_state(run, theta, ks.at(t0), t0, t_init, fit_current=self.current)
            cur = np.clip(cur, -self.max_current_mps, self.max_current_mps)
        else:
            x0, cur = fit_initial_state(run, theta, ks.at(t0), t0, t_init, fit_current=False, current0=current)
        t = ks.free_run_times(t0, run.t_thrust[-1])
        with np.errstate(over="ignore", invalid="ignore"):
            sim = simulate_run(run, theta, cur, x0, t0, t)
        meas = ks.at(t, cur)
        return _validation(t, meas, sim, cur, t0, t_init)

    def _validate_ext(self, run: RunData, ks: KinStates, theta, current, t0: float, t_init: float) -> Validation:
        """:meth:`_validate_run` for the extended model: the initial state fitted on [t0, t_init]
        with the current held (None: the equation-error model's zero current)."""
        from .extended_oe import fit_initial_state_ext, free_run_full  # lazy: the extended model only

        cur = np.zeros(2) if current is None else np.clip(np.asarray(current, float), -self.max_current_mps,
                                                          self.max_current_mps)
        x0 = fit_initial_state_ext(run, theta, ks.at(t0, tuple(cur)), t0, t_init, cur)
        t = ks.free_run_times(t0, run.t_thrust[-1])
        with np.errstate(over="ignore", invalid="ignore"):
            sim = free_run_full(run, theta, cur, x0, t0, t)
        meas = ks.at(t, tuple(cur))
        return _validation(t, meas, sim, cur, t0, t_init)

    def fit_frame(self, run_index: int = 0) -> tuple[np.ndarray, dict]:
        """(t_s, columns) of measured vs fitted-model states of a fitted run (``/identify/fit``):
        the output-error model from each segment's fitted initial state (equation error: a
        free run).

        ``t_s``: s from the run's first thrust sample; columns u_mps, u_sim_mps, v_mps,
        v_sim_mps, r_radps, r_sim_radps, n_m, n_sim_m, e_m, e_sim_m, psi_rad, psi_sim_rad
        (headings wrapped). Raises ConfigError if the identifier is not fitted."""
        self._check_fitted()
        run, ks = self.runs_[run_index], self._kin[run_index]
        cur = self.current_[run_index]
        t = ks.t
        if self.extended_ is not None:
            from .extended_oe import free_run_full  # lazy: the extended model only

            sim = free_run_full(run, self.extended_.as_array(), cur, ks.at(t[0], cur), t[0], t)
        elif self.oe_ is not None:
            sim = predict_segments(self.runs_, self.segment_s, self.oe_.x0s, self.theta_,
                                   np.asarray(self.current_, float), run_index, t)
        else:
            sim = simulate_run(run, self.theta_, cur, ks.at(t[0]), t[0], t)
        meas = ks.at(t, cur)
        sim[:, 2] = ssa(sim[:, 2])
        meas[:, 2] = ssa(meas[:, 2])
        cols = {}
        for i, (name, unit) in enumerate((("u", "mps"), ("v", "mps"), ("r", "radps"), ("n", "m"),
                                          ("e", "m"), ("psi", "rad"))):
            j = [3, 4, 5, 0, 1, 2][i]
            cols[f"{name}_{unit}"] = meas[:, j]
            cols[f"{name}_sim_{unit}"] = sim[:, j]
        return t, cols

    def fit_percent_(self) -> dict:
        """Fit % of the fitted model on its own runs (u, v, r, track)."""
        t, c = self.fit_frame(0)
        return {"u": fit_percent(c["u_mps"], c["u_sim_mps"]), "v": fit_percent(c["v_mps"], c["v_sim_mps"]),
                "r": fit_percent(c["r_radps"], c["r_sim_radps"]),
                "track": fit_percent(np.stack([c["n_m"], c["e_m"]], 1), np.stack([c["n_sim_m"], c["e_sim_m"]], 1))}

    def to_dict(self, validation: Validation | None = None) -> dict:
        """JSON-ready report of the fit (what ``usvlog identify --json`` prints).

        Parameters
        ----------
        validation : Validation, optional
            Validation to report (e.g. on another log); default the held-out or left-out
            data's (``validations_``), else the fit % is computed on the fitted runs.

        Returns
        -------
        dict
            method, params (SI), stderr, ci95, fit_percent and what it was computed on
            (``fit_percent_on``: ``"validation"`` or ``"fitted runs"``; values None where not
            finite), validation_mode, current_ne_mps, condition_number, correlation,
            ``verdict`` (usable / usable with caveats / unusable), ``reasons`` (plain words),
            ``usable``, fixed, the equation-error params and stderr, Iz_minus_m_xg2
            (kg m^2), the candidates (name, params, fit_percent, failed) and the one
            chosen, and with a validation its summary.

        Raises
        ------
        usvlog.errors.ConfigError
            If the identifier is not fitted.
        """
        self._check_fitted()
        if validation is not None:
            fp, on = validation.fit_percent, "validation"
        elif self.validations_:
            fp, on = self.validation_fit_percent_(), "validation"
        else:
            fp, on = self.fit_percent_(), "fitted runs"
        val = validation if validation is not None else self.validation_
        d = {"method": self.method,
             "params": self.params_.to_dict(),
             "stderr": dict(self.stderr_),
             "ci95": {k: list(v) for k, v in self.ci95_.items()},
             "fit_percent": _finite_dict(fp),
             "fit_percent_on": on,
             "validation_mode": self.validation_mode_,
             "current_ne_mps": [list(c) for c in self.current_],
             "condition_number": self.cond_ if math.isfinite(self.cond_) else None,
             "correlation": {k: {j: (float(x) if math.isfinite(x) else None) for j, x in row.items()}
                             for k, row in self.corr_.to_dict("index").items()},
             "verdict": self.verdict_,
             "reasons": list(self.reasons_),
             "usable": self.usable_,
             "fixed": dict(self.fix),
             "equation_error": {"params": self.equation_error_.to_dict(),
                                "stderr": dict(self.equation_error_.stderr)},
             "Iz_minus_m_xg2": self.params_.Iz_eff,
             "candidates": [c.to_dict() for c in self.candidates_],
             "chosen": self.chosen_.start.name,
             "thrust_scale": self.thrust_scale_.to_dict(),
             "model": self.model,
             "structure": "paper" if self.extended_ is None else "extended",
             "fit_percent_ahead": {h: _finite_dict(v) for h, v in getattr(self, "fit_percent_ahead_", {}).items()},
             "sign_checks": list(getattr(self, "sign_checks_", []))}
        if self.extended_ is not None:
            d["extended"] = {"params": self.extended_.to_dict(), "stderr": dict(self.extended_stderr_)}
        if self.model_comparison_ is not None:
            d["model_comparison"] = self.model_comparison_
        if val is not None:
            d["validation"] = val.to_dict()
        return d

    def toml_record(self) -> str:
        """The ``[identification]`` table written after the vessel TOML: verdict, usable,
        reasons, method, the candidate chosen, the thrust-scale case (``known``, ``command
        units``, ``gain identified``) and the validation fit % (what a reader of the file needs
        to know before trusting it).

        Returns
        -------
        str
            TOML text (the vessel reader ignores this table).

        Raises
        ------
        usvlog.errors.ConfigError
            If the identifier is not fitted.
        """
        self._check_fitted()

        def q(x: str) -> str:
            return '"' + x.replace("\\", "\\\\").replace('"', '\\"') + '"'

        fp = self.validation_fit_percent_()
        lines = ["", "[identification]", f"usable = {'true' if self.usable_ else 'false'}",
                 f"verdict = {q(self.verdict_)}", f"method = {q(self.method)}",
                 f"structure = {q('paper' if self.extended_ is None else 'extended')}",
                 f"chosen = {q(self.chosen_.start.name)}", f"validation = {q(self.validation_mode_)}",
                 f"thrust_scale = {q(self.thrust_scale_.case)}"]
        lines += [f"fit_{k}_pct = {fp[k]:.2f}" for k in ("u", "v", "r", "track") if math.isfinite(fp[k])]
        for h, v in getattr(self, "fit_percent_ahead_", {}).items():   # k-step-ahead fit % per horizon (s)
            lines += [f"fit_ahead_{h}s_{k}_pct = {v[k]:.2f}" for k in ("u", "v", "r") if math.isfinite(v[k])]
        lines.append("reasons = [" + ", ".join(q(r) for r in self.reasons_) + "]")
        return "\n".join(lines) + "\n"


class _Once:
    """A computation made at most once, when first run or asked for: :meth:`get` returns its
    result or raises its exception (at the place that needs it, wherever it was made)."""

    def __init__(self, fn: Callable[[], object]):
        self._fn = fn
        self._out: tuple | None = None

    def run(self) -> None:
        """Make it now (once); an exception is kept for :meth:`get`."""
        if self._out is None:
            try:
                self._out = (True, self._fn())
            except Exception as err:   # raised where the result is needed
                self._out = (False, err)

    def get(self):
        """The result (made now if it was not), or its exception raised."""
        self.run()
        assert self._out is not None
        ok, val = self._out
        if not ok:
            raise val
        return val


def _validation(t, meas, sim, cur, t0: float, t_init: float) -> Validation:
    """A free run against the measured states: heading unwrapped onto the measurement, fit %
    of u, v, r and the track after the initial-state window."""
    sim[:, 2] = meas[:, 2] + ssa(sim[:, 2] - meas[:, 2])
    after = t > t_init
    fp = {"u": fit_percent(meas[after, 3], sim[after, 3]), "v": fit_percent(meas[after, 4], sim[after, 4]),
          "r": fit_percent(meas[after, 5], sim[after, 5]),
          "track": fit_percent(meas[after, :2], sim[after, :2])}
    return Validation(fit_percent=fp, t=t, measured=meas, simulated=sim,
                      current=(float(cur[0]), float(cur[1])), init_window_s=float(t_init - t0))
