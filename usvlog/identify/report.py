"""The identifier's reports: the fitted model against the data, the JSON dict, the TOML record.

:func:`fit_frame` gives the measured and fitted-model states of a fitted run (the
``/identify/fit`` channel and the fit % of :func:`fit_percent_`), :func:`to_dict` what
``usvlog identify --json`` prints, and :func:`toml_record` the ``[identification]`` table
written after the vessel TOML. They only read what
:meth:`~usvlog.identify.identifier.Identifier.fit` set; the functions taking ``self`` are
methods of :class:`~usvlog.identify.identifier.Identifier`, kept here with the job they do.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from ..model.frames import ssa
from ..model.stats import fit_percent
from .ahead import WHITENESS_STEP_S
from .output import (
    predict_segments,
    simulate_run,
)
from .validation import Validation, _finite_dict

# typing only: the class whose methods these are (it imports this module)
if TYPE_CHECKING:
    from .identifier import Identifier


def fit_frame(self: Identifier, run_index: int = 0) -> tuple[np.ndarray, dict]:
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


def fit_percent_(self: Identifier) -> dict:
    """Fit % of the fitted model on its own runs (u, v, r, track)."""
    t, c = self.fit_frame(0)
    return {"u": fit_percent(c["u_mps"], c["u_sim_mps"]), "v": fit_percent(c["v_mps"], c["v_sim_mps"]),
            "r": fit_percent(c["r_radps"], c["r_sim_radps"]),
            "track": fit_percent(np.stack([c["n_m"], c["e_m"]], 1), np.stack([c["n_sim_m"], c["e_sim_m"]], 1))}


def to_dict(self: Identifier, validation: Validation | None = None) -> dict:
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
         "structure": self.structure_,
         "fit_percent_ahead": {h: _finite_dict(v) for h, v in getattr(self, "fit_percent_ahead_", {}).items()},
         "excitation": {ch: e.to_dict() for ch, e in (getattr(self, "excitation_", {}) or {}).items()},
         "thruster_lag_s": getattr(self, "lag_applied_s_", 0.0),
         "thruster_lag": lag.to_dict() if (lag := getattr(self, "thruster_lag_", None)) is not None else None,
         "sign_checks": list(getattr(self, "sign_checks_", [])),
         "smoother_bias": dict(getattr(self, "smoother_bias_", {}) or {}),
         "smoother_bias_switch": getattr(self, "bias_switch_", None),
         "whiteness": {ch: {"step_s": WHITENESS_STEP_S, "lags": len(w.lags), "outside": w.outside,
                            "allowed": w.allowed, "white": w.white, "p_value": w.p_value}
                       for ch, w in (getattr(self, "whiteness_", {}) or {}).items()}}
    if self.extended_ is not None:
        d["extended"] = {"params": self.extended_.to_dict(), "stderr": dict(self.extended_stderr_)}
    if self.model_comparison_ is not None:
        d["model_comparison"] = self.model_comparison_
    if val is not None:
        d["validation"] = val.to_dict()
    return d


def toml_record(self: Identifier) -> str:
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
             f"structure = {q(self.structure_)}",
             f"chosen = {q(self.chosen_.start.name)}", f"validation = {q(self.validation_mode_)}",
             f"thrust_scale = {q(self.thrust_scale_.case)}"]
    lag = getattr(self, "lag_applied_s_", 0.0)
    if lag or getattr(self, "thruster_lag_", None) is not None:
        lines.append(f"thruster_lag_s = {lag:.4g}"
                     + ("   # identified" if getattr(self, "thruster_lag_", None) is not None else "   # given"))
    lines += [f"fit_{k}_pct = {fp[k]:.2f}" for k in ("u", "v", "r", "track") if math.isfinite(fp[k])]
    for h, v in getattr(self, "fit_percent_ahead_", {}).items():   # k-step-ahead fit % per horizon (s)
        lines += [f"fit_ahead_{h}s_{k}_pct = {v[k]:.2f}" for k in ("u", "v", "r") if math.isfinite(v[k])]
    lines.append("reasons = [" + ", ".join(q(r) for r in self.reasons_) + "]")
    return "\n".join(lines) + "\n"
