"""Validation by leaving each log out, for identification from several logs without a held-out part.

Each log in turn is left out: the chosen candidate (:mod:`usvlog.identify.candidates`) is fitted
again on the others, as it was fitted on all of them, and its free run judged on the log left out;
equation error of the same model alike, the floor the answer must not validate worse than. A
function of :class:`~usvlog.identify.identifier.Identifier`, kept here with its job.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..model.vessel import PARAM_NAMES
from .candidates import (
    EXT_SEGMENT_S,
    Candidate,
    _ext_oe_form,
    _ext_surge_mass,
    _ext_velocity_form,
    physical_problem,
)
from .output import fit_output_error, velocity_samples
from .velocity import fit_velocity_error

if TYPE_CHECKING:
    from .identifier import Identifier


def _leave_one_out(self: Identifier, chosen: Candidate, cands, runs, kin, logs, vessel) -> tuple[list, list]:
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
            if st.kind == "velocity-error":
                th0 = chosen.theta
                if st.surge_mass:
                    th0, _ = _ext_surge_mass(self, r_, k_, th0)
                free, ties = _ext_velocity_form(st)
                theta = fit_velocity_error(r_, k_, th0, free_mask=free, ties=ties, fit_current=self.current,
                                           max_current_mps=self.max_current_mps, model="extended").theta
            else:
                fix, ties = _ext_oe_form(st, chosen.theta)
                theta = fit_extended_output_error(r_, k_, chosen.theta, fit_current=self.current,
                                                  max_current_mps=self.max_current_mps,
                                                  segment_s=EXT_SEGMENT_S, fix=fix, ties=ties).theta
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
