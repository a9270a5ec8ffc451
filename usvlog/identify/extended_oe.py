"""Output-error identification of the extended 3-DOF model (:class:`usvlog.model.vessel.ExtendedParams`).

The extended model's free run (eq. (1) kinematics plus a constant current, the extended
velocity dynamics of :func:`usvlog.model.vessel.nu_dot_ext_terms`, compiled) is fitted to
the GNSS positions and compass headings by bounded least squares
(:func:`scipy.optimize.least_squares`, finite-difference Jacobian). Multiple shooting: each
run is cut into segments whose initial states start from the smoothed kinematic states
(:class:`usvlog.identify.smooth.KinStates`, velocities relative to the water for the current
being fitted) and are fitted as nuisance parameters (their finite differences taken for all
segments at once: a segment's start moves only its own residuals), so neither a poor start nor
the smoother's velocity errors run away over a long record. Parameters: the ten
extended ones (inertia > 0, damping >= 0, m22 m66 - m26^2 > 0) and a constant current per run
(each component bounded).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from .._jit import njit
from ..choices import EXTENDED_PARAM_NAMES
from ..errors import FitFailed
from ..model.frames import ssa, wrap_angle
from ..model.vessel import ExtendedParams, nu_dot_ext_terms
from .data import RunData, coarse_thrust
from .extended import MAX_DT, NE
from .smooth import KinStates

_IX = {k: i for i, k in enumerate(EXTENDED_PARAM_NAMES)}
_INERTIA = ("m11", "m22", "m66")
BAD_RESIDUAL = 1e3     # residual of a sample whose simulation diverged (whitened units)
X0_SCALE = np.array([1.0, 1.0, 0.05, 0.1, 0.05, 0.02])   # typical segment initial-state offsets
FD_STEP = 1e-6         # finite-difference step, relative to a parameter's scale


def ext_physical_problem(theta) -> str:
    """Why an extended parameter vector is not a boat (empty when it is).

    Parameters
    ----------
    theta : array_like, shape (10,)
        EXTENDED_PARAM_NAMES order, SI units.

    Returns
    -------
    str
        Inertia not positive, damping negative, m22 m66 - m26^2 not positive, not finite; or "".
    """
    th = np.asarray(theta, float)
    if not np.all(np.isfinite(th)):
        return "parameters not finite"
    bad = [k for k in _INERTIA if th[_IX[k]] <= 0]
    if bad:
        return f"{', '.join(bad)} not positive"
    neg = [k for k in EXTENDED_PARAM_NAMES if k.startswith("d") and th[_IX[k]] < 0]
    if neg:
        return f"{', '.join(neg)} negative"
    m22, m26, m66 = (float(th[_IX[k]]) for k in ("m22", "m26", "m66"))   # Python floats: no overflow warning
    if m22 * m66 - m26 * m26 <= 0:
        return "m22 m66 - m26^2 not positive"
    return ""


@njit
def _full_deriv(n, e, psi, u, v, r, tu, tr, th, cn, ce):
    c, s = math.cos(psi), math.sin(psi)
    ud, vd, rd = nu_dot_ext_terms(u, v, r, tu, tr, th[0], th[1], th[2], th[3], th[4], th[5], th[6], th[7],
                                  th[8], th[9])
    return c * u - s * v + cn, s * u + c * v + ce, r, ud, vd, rd


@njit
def _full_rk4(x0, x1, x2, x3, x4, x5, tu, tr, th, cn, ce, h):
    """One RK4 step of (n, e, psi, u, v, r) (scalars: no allocation in the inner loop)."""
    a0, a1, a2, a3, a4, a5 = _full_deriv(x0, x1, x2, x3, x4, x5, tu, tr, th, cn, ce)
    q = 0.5 * h
    b0, b1, b2, b3, b4, b5 = _full_deriv(x0 + q * a0, x1 + q * a1, x2 + q * a2, x3 + q * a3, x4 + q * a4,
                                         x5 + q * a5, tu, tr, th, cn, ce)
    c0, c1, c2, c3, c4, c5 = _full_deriv(x0 + q * b0, x1 + q * b1, x2 + q * b2, x3 + q * b3, x4 + q * b4,
                                         x5 + q * b5, tu, tr, th, cn, ce)
    d0, d1, d2, d3, d4, d5 = _full_deriv(x0 + h * c0, x1 + h * c1, x2 + h * c2, x3 + h * c3, x4 + h * c4,
                                         x5 + h * c5, tu, tr, th, cn, ce)
    w = h / 6.0
    return (x0 + w * (a0 + 2 * b0 + 2 * c0 + d0), x1 + w * (a1 + 2 * b1 + 2 * c1 + d1),
            x2 + w * (a2 + 2 * b2 + 2 * c2 + d2), x3 + w * (a3 + 2 * b3 + 2 * c3 + d3),
            x4 + w * (a4 + 2 * b4 + 2 * c4 + d4), x5 + w * (a5 + 2 * b5 + 2 * c5 + d5))


@njit
def simulate_full(tg, tau_u, tau_r, seg_i0, seg_i1, x0s, theta, cn, ce, meas_t, meas_ptr, max_dt, out):
    """State (n, e, psi, u, v, r) of every segment k from ``x0s[k]`` at ``tg[seg_i0[k]]``
    under the extended model plus a constant current (``cn``, ``ce`` m/s), thrust held over
    each grid step (RK4 sub-stepped to <= ``max_dt`` s), written at the segment's sorted
    times ``meas_t[meas_ptr[k]:meas_ptr[k + 1]]`` into ``out`` (linear interpolation inside a
    step); NaN once the state is no longer finite or |u| + |v| > 1000 m/s (divergence)."""
    for k in range(len(seg_i0)):
        x0, x1, x2, x3, x4, x5 = x0s[k, 0], x0s[k, 1], x0s[k, 2], x0s[k, 3], x0s[k, 4], x0s[k, 5]
        j, jend = meas_ptr[k], meas_ptr[k + 1]
        while j < jend and meas_t[j] < tg[seg_i0[k]] - 1e-9:
            j += 1
        for i in range(seg_i0[k], seg_i1[k]):
            if j >= jend:
                break
            ta, tb = tg[i], tg[i + 1]
            dt = tb - ta
            y0, y1, y2, y3, y4, y5 = x0, x1, x2, x3, x4, x5
            nsub = max(1, int(math.ceil(dt / max_dt - 1e-9)))
            h = dt / nsub
            for _ in range(nsub):
                x0, x1, x2, x3, x4, x5 = _full_rk4(x0, x1, x2, x3, x4, x5, tau_u[i], tau_r[i], theta, cn, ce, h)
            fin = (math.isfinite(x0) and math.isfinite(x1) and math.isfinite(x2) and math.isfinite(x3)
                   and math.isfinite(x4) and math.isfinite(x5))
            if not fin or abs(x3) + abs(x4) > 1e3:
                x0 = x1 = x2 = x3 = x4 = x5 = np.nan
            while j < jend and meas_t[j] <= tb + 1e-9:
                w = min(max((meas_t[j] - ta) / dt, 0.0), 1.0)
                out[j, 0] = (1 - w) * y0 + w * x0
                out[j, 1] = (1 - w) * y1 + w * x1
                out[j, 2] = (1 - w) * y2 + w * x2
                out[j, 3] = (1 - w) * y3 + w * x3
                out[j, 4] = (1 - w) * y4 + w * x4
                out[j, 5] = (1 - w) * y5 + w * x5
                j += 1


@njit
def residual_rows(x, is_gps, y_n, y_e, y_psi, w_gps, w_psi, out):
    """Whitened residuals (simulated - measured) of states ``x`` (n, 6) at time-sorted
    measurements (``is_gps``: a GNSS fix, else a compass heading) into ``out``: the fixes'
    north rows, their east rows, then the headings (wrapped); BAD_RESIDUAL where not finite."""
    ng = len(y_n)
    ig, ic = 0, 0
    for j in range(len(is_gps)):
        if is_gps[j]:
            a = (x[j, 0] - y_n[ig]) * w_gps[ig]
            b = (x[j, 1] - y_e[ig]) * w_gps[ig]
            out[ig] = a if math.isfinite(a) else BAD_RESIDUAL
            out[ng + ig] = b if math.isfinite(b) else BAD_RESIDUAL
            ig += 1
        else:
            d = x[j, 2] - y_psi[ic]
            c = wrap_angle(d) * w_psi[ic] if math.isfinite(d) else BAD_RESIDUAL
            out[2 * ng + ic] = c if math.isfinite(c) else BAD_RESIDUAL
            ic += 1


def free_run_full(run: RunData, theta, current, x0, t0: float, times) -> np.ndarray:
    """Free run of the extended model (with kinematics and a current) through a run's thrust.

    Parameters
    ----------
    run : RunData
        Thrust grid and forces.
    theta : array_like, shape (10,)
        Extended parameters (EXTENDED_PARAM_NAMES order, SI).
    current : (float, float)
        Current north, east in m/s.
    x0 : array_like, shape (6,)
        Initial n (m), e (m), psi (rad), u, v (m/s, relative to the water), r (rad/s).
    t0 : float
        Start, s from the run's start (on or after its first thrust sample).
    times : array_like
        Sorted output times in s (>= t0).

    Returns
    -------
    numpy.ndarray, shape (len(times), 6)
        n, e, psi (unwrapped), u, v, r; NaN outside the thrust record or after a divergence,
        and everywhere when the parameters are not a boat (:func:`ext_physical_problem`) or
        ``x0`` or the current is not finite.
    """
    times = np.ascontiguousarray(times, float)
    out = np.full((len(times), 6), np.nan)
    if (len(run.t_thrust) == 0 or np.shape(theta) != (NE,) or ext_physical_problem(theta)
            or not np.all(np.isfinite(x0)) or not np.all(np.isfinite(current))):
        return out
    i0 = run.thrust_index_at(t0)   # the command in force at t0: the free run starts between two commands
    simulate_full(run.t_thrust, run.tau_u, run.tau_r, np.array([i0]), np.array([len(run.t_thrust) - 1]),
                  np.asarray(x0, float)[None, :], np.asarray(theta, float), float(current[0]), float(current[1]),
                  times, np.array([0, len(times)], np.int64), MAX_DT, out)
    return out


class _RunProblem:
    """One run cut into shooting segments, with its measurement times sorted per segment."""

    def __init__(self, run: RunData, ks: KinStates, segment_s: float):
        self.run, self.ks = run, ks
        self.tg, self.tau_u, self.tau_r = coarse_thrust(run.t_thrust, run.tau_u, run.tau_r, MAX_DT)
        tg = self.tg
        if len(tg) < 2 or len(ks.t) == 0:
            raise FitFailed(f"{run.source or 'run'}: no thrust or smoothed states to fit the extended model on")
        t_lo = max(tg[0], ks.t[0])
        t_hi = min(tg[-1], ks.t[-1])
        if not t_hi > t_lo:
            raise FitFailed(f"{run.source or 'run'}: the thrust and the smoothed states do not overlap in time")
        edges = np.arange(t_lo, t_hi, segment_s)
        if len(edges) > 1 and t_hi - edges[-1] < 0.5 * segment_s:
            edges = edges[:-1]          # no short last segment
        i_edges = np.unique(np.clip(np.searchsorted(tg, edges - 1e-9), 0, len(tg) - 1))
        self.seg_i0 = i_edges
        self.seg_i1 = np.append(i_edges[1:], np.searchsorted(tg, t_hi + 1e-9) - 1)
        g = (run.t_gps >= tg[self.seg_i0[0]]) & (run.t_gps <= tg[self.seg_i1[-1]])
        c = (run.t_compass >= tg[self.seg_i0[0]]) & (run.t_compass <= tg[self.seg_i1[-1]])
        t_all = np.concatenate([run.t_gps[g], run.t_compass[c]])
        kind = np.concatenate([np.zeros(g.sum(), int), np.ones(c.sum(), int)])
        order = np.argsort(t_all, kind="stable")
        self.t = np.ascontiguousarray(t_all[order])
        self.is_gps = kind[order] == 0
        y_n = np.concatenate([run.n_gps[g], np.zeros(c.sum())])[order]
        y_e = np.concatenate([run.e_gps[g], np.zeros(c.sum())])[order]
        y_psi = np.concatenate([np.zeros(g.sum()), run.psi_compass[c]])[order]
        sig = np.concatenate([run.sigma_gps[g], run.sigma_compass[c]])[order]
        self.y_n, self.y_e, self.y_psi = y_n[self.is_gps], y_e[self.is_gps], y_psi[~self.is_gps]
        self.w_gps, self.w_psi = 1.0 / sig[self.is_gps], 1.0 / sig[~self.is_gps]
        seg_t0 = tg[self.seg_i0]
        self.ptr = np.searchsorted(self.t, np.append(seg_t0, np.inf) - 1e-9).astype(np.int64)
        self.ptr[-1] = len(self.t)
        self.n_res = 2 * int(self.is_gps.sum()) + int((~self.is_gps).sum())
        self.n_seg = len(self.seg_i0)
        seg = np.searchsorted(self.ptr, np.arange(len(self.t)), side="right") - 1
        self.row_seg = np.concatenate([seg[self.is_gps], seg[self.is_gps], seg[~self.is_gps]])
        self._out = np.empty((len(self.t), 6))
        self._x0_key: bytes | None = None
        self._x0 = np.empty((self.n_seg, 6))

    def start_states(self, cur) -> np.ndarray:
        """The segments' smoothed initial states for a current (cached: the finite differences
        of the parameters reuse them)."""
        key = np.asarray(cur, float).tobytes()
        if key != self._x0_key:
            self._x0_key, self._x0 = key, self.ks.at(self.tg[self.seg_i0], tuple(cur))
        return self._x0

    def simulate(self, theta, cur, dx=None) -> np.ndarray:
        x0s = self.start_states(cur)
        if dx is not None:
            x0s = x0s + dx
        x0s = np.ascontiguousarray(x0s)
        out = self._out
        out.fill(np.nan)
        simulate_full(self.tg, self.tau_u, self.tau_r, self.seg_i0, self.seg_i1, x0s,
                      np.asarray(theta, float), float(cur[0]), float(cur[1]), self.t, self.ptr, MAX_DT, out)
        return out

    def residuals(self, theta, cur, dx=None) -> np.ndarray:
        x = self.simulate(theta, cur, dx)
        r = np.empty(self.n_res)
        residual_rows(x, self.is_gps, self.y_n, self.y_e, self.y_psi, self.w_gps, self.w_psi, r)
        return r


@dataclass(frozen=True, kw_only=True)
class ExtendedOEResult:
    """An extended model fitted by output error.

    Attributes
    ----------
    theta : numpy.ndarray, shape (10,)
        EXTENDED_PARAM_NAMES order, SI units.
    currents : numpy.ndarray, shape (n_runs, 2)
        Current north, east per run, m/s (zeros when not fitted).
    stderr : dict of str to float
        One-sigma standard errors of the parameters (0 for fixed ones), residual-scaled.
    cov : numpy.ndarray
        Covariance of the free quantities named in ``names`` (parameters, then
        ``current_n_<i>``, ``current_e_<i>``).
    names : list of str
    cond : float
        Condition number of the column-scaled Jacobian.
    rms : dict of str to float
        RMS of the noise-weighted residuals per sensor (``gps``, ``compass``).
    nfev : int
        Residual evaluations (the finite differences included).
    diverged : bool
        True when a simulation of the fitted model left the finite range.
    """

    theta: np.ndarray
    currents: np.ndarray
    stderr: dict
    cov: np.ndarray
    names: list
    cond: float
    rms: dict
    nfev: int
    diverged: bool

    @property
    def params(self) -> ExtendedParams:
        """The fit as :class:`~usvlog.model.vessel.ExtendedParams` (ConfigError if not physical)."""
        return ExtendedParams(**{k: float(v) for k, v in zip(EXTENDED_PARAM_NAMES, self.theta)})


def _block_solve(A, b, n_glob: int):
    """Solve A x = b for A whose trailing part is block-diagonal in 6x6 blocks (the segments'
    initial states), by the Schur complement on the leading ``n_glob`` unknowns."""
    ns = (len(b) - n_glob) // 6
    Agg, Ags, bg = A[:n_glob, :n_glob], A[:n_glob, n_glob:], b[:n_glob]
    B = np.stack([A[n_glob + 6 * k:n_glob + 6 * k + 6, n_glob + 6 * k:n_glob + 6 * k + 6] for k in range(ns)])
    Binv = np.linalg.inv(B)                                  # (ns, 6, 6), batched
    Agk = Ags.reshape(n_glob, ns, 6).transpose(1, 0, 2)      # (ns, n_glob, 6)
    bs = b[n_glob:].reshape(ns, 6)
    AB = Agk @ Binv                                          # (ns, n_glob, 6)
    S = Agg - np.einsum("kij,klj->il", AB, Agk)
    xg = np.linalg.solve(S, bg - np.einsum("kij,kj->i", AB, bs))
    xs = np.einsum("kij,kj->ki", Binv, bs - np.einsum("kij,i->kj", Agk, xg))
    return np.concatenate([xg, xs.ravel()])


def _levenberg_marquardt(fun, jac, normal, x0, lo, hi, scale, *, n_glob, max_iter=40, ftol=1e-6, xtol=1e-6):
    """Bounded Levenberg-Marquardt on the normal equations (the Jacobian is tall and thin and
    block-sparse: ``normal(J, f)`` gives J^T J and J^T f without forming it whole, a
    decomposition of it would cost more than the simulations). Steps are in units of
    ``scale`` and clipped to the bounds. Returns (x, residuals, J^T J at x)."""
    x = np.asarray(x0, float).copy()
    f = fun(x)
    cost = float(f @ f)
    lam = 1e-3
    H0, g0 = normal(jac(x), f)
    for _ in range(max_iter):
        H = H0 * np.outer(scale, scale)
        g = g0 * scale
        d = np.full(len(x), max(float(np.max(np.diag(H))), 1e-12))   # Levenberg: isotropic in scaled units
        improved = False
        for _ in range(12):
            try:
                step = _block_solve(H + lam * np.diag(d), -g, n_glob)
            except np.linalg.LinAlgError:
                lam *= 10.0
                continue
            x_new = np.clip(x + scale * step, lo, hi)
            f_new = fun(x_new)
            c_new = float(f_new @ f_new)
            if c_new < cost:
                improved = True
                break
            lam *= 4.0
        if not improved:
            break
        dc = (cost - c_new) / max(cost, 1e-300)
        dxn = float(np.max(np.abs((x_new - x) / scale)))
        x, f, cost = x_new, f_new, c_new
        lam = max(lam / 3.0, 1e-9)
        H0, g0 = normal(jac(x), f)
        if dc < ftol and dxn < xtol * 1e3 or dxn < xtol:
            break
    return x, f, H0


def fit_extended_output_error(runs: list[RunData], kin: list[KinStates], theta0, *, fix: dict | None = None,
                              fit_current: bool = True, currents0=None, max_current_mps: float = 0.5,
                              segment_s: float = 120.0, max_iter: int = 60, ties: tuple = ()) -> ExtendedOEResult:
    """Fit the extended model (and a current per run) to GPS and compass by output error.

    Parameters
    ----------
    runs : list of RunData
        The runs (thrust in N, GPS, compass).
    kin : list of KinStates
        Their smoothed states: each segment starts from them.
    theta0 : array_like, shape (10,)
        Start, EXTENDED_PARAM_NAMES order, SI (fixed parameters keep these values).
    fix : dict of str to float, optional
        Known parameters by extended name, SI.
    fit_current : bool, default True
        Fit a constant current per run (else ``currents0`` held).
    currents0 : array_like, shape (n_runs, 2), optional
        Starting currents north, east in m/s (default zeros).
    max_current_mps : float, default 0.5
        Bound on each current component, m/s.
    segment_s : float, default 120.0
        Shooting segment length in s, > 0.
    max_iter : int, default 60
        Iteration limit (Jacobians) of the Levenberg-Marquardt solver.
    ties : sequence of (str, str), optional
        Parameters that equal another as it is fitted, by name (``(("m22", "m11"),)``); the
        first of each pair must be in ``fix`` (its value there is replaced), its standard error
        is the other's.

    Returns
    -------
    ExtendedOEResult

    Raises
    ------
    usvlog.errors.FitFailed
        The start is not finite, a run has no thrust, smoothed states or measurements to fit.
    """
    fix = dict(fix or {})
    th0 = np.asarray(theta0, float).copy()
    for k, v in fix.items():
        th0[_IX[k]] = v
    if any(a not in fix for a, _ in ties):
        raise ValueError("a tied parameter is not fitted: put it in fix")
    tie_ix = [(_IX[a], _IX[b]) for a, b in ties]
    for a, b in tie_ix:
        th0[a] = th0[b]
    if th0.shape != (NE,) or not np.all(np.isfinite(th0)):
        raise FitFailed(f"extended output error: the start values are not {NE} finite numbers")
    if not segment_s > 0:
        raise FitFailed(f"extended output error: segment length {segment_s} s is not positive")
    free = np.array([k not in fix for k in EXTENDED_PARAM_NAMES])
    n_free = int(free.sum())
    cur0 = np.zeros((len(runs), 2)) if currents0 is None else np.asarray(currents0, float).copy()
    cur0 = np.clip(cur0, -0.99 * max_current_mps, 0.99 * max_current_mps)
    probs = [_RunProblem(r, k, segment_s) for r, k in zip(runs, kin)]
    names_free = [k for k in EXTENDED_PARAM_NAMES if k not in fix]
    lo = np.array([1e-3 * max(abs(th0[_IX[k]]), 1.0) if k in _INERTIA else (-np.inf if k == "m26" else 0.0)
                   for k in names_free])
    hi = np.full(n_free, np.inf)
    scale = np.array([max(abs(th0[_IX[k]]), 1.0) for k in names_free])
    x0 = np.clip(th0[free], lo + 1e-9 * scale, hi)
    n_cur = 2 * len(runs) if fit_current else 0
    if n_cur:
        lo = np.append(lo, -max_current_mps * np.ones(n_cur))
        hi = np.append(hi, max_current_mps * np.ones(n_cur))
        x0 = np.append(x0, cur0.ravel())
        scale = np.append(scale, 0.1 * np.ones(n_cur))
    n_glob = len(x0)
    n_seg = sum(pr.n_seg for pr in probs)
    x0 = np.append(x0, np.zeros(6 * n_seg))
    lo = np.append(lo, -np.inf * np.ones(6 * n_seg))
    hi = np.append(hi, np.inf * np.ones(6 * n_seg))
    scale = np.append(scale, np.tile(X0_SCALE, n_seg))
    seg_off = np.cumsum([0] + [pr.n_seg for pr in probs])
    row_seg = np.concatenate([pr.row_seg + o for pr, o in zip(probs, seg_off)])
    n_rows = len(row_seg)
    if n_rows == 0:
        raise FitFailed("extended output error: no GNSS fix or compass heading inside the fitted time")
    nfev = 0

    def unpack(p):
        th = th0.copy()
        th[free] = p[:n_free]
        for a, b in tie_ix:
            th[a] = th[b]
        cur = p[n_free:n_glob].reshape(-1, 2) if n_cur else cur0
        dx = p[n_glob:].reshape(-1, 6)
        return th, cur, dx

    def fun(p):
        nonlocal nfev
        nfev += 1
        th, cur, dx = unpack(p)
        if ext_physical_problem(th):
            return np.full(n_rows, BAD_RESIDUAL)
        return np.concatenate([pr.residuals(th, c, dx[o:o + pr.n_seg]) for pr, c, o in zip(probs, cur, seg_off)])

    cache: dict = {}

    def fun_cached(p):
        key = p.tobytes()
        if key not in cache:
            cache.clear()
            cache[key] = fun(p)
        return cache[key]

    def jac(p):
        """Forward differences: one evaluation per global column, one per initial-state
        component for all segments together (each moves only its segment's rows)."""
        f0 = fun_cached(p)
        J = np.zeros((n_rows, n_glob), order="F")      # written column by column
        J6 = np.zeros((n_rows, 6), order="F")
        for j in range(n_glob):
            h = FD_STEP * max(abs(p[j]), scale[j])
            if p[j] + h > hi[j]:
                h = -h
            q = p.copy()
            q[j] += h
            J[:, j] = (fun(q) - f0) / h
        for c in range(6):
            h = FD_STEP * X0_SCALE[c]
            q = p.copy()
            q[n_glob + c::6] += h
            J6[:, c] = (fun(q) - f0) / h
        return J, J6

    by_seg = np.argsort(row_seg, kind="stable")        # rows grouped by segment
    seg_start = np.searchsorted(row_seg[by_seg], np.arange(n_seg + 1))

    def normal(JJ, f):
        """J^T J and J^T f from the global columns and the segments' initial-state columns."""
        Jg, J6 = JJ
        n = n_glob + 6 * n_seg
        H, g = np.zeros((n, n)), np.zeros(n)
        H[:n_glob, :n_glob] = Jg.T @ Jg
        g[:n_glob] = Jg.T @ f
        Jg_s, J6_s, f_s = Jg[by_seg], J6[by_seg], f[by_seg]
        for k in range(n_seg):
            i, j = seg_start[k], seg_start[k + 1]
            a = n_glob + 6 * k
            Jk = J6_s[i:j]
            H[a:a + 6, a:a + 6] = Jk.T @ Jk
            cross = Jg_s[i:j].T @ Jk
            H[:n_glob, a:a + 6], H[a:a + 6, :n_glob] = cross, cross.T
            g[a:a + 6] = Jk.T @ f_s[i:j]
        return H, g

    p_opt, r, H = _levenberg_marquardt(fun_cached, jac, normal, x0, lo, hi, scale, n_glob=n_glob,
                                       max_iter=max_iter)
    th, cur, dx = unpack(p_opt)
    n_res, n_par = len(r), len(p_opt)
    sigma2 = float(r @ r) / max(n_res - n_par, 1)
    if np.all(np.isfinite(H)) and math.isfinite(sigma2):
        colnorm = np.sqrt(np.maximum(np.diag(H), 1e-300))
        JtJ = H / np.outer(colnorm, colnorm)
        ev = np.linalg.eigvalsh(JtJ)
        cond = float(math.sqrt(ev[-1] / ev[0])) if ev[0] > 0 else math.inf
        cov = (sigma2 * np.linalg.pinv(JtJ) / np.outer(colnorm, colnorm))[:n_glob, :n_glob]
    else:   # the Jacobian left the finite range: no curvature to read
        cond, cov = math.inf, np.full((n_glob, n_glob), np.nan)
    se = np.zeros(NE)
    se[free] = np.sqrt(np.maximum(np.diag(cov)[:n_free], 0.0))
    for a, b in tie_ix:
        se[a] = se[b]
    names = names_free + [f"current_{ax}_{i}" for i in range(len(runs)) for ax in ("n", "e")][:n_cur]
    rg, rc = [], []
    for pr, c, o in zip(probs, cur, seg_off):
        res = pr.residuals(th, c, dx[o:o + pr.n_seg])
        ng = int(pr.is_gps.sum())
        rg.append(res[:2 * ng])
        rc.append(res[2 * ng:])
    rg_a, rc_a = np.concatenate(rg), np.concatenate(rc)
    diverged = bool(np.any(np.abs(np.concatenate([rg_a, rc_a])) >= BAD_RESIDUAL))
    rms = {"gps": float(np.sqrt(np.mean(rg_a ** 2))) if len(rg_a) else float("nan"),
           "compass": float(np.sqrt(np.mean(rc_a ** 2))) if len(rc_a) else float("nan")}
    return ExtendedOEResult(theta=th, currents=np.asarray(cur, float), cov=cov, names=names, cond=cond, rms=rms,
                            stderr={k: float(s) for k, s in zip(EXTENDED_PARAM_NAMES, se)}, nfev=nfev,
                            diverged=diverged)


def fit_initial_state_ext(run: RunData, theta, x0_guess, t0: float, t1: float, current) -> np.ndarray:
    """Initial state (n, e, psi, u, v, r) at ``t0`` of the extended model with its parameters
    and the current held, fitted to the GPS and compass in [t0, t1] (s from the run's start).

    Parameters
    ----------
    run : RunData
    theta : array_like, shape (10,)
        Extended parameters, SI.
    x0_guess : array_like, shape (6,)
        Start: n, e (m), psi (rad), u, v (m/s relative to the water), r (rad/s).
    t0, t1 : float
        The window, s.
    current : (float, float)
        Current north, east, m/s.

    Returns
    -------
    numpy.ndarray, shape (6,)
        ``x0_guess`` itself (non-finite entries as 0) with fewer than three GNSS fixes or
        compass headings in the window.

    Raises
    ------
    usvlog.errors.FitFailed
        If the parameters are not a boat (:func:`ext_physical_problem`) or the current is not finite.
    """
    why = ext_physical_problem(theta) if np.shape(theta) == (NE,) else f"not {NE} parameters"
    if why or not np.all(np.isfinite(current)):
        raise FitFailed(f"extended model: no initial state to fit: {why or 'the current is not finite'}")
    x0_guess = np.nan_to_num(np.asarray(x0_guess, float), nan=0.0, posinf=0.0, neginf=0.0)
    w = run.window(t0, t1)
    g = w.t_gps >= t0
    c = w.t_compass >= t0
    tg, tc = w.t_gps[g], w.t_compass[c]
    if len(tg) < 3 or len(tc) < 3:
        return np.asarray(x0_guess, float)
    t_all = np.concatenate([tg, tc])
    order = np.argsort(t_all, kind="stable")
    inv = np.empty_like(order)
    inv[order] = np.arange(len(order))
    ts = t_all[order]
    sg, sc = 1.0 / w.sigma_gps[g], 1.0 / w.sigma_compass[c]

    def fun(x0):
        with np.errstate(invalid="ignore", over="ignore"):
            out = free_run_full(w, theta, current, x0, t0, ts)[inv]
            a, b = out[:len(tg)], out[len(tg):]
            r = np.concatenate([(a[:, 0] - w.n_gps[g]) * sg, (a[:, 1] - w.e_gps[g]) * sg,
                                ssa(b[:, 2] - w.psi_compass[c]) * sc])
        return np.where(np.isfinite(r), r, BAD_RESIDUAL)

    x_guess = np.asarray(x0_guess, float)
    sol = least_squares(fun, x_guess, x_scale=np.array([1.0, 1.0, 0.05, 0.1, 0.05, 0.02]), max_nfev=30,
                        diff_step=1e-6, method="trf")
    return sol.x


__all__ = ["BAD_RESIDUAL", "ExtendedOEResult", "ext_physical_problem", "fit_extended_output_error",
           "fit_initial_state_ext", "free_run_full", "simulate_full", "coarse_thrust", "residual_rows"]
