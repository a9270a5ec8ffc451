"""The candidate strategy of the identifier: which fits to try, fitting them, picking one.

Output error fits several candidates (:class:`Start`) and keeps the one that validates best
(:class:`Candidate`): equation error as it is (the floor: the answer never validates worse) and
with the water current its residuals give (:func:`_equation_error_current`), output error from
it with and without the smoothed velocities, from the vessel's values, the velocity output
error from the data's scales, the extended model's fits (one with m11 held at
the surge equation's own fit, :func:`_ext_surge_mass`), the paper model with a quadratic surge
damping when asked (:func:`quadratic_surge_start`, QS_HELD, QS_TIES), and the surge candidate (m
held at the surge equation's own fit, :func:`_surge_candidate`). They are fitted
one after another (:func:`_fit_candidates`), picked by validation
with a tie margin (:func:`_pick`, :data:`PREFER_WITHIN`), refitted on all the data
(:func:`_refit`) or validated by leaving each log out (:mod:`usvlog.identify.leave_one_out`). The functions
taking ``self`` are methods of :class:`~usvlog.identify.identifier.Identifier`, kept here
with the job they do.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from ..choices import EXTENDED_PARAM_NAMES
from ..errors import UnusableResultError
from ..estimate import EstimateSettings, estimate
from ..estimate.latency import stored_delays, with_settings_delays
from ..log.fieldlog import FieldLog
from ..model.vessel import PARAM_NAMES, ExtendedParams, Vessel, VesselParams
from .data import RunData
from .equation import EquationErrorResult, fit_equation_error
from .output import (
    MAX_STIFFNESS,
    OutputErrorResult,
    fit_output_error,
    stiffness,
    velocity_samples,
)
from .smooth import KinStates, derivative, smooth_like, thrust_on_grid
from .surge import SurgeFit, fit_surge
from .thrust_scale import EXT_PROFILE_SEGMENT_S
from .validation import SCORE_WORDS, _finite_dict
from .velocity import QUADRATIC_START, VelocityFitResult, extended_start, fit_velocity_error

# typing only: the extended model is imported where used (start-up of the default fit); the Identifier
# imports this module
if TYPE_CHECKING:
    from .extended import ExtendedFit
    from .identifier import Identifier


# equation-error smoothing (s): positions, heading, accelerations (thrust filtered alike)
EE_POS_S, EE_PSI_S, EE_ACC_S = 16.0, 6.0, 6.0
VEL_WEIGHT = 1.0            # weight of the smoothed velocities against GPS + compass (robust start)
PREFER_WITHIN = 1.0         # fit % points: a preferred candidate this close to the best is taken
# the surge equation's own m (fit_surge) this factor away from the full fit's: a candidate holding it
SURGE_MASS_RATIO = 1.5
SURGE_MASS_PRECISION = 0.3   # ... preferred in a tie only with its m's standard error within this share of it
EXT_SEGMENT_S = 120.0       # extended output error: shooting segment length (s)
DEGENERATE_COND = 1e10     # condition number of a fit whose Jacobian is numerically singular
START_RATIO = 3.0           # output-error start: an equation-error value this close to the vessel's is plausible
START_SCALE_RATIO = 10.0    # ... or this close to the data's scale (data_scales: a crude time-constant guess)
# the paper model with a quadratic surge damping d11q, as the extended structure: m22 tied to m11 (one
# mass), no quadratic sway or yaw damping (held at 0); m26 = m xg and m66 = Iz are the paper's terms
QS_HELD = ("m22", "d22q", "d33q")
QS_TIES = (("m22", "m11"),)
EXT_REFIT_ITER = 20         # extended output error: iterations of the refit on all data (it starts converged)


MODEL_RULE = ("the extended model is returned only when its best candidate validates better than the paper "
              f"model's by at least {PREFER_WITHIN:g} point (score: " + SCORE_WORDS + " on the held-out part); "
              "never a fit that validates worse than equation error")


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
        made again on the data each fit uses) instead of fitted with the coupled sway and yaw; for the
        extended model's velocity output error, m11 held at it (:func:`_ext_surge_mass`).
    quadratic_surge : bool
        The paper model with a quadratic surge damping d11q (``Identifier(quadratic_surge=True)``),
        fitted by velocity output error as the extended structure with m22 tied to m11 and d22q,
        d33q held at 0 (QS_HELD, QS_TIES); ``model`` is then ``"extended"`` (its TOML form).
    ee_current : bool
        Equation error with each run's water current, the one its residuals are smallest with
        (:func:`_equation_error_current`); plain equation error fits none.
    """

    name: str
    kind: str
    theta: np.ndarray
    vel_weight: float = 0.0
    model: str = "paper"
    surge_mass: bool = False
    quadratic_surge: bool = False
    ee_current: bool = False


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
        Free runs it was judged on (held-out parts, or the fitted runs without validation): their
        :meth:`~usvlog.identify.validation.Validation.summary` (fit %, score) until
        :func:`~usvlog.identify.validation.with_arrays` makes them again with their arrays (the
        returned candidate's).
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
    """Why a parameter vector is not a boat (empty when it is): m, Iz, d.. > 0, finite, Iz - m xg^2 > 0,
    no velocity time constant under 1 / MAX_STIFFNESS."""
    th = np.asarray(theta, float)
    if not np.all(np.isfinite(th)):
        return "parameters not finite"
    bad = [k for k, v in zip(PARAM_NAMES[:5], th[:5]) if v <= 0]
    if bad:
        return f"{', '.join(bad)} not positive"
    if th[1] - th[0] * th[5] ** 2 <= 0:
        return "Iz - m xg^2 not positive"
    k = stiffness(th)
    if not k <= MAX_STIFFNESS:   # its simulation would need ever smaller steps (a hang, not a result)
        return f"a velocity time constant of {1e3 / k:.2g} ms (under {1e3 / MAX_STIFFNESS:.0f} ms): no boat's"
    return ""


def _ee_inputs(run: RunData, ks: KinStates, current=(0.0, 0.0)):
    nu = ks.nu(current)
    tu, tr = thrust_on_grid(run, ks.t)
    tu = smooth_like(ks.t, smooth_like(ks.t, tu, EE_POS_S), EE_ACC_S)
    tr = smooth_like(ks.t, smooth_like(ks.t, tr, EE_PSI_S), EE_ACC_S)
    return smooth_like(ks.t, nu, EE_ACC_S), derivative(ks.t, nu, EE_ACC_S), tu, tr


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


# -- the candidate list, one fit, the pick by validation -------------------------
def candidate_starts(self: Identifier, ee: EquationErrorResult, vessel: Vessel) -> list[Start]:
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


def _extended_starts(self: Identifier, th_paper) -> list[Start]:
    """Extended-model candidates: velocity output error from the data's scales (as the paper
    model's, :mod:`usvlog.identify.velocity`), output error from the paper's equation-error start in the
    extended form (preferred: the extended equation-error fit is biased by the noise of its
    regressors, m11 a third of the truth on a noisy run) and from the extended
    equation-error fit, then that fit itself."""
    from .extended_oe import ext_physical_problem  # lazy: the extended model only

    ext_ee = getattr(self, "_ext_ee", None)
    assert ext_ee is not None
    paper = ExtendedParams.from_paper(VesselParams(**dict(zip(PARAM_NAMES, map(float, th_paper))))).as_array()
    th_ee = ext_ee.theta
    scales = getattr(self, "_data_scales", None)
    voe = ([Start(name="extended velocity output error with the surge equation's mass", kind="velocity-error",
                  model="extended", theta=extended_start(scales), surge_mass=True),
            Start(name="extended velocity output error from the data's scales", kind="velocity-error",
                  model="extended", theta=extended_start(scales))]
           if scales is not None and not getattr(self, "_command_units", False) else [])
    if not ext_physical_problem(th_ee) and not getattr(self, "_command_units", False):
        voe.append(Start(name="extended velocity output error from extended equation error", kind="velocity-error",
                         model="extended", theta=th_ee))
    return voe + [Start(name="extended output error from the paper's equation error", kind="output-error",
                  model="extended", theta=paper),
            Start(name="extended output error from extended equation error", kind="output-error",
                  model="extended", theta=th_ee if not ext_physical_problem(th_ee) else paper),
            Start(name="extended equation error", kind="equation-error", model="extended", theta=th_ee)]


def candidate_starts_paper(self: Identifier, ee: EquationErrorResult, vessel: Vessel, th) -> list[Start]:
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
    out.append(ee_start)
    if self.current and getattr(self, "validation_mode_", "") == "holdout":
        # right after it: preferred in a tie with the current the run's own residuals give (a
        # held-out part judges whether that current is real; without one a current always
        # fits the fitted runs a little better)
        out.append(Start(name="equation error with its water current", kind="equation-error",
                         theta=ee_start.theta, ee_current=True))
    if getattr(self, "quadratic_surge", False) and scales is not None and not getattr(self, "_command_units", False):
        # last: a tie in validation goes to the paper model without it
        out += [Start(name="output error, the paper model with quadratic surge damping", kind="output-error",
                      model="extended", theta=quadratic_surge_start(th), quadratic_surge=True),
                Start(name="velocity output error, the paper model with quadratic surge damping",
                      kind="velocity-error", model="extended", theta=quadratic_surge_start(scales),
                      quadratic_surge=True)]
    return out


def quadratic_surge_start(theta_paper) -> np.ndarray:
    """The paper model's (m, Iz, d11, d22, d33, xg) in the extended form with a quadratic surge
    damping: the surge damping QUADRATIC_START of it quadratic per unit speed, the linear part
    reduced to match at that speed, no quadratic sway or yaw damping (EXTENDED_PARAM_NAMES order)."""
    m, Iz, d11, d22, d33, xg = (float(x) for x in theta_paper)
    q = QUADRATIC_START
    return np.array([m, m, m * xg, Iz, d11 * (1 - q), d11 * q, d22, 0.0, d33, 0.0])


def _ext_form(st: Start) -> tuple[tuple, tuple]:
    """(held, ties) of an extended-structure fit of candidate ``st``: the names held at the start's
    values (the quadratic-surge form: QS_HELD, m22 tied to m11 by QS_TIES; the surge-mass one: m11)
    and the (tied, source) pairs."""
    held = (QS_HELD if st.quadratic_surge else ()) + (("m11",) if st.surge_mass else ())
    return held, (QS_TIES if st.quadratic_surge else ())


def _ext_velocity_form(st: Start) -> tuple[np.ndarray | None, tuple]:
    """``free_mask`` and ``ties`` of candidate ``st``'s extended velocity fit (None: all ten free)."""
    held, ties = _ext_form(st)
    return (np.array([k not in held for k in EXTENDED_PARAM_NAMES]) if held else None), ties


def _ext_oe_form(st: Start, theta) -> tuple[dict, tuple]:
    """``fix`` and ``ties`` of candidate ``st``'s extended output error (the held values from ``theta``)."""
    held, ties = _ext_form(st)
    return {k: float(theta[EXTENDED_PARAM_NAMES.index(k)]) for k in held}, ties


def _tied_stderr(st: Start, fitted) -> dict:
    """Standard errors of the tied parameters (m22 is m11 in the quadratic-surge form): not in the
    fit's covariance, they are their source's."""
    if not st.quadratic_surge or "m11" not in fitted.names:
        return {}
    i = fitted.names.index("m11")
    return {"m22": float(math.sqrt(max(fitted.cov[i, i], 0.0)))}


def _with_fixed(self: Identifier, theta) -> np.ndarray:
    """``theta`` with the fixed parameters set to their values."""
    th = np.array(theta, float)
    for i, k in enumerate(PARAM_NAMES):
        if k in self.fix:
            th[i] = self.fix[k]
    return th


def _free(self: Identifier, st: Start) -> np.ndarray:
    """Which of the paper model's parameters a candidate's output or filter error fits."""
    return np.array([k not in self.fix and not (k == "m" and st.surge_mass) for k in PARAM_NAMES])


def _surge(self: Identifier, runs, kin, theta) -> SurgeFit:
    """m and d11 of the surge equation alone (output error to the GPS track), from ``theta``."""
    return fit_surge(runs, kin, float(theta[0]), float(theta[2]), float(theta[5]), fit_current=self.current,
                     max_current_mps=self.max_current_mps)


def _surge_wanted(self: Identifier) -> bool:
    """Whether :meth:`_surge_candidate` fits the surge equation (not for the extended model
    alone, equation or filter error, a fixed m)."""
    return not (self.model == "extended" or self.method != "output-error" or "m" in self.fix)


def _surge_candidate(self: Identifier, cands, runs, kin, fit_logs, vessel, held) -> Candidate | None:
    """Output error with m held at the surge equation's own fit, when that m is more than
    SURGE_MASS_RATIO away from the full output-error fit's (None otherwise, and for the
    extended model alone, equation or filter error, a fixed m). Where that m is determined it is
    the most preferred candidate (:func:`place_surge_candidate`): when it and the full fit
    validate alike (within PREFER_WITHIN), the data's surge evidence decides for its m (the
    held-out track and r barely see the surge time constant; the smoothed u lags and cannot
    judge it).

    The paper's model has one mass for surge, sway and the yaw coupling (m xg); on a boat
    whose sway and yaw are of another form the full fit can move m far from the surge's to
    absorb that mismatch (the track barely sees the surge time constant), and its surge
    speed is then wrong. The validation judges the two."""
    if not self._surge_wanted():
        return None
    full = [c for c in cands if c.start.model == "paper" and c.start.kind == "output-error"
            and c.start.vel_weight == 0]
    th = self._start(self.equation_error_, vessel)
    sf = self._surge(runs, kin, th)
    if full and not full[0].failed and 1 / SURGE_MASS_RATIO < sf.m / full[0].theta[0] < SURGE_MASS_RATIO:
        return None
    th[0] = sf.m
    st = Start(name="output error with the surge equation's mass", kind="output-error", theta=th,
               surge_mass=True)
    return self._fit_candidate(st, runs, kin, fit_logs, vessel, held, held_stderr={"m": sf.stderr["m"]})


def place_surge_candidate(cands: list[Candidate], sc: Candidate | None) -> list[Candidate]:
    """The candidates with the surge candidate (:func:`_surge_candidate`) in its place: first,
    preferred in a tie, when the surge equation determines its m (standard error within
    SURGE_MASS_PRECISION of it: its m then agrees with the surge's own evidence); else after the
    paper model's other candidates, where evidence that leaves m poorly determined decides no
    tie (a thruster lag fitted with the mass can swap the two: m 13 +- 7 kg on a Fossen Otter
    run, the hull 85 kg)."""
    if sc is None:
        return list(cands)
    if sc.held_stderr.get("m", math.inf) <= SURGE_MASS_PRECISION * sc.theta[0]:
        return [sc, *cands]
    i = next((j for j, c in enumerate(cands) if c.start.model != "paper"), len(cands))
    return [*cands[:i], sc, *cands[i:]]


def _fit_candidates(self: Identifier, starts: list[Start], runs, kin, fit_logs, vessel, held) -> list[Candidate]:
    """:meth:`_fit_candidate` of each start, one after another in their order. (Fitting the
    paper model's output-error candidates two at a time in threads was measured in issue 32:
    a 1-hour ``usvlog identify`` 7.4 % faster and 106 MB more at its peak, under the 10 % bar,
    so it was taken out; docs/performance.md.)"""
    return [self._fit_candidate(st, runs, kin, fit_logs, vessel, held) for st in starts]


def _fit_candidate(self: Identifier, st: Start, runs, kin, fit_logs, vessel, held, held_stderr=None) -> Candidate:
    """Fit one candidate and validate it (a failure is a result: ``failed`` says why, also when
    its fit could not proceed, :class:`~usvlog.errors.FitFailed`)."""
    try:
        return self._fit_candidate_raw(st, runs, kin, fit_logs, vessel, held, held_stderr)
    except UnusableResultError as err:   # FitFailed, or an estimate inside the fit that diverged
        return Candidate(start=st, theta=np.asarray(st.theta, float), currents=np.zeros((len(runs), 2)),
                         fitted=None, validations=[], failed=str(err))


def _fit_candidate_raw(self: Identifier, st: Start, runs, kin, fit_logs, vessel, held, held_stderr=None
                       ) -> Candidate:
    """:meth:`_fit_candidate` without the catch."""
    if st.model == "extended":
        return self._fit_ext_candidate(st, runs, kin, held)
    fitted, theta, cur = self._fit_paper_kind(st, runs, kin, fit_logs, vessel)
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
                     fitted=fitted, validations=[v.summary() for v in vals], failed=failed,
                     held_stderr=dict(held_stderr or {}))


def _fit_paper_kind(self: Identifier, st: Start, runs, kin, fit_logs, vessel, noise_free: bool = False
                    ) -> tuple[object, np.ndarray, np.ndarray]:
    """(fitted result, parameters, currents (n_runs, 2)) of a paper-model start's fit on these runs:
    its kind's fit (equation error, with its current or none, filter error, velocity or
    output error) from the start's values. ``noise_free``: measurements without noise (the
    smoother-bias check's): output error weighs the fixes and headings by their stated noise
    instead of their residuals' scatter (nothing there), and drops none as outliers."""
    free = self._free(st)
    zeros = np.zeros((len(runs), 2))
    fitted: object
    if st.kind == "equation-error" and st.ee_current:
        fitted, cur = self._equation_error_current(runs, kin)
        theta = self._ee_theta(fitted, vessel)
    elif st.kind == "equation-error":
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
                                  reweight=not noise_free, drop_outliers=not noise_free)
        theta, cur = fitted.theta, np.asarray(fitted.currents, float)
    return fitted, theta, cur


def _fit_ext_candidate(self: Identifier, st: Start, runs, kin, held, currents0=None) -> Candidate:
    """An extended-model candidate fitted (output error) or taken (equation error) and validated."""
    # lazy: the extended model only
    from .extended_oe import ExtendedOEResult, ext_physical_problem, fit_extended_output_error

    fitted: object
    held_se: dict = {}
    if st.kind == "equation-error":
        theta, cur, fitted = np.asarray(st.theta, float), np.zeros((len(runs), 2)), self._ext_ee
    elif st.kind == "velocity-error":
        th0 = np.asarray(st.theta, float)
        if st.surge_mass:
            th0, held_se = _ext_surge_mass(self, runs, kin, th0)
        free, ties = _ext_velocity_form(st)
        fitted = fit_velocity_error(runs, kin, th0, free_mask=free, ties=ties, fit_current=self.current,
                                    currents0=currents0, max_current_mps=self.max_current_mps, model="extended")
        theta, cur = fitted.theta, np.asarray(fitted.currents, float)
        held_se.update(_tied_stderr(st, fitted))
    else:
        # in command units the ratio search's short segments (its optimum stalls with long ones)
        seg = EXT_PROFILE_SEGMENT_S if getattr(self, "_command_units", False) else EXT_SEGMENT_S
        fix, ties = _ext_oe_form(st, st.theta)
        fitted = fit_extended_output_error(runs, kin, st.theta, fit_current=self.current, currents0=currents0,
                                           max_current_mps=self.max_current_mps, segment_s=seg, fix=fix, ties=ties)
        theta, cur = fitted.theta, fitted.currents
        held_se.update(_tied_stderr(st, fitted))
    failed = ext_physical_problem(theta)
    if not failed and isinstance(fitted, (ExtendedOEResult, VelocityFitResult)) and fitted.diverged:
        failed = "its simulation diverged"
    vals = []
    if not failed:
        pairs = held if held else list(zip(runs, kin))
        vals = [self._validate_run(r, k, theta, cur[i]) for i, (r, k) in enumerate(pairs)]
        if any(v.diverged for v in vals):
            failed = "its free run diverged"
    return Candidate(start=st, theta=np.asarray(theta, float), currents=np.asarray(cur, float),
                     fitted=fitted, validations=[v.summary() for v in vals], failed=failed, held_stderr=held_se)


def _ext_surge_mass(self: Identifier, runs, kin, theta) -> tuple[np.ndarray, dict]:
    """An extended-model start with m11 at the surge equation's own fit on these runs
    (:func:`~usvlog.identify.surge.fit_surge`, the GPS track) and its standard error
    (``{"m11": ...}``); :func:`_ext_velocity_form` holds it.

    Why: the velocity fit compares predictions started from the smoothed state with the smoothed
    velocities; the state it starts from is off by the smoother's error, and a surge with no
    inertia removes that error at once. The paper model's one m is held by the sway and yaw it
    also sets; the extended model's m11 is set by the surge transients alone and is pulled towards
    zero (a Fossen Otter run: 1.35 kg for the truth's 85.5, the held-out u 79 %). The surge
    equation fitted to the raw GPS positions has no such error (85.8 kg there)."""
    th = np.asarray(theta, float).copy()
    sf = fit_surge(runs, kin, float(th[0]), float(th[4]), float(th[2] / th[0]) if th[0] > 0 else 0.0,
                   fit_current=self.current, max_current_mps=self.max_current_mps)
    th[0] = sf.m
    return th, {"m11": sf.stderr["m"]}


def _compare_models(self: Identifier, cands: list[Candidate]) -> dict:
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


def _pick(self: Identifier, cands: list[Candidate]) -> Candidate:
    """The best candidate by validation; a preferred one (earlier) within PREFER_WITHIN
    points of the best is taken, but never one that validates worse than equation error."""
    ok = [c for c in cands if not c.failed]
    if not ok:
        why = [f"{c.start.name}: {c.failed}" for c in cands]
        err = UnusableResultError(f"identification failed: every candidate failed ({'; '.join(why)})")
        err.reasons = why      # type: ignore[attr-defined]
        raise err
    best = max(c.score for c in ok)
    ee = [c.score for c in ok if c.start.kind == "equation-error" and not c.start.ee_current]
    floor = max(best - PREFER_WITHIN, max(ee) if ee else -math.inf)
    return next(c for c in ok if c.score >= floor)


def _refit(self: Identifier, chosen: Candidate, runs, kin, logs, vessel, held) -> Candidate:
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
        elif st.kind == "velocity-error":
            th0 = chosen.theta
            if st.surge_mass:   # the surge equation's m11 from all the data too
                th0, held_se = _ext_surge_mass(self, runs, kin, th0)
            free, ties = _ext_velocity_form(st)
            fitted = fit_velocity_error(runs, kin, th0, free_mask=free, ties=ties, fit_current=self.current,
                                        currents0=chosen.currents, max_current_mps=self.max_current_mps,
                                        horizons_s=(120.0,), model="extended")
            held_se = {**held_se, **_tied_stderr(st, fitted)}
            theta, cur = fitted.theta, fitted.currents
            if fitted.diverged:
                return chosen
        else:
            fix, ties = _ext_oe_form(st, chosen.theta)
            fitted = fit_extended_output_error(runs, kin, chosen.theta, fit_current=self.current,
                                               currents0=chosen.currents, max_current_mps=self.max_current_mps,
                                               segment_s=EXT_SEGMENT_S, max_iter=EXT_REFIT_ITER, fix=fix, ties=ties)
            theta, cur = fitted.theta, fitted.currents
            held_se = {**held_se, **_tied_stderr(st, fitted)}
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
        ee, cur = (self._equation_error_current(runs, kin) if st.ee_current
                   else (self._equation_error(runs, kin), np.zeros((len(runs), 2))))
        theta, fitted = self._ee_theta(ee, vessel), ee
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
    if _degenerate(fitted) and not _degenerate(chosen.fitted):
        # on all the data the fit ran onto a bound or a cliff (a parameter its data push
        # outside a boat's range): the validated fit's values stand
        return chosen
    vals = [self._validate_run(r, k, theta, cur[i]) for i, (r, k) in enumerate(held)]
    again = Candidate(start=st, theta=np.asarray(theta, float), currents=cur, fitted=fitted,
                      validations=[v.summary() for v in vals], held_stderr=held_se)
    if again.score < chosen.score - PREFER_WITHIN:
        return chosen
    return again


def _degenerate(fitted) -> bool:
    """True when a fit's scaled Jacobian is numerically singular (condition number over
    :data:`DEGENERATE_COND`, or not finite): its standard errors mean nothing."""
    cond = getattr(fitted, "cond", None)
    return cond is not None and not (math.isfinite(cond) and cond <= DEGENERATE_COND)


def _ee_theta(self: Identifier, ee: EquationErrorResult, vessel: Vessel) -> np.ndarray:
    """Equation error's values as a candidate: d22 at its bound 0 (not determined by it)
    taken from the vessel, so that the candidate is a boat that can be simulated."""
    th = ee.theta.copy()
    if th[3] <= 0 and "d22" not in self.fix:
        th[3] = vessel.params.d22
    return th


def _equation_error(self: Identifier, runs, kin) -> EquationErrorResult:
    parts = [_ee_inputs(r, k) for r, k in zip(runs, kin)]
    return fit_equation_error(np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts]),
                              np.concatenate([p[2] for p in parts]), np.concatenate([p[3] for p in parts]),
                              fix=self.fix)


def _equation_error_current(self: Identifier, runs, kin) -> tuple[EquationErrorResult, np.ndarray]:
    """Equation error with a constant water current per run (north, east, m/s, each within
    ``max_current_mps``): the currents that make the sum of the log residual RMS of the surge
    and yaw equations smallest (the likelihood of Gaussian equation errors of unknown scale
    each), by Nelder-Mead per run, two sweeps over the runs. Not the sway equation's: it has no
    force of its own, and as in :func:`~usvlog.identify.equation.fit_equation_error` it would
    pull the fit (on the whole of a Fossen Otter run in a 0.25 m/s current, the current 0.045 m/s off
    with it, 0.011 without). A current changes the body velocities
    relative to the water by a rotation, and the smoothing and derivative after it are linear,
    so each run's inputs are made three times (no current, 1 m/s north, 1 m/s east) and
    combined, not made again at every step. Returns the fit and the currents, shape (n_runs, 2)."""
    from scipy.optimize import minimize  # lazy: this candidate only

    basis = []
    for r, k in zip(runs, kin):
        p0, pn, pe = (_ee_inputs(r, k, c) for c in ((0.0, 0.0), (1.0, 0.0), (0.0, 1.0)))
        basis.append((p0, [pn[i] - p0[i] for i in (0, 1)], [pe[i] - p0[i] for i in (0, 1)]))
    cur = np.zeros((len(runs), 2))

    def fit(c):
        parts = [(p0[0] + cn * dn[0] + ce * de[0], p0[1] + cn * dn[1] + ce * de[1], p0[2], p0[3])
                 for (p0, dn, de), (cn, ce) in zip(basis, c)]
        return fit_equation_error(*(np.concatenate([p[i] for p in parts]) for i in range(4)), fix=self.fix)

    def cost(x, i):
        c = cur.copy()
        c[i] = x
        with np.errstate(divide="ignore"):
            rms = fit(c).rms
            return float(np.log(rms[0]) + np.log(rms[2]))

    bound = self.max_current_mps
    for _ in range(2 if len(runs) > 1 else 1):
        for i in range(len(runs)):
            res = minimize(cost, cur[i], args=(i,), method="Nelder-Mead", bounds=[(-bound, bound)] * 2,
                           options={"xatol": 1e-3, "fatol": 1e-6,
                                    "initial_simplex": cur[i] + np.array([[0, 0], [0.1, 0], [0, 0.1]])})
            if np.all(np.isfinite(res.x)) and res.fun <= cost(cur[i], i):
                cur[i] = res.x
    return fit(cur), cur


def _ext_equation_error(self: Identifier, runs, kin) -> ExtendedFit:
    from .extended import fit_extended_equation_error  # lazy: the extended model only

    parts = [_ee_inputs(r, k) for r, k in zip(runs, kin)]
    return fit_extended_equation_error(*(np.concatenate([p[i] for p in parts]) for i in range(4)))


def _start(self: Identifier, ee: EquationErrorResult, vessel: Vessel) -> np.ndarray:
    """Output-error start: the equation-error values where plausible, else the data's scales
    (:func:`~usvlog.identify.velocity.data_scales`), else the vessel's. A value is plausible
    within a factor START_RATIO of the vessel's or START_SCALE_RATIO of the data's scale: a
    user's guess far from the boat (a tiny boat's values for an 80 kg hull) must not replace
    what the data say."""
    prior = vessel.params.as_array()
    scales = getattr(self, "_data_scales", None)
    th = ee.theta.copy()
    for i, k in enumerate(PARAM_NAMES):
        if k in self.fix:
            th[i] = self.fix[k]
            continue
        v = th[i]
        if k == "xg":
            ok = math.isfinite(v) and abs(v) < 1.0
        else:
            ok = math.isfinite(v) and v > 0 and (
                1 / START_RATIO < v / prior[i] < START_RATIO
                or (scales is not None and 1 / START_SCALE_RATIO < v / scales[i] < START_SCALE_RATIO))
        if not ok:
            th[i] = prior[i] if scales is None else scales[i]
    if th[1] - th[0] * th[5] ** 2 <= 0.05 * th[1]:
        th[5] = 0.0 if "xg" not in self.fix else th[5]
    return th
