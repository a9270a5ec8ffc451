"""Free runs of the identified model: simulated through a run's thrust, per segment, or from a fitted start.

:func:`simulate_run` integrates the model from one state through a run's recorded thrust
(validation, the look-ahead test, the sign checks); :func:`predict_segments` gives the
fitted multiple-shooting model's states, each segment from its fitted initial state;
:func:`fit_initial_state` fits the initial state (and a current) of a run with the
parameters held fixed.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares

from ..errors import FitFailed
from .data import RunData
from .problem import Problem, _fmt, max_step
from .projection import _VP, _inner
from .shoot import no_rows, shoot


def _state_at(prob: Problem, x0s, theta, cur, run, t):
    """State of the fitted multiple-shooting model at time t of a run (simulated from its segment)."""
    segs = np.flatnonzero(prob.seg_run == run)
    t_start = prob.tg[prob.seg_i0[segs]]
    k = segs[max(int(np.searchsorted(t_start, t + 1e-9)) - 1, 0)]
    sub = _SingleSeg(prob, k, t)
    out_x = sub.run(theta, cur[run], x0s[k])
    return out_x[0]


class _SingleSeg:
    def __init__(self, prob, k, t):
        self.prob, self.k, self.t = prob, k, t

    def run(self, theta, cur, x0):
        p = self.prob
        i0, i1 = p.seg_i0[self.k], p.seg_i1[self.k]
        out_x = np.zeros((1, 6))
        shoot(p.tg, p.tau_u, p.tau_r, np.array([i0]), np.array([i1]), x0[None, :].astype(float),
              np.asarray(theta, float), np.asarray(cur, float)[None, :], np.array([float(self.t)]),
              np.array([0, 1], np.int64), max_step(theta), False, out_x, *no_rows())
        return out_x


def simulate_run(run: RunData, theta, current, x0, t0: float, times) -> np.ndarray:
    """Free run of the model from state ``x0`` at ``t0`` (s, on the run's thrust grid) through
    the run's thrust; states (len(times), 6) at ``times`` (sorted, >= t0).

    ``theta``: m, Iz, d11, d22, d33, xg (SI); ``current``: north, east in m/s; ``x0``:
    [n (m), e (m), psi (rad), u (m/s), v (m/s), r (rad/s)]. Rows for times outside the
    thrust record are NaN; so is every row when the parameters are not a model that can be
    integrated (not finite, m or Iz - m xg^2 not positive) or ``x0`` is not finite, and every
    row after the simulation left the finite range (NaN or inf: diverged)."""
    times = np.asarray(times, float)
    out_x = np.full((len(times), 6), np.nan)
    th = np.asarray(theta, float)
    if (len(run.t_thrust) == 0 or th.shape != (6,) or not np.all(np.isfinite(th)) or not th[0] > 0
            or not th[1] - th[0] * th[5] ** 2 > 0 or not np.all(np.isfinite(x0)) or not np.all(np.isfinite(current))):
        return out_x
    i0 = run.thrust_index_at(t0)
    ok = (times >= min(t0, run.t_thrust[i0]) - 1e-9) & (times <= run.t_thrust[-1] + 1e-9)
    tt = np.ascontiguousarray(times[ok])
    ox = np.zeros((len(tt), 6))
    # C-ordered arrays whatever the caller's (a row of a column-ordered array): numba compiles one signature
    shoot(run.t_thrust, run.tau_u, run.tau_r, np.array([i0]), np.array([len(run.t_thrust) - 1]),
          np.array(x0, float, ndmin=2), np.ascontiguousarray(theta, float), np.array(current, float, ndmin=2),
          tt, np.array([0, len(tt)], np.int64), max_step(theta), False, ox, *no_rows())
    out_x[ok] = ox
    return out_x


def predict_segments(runs: list[RunData], segment_s: float, x0s, theta, currents, run_index: int, times):
    """States of the fitted multiple-shooting model (each segment from its own fitted initial
    state) at ``times`` of one run."""
    prob = Problem(runs, segment_s)
    segs = np.flatnonzero(prob.seg_run == run_index)
    off = sum(len(r.t_thrust) for r in prob.runs[:run_index])
    run = prob.runs[run_index]      # the grid the segments were fitted on
    times = np.asarray(times, float)
    out = np.full((len(times), 6), np.nan)
    for k in segs:
        a, b = prob.seg_i0[k] - off, prob.seg_i1[k] - off
        last = k == segs[-1]
        sel = (times >= run.t_thrust[a]) & ((times < run.t_thrust[b]) | (last & (times <= run.t_thrust[b])))
        if sel.any():
            out[sel] = simulate_run(run, theta, currents[run_index], x0s[k], run.t_thrust[a], times[sel])
    return out


def fit_initial_state(run: RunData, theta, x0_guess, t0: float, t1: float, *, fit_current=True,
                      current0=(0.0, 0.0)):
    """Initial state at ``t0`` (and a constant current) of a run with the parameters held
    fixed, fitted to the measurements in [t0, t1]. Returns (x0, current).

    Times in s from the run's start; ``x0`` (6,) as [n (m), e (m), psi (rad), u (m/s),
    v (m/s), r (rad/s)], ``current`` (2,) north, east in m/s (``current0`` when
    ``fit_current`` is False).

    Raises :class:`~usvlog.errors.FitFailed` when the window has less than two thrust samples
    or the parameters cannot be simulated (not finite, m or Iz - m xg^2 not positive). With
    fewer than two measurements in the window the current is held at ``current0``."""
    w = run.window(t0, t1)
    free = np.zeros(6, bool)
    theta = np.asarray(theta, float)
    if len(w.t_thrust) < 2 or not w.t_thrust[-1] > w.t_thrust[0]:
        raise FitFailed(f"{run.source or 'run'}: less than two thrust samples in {t0:.1f}..{t1:.1f} s: "
                        "no initial state to fit")
    if theta.shape != (6,) or not np.all(np.isfinite(theta)) or not theta[0] > 0 \
            or not theta[1] - theta[0] * theta[5] ** 2 > 0:
        raise FitFailed(f"the parameters {_fmt(theta)} are not a model that can be simulated "
                        "(six finite numbers with m > 0 and Iz - m xg^2 > 0)")
    prob = Problem([w], 1e12)
    cur = np.asarray(current0, float)[None, :]
    # a state the smoother could not give (NaN) starts at rest at the origin: the fit moves it
    x0s = np.nan_to_num(np.asarray(x0_guess, float), nan=0.0, posinf=0.0, neginf=0.0)[None, :]
    if not fit_current or prob.n_res < 2:   # (too few measurements to tell a current)
        with np.errstate(over="ignore", invalid="ignore"):
            _, _, x0s, _ = _inner(prob, theta, cur, x0s)
        return x0s[0], cur[0]
    vp = _VP(prob, theta, free, True, x0s, cur)
    sol = least_squares(vp.fun, cur.ravel(), jac=vp.jac, method="lm", xtol=1e-8, ftol=1e-8, max_nfev=50)
    vp._eval(sol.x)
    return vp.x0s[0], sol.x.reshape(2)
