"""Identifier: scikit-learn style fitter of the paper's model (3) from field logs."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pandas as pd

from ..choices import IDENTIFY_METHODS
from ..errors import ConfigError, InputError
from ..estimate import EstimateSettings, estimate
from ..log.fieldlog import FieldLog
from ..model.frames import ssa
from ..model.stats import fit_percent
from ..model.vessel import PARAM_NAMES, Vessel, VesselParams, default_vessel
from .data import RunData, run_data
from .equation import EquationErrorResult, fit_equation_error
from .filter import fit_filter_error
from .output import (
    fit_initial_state,
    fit_output_error,
    predict_segments,
    simulate_run,
)
from .smooth import KinStates, derivative, kinematic_states, smooth_like, thrust_on_grid
from .thrust_scale import ThrustScale, fit_in_command_units, thrust_scale_known

METHODS = IDENTIFY_METHODS
Z95 = 1.959963984540054
# equation-error smoothing (s): positions, heading, accelerations (thrust filtered alike)
EE_POS_S, EE_PSI_S, EE_ACC_S = 16.0, 6.0, 6.0


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

    def to_dict(self) -> dict:
        """JSON-ready summary: fit_percent, current_ne_mps, init_window_s, duration_s."""
        return {"fit_percent": dict(self.fit_percent), "current_ne_mps": list(self.current),
                "init_window_s": self.init_window_s, "duration_s": float(self.t[-1] - self.t[0])}


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
    st = estimate(log, EstimateSettings(model="dynamic", current=True, output_step_s=0.1), v).state
    return (float(np.nanmean(st["current_n_mps"])), float(np.nanmean(st["current_e_mps"])))


def _excitation_warnings(kin: list[KinStates], force: bool = False) -> list[str]:
    r_rms = math.sqrt(np.mean(np.concatenate([k.r for k in kin]) ** 2))
    psi_span = max(float(np.ptp(k.psi)) for k in kin)
    if force or r_rms < math.radians(2.0) or psi_span < math.radians(30.0):
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

    Follows the scikit-learn contract: :meth:`fit` returns the identifier, and what it
    fitted is in attributes ending in ``_``.

    Parameters
    ----------
    method : {"output-error", "equation-error", "filter-error"}, default "output-error"
        Identification method (see above).
    fix : dict of str to float, optional
        Known parameters by paper symbol, SI units (e.g. ``{"m": 31.5}`` kg); they are
        held at these values and get standard error 0.
    current : bool, default True
        Fit a constant water current (north, east) per run. Equation error never fits it.
    segment_s : float, default 300.0
        Output error: segment length in s of the final multiple-shooting fit, > 0.
    warm_segment_s : float, default 60.0
        Output error: a warm-up fit with segments this long (s) on the first 900 s of each
        run precedes the final one when 0 < warm_segment_s < segment_s; 0 turns it off.
    holdout : float, default 0.0
        Fraction in [0, 0.9) of each run's end kept out of the fit; the first run's held
        part is then validated (``validation_``).

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
    verdict_ : list of str
        Warnings about identifiability, excitation, correlations and the thruster map
        (empty when nothing stands out).
    thrust_scale_ : ThrustScale
        Whether the thrust had a known force scale; if not, the fit is in command units
        (per unit of full forward command) or, with one physical value fixed, scaled to
        physical units with the thrust gains found (:mod:`usvlog.identify.thrust_scale`).
    equation_error_ : EquationErrorResult
        The equation-error fit (always computed: the output-error start and a comparison).
    oe_ : OutputErrorResult or None
        Full output-error result (None for the other methods).
    fe_ : FilterErrorResult
        Full filter-error result (only set by that method).
    validation_ : Validation or None
        Free run on the held-out part when ``holdout > 0``, else None.
    vessel_in_ : Vessel
        Vessel given to :meth:`fit` (thruster map and starting values).
    runs_ : list of RunData
        The fitted runs (without the held-out part).

    Raises
    ------
    usvlog.errors.ConfigError
        On an unknown method, an unknown or non-finite fixed parameter, or segment
        lengths or ``holdout`` out of range.

    Examples
    --------
    >>> ident = Identifier(fix={"m": 33.0}).fit(log)        # doctest: +SKIP
    >>> ident.params_, ident.stderr_["d11"]                  # doctest: +SKIP
    >>> vessel = ident.to_vessel("my-boat")                  # doctest: +SKIP
    """

    def __init__(self, method: str = "output-error", *, fix: dict | None = None, current: bool = True,
                 segment_s: float = 300.0, warm_segment_s: float = 60.0, holdout: float = 0.0):
        if method not in METHODS:
            raise ConfigError(f"method {method!r} is not one of {', '.join(METHODS)}")
        fix = dict(fix or {})
        for k, v in fix.items():
            if k not in PARAM_NAMES:
                raise ConfigError(f"cannot fix {k!r}: not one of {', '.join(PARAM_NAMES)}")
            if not (isinstance(v, (int, float)) and math.isfinite(v)):
                raise ConfigError(f"fixed value {k} = {v!r} is not a finite number")
        if not (segment_s > 0 and warm_segment_s >= 0):
            raise ConfigError("segment_s must be > 0 and warm_segment_s >= 0")
        if not (0.0 <= holdout < 0.9):
            raise ConfigError(f"holdout = {holdout} must be in [0, 0.9)")
        self.method = method
        self.fix = fix
        self.current = current
        self.segment_s = float(segment_s)
        self.warm_segment_s = float(warm_segment_s)
        self.holdout = float(holdout)

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
            Thruster map and geometry, and the fallback starting values; default the
            first log's vessel, else the built-in :func:`~usvlog.model.vessel.default_vessel`.

        Returns
        -------
        Identifier
            ``self``, with the fitted attributes (``params_``, ``stderr_``, ...) set.

        Raises
        ------
        usvlog.errors.InputError
            If there are no logs, a log lacks a channel or has too few samples, or the
            fit gives physically impossible parameters (poorly excited runs).
        """
        if isinstance(logs, FieldLog):
            logs = [logs]
        if not logs:
            raise InputError("no logs to identify from")
        vessel = vessel or logs[0].vessel or default_vessel()
        # thrust without a known force scale: the model in command units (and the gain from a fixed value)
        if not getattr(self, "_command_units", False) and not all(thrust_scale_known(lg, vessel) for lg in logs):
            return fit_in_command_units(self, logs, vessel)
        self.thrust_scale_ = ThrustScale()
        self.vessel_in_ = vessel
        runs, kin = [], []
        held = []
        fit_logs = []
        for log in logs:
            run = run_data(log, vessel)
            ks = kinematic_states(log, run, vessel)
            if self.holdout > 0:
                t_cut = run.t_thrust[0] + (1 - self.holdout) * run.duration_s
                held.append((run.window(t_cut, run.t_thrust[-1]), ks.window(t_cut, np.inf)))
                run, ks = run.window(-np.inf, t_cut), ks.window(-np.inf, t_cut)
                log = _log_before(log, run.t0_ns + int(t_cut * 1e9))
            fit_logs.append(log)
            runs.append(run)
            kin.append(ks)
        self.runs_ = runs
        self._kin = kin
        fixv = self.fix
        # -- equation error (always: the start of output error, and a comparison) --------
        parts = [_ee_inputs(r, k) for r, k in zip(runs, kin)]
        ee = fit_equation_error(np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts]),
                                np.concatenate([p[2] for p in parts]), np.concatenate([p[3] for p in parts]),
                                fix=fixv)
        self.equation_error_ = ee
        free = np.array([k not in fixv for k in PARAM_NAMES])
        if self.method == "equation-error":
            theta = ee.theta
            se = np.array([ee.stderr[k] for k in PARAM_NAMES])
            names = [k for k in PARAM_NAMES if k not in fixv]
            cov = np.diag([ee.stderr[k] ** 2 for k in names])
            self.current_: list[tuple[float, ...]] = [(0.0, 0.0)] * len(runs)
            self.current_stderr_: list[tuple[float, ...]] = [(float("nan"), float("nan"))] * len(runs)
            self.cond_ = float("nan")
            self.residual_rms_ = {"surge_n": ee.rms[0], "sway_n": ee.rms[1], "yaw_nm": ee.rms[2]}
            self.oe_ = None
        elif self.method == "filter-error":
            fe = fit_filter_error(fit_logs, vessel, self._start(ee, vessel), free_mask=free,
                                  current=self.current)
            self.oe_ = None
            self.fe_ = fe
            theta, names, cov = fe.theta, list(fe.free), fe.cov
            d = np.sqrt(np.maximum(np.diag(cov), 0))
            se = np.zeros(6)
            for i, k in enumerate(names):
                se[PARAM_NAMES.index(k)] = d[i]
            self.current_ = [_ekf_current(lg, vessel, theta, self.current) for lg in fit_logs]
            self.current_stderr_ = [(float("nan"), float("nan"))] * len(runs)   # not computed
            corr = cov / np.outer(np.maximum(d, 1e-300), np.maximum(d, 1e-300))
            self.cond_ = float(np.sqrt(np.linalg.cond(corr)))
            self.residual_rms_ = {}
        else:
            theta0 = self._start(ee, vessel)
            oe = fit_output_error(runs, theta0, lambda i, t: kin[i].at(t), free_mask=free,
                                  fit_current=self.current, segment_s=self.segment_s,
                                  warm_segment_s=self.warm_segment_s, warm_span_s=900.0)
            self.oe_ = oe
            theta = oe.theta
            names = list(oe.names)
            cov = oe.cov
            se = np.zeros(6)
            d = np.sqrt(np.maximum(np.diag(cov), 0))
            for i, k in enumerate(names):
                if k in PARAM_NAMES:
                    se[PARAM_NAMES.index(k)] = d[i]
            self.current_ = [tuple(float(x) for x in c) for c in oe.currents]
            self.current_stderr_ = [tuple(float(d[names.index(f"current_{ax}_{i}")]) for ax in ("n", "e"))
                                    if self.current else (0.0, 0.0) for i in range(len(runs))]
            self.cond_ = oe.cond
            self.residual_rms_ = dict(oe.rms)
        try:
            self.params_ = VesselParams(**{k: float(v) for k, v in zip(PARAM_NAMES, theta)})
        except ConfigError as err:
            hint = "; ".join(_excitation_warnings(kin)) or "the runs do not excite the model enough"
            raise InputError(f"identification gave physically impossible parameters ({err}): {hint}") from err
        self.theta_ = np.asarray(theta, float)
        self.stderr_ = {k: float(s) for k, s in zip(PARAM_NAMES, se)}
        self.ci95_ = {k: (float(v - Z95 * s), float(v + Z95 * s)) for k, v, s in zip(PARAM_NAMES, theta, se)}
        sd = np.sqrt(np.maximum(np.diag(cov), 1e-300))
        self.corr_ = pd.DataFrame(cov / np.outer(sd, sd), index=names, columns=names)
        self.cov_ = cov
        self.verdict_ = self._verdict(vessel, runs, kin)
        self.validation_ = None
        if held:
            vals = [self._validate_run(r, k) for r, k in held]
            self.validation_ = vals[0]
        return self

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
    def _verdict(self, vessel, runs, kin) -> list[str]:
        p = self.params_
        rel = {k: self.stderr_[k] / abs(getattr(p, k)) if getattr(p, k) else np.inf for k in PARAM_NAMES}
        out = _excitation_warnings(kin, force=rel["Iz"] > 0.2 or rel["d33"] > 0.2)
        for k in PARAM_NAMES:
            if k in self.fix:
                continue
            if rel[k] > 0.1 and not (k == "xg" and abs(p.xg) < 0.05):
                out.append(f"{k} poorly determined: {getattr(p, k):.4g} +- {self.stderr_[k]:.2g} "
                           f"({100 * rel[k]:.0f}%)")
        names = list(self.corr_.index)
        C = self.corr_.to_numpy()
        for i in range(len(names)):
            for j in range(i + 1, len(names)):
                if abs(C[i, j]) >= 0.95:
                    out.append(f"{names[i]} and {names[j]} correlated at {C[i, j]:.2f}: "
                               f"excite the run differently or --fix one of them")
        if math.isfinite(self.cond_) and self.cond_ > 1e3:
            out.append(f"condition number {self.cond_:.3g}: parameters nearly unidentifiable together")
        iz_eff = p.Iz_eff
        if iz_eff <= 0:
            out.append(f"Theorem 3.1 condition 1 fails: Iz - m xg^2 = {iz_eff:.4g} <= 0")
        else:
            se = math.sqrt(self.stderr_["Iz"] ** 2 + (p.xg ** 2 * self.stderr_["m"]) ** 2
                           + (2 * p.m * p.xg * self.stderr_["xg"]) ** 2)
            if iz_eff < 2 * se:
                out.append(f"Theorem 3.1 condition 1 uncertain: Iz - m xg^2 = {iz_eff:.4g} +- {se:.2g}")
        if not vessel.thrusters.known and any(r.thrust_source != "logged newtons" for r in runs):
            out.append("thruster map is only a guess (thrusters.known = false): forces set the absolute "
                       "scale of m, Iz and the damping; --fix a known value (e.g. a weighed mass)")
        skipped = sum(r.thrust_skipped for r in runs)
        if skipped:
            out.append(f"{skipped} thrust record(s) not finite: skipped (the command before each held)")
        if self.method == "output-error" and self.oe_ is not None and self.oe_.outliers:
            o = self.oe_.outliers
            if o["gps"] or o["compass"]:
                out.append(f"{o['gps']} GNSS fix(es) and {o['compass']} compass reading(s) beyond "
                           f"5 sigma of the fitted model dropped as outliers")
        if self.method == "output-error":
            for s, v in self.residual_rms_.items():
                if v > 2.0:
                    out.append(f"{s} residuals {v:.1f} times their stated noise: model mismatch or "
                               f"sensor trouble")
        else:
            out.append("equation error is biased by measurement noise in its regressors (inertia "
                       "terms and d22 typically tens of percent off): use output-error for numbers "
                       "to rely on")
            if p.d22 == 0.0 and "d22" not in self.fix:
                out.append("d22 at its bound 0: not determined by equation error")
        if not self.current and self.method == "output-error":
            out.append("current not fitted: a real current biases d11 and d22")
        return out

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

    def _validate_run(self, run: RunData, ks: KinStates, init_window_s: float = 60.0) -> Validation:
        t0 = max(run.t_thrust[0], ks.t[0])
        t_init = t0 + min(init_window_s, 0.5 * (run.t_thrust[-1] - t0))
        x0, cur = fit_initial_state(run, self.theta_, ks.at(t0), t0, t_init, fit_current=self.current)
        t = ks.t[ks.t >= t0]
        sim = simulate_run(run, self.theta_, cur, x0, t0, t)
        meas = ks.at(t, cur)
        sim[:, 2] = meas[:, 2] + ssa(sim[:, 2] - meas[:, 2])
        after = t > t_init
        fp = {"u": fit_percent(meas[after, 3], sim[after, 3]), "v": fit_percent(meas[after, 4], sim[after, 4]),
              "r": fit_percent(meas[after, 5], sim[after, 5]),
              "track": fit_percent(meas[after, :2], sim[after, :2])}
        return Validation(fit_percent=fp, t=t, measured=meas, simulated=sim,
                          current=(float(cur[0]), float(cur[1])), init_window_s=float(t_init - t0))

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
        if self.oe_ is not None:
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
            Validation to report; default ``validation_`` (held-out part), else the fit %
            is computed on the fitted runs.

        Returns
        -------
        dict
            method, params (SI), stderr, ci95, fit_percent and what it was computed on,
            current_ne_mps, condition_number, correlation, verdict, fixed, the
            equation-error params and stderr, Iz_minus_m_xg2 (kg m^2) and, with a
            validation, its summary.

        Raises
        ------
        usvlog.errors.ConfigError
            If the identifier is not fitted.
        """
        self._check_fitted()
        val = validation if validation is not None else self.validation_
        d = {"method": self.method,
             "params": self.params_.to_dict(),
             "stderr": dict(self.stderr_),
             "ci95": {k: list(v) for k, v in self.ci95_.items()},
             "fit_percent": val.fit_percent if val is not None else self.fit_percent_(),
             "fit_percent_on": "validation" if val is not None else "fitted runs",
             "current_ne_mps": [list(c) for c in self.current_],
             "condition_number": self.cond_ if math.isfinite(self.cond_) else None,
             "correlation": {k: {j: float(x) for j, x in row.items()}
                             for k, row in self.corr_.to_dict("index").items()},
             "verdict": list(self.verdict_),
             "fixed": dict(self.fix),
             "equation_error": {"params": self.equation_error_.to_dict(),
                                "stderr": dict(self.equation_error_.stderr)},
             "Iz_minus_m_xg2": self.params_.Iz_eff,
             "thrust_scale": self.thrust_scale_.to_dict()}
        if val is not None:
            d["validation"] = val.to_dict()
        return d
