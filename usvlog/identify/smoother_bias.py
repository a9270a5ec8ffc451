"""The smoother's bias on a fit to smoothed states, measured on the model's own motion.

Velocity output error fits the model to the velocities the kinematic smoother made from GNSS
positions and compass headings. The smoother rounds off changes faster than those sensors
resolve: with 1 Hz GNSS, the smoothed surge speed of a boat with a 3 s time constant rises over
several seconds, and a model fitted to it takes too large a mass. (A simulated 24 kg boat of the
paper's structure, Otter-like manoeuvres, 1 Hz GNSS: velocity output error m 66 kg with a standard
error of 1 kg, 23.7 kg from the true states; the like-with-like validation cannot see it, it
compares through the same smoother.)

The check is a parametric bootstrap of that bias. The validated model's free run over the
held-out part, as the sensors and the smoother would show it (the validation's ``seen``:
sampled at the log's own stamps and smoothed with the data's settings), is fitted again by the
same fit, from the model's own values. A fit that gets its own values back is not biased
there; where it does not, the relative change of each parameter is the bias the smoother
puts on that fit (the model's motion standing in for the boat's). On the 24 kg boat above
(seed 8 of ``benchmarks/bench_identify_honesty.py``): m comes back +76 %.

Output error fits the raw fixes and headings, which carry no smoother, but starts its segments
from smoothed states and weighs smoothed velocities with them: it is checked the same way, on the
fixes and headings the sensors would have measured of the free run (no noise: weighed by their
stated noise, as the data's are by their scatter, so that the fixes and the smoothed velocities
pull on the fit as they did). A 24 kg boat at 5 Hz GNSS: output error with velocities, m 31 kg
for 24, comes back +80 % (weighed by the noise-free fixes' own scatter, +8 %: they would outweigh
the velocities as the real fixes do not).

Pure: arrays and fitted results in, a dict out.
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from ..errors import UsvlogError
from ..model.frames import ssa
from ..model.vessel import PARAM_NAMES
from .data import RunData
from .seen import ground_velocity
from .smooth import KinStates
from .validation import with_arrays

if TYPE_CHECKING:
    from .candidates import Candidate
    from .identifier import Identifier

BIAS_UNUSABLE = 0.3
"""A smoother bias beyond this share of m, Iz, d11 or d33 makes a fit unusable (the same share as a
standard error: :data:`usvlog.identify.verdict.REL_SE_UNUSABLE`)."""
BIAS_SWITCH_WITHIN = 5.0
"""Validation score points within which a candidate the smoother does not bias is returned instead
of one it does (the scores of fits that differ by a few points are within the validation's own
noise; seed 32 of ``benchmarks/bench_identify_honesty.py``: velocity output error 37.1 with m +186 %
on the truth, its check +202 %, against output error with velocities 33.5, m +1.8 %)."""

CHECKED_KINDS = ("velocity-error", "output-error")
"""Candidate kinds the check applies to. Not equation error: its bias is mostly the measurement
noise in its regressors (errors in variables), which the noise-free free run does not have, so the
check would measure a bias the fit does not carry (the paper's vessel, 1 hour, 10 Hz GNSS:
equation error m +5.9 % on the truth, the check +38 %); it says so in its own caveat. Nor filter
error, which reads the logs themselves."""


def seen_states(v) -> KinStates | None:
    """A validation's smoothed free run (:attr:`~usvlog.identify.validation.Validation.seen`) as
    :class:`KinStates` (ground velocities: its u, v relative to the water plus its current);
    None when it was not made."""
    if v is None or v.seen is None:
        return None
    s = np.asarray(v.seen, float)
    vn, ve = ground_velocity(s[:, 2], s[:, 3], s[:, 4], v.current)
    return KinStates(t=np.asarray(v.t, float), n=s[:, 0], e=s[:, 1], psi=s[:, 2], vn=vn, ve=ve, r=s[:, 5],
                     source="the model's free run, smoothed as the data were")


def measured_free_run(run: RunData, v) -> RunData:
    """``run`` over the validation's span with its fixes and headings replaced by the validation's
    free run at their times (no noise: what the sensors would have measured of the model)."""
    t = np.asarray(v.t, float)
    sim = np.asarray(v.simulated, float)
    r = run.window(float(t[0]), float(t[-1]))
    return replace(r, n_gps=np.interp(r.t_gps, t, sim[:, 0]), e_gps=np.interp(r.t_gps, t, sim[:, 1]),
                   psi_compass=ssa(np.interp(r.t_compass, t, sim[:, 2])))


def smoother_bias(self: Identifier, cand: Candidate, held, vessel) -> dict[str, float]:
    """The relative change of each fitted parameter when ``cand``'s fit is made again, from its own
    values, on its own validated free runs as the sensors and the smoother show them (``held``: the
    (RunData, KinStates) its validations were made on: the held-out parts, or the fitted runs).

    ``{name: refitted / fitted - 1}`` for m, Iz, d11, d22, d33 (xg: its change in metres); empty
    where the check does not apply (equation error, filter error, the extended model, no smoothed
    free run, m held at the surge equation's) or the fit again failed."""
    st = cand.start
    if st.model != "paper" or st.kind not in CHECKED_KINDS or st.surge_mass or cand.failed:
        return {}
    parts = [(r, seen_states(v), v) for (r, _), v in zip(held, with_arrays(self, cand, held))]
    parts = [(measured_free_run(r, v), k, v) for r, k, v in parts if k is not None and len(k.t) > 20]
    if not parts:
        return {}
    runs, kin = [p[0] for p in parts], [p[1] for p in parts]
    theta = np.asarray(cand.theta, float)
    try:
        fitted, th, _ = self._fit_paper_kind(replace(st, theta=theta), runs, kin, None, vessel, noise_free=True)
        if getattr(fitted, "diverged", False):
            return {}
    except (UsvlogError, ValueError, ArithmeticError, IndexError, np.linalg.LinAlgError):
        return {}   # the fit again failed on the model's own motion: not checked (never an internal error)
    held_names = self._held_names()
    out = {}
    for i, k in enumerate(PARAM_NAMES):
        if k in held_names:
            continue
        if k == "xg":
            out[k] = float(th[i] - theta[i])
        elif theta[i] > 0 and np.isfinite(th[i]):
            out[k] = float(th[i] / theta[i] - 1.0)
    return out


def biased(bias: dict) -> list[str]:
    """The parameters of m, Iz, d11, d33 a :func:`smoother_bias` puts beyond BIAS_UNUSABLE (the share
    whose standard error would make the fit unusable)."""
    return [k for k in ("m", "Iz", "d11", "d33") if k in bias and not abs(bias[k]) <= BIAS_UNUSABLE]


def pick_unbiased(self: Identifier, chosen: Candidate, cands: list[Candidate], held, vessel
                  ) -> tuple[Candidate, dict, dict | None]:
    """(candidate, its smoother bias, the switch or None): ``chosen`` with its bias, unless the
    smoother biases it beyond BIAS_UNUSABLE and another candidate that validates within
    BIAS_SWITCH_WITHIN points of it is not biased so (the best-validating such one, checked in
    order of score): a fit the smoother misleads is not returned where one it does not validates
    about as well. ``switch``: ``from``, ``score``, ``bias`` (the share of the worst parameter) and
    ``param``, of the candidate passed over."""
    bias = smoother_bias(self, chosen, held, vessel)
    bad = biased(bias)
    if not bad:
        return chosen, bias, None
    others = sorted((c for c in cands if c is not chosen and not c.failed
                     and c.score >= chosen.score - BIAS_SWITCH_WITHIN), key=lambda c: -c.score)
    for alt in others:
        b = smoother_bias(self, alt, held, vessel)
        if b and not biased(b):   # checked and passed (an unchecked fit proves nothing)
            worst = max(bad, key=lambda k: abs(bias[k]))
            return alt, b, {"from": chosen.start.name, "score": chosen.score, "param": worst, "bias": bias[worst]}
    return chosen, bias, None


__all__ = ["BIAS_SWITCH_WITHIN", "BIAS_UNUSABLE", "CHECKED_KINDS", "biased", "measured_free_run", "pick_unbiased",
           "seen_states", "smoother_bias"]
