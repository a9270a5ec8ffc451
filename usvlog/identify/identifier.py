"""Identifier: scikit-learn style fitter of the paper's model (3) from field logs.

:class:`Identifier` holds the settings and the fitted attributes; :meth:`Identifier.fit`
reads the runs, runs the checks before fitting (:mod:`usvlog.identify.checks`), fits and
picks the candidates (:mod:`usvlog.identify.candidates`), sets the fitted attributes from the
one returned and judges it (:mod:`usvlog.identify.verdict`). Validation is
:mod:`usvlog.identify.validation`'s and the reports :mod:`usvlog.identify.report`'s: their
functions are the class's methods.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pandas as pd

from ..choices import EXT_SCALE_FIX, EXTENDED_PARAM_NAMES, IDENTIFY_METHODS, IDENTIFY_MODELS
from ..errors import ConfigError, FitFailed, InputError, UnusableResultError
from ..log.fieldlog import FieldLog
from ..log.summary import health_from_provenance
from ..model.vessel import PARAM_NAMES, ExtendedParams, Vessel, VesselParams, default_vessel, extended_vessel
from . import candidates, leave_one_out, report, validation, verdict
from .ahead import (
    WHITENESS_LAGS,
    WHITENESS_STEP_S,
    fit_percent_ahead,
    one_step_residuals,
    residual_whiteness,
)
from .candidates import Candidate, Start, _returned, place_surge_candidate
from .checks import _excitation_warnings, _refuse_dead_channels, _refuse_outside_model, _refuse_wrong_signs
from .data import lag_thrust, runs_and_lean_logs
from .equation import EquationErrorResult
from .lag import LagFit, fit_thruster_lag
from .output import OutputErrorResult, simulate_run
from .smooth import kinematic_states
from .smoother_bias import pick_unbiased
from .thrust_scale import ThrustScale, fit_in_command_units, thrust_scale_known
from .validation import Validation, _mean_score, excitation_of, with_arrays
from .velocity import VelocityFitResult, data_scales
from .verdict import VERDICTS

# what other units import from here (Validation and VERDICTS are defined in .validation, .verdict)
__all__ = ["METHODS", "VERDICTS", "Identifier", "Validation"]


METHODS = IDENTIFY_METHODS
Z95 = 1.959963984540054
DEFAULT_HOLDOUT = 0.3       # one log: the last 30 % validates
MAX_CURRENT_MPS = 0.5       # default bound on each current component (m/s)
AHEAD_S = (5.0, 10.0, 30.0)  # k-step-ahead validation horizons (s): a path follower's prediction horizons


def _log_before(log: FieldLog, t_ns: int) -> FieldLog:
    """The part of a log before ``t_ns`` (every channel)."""
    out = log.copy()
    for topic, frame in log.channels.items():
        out.channels[topic] = frame[np.asarray(frame.index, dtype=np.int64) < t_ns]
    return out


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
        Fit a constant water current (north, east) per run. Plain equation error fits none; with a
        held-out part, equation error with the current its residuals give is a candidate too.
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
    fit_lag : bool, default False
        Identify a first-order thruster lag (:mod:`usvlog.identify.lag`) and fit through it.
    lag_s : float, default 0.0
        A known thruster lag (s) the thrust goes through before the fit (not with ``fit_lag``).
    quadratic_surge : bool, default False
        Also fit the paper model with a quadratic surge damping d11q (surge force
        ``d11 u + d11q u|u|``; a propeller-driven hull's drag grows with u^2) by velocity
        output error: the extended structure with one mass (m22 = m11), no quadratic sway or yaw
        damping. Returned only when it validates better by PREFER_WITHIN points, written as an
        ``[extended]`` vessel. With ``model`` paper or both, output error.

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
        Every candidate fitted, with its validation's figures (fit %, score;
        :meth:`candidate_validations` gives its free runs); ``chosen_`` is the one returned.
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
    smoother_bias_ : dict of str to float
        The validated candidate's fit made again on its own free runs as the sensors and the
        smoother show them, over the held-out data (without it, over the fitted runs)
        (:mod:`usvlog.identify.smoother_bias`): refitted / fitted - 1 per parameter (xg: the
        difference in m); empty where not checked (equation error, filter error, the extended
        model).
    bias_switch_ : dict or None
        Set when the candidate picked was biased by the smoother beyond
        :data:`~usvlog.identify.smoother_bias.BIAS_UNUSABLE` and one that is not, validating within
        :data:`~usvlog.identify.smoother_bias.BIAS_SWITCH_WITHIN` points, was returned instead:
        ``from`` (its name), ``score``, ``param`` and ``bias`` (its worst parameter's share).
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
        score, the ``winner`` (better score) and its ``margin`` in score points
        (:data:`~usvlog.identify.validation.SCORE_WORDS`), the model ``returned`` (the paper's when
        the extended one is better by less than PREFER_WITHIN points, or equation error's when that
        validates better), ``why`` in plain words and the ``rule`` (MODEL_RULE).

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
                 max_current_mps: float = MAX_CURRENT_MPS, model: str = "paper", fit_lag: bool = False,
                 lag_s: float = 0.0, quadratic_surge: bool = False):
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
        if not (math.isfinite(lag_s) and lag_s >= 0):
            raise ConfigError(f"lag_s = {lag_s} must be a thruster time constant >= 0 (s)")
        if fit_lag and lag_s:
            raise ConfigError("a known thruster lag (lag_s) or one identified (fit_lag), not both")
        if (fit_lag or lag_s) and method == "filter-error":
            raise ConfigError("a thruster lag is identified with output error or equation error, not filter error "
                              "(its filter reads the logs' thrust itself)")
        if quadratic_surge and (model == "extended" or method != "output-error"):
            raise ConfigError("quadratic surge damping is an option of the paper model fitted by output error "
                              "(the extended model has its own d11q)")
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
        self.fit_lag = bool(fit_lag)
        self.quadratic_surge = bool(quadratic_surge)
        self.lag_s = float(lag_s)

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
        holdout = self.holdout if self.holdout is not None else (DEFAULT_HOLDOUT if len(logs) == 1 else None)
        # memory: the logs' thrust channels go (the runs' arrays are the one copy of it the fit keeps)
        all_runs, logs = runs_and_lean_logs(logs, vessel, keep_thrust=self.method == "filter-error")
        all_kin = [kinematic_states(lg, r, vessel, tune=self._tune_smoother) for lg, r in zip(logs, all_runs)]
        self.sign_checks_ = _refuse_wrong_signs(all_runs, all_kin, vessel.thrusters.arm_m)
        # a thruster lag, known or found on the part fitted: the thrust the model is fitted on goes through it
        self.thruster_lag_ = self._fit_thruster_lag(all_runs, all_kin, holdout, vessel) if self.fit_lag else None
        lag = self.thruster_lag_.lag_s if self.thruster_lag_ is not None else self.lag_s
        self.lag_applied_s_ = lag
        if lag > 0:
            vessel = replace(vessel, thrusters=replace(vessel.thrusters, lag_s=lag))
            self.vessel_in_ = vessel
            all_runs = [lag_thrust(r, lag) for r in all_runs]
        if self.method != "filter-error":   # the only fit that reads the logs again: the rest has what it needs
            logs = [FieldLog(meta=lg.meta, recovery=lg.recovery, source=lg.source) for lg in logs]
        if holdout is None:
            self.validation_mode_ = "leave-one-out"
        else:
            self.validation_mode_ = "holdout" if holdout > 0 else "none"
        runs, kin, held, fit_logs = [], [], [], []
        for log, run, ks in zip(logs, all_runs, all_kin):
            if holdout is not None and holdout > 0:
                t_cut = run.t_thrust[0] + (1 - holdout) * run.duration_s
                # free runs are smoothed like the data on the held-out part only: it keeps its own part of the log
                held.append((run.window(t_cut, run.t_thrust[-1]), ks.window(t_cut, np.inf).trimmed()))
                run, ks = run.window(-np.inf, t_cut), replace(ks.window(-np.inf, t_cut), smoother=None)
                if self.method == "filter-error":   # the only fit that reads the logs themselves
                    log = _log_before(log, run.t0_ns + int(t_cut * 1e9))
            fit_logs.append(log)
            runs.append(run)
            kin.append(ks)
        if held:   # nor on the whole runs: the rest of the log can go
            all_kin = [replace(k, smoother=None) for k in all_kin]
        # -- candidates, fitted on the fit part, judged on the held-out part ---------------
        self._data_scales = data_scales(runs, kin)
        ee = self._equation_error(runs, kin)
        self.equation_error_ = ee
        self._ext_ee = self._ext_equation_error(runs, kin) if self.model != "paper" else None
        cands = self._fit_candidates(self.candidate_starts(ee, vessel), runs, kin, fit_logs, vessel, held)
        cands = place_surge_candidate(cands, self._surge_candidate(cands, runs, kin, fit_logs, vessel, held))
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
        # what the smoother does to a fit on smoothed states: the chosen model's own free runs fitted again
        # (one it misleads is passed over for one it does not that validates about as well), on the runs
        # the candidates were validated on: the held-out parts, else the fitted runs themselves
        self.bias_switch_: dict | None
        pairs = held if held else list(zip(runs, kin))
        chosen, self.smoother_bias_, self.bias_switch_ = pick_unbiased(self, chosen, cands, pairs, vessel)
        if self.model_comparison_ is not None:   # the simpler paper model is kept within PREFER_WITHIN
            self.model_comparison_.update(_returned(self.model_comparison_, chosen))
        self.validations_ = list(with_arrays(self, chosen, pairs)) if self.validation_mode_ == "holdout" else []
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
            self.fit_percent_ahead_ = self._ahead(held)
        except FitFailed:   # too short a held-out part to predict ahead: the free run alone judges
            self.fit_percent_ahead_ = {}
        self.excitation_ = excitation_of(self.validations_)
        self.whiteness_ = self._whiteness(held)
        self.reasons_, self.verdict_ = self._verdict(vessel, runs, kin)
        self.usable_ = self.verdict_ != "unusable"
        return self

    def _fit_thruster_lag(self, runs, kin, holdout, vessel) -> LagFit:
        """A first-order thruster lag identified on the part of the runs fitted
        (:func:`~usvlog.identify.lag.fit_thruster_lag`), from the data's scales (else the
        vessel's values)."""
        if holdout:
            cut = [r.t_thrust[0] + (1 - holdout) * r.duration_s for r in runs]
            runs = [r.window(-np.inf, c) for r, c in zip(runs, cut)]
            kin = [k.window(-np.inf, c) for k, c in zip(kin, cut)]
        start = data_scales(runs, kin)
        if start is None:
            start = vessel.params.as_array()
        return fit_thruster_lag(runs, kin, start, fit_current=self.current, max_current_mps=self.max_current_mps)

    def _predictor(self):
        """(parameters, free-run function) of the returned model for predictions ahead: the paper
        model's :func:`~usvlog.identify.output.simulate_run`, or the extended model's
        :func:`~usvlog.identify.extended_oe.free_run_full`."""
        if self.extended_ is None:
            return self.theta_, simulate_run
        from .extended_oe import free_run_full  # lazy: the extended model only

        return self.extended_.as_array(), free_run_full

    def _current_of(self, i: int):
        """Run i's fitted current (north, east, m/s); none for a run without one."""
        return self.current_[i] if i < len(self.current_) else (0.0, 0.0)

    def _ahead(self, held) -> dict:
        """k-step-ahead fit % (:func:`~usvlog.identify.ahead.fit_percent_ahead`, H = AHEAD_S) of the
        returned model on the held-out parts (mean over them); empty without held-out data."""
        if not held:
            return {}
        theta, simulate = self._predictor()
        per = []
        for i, (r, k) in enumerate(held):
            cur = self._current_of(i)
            per.append(fit_percent_ahead(r, k, theta, cur, AHEAD_S, simulate=simulate))
        return {h: {c: float(np.mean([p[h][c] for p in per])) for c in ("u", "v", "r")} for h in per[0]}

    def _whiteness(self, held) -> dict:
        """Whiteness of the yaw rate's residuals predicted WHITENESS_STEP_S ahead on the held-out
        parts (:func:`~usvlog.identify.ahead.residual_whiteness`): ``{"r": WhitenessResult}``, empty
        without held-out data or with too few residuals. Only r: the smoothed u is correlated over
        the smoother's window, and its residuals were measured as often not white for the true
        model (3 seeds of the paper's vessel: 0-6 of 25 lags outside at 5 s) as for a d11 30 % off;
        for r the true model was white (0 of 25) and a d33 50 % off was not (15 of 25)."""
        if not held:
            return {}
        theta, simulate = self._predictor()
        res = []
        for i, (r, k) in enumerate(held):
            cur = self._current_of(i)
            t0 = max(r.t_thrust[0], k.t[0])
            try:
                _, e = one_step_residuals(r, k, theta, cur, WHITENESS_STEP_S, t_from=t0, simulate=simulate)
            except (FitFailed, ValueError):
                continue
            res.append(e[:, 2])
        e = np.concatenate(res) if res else np.zeros(0)
        lags = min(WHITENESS_LAGS, int(np.isfinite(e).sum()) // 4)
        if lags < 5:
            return {}
        try:
            return {"r": residual_whiteness(e, max_lag=lags)}
        except ValueError:   # constant residuals: nothing to test
            return {}

    # -- methods whose code is in the module of their job (functions of the Identifier there) -----------
    # the candidate strategy: starts, fits, the surge candidate, the pick, the refit (.candidates)
    candidate_starts = candidates.candidate_starts
    _extended_starts = candidates._extended_starts
    candidate_starts_paper = candidates.candidate_starts_paper
    _with_fixed = candidates._with_fixed
    _free = candidates._free
    _surge = candidates._surge
    _surge_wanted = candidates._surge_wanted
    _surge_candidate = candidates._surge_candidate
    _fit_candidates = candidates._fit_candidates
    _fit_candidate = candidates._fit_candidate
    _fit_candidate_raw = candidates._fit_candidate_raw
    _fit_paper_kind = candidates._fit_paper_kind
    _fit_ext_candidate = candidates._fit_ext_candidate
    _compare_models = candidates._compare_models
    _pick = candidates._pick
    _refit = candidates._refit
    _leave_one_out = leave_one_out._leave_one_out
    _ee_theta = candidates._ee_theta
    _equation_error = candidates._equation_error
    _equation_error_current = candidates._equation_error_current
    _ext_equation_error = candidates._ext_equation_error
    _start = candidates._start

    # the validation: free runs of the model and their fit % (.validation)
    validation_fit_percent_ = validation.validation_fit_percent_
    use_validation = validation.use_validation
    validate = validation.validate
    _validate_run = validation._validate_run
    _validate_ext = validation._validate_ext

    # the verdict: usable, with caveats or unusable, and why (.verdict)
    _held_names = verdict._held_names
    _ext_term_findings = verdict._ext_term_findings
    _verdict = verdict._verdict

    # the reports: measured against fitted, the JSON dict and the TOML record (.report)
    fit_frame = report.fit_frame
    fit_percent_ = report.fit_percent_
    to_dict = report.to_dict
    toml_record = report.toml_record

    @property
    def structure_(self) -> str:
        """The model structure returned: ``"paper"``, ``"extended"``, or ``"paper with quadratic surge
        damping"`` (``quadratic_surge``: the extended form with m22 = m11 and no quadratic sway or
        yaw damping, written as an ``[extended]`` vessel)."""
        if self.extended_ is None:
            return "paper"
        return "paper with quadratic surge damping" if self.final_.start.quadratic_surge else "extended"

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
        if isinstance(fitted, (ExtendedOEResult, VelocityFitResult)):
            names = list(fitted.names)
            cov = fitted.cov
            cov_ext = np.zeros((ne, ne))
            pos = [ix[k] for k in names if k in ix]
            cov_ext[np.ix_(pos, pos)] = cov[:len(pos), :len(pos)]
            for k, x in cand.held_stderr.items():   # held in this fit, estimated by another (not in cov_)
                cov_ext[ix[k], ix[k]] = x * x
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
            self.current_ = [tuple(float(x) for x in c) for c in cand.currents]   # zeros: none fitted
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

    @property
    def _tune_smoother(self) -> bool:
        """Whether the smoothed states are made with process noise tuned to the run
        (:func:`~usvlog.identify.smooth.kinematic_states`). Not in command units: the thrust
        ratio search (:mod:`usvlog.identify.thrust_scale`) and the per-unit fit after it share
        the default smoother, on whose states their targets were set (an extended boat's per-unit
        d22 came out 12.5 % off on tuned states, 5.6 % on the default)."""
        return not getattr(self, "_command_units", False)

    def candidate_validations(self, cand: Candidate) -> list[Validation]:
        """The validations of one of :attr:`candidates_` with their arrays (measured and simulated
        states, the smoothed free run): a candidate keeps their figures only, and they are made
        again, to the same numbers, on the parts it was validated on.

        Raises
        ------
        usvlog.errors.ConfigError
            If the identifier is not fitted.
        """
        self._check_fitted()
        return with_arrays(self, cand, self._held or list(zip(self.runs_, self._kin)))

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
