"""How an identified model is judged on data: :class:`Validation`, a free run and its fit %.

A candidate's parameters are run through a run's recorded thrust from an initial state (and
current) fitted on its first seconds (:func:`validate`, :func:`_validate_run`; the extended
model: :func:`_validate_ext`), and the run is compared with the smoothed measurements
(:func:`_validation`: fit % of u, v, r and the track). :mod:`usvlog.identify.candidates`
ranks the candidates by these figures and :mod:`usvlog.identify.verdict` judges the returned
one by them. The functions taking ``self`` are methods of
:class:`~usvlog.identify.identifier.Identifier`, kept here with the job they do.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import cached_property
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from ..choices import EXTENDED_PARAM_NAMES
from ..log.fieldlog import FieldLog
from ..model.frames import ssa
from ..model.stats import fit_percent
from .ahead import displacement_fit_ahead, excitation, smoother_noise
from .data import RunData, lag_thrust, run_data
from .output import (
    fit_initial_state,
    simulate_run,
)
from .smooth import KinStates, kinematic_states

TRACK_AHEAD_S = 30.0   # horizon (s) of the displacement fit reported with a validation
# what the candidates are compared by (:attr:`Validation.score`), in words for the reports
SCORE_WORDS = "mean fit % of the track (0 when below 0), r and, where the part excites it, u"

# typing only: the class whose methods these are (it imports this module)
if TYPE_CHECKING:
    from .candidates import Candidate
    from .identifier import Identifier


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
    seen : numpy.ndarray, shape (N, 6), or None
        The free run as the data's smoother shows it (:mod:`usvlog.identify.seen`): its
        positions and heading sampled at the log's sensor stamps and smoothed with the
        measurements' own settings. The fit % of u, v and r compares ``measured`` with
        this, so that the smoother's lag is not charged to the model; None when it could
        not be made (then they compare ``measured`` with ``simulated``).
    track_ahead : float
        Fit % of the displacement the model predicts :data:`TRACK_AHEAD_S` ahead, re-initialised
        from the smoothed state (:func:`~usvlog.identify.ahead.displacement_fit_ahead`), after
        the initial window; NaN when not made.
    sd : numpy.ndarray, shape (N, 3), or None
        The smoother's one-sigma of the measured u, v, r at ``t`` (None: the smoother reports
        none); with ``measured`` it says which channels the scored part excites
        (:func:`excitation_of`).
    figures : (float, bool) or None
        A :meth:`summary`'s :attr:`score` and :attr:`diverged`, kept when its arrays
        (``measured``, ``simulated``, ``seen``, ``sd``: None then) were let go; None otherwise.
    """

    fit_percent: dict            # "u", "v", "r", "track": 100 (1 - |y - yhat| / |y - mean y|)
    t: np.ndarray                # s from the run's start (smoothed-state grid)
    measured: np.ndarray | None  # (N, 6) n, e, psi, u, v, r from the smoothed measurements
    simulated: np.ndarray | None  # (N, 6) the model's free run (None: a summary)
    current: tuple[float, float]  # current used (fitted with the initial state)
    init_window_s: float         # initial state (and current) fitted on [0, init_window_s]
    seen: np.ndarray | None = None  # (N, 6) the free run smoothed as the measurements were (None: not made)
    track_ahead: float = float("nan")  # fit % of the displacement predicted TRACK_AHEAD_S ahead
    sd: np.ndarray | None = None  # (N, 3) the smoother's one-sigma of the measured u, v, r (None: not reported)
    figures: tuple[float, bool] | None = None   # (score, diverged) of a summary (arrays let go), else None

    def summary(self) -> Validation:
        """This validation without its arrays: its fit %, score, divergence, current and span kept
        (:attr:`t` its first and last times only; :attr:`has_arrays` False). What a candidate holds
        (memory: ~8 MB a validation of a 3-hour log's held-out part); the arrays are made again, to
        the same numbers, where they are needed (:func:`with_arrays`)."""
        return replace(self, t=self.t[[0, -1]] if len(self.t) else self.t, measured=None, simulated=None,
                       seen=None, sd=None, figures=(self.score, self.diverged))

    @property
    def has_arrays(self) -> bool:
        """False for a :meth:`summary`."""
        return self.figures is None

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """(measured, simulated); a :meth:`summary` has none (ValueError: a caller's mistake)."""
        if self.measured is None or self.simulated is None:
            raise ValueError("a validation's summary has no arrays (usvlog.identify.validation.with_arrays)")
        return self.measured, self.simulated

    def to_dataframe(self) -> pd.DataFrame:
        """Measured and simulated states side by side, indexed by ``t_s`` (s).

        Columns n_m, n_sim_m, e_m, e_sim_m, psi_rad, psi_sim_rad, u_mps, u_sim_mps, v_mps,
        v_sim_mps, r_radps, r_sim_radps (and ``<name>_seen_<unit>``, the smoothed free run, when
        :attr:`seen` was made).
        """
        cols = {}
        measured, simulated = self.arrays()
        for i, (name, unit) in enumerate((("n", "m"), ("e", "m"), ("psi", "rad"), ("u", "mps"),
                                          ("v", "mps"), ("r", "radps"))):
            cols[f"{name}_{unit}"] = measured[:, i]
            cols[f"{name}_sim_{unit}"] = simulated[:, i]
            if self.seen is not None:
                cols[f"{name}_seen_{unit}"] = self.seen[:, i]
        return pd.DataFrame(cols, index=pd.Index(self.t, name="t_s"))

    @property
    def diverged(self) -> bool:
        """True when the free run left the finite range (a failed model, not a fit %)."""
        if self.figures is not None:
            return self.figures[1]
        sim = self.arrays()[1]
        return bool(not np.all(np.isfinite(sim)) or np.any(np.abs(sim[:, 3:]) > 1e3))

    @cached_property
    def score(self) -> float:
        """The figure candidates are compared by: the mean fit % of the track (floored at 0), of
        r and, where the scored part excites it (:func:`excitation_of`), of u (-inf when
        diverged).

        The track (smoothed GPS positions, whose errors are small beside the track's extent)
        judges u and v together: a free run's position error integrates their errors. Below 0
        it has no skill left -- the free run's heading has drifted and the positions are
        wherever that drift put them -- and how far below says nothing more about the model
        (on a Fossen Otter run in a current, a model whose u validates at 83 % scored -117 on
        the track against -41 for one at 55 %), so it counts as 0 there. u and r are compared
        through the smoother (:attr:`seen`), u only when the part moves it beyond the smoother's
        noise. (Ranking by the displacement predicted 30 s ahead, :attr:`track_ahead`, or by u
        instead of the track was tried: it picks the better model on a Fossen Otter run, but
        a worse d11 than this on short runs of the paper's vessel.)"""
        if self.figures is not None:
            return self.figures[0]
        if self.diverged:
            return -math.inf
        fp = self.fit_percent
        parts = [max(fp["track"], 0.0), fp["r"]]
        if excitation_of([self])["u"].excited:
            parts.append(fp["u"])
        s = float(np.mean(parts))
        return s if math.isfinite(s) else -math.inf

    def to_dict(self) -> dict:
        """JSON-ready summary: fit_percent, current_ne_mps, track_ahead_30s_pct, init_window_s,
        duration_s, diverged."""
        return {"fit_percent": _finite_dict(self.fit_percent), "current_ne_mps": list(self.current),
                "track_ahead_30s_pct": _finite_dict({"x": self.track_ahead})["x"],
                "init_window_s": self.init_window_s, "duration_s": float(self.t[-1] - self.t[0]),
                "diverged": self.diverged}


def _mean_score(vals: list) -> float:
    """Mean :attr:`Validation.score` of a list (a None, a fit that was not a boat, counts -inf)."""
    return float(np.mean([v.score if v is not None else -math.inf for v in vals])) if vals else -math.inf


def _finite_dict(d: dict) -> dict:
    """Values as floats, None where not finite (JSON has no NaN)."""
    return {k: (float(v) if v is not None and math.isfinite(v) else None) for k, v in d.items()}


def _validation(t, meas, sim, cur, t0: float, t_init: float, ks: KinStates | None = None,
                track_ahead: float = float("nan")) -> Validation:
    """A free run against the measured states: heading unwrapped onto the measurement, fit %
    of u, v, r (the free run smoothed as the measurements were, when ``ks`` can) and of the
    track after the initial-state window."""
    sim[:, 2] = meas[:, 2] + ssa(sim[:, 2] - meas[:, 2])
    seen = ks.seen(t, sim, cur) if ks is not None else None
    vel = sim if seen is None else seen
    after = t > t_init
    fp = {"u": fit_percent(meas[after, 3], vel[after, 3]), "v": fit_percent(meas[after, 4], vel[after, 4]),
          "r": fit_percent(meas[after, 5], vel[after, 5]),
          "track": fit_percent(meas[after, :2], sim[after, :2])}
    sd = None if ks is None or ks.sd is None else np.stack([np.interp(t, ks.t, c) for c in ks.sd.T], -1)
    return Validation(fit_percent=fp, t=t, measured=meas, simulated=sim,
                      current=(float(cur[0]), float(cur[1])), init_window_s=float(t_init - t0), seen=seen,
                      track_ahead=track_ahead, sd=sd)


def with_arrays(self: Identifier, cand: Candidate, pairs) -> list[Validation]:
    """``cand``'s validations with their arrays (measured, simulated, smoothed free run): made again
    where it holds summaries, to the same numbers (a free run is a deterministic function of the
    parameters, currents and data), and kept in the candidate from then on.

    ``pairs``: the (RunData, KinStates) its validations were made on (the held-out parts, or the
    fitted runs). Memory: a candidate keeps summaries only (the arrays of a 3-hour log's held-out part
    are ~8 MB a validation, and there are six candidates or more); the arrays are wanted for the
    candidate returned and the ones the smoother-bias check looks at."""
    if all(v.has_arrays for v in cand.validations):
        return cand.validations
    cand.validations[:] = [self._validate_run(r, k, cand.theta, cand.currents[i]) for i, (r, k) in enumerate(pairs)]
    return cand.validations


def excitation_of(validations: list[Validation]) -> dict:
    """Which of u, v, r the scored parts of these validations excite beyond the smoother's
    noise (:func:`~usvlog.identify.ahead.excitation` over their samples together, the noise
    from the smoother's own one-sigma there): ``{channel: Excitation}``, empty without any."""
    if not validations:
        return {}
    scored = [v.t > v.t[0] + v.init_window_s for v in validations]
    nu = np.concatenate([v.arrays()[0][k, 3:6] for v, k in zip(validations, scored)])
    sd = (None if any(v.sd is None for v in validations)
          else np.concatenate([np.asarray(v.sd)[k] for v, k in zip(validations, scored)]))
    return excitation(nu, smoother_noise(sd))


def validation_fit_percent_(self: Identifier) -> dict:
    """Mean validation fit % of u, v, r and track over ``validations_`` (NaN without)."""
    if not self.validations_:
        return {k: float("nan") for k in ("u", "v", "r", "track")}
    return {k: float(np.mean([v.fit_percent[k] for v in self.validations_])) for k in ("u", "v", "r", "track")}


def use_validation(self: Identifier, validations: list[Validation]) -> None:
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
    self.excitation_ = excitation_of(self.validations_)
    self.reasons_, self.verdict_ = self._verdict(self.vessel_in_, self.runs_, self._kin)
    self.usable_ = self.verdict_ != "unusable"


def validate(self: Identifier, log: FieldLog, *, init_window_s: float = 60.0) -> Validation:
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
    run = lag_thrust(run_data(log, self.vessel_in_), getattr(self, "lag_applied_s_", 0.0))
    return self._validate_run(run, kinematic_states(log, run, self.vessel_in_, tune=self._tune_smoother),
                              init_window_s=init_window_s)


def _validate_run(self: Identifier, run: RunData, ks: KinStates, theta=None, current=None,
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
    ta = displacement_fit_ahead(run, ks, theta, cur, TRACK_AHEAD_S, t_from=t_init)
    return _validation(t, meas, sim, cur, t0, t_init, ks, ta)


def _validate_ext(self: Identifier, run: RunData, ks: KinStates, theta, current, t0: float,
                  t_init: float) -> Validation:
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
    ta = displacement_fit_ahead(run, ks, theta, cur, TRACK_AHEAD_S, t_from=t_init, simulate=free_run_full)
    return _validation(t, meas, sim, cur, t0, t_init, ks, ta)
