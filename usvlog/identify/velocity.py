"""Velocity output error: the model's velocities fitted to the smoothed u, v, r.

The paper's model (3) is integrated through the recorded thrust over windows of ``H``
seconds, each started from the smoothed state at its start, and its velocities u, v, r are
compared with the smoothed ones (u, v relative to the water: a constant current per run is
fitted with them). The windows are lengthened in stages (5 s, 30 s, 120 s by default): short
windows make the problem nearly convex (each prediction is a few time constants long and
cannot drift away), so any starting guess from a tenth to ten times the truth reaches the
same basin; the long ones then weigh the slow surge and yaw responses as a free run does.

Positive parameters are fitted as logarithms (a step can never make a mass negative and a
factor of ten is as easy as a factor of two). Each channel's weight is the inverse of its
own residual RMS from the stage before (maximum likelihood with an unknown noise level per
channel), so a channel the model cannot explain -- sway crab from wind -- loses weight
instead of dragging the surge and yaw parameters. Velocities are over the fast dynamics
only: the slow position and heading drift of a free run never enters, which is what makes
this fit robust on boats and logs of other forms.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from ..choices import EXTENDED_PARAM_NAMES
from ..model.vessel import PARAM_NAMES
from .data import RunData
from .extended import MAX_DT as EXT_MAX_DT
from .extended_oe import ext_physical_problem, simulate_full
from .output import DIVERGED, MAX_STIFFNESS, coarse_run, max_step, stiffness
from .projection import triangular_factor
from .shoot import no_rows, shoot
from .smooth import KinStates, thrust_on_grid

HORIZONS_S = (5.0, 30.0, 120.0)   # window lengths of the stages (s)
MIN_SIGMA = (0.01, 0.01, 0.002)   # floor of each channel's residual scale: u, v (m/s), r (rad/s)
MIN_START = 1e-3                  # smallest start of a positive parameter, relative to the largest one
NFEV_PER_PARAM = 12               # model evaluations per stage per fitted quantity (a dozen Jacobians)
BIG = 1e3                         # a residual that is not finite counts as this many sigma
MAX_XG = 1.0                      # |xg| bound (m): the centre of gravity stays on a small hull
# largest share of the yaw inertia Iz the sway-yaw coupling m xg^2 may take (extended: m26^2 of m22 m66).
# A small hull's is a few % (the paper's vessel 3 %); a fit that drives it towards Iz makes the
# effective yaw inertia Iz - m xg^2 vanish, the model's sensitivity to m and xg a cliff (a Fossen Otter
# run: 95 % of Iz, condition number 1e16) and buys an unmodelled yaw effect (quadratic damping, a Munk
# moment) with a centre of gravity metres off the hull's. The signed parameter is fitted as
# signed_max * tanh(z), so the bound is approached smoothly instead of hit as a wall
MAX_COUPLING = 0.5
WALL_COUPLING = 0.98              # beyond this share a parameter vector is no boat (its simulation a cliff)
Z_MAX = 6.0                       # bound of the signed parameter's fitted coordinate (tanh(6) = 1 - 1e-5)
DIFF_STEP = 1e-4                  # relative step of the finite-difference Jacobian
QUADRATIC_START = 0.3             # extended start: each quadratic damping this share of the linear one per unit speed


@dataclass(frozen=True)
class Structure:
    """A model structure the velocity fit can fit: its parameters, which are positive (fitted as
    logarithms), the bound of the signed ones, its simulation of windows and what is no boat."""

    name: str
    names: tuple
    positive: np.ndarray

    @property
    def signed(self) -> int:
        """Index of the one signed parameter (xg, or m26)."""
        return int(np.flatnonzero(~self.positive)[0])

    def signed_max(self, theta) -> float:
        """Largest magnitude the signed parameter may take with the others at ``theta``: the
        coupling at most :data:`MAX_COUPLING` of the yaw (paper: and |xg| <= MAX_XG)."""
        th = np.asarray(theta, float)
        if self.name == "paper":
            return float(min(MAX_XG, math.sqrt(MAX_COUPLING * max(th[1], 0.0) / max(th[0], 1e-12))))
        # Python floats: a product of absurd values is inf, without numpy's overflow warning
        return math.sqrt(MAX_COUPLING * max(float(th[1]), 0.0) * max(float(th[3]), 0.0))

    def simulate(self, w: _Windows, theta, cur, x0s, out) -> None:
        """States (n, e, psi, u, v, r) of every window of ``w`` at its grid times into ``out``."""
        r = w.run
        if self.name == "paper":
            nseg = len(w.i0)
            shoot(r.t_thrust, r.tau_u, r.tau_r, w.i0, w.i1, x0s, np.ascontiguousarray(theta, dtype=np.float64),
                  np.tile(np.asarray(cur, float), (nseg, 1)), w.t, w.ptr, max_step(theta), False, out, *no_rows())
        else:
            simulate_full(r.t_thrust, r.tau_u, r.tau_r, w.i0, w.i1, x0s, np.ascontiguousarray(theta, dtype=np.float64),
                          float(cur[0]), float(cur[1]), w.t, w.ptr, EXT_MAX_DT, out)

    def not_a_boat(self, theta) -> bool:
        """Parameters no boat has (see :func:`_not_a_boat`; the extended model: not a boat by
        :func:`~usvlog.identify.extended_oe.ext_physical_problem`, or a coupling m26^2 over
        MAX_COUPLING of m22 m66)."""
        if self.name == "paper":
            return _not_a_boat(theta)
        th = np.asarray(theta, float)
        if ext_physical_problem(th):
            return True
        m22, m26, m66 = float(th[1]), float(th[2]), float(th[3])   # Python floats: no overflow warning
        return m26 * m26 > WALL_COUPLING * m22 * m66


PAPER = Structure("paper", PARAM_NAMES, np.array([k != "xg" for k in PARAM_NAMES]))
POSITIVE = PAPER.positive
EXTENDED = Structure("extended", EXTENDED_PARAM_NAMES, np.array([k != "m26" for k in EXTENDED_PARAM_NAMES]))
STRUCTURES = {"paper": PAPER, "extended": EXTENDED}


def extended_start(theta_paper) -> np.ndarray:
    """An extended-model start from paper parameters (m, Iz, d11, d22, d33, xg): the paper's
    dynamics in the extended form, each quadratic damping :data:`QUADRATIC_START` of its linear
    one per unit speed (a logarithm cannot start from zero) and the linear ones reduced to match
    at that speed."""
    m, Iz, d11, d22, d33, xg = (float(x) for x in theta_paper)
    q = QUADRATIC_START
    return np.array([m, m, m * xg, Iz, d11 * (1 - q), d11 * q, d22 * (1 - q), d22 * q, d33 * (1 - q), d33 * q])


@dataclass(frozen=True, kw_only=True)
class VelocityFitResult:
    """Result of :func:`fit_velocity_error`.

    Attributes
    ----------
    theta : numpy.ndarray, shape (6,) or (10,)
        m (kg), Iz (kg m^2), d11, d22 (kg/s), d33 (kg m^2/s), xg (m).
    currents : numpy.ndarray, shape (n_runs, 2)
        Current north, east per run (m/s; zeros when not fitted).
    names : tuple of str
        The fitted quantities (free parameters, then ``current_n_<i>``, ``current_e_<i>``).
    cov : numpy.ndarray
        Covariance of ``names`` (parameters in their units, from the final stage's Jacobian
        scaled by its residual variance).
    cond : float
        Condition number of the final stage's scaled Jacobian.
    rms : dict of str to float
        Residual RMS of ``u`` (m/s), ``v`` (m/s), ``r`` (rad/s) of the final stage.
    diverged : bool
        True when the final model's predictions left the finite range.
    nfev : int
        Model evaluations over all stages.
    residuals : numpy.ndarray, shape (N, 3)
        The final stage's residuals of u (m/s), v (m/s), r (rad/s), prediction minus smoothed
        (a prediction that is not finite counts as BIG of its channel's scale).
    """

    theta: np.ndarray
    currents: np.ndarray
    names: tuple
    cov: np.ndarray
    cond: float
    rms: dict
    diverged: bool
    nfev: int
    residuals: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)), repr=False)


class _Windows:
    """One run cut into prediction windows of ``H`` s on the smoothed-state grid."""

    def __init__(self, run: RunData, ks: KinStates, H: float, structure: Structure = PAPER):
        self.structure = structure
        self.run = coarse_run(run)
        tg = self.run.t_thrust
        t = ks.t[(ks.t >= tg[0]) & (ks.t <= tg[-1])]
        self.ks = ks
        self.t = t
        starts = np.arange(t[0], t[-1], H) if len(t) > 1 else t[:1]
        i0 = np.unique(np.clip(np.searchsorted(tg, starts - 1e-9), 0, len(tg) - 1))
        i0 = i0[i0 < len(tg) - 1] if len(i0) > 1 else i0
        self.i0 = i0.astype(np.int64)
        self.i1 = np.append(i0[1:], len(tg) - 1).astype(np.int64)
        self.t_start = tg[self.i0]
        ptr = np.searchsorted(t, self.t_start - 1e-9)
        ptr[0] = 0
        self.ptr = np.append(ptr, len(t)).astype(np.int64)
        self._smoothed: tuple = (None, None, None)   # (current, window starts' states, u, v, r at t)

    def _states(self, cur) -> tuple[np.ndarray, np.ndarray]:
        """The smoothed states at the window starts and u, v, r at ``t`` for a current, made once per
        current (a finite-difference Jacobian asks for them with one current for every parameter)."""
        key = (float(cur[0]), float(cur[1]))
        if self._smoothed[0] != key:
            self._smoothed = (key, np.ascontiguousarray(self.ks.at(self.t_start, cur), dtype=np.float64),
                              self.ks.at(self.t, cur)[:, 3:])
        return self._smoothed[1], self._smoothed[2]

    def predict(self, theta, cur) -> tuple[np.ndarray, np.ndarray]:
        """(predicted, smoothed) u, v, r at ``t`` (two (N, 3) arrays) for parameters and a current."""
        x0s, meas = self._states(cur)
        ox = np.zeros((len(self.t), 6))
        with np.errstate(all="ignore"):
            self.structure.simulate(self, theta, cur, x0s, ox)
        return ox[:, 3:], meas


def _not_a_boat(theta) -> bool:
    """Parameters no boat has: not finite, a sway-yaw coupling m xg^2 over WALL_COUPLING of Iz, or a
    velocity time constant under 1 / MAX_STIFFNESS (whose simulation would need ever smaller steps)."""
    m, Iz, _, _, _, xg = theta
    if not np.all(np.isfinite(theta)) or m * xg * xg > WALL_COUPLING * Iz:
        return True
    return not stiffness(theta) <= MAX_STIFFNESS


class _Problem:
    """The stacked residuals of every run's windows, in the fitted (log) coordinates."""

    def __init__(self, runs, kin, H, theta0, free, fit_current, currents0, sigma, structure: Structure = PAPER,
                 ties: tuple = ()):
        self.structure = structure
        self.ties = ties          # (index, index of the parameter it equals)
        self.win = [_Windows(r, k, H, structure) for r, k in zip(runs, kin)]
        self.theta0 = np.asarray(theta0, float)
        self.free = np.asarray(free, bool)
        self.fit_current = fit_current
        self.currents0 = np.asarray(currents0, float)
        self.sigma = np.asarray(sigma, float)
        self.nfev = 0

    def unpack(self, p):
        """(parameters, currents) from the fitted coordinates: logarithms of the positive
        parameters, z of the signed one (signed_max * tanh(z)), the currents as they are."""
        st = self.structure
        th = self.theta0.copy()
        q = p[:int(self.free.sum())]
        th[self.free] = np.where(st.positive[self.free], np.exp(np.clip(q, -50, 50)), q)
        for a, b in self.ties:
            th[a] = th[b]
        if self.free[st.signed]:
            th[st.signed] = st.signed_max(th) * math.tanh(th[st.signed])
        cur = p[len(q):].reshape(-1, 2) if self.fit_current else self.currents0
        return th, cur

    def pack(self, theta, cur) -> np.ndarray:
        """The fitted coordinates of (parameters, currents) (see :meth:`unpack`)."""
        st = self.structure
        full = np.asarray(theta, float).copy()
        z = full.copy()
        z[st.positive] = np.log(np.maximum(full[st.positive], 1e-12))
        lim = st.signed_max(full)
        z[st.signed] = math.atanh(float(np.clip(full[st.signed] / lim, -0.999, 0.999))) if lim > 0 else 0.0
        return np.concatenate([z[self.free], np.asarray(cur, float).ravel() if self.fit_current else []])

    def residuals(self, p, by_channel: bool = False):
        self.nfev += 1
        th, cur = self.unpack(p)
        out = []
        for i, w in enumerate(self.win):
            if self.structure.not_a_boat(th):
                res = np.full((len(w.t), 3), BIG)
            else:
                pred, meas = w.predict(th, cur[i])
                res = (pred - meas) / self.sigma
                bad = ~np.isfinite(res) | (np.abs(pred) > DIVERGED)
                res[bad] = BIG
                res = np.clip(res, -BIG, BIG)
            out.append(res)
        res = np.concatenate(out)
        return res if by_channel else res.ravel()


def fit_velocity_error(runs: list[RunData], kin: list[KinStates], theta0, *, free_mask=None,
                       fit_current: bool = True, currents0=None, max_current_mps: float = 0.5,
                       horizons_s=HORIZONS_S, max_nfev: int | None = None, model: str = "paper",
                       ties: tuple = ()) -> VelocityFitResult:
    """Fit m, Iz, d11, d22, d33, xg (and a current per run) to the smoothed velocities.

    With ``model="extended"`` the ten parameters of the extended model
    (EXTENDED_PARAM_NAMES order) instead, the same way.

    Parameters
    ----------
    runs : list of RunData
        The runs (recorded thrust, times in s from each run's start).
    kin : list of KinStates
        Their smoothed states (the measurements: u, v, r; relative to the water for a current).
    theta0 : array_like, shape (6,) or (10,)
        Starting m, Iz, d11, d22, d33, xg (SI), or the extended model's ten. Any boat-like
        values; positive ones are fitted as logarithms.
    free_mask : array_like of bool, shape (6,) or (10,), optional
        Which parameters are fitted (default all); the others are held at ``theta0``.
    fit_current : bool, default True
        Fit a constant current (north, east, m/s) per run, each within +-``max_current_mps``.
    currents0 : array_like, shape (n_runs, 2), optional
        Starting (or, without ``fit_current``, held) currents; default zero.
    max_current_mps : float, default 0.5
        Bound on each current component (m/s).
    horizons_s : sequence of float, default (5, 30, 120)
        Window lengths of the stages, each started from the stage before.
    max_nfev : int, optional
        Model evaluations per stage at most (default :data:`NFEV_PER_PARAM` per fitted
        quantity: a finite-difference Jacobian costs one evaluation each).
    model : {"paper", "extended"}, default "paper"
        The model structure.
    ties : sequence of (str, str), optional
        Parameters that equal another, by name: ``(("m22", "m11"),)`` holds m22 at m11's value
        as it is fitted (the first of each pair must be held by ``free_mask``). With m22 tied to
        m11 and d22q, d33q held at 0 the extended structure is the paper model with a quadratic
        surge damping d11q (m26 = m xg, m66 = Iz).

    Returns
    -------
    VelocityFitResult
    """
    st = STRUCTURES[model]
    tie_ix = tuple((st.names.index(a), st.names.index(b)) for a, b in ties)
    if max_nfev is None:
        max_nfev = NFEV_PER_PARAM * (len(st.names) + (2 * len(runs) if fit_current else 0))
    theta = np.array(theta0, float)
    free = np.ones(len(st.names), bool) if free_mask is None else np.asarray(free_mask, bool)
    if any(free[a] for a, _ in tie_ix):
        raise ValueError("a tied parameter is not fitted: hold it with free_mask")
    # a positive parameter at (or near) zero cannot move as a logarithm: from a thousandth of the largest
    grow = st.positive & free
    theta[grow] = np.maximum(theta[grow], MIN_START * np.max(np.abs(theta[st.positive])))
    for a, b in tie_ix:
        theta[a] = theta[b]
    lim = 0.99 * st.signed_max(theta)
    theta[st.signed] = float(np.clip(theta[st.signed], -lim, lim))
    if st.not_a_boat(theta):   # not a boat for another reason (stiffness): start from the centre line
        theta[st.signed] = 0.0
    cur = np.zeros((len(runs), 2)) if currents0 is None else np.array(currents0, float).reshape(-1, 2)
    cur = np.clip(cur, -0.99 * max_current_mps, 0.99 * max_current_mps)
    sigma = np.array([max(float(np.std(np.concatenate([k.nu()[:, j] for k in kin]))), MIN_SIGMA[j])
                      for j in range(3)])
    nfev = 0
    prob = None
    sol = None
    for H in horizons_s:
        prob = _Problem(runs, kin, H, theta, free, fit_current, cur, sigma, st, tie_ix)
        p0 = prob.pack(theta, cur)
        lb = np.where(st.positive[free], -np.inf, -Z_MAX)
        ub = np.where(st.positive[free], np.inf, Z_MAX)
        if fit_current:
            lb = np.concatenate([lb, np.full(2 * len(runs), -max_current_mps)])
            ub = np.concatenate([ub, np.full(2 * len(runs), max_current_mps)])
        inner = 1e-6 * np.where(np.isfinite(ub - lb), ub - lb, 0.0)   # strictly inside the bounds
        p0 = np.clip(p0, lb + inner, ub - inner)
        small = _Small(prob, lb, ub)
        sol = least_squares(small.fun, p0, jac=small.jac, bounds=(lb, ub), max_nfev=max_nfev, x_scale=1.0)
        theta, cur = prob.unpack(sol.x)
        nfev += prob.nfev
        # each channel weighted by its own residual RMS for the next stage (unknown noise per channel)
        res = prob.residuals(sol.x, by_channel=True) * sigma
        ok = np.all(np.abs(res) < BIG * 0.5, axis=1)
        if ok.sum() > 10:
            sigma = np.maximum(np.sqrt(np.mean(res[ok] ** 2, axis=0)), MIN_SIGMA)
    assert prob is not None and sol is not None
    res = prob.residuals(sol.x, by_channel=True)
    diverged = bool(st.not_a_boat(theta) or np.any(np.abs(res) >= BIG))
    names, cov, cond = _covariance(prob, sol, res.size, theta, free, fit_current, len(runs))
    rms_ch = np.sqrt(np.mean((res * prob.sigma) ** 2, axis=0)) if len(res) else np.full(3, np.nan)
    return VelocityFitResult(theta=theta, currents=np.asarray(cur, float).reshape(-1, 2), names=names, cov=cov,
                             cond=cond, rms=dict(zip(("u", "v", "r"), map(float, rms_ch))), diverged=diverged,
                             nfev=nfev, residuals=res * prob.sigma)


class _Small:
    """A stage of the fit as :func:`scipy.optimize.least_squares` sees it: P + 1 rows (P fitted
    quantities) instead of the 3 N residuals, with the same cost, gradient and Gauss-Newton matrix.

    :meth:`fun` gives the residuals' norm and P zeros; :meth:`jac` the forward-difference
    Jacobian J there, with the residuals r as the triangular factor R of [r J] = Q R (R's first
    column is then (|r|, 0, ..., 0), :meth:`fun`'s): R^T R = [r J]^T [r J]. least_squares
    decomposes a (P + 1) x P matrix instead of copies of a whole-run one (its working copies of
    J and the differences took ~40 MB an hour of log at the fit's peak); the evaluations are
    those of its own '2-point' differences (``diff_step`` :data:`DIFF_STEP`)."""

    def __init__(self, prob: _Problem, lb, ub):
        self.prob, self.lb, self.ub = prob, lb, ub
        self._last: tuple[bytes, np.ndarray] = (b"", np.zeros(0))   # (p, residuals) of the last fun

    def fun(self, p):
        r = self.prob.residuals(p)
        self._last = (p.tobytes(), r)
        out = np.zeros(len(p) + 1)
        out[0] = math.sqrt(float(r @ r))
        return out

    def jac(self, p):
        key, r = self._last
        if key != p.tobytes():
            r = self.prob.residuals(p)
        A = np.empty((len(r), len(p) + 1))
        A[:, 0] = r
        _forward_differences(self.prob.residuals, p, r, self.lb, self.ub, A[:, 1:])
        R = triangular_factor(A)
        if R[0, 0] < 0:   # (a QR's row may come with either sign)
            R[0] = -R[0]
        return R[:, 1:]


def _forward_differences(fun, x, f0, lb, ub, out) -> None:
    """``out[:, j] = (fun(x + h_j e_j) - f0) / h_j``: scipy's '2-point' Jacobian with ``diff_step``
    :data:`DIFF_STEP` (h_j = DIFF_STEP |x_j| with x_j's sign, sqrt(eps) max(1, |x_j|) where that is
    lost, the other way where it would leave the bounds), the same numbers."""
    sign = np.where(x >= 0, 1.0, -1.0)
    h = DIFF_STEP * sign * np.abs(x)
    h = np.where((x + h) - x == 0, np.finfo(float).eps ** 0.5 * sign * np.maximum(1.0, np.abs(x)), h)
    h = np.where((x + h < lb) | (x + h > ub), -h, h)
    for j in range(len(x)):
        x1 = x.copy()
        x1[j] = x[j] + h[j]
        out[:, j] = (fun(x1) - f0) / (x1[j] - x[j])


def _covariance(prob: _Problem, sol, n: int, theta, free, fit_current: bool, n_runs: int):
    """Names, covariance in the parameters' own units and condition number of the final stage
    (``sol.jac``: its Jacobian, compressed or not, of ``n`` residuals)."""
    st = prob.structure
    names = tuple([k for k, f in zip(st.names, free) if f] +
                  ([f"current_{ax}_{i}" for i in range(n_runs) for ax in ("n", "e")] if fit_current else []))
    J = np.asarray(sol.jac, float)
    # back from the fitted coordinates (logarithms, the signed parameter's z): d theta = T d q
    T = _coordinate_jacobian(prob, np.asarray(sol.x, float))
    k = J.shape[1]
    s2 = float(2 * sol.cost / max(n - k, 1))
    with np.errstate(all="ignore"):
        col = np.sqrt(np.sum(J * J, axis=0))
        col[col == 0] = 1.0
        Js = J / col
        sv = np.linalg.svd(Js, compute_uv=False) if np.all(np.isfinite(Js)) else np.array([np.nan])
        cond = float(sv[0] / sv[-1]) if sv[-1] > 0 else math.inf
        try:
            cov_q = np.linalg.pinv(Js.T @ Js) / np.outer(col, col) * s2
        except np.linalg.LinAlgError:
            cov_q = np.full((k, k), np.nan)
    cov = T @ cov_q @ T.T
    return names, cov, cond


def _coordinate_jacobian(prob: _Problem, x: np.ndarray, h: float = 1e-6) -> np.ndarray:
    """d (free parameters, currents) / d (fitted coordinates) at ``x`` by central differences of
    :meth:`_Problem.unpack` (the currents' block is the identity)."""
    k = len(x)
    nf = int(prob.free.sum())
    T = np.eye(k)
    for j in range(nf):
        e = np.zeros(k)
        e[j] = h
        hi, lo = prob.unpack(x + e)[0][prob.free], prob.unpack(x - e)[0][prob.free]
        T[:nf, j] = (hi - lo) / (2 * h)
    return T


def data_scales(runs: list[RunData], kin: list[KinStates]) -> np.ndarray | None:
    """A start for the fit from the data alone: the scales of the surge and yaw responses.

    d11 = typical surge force / typical speed while moving, d33 = typical yaw moment / typical
    yaw rate while turning, time constants of 2 s in surge and 1 s in yaw (m = 2 d11,
    Iz = d33), sway twice as damped as surge, xg = 0. Medians of magnitudes, so a log's
    spikes do not matter. None when the run neither moves nor turns enough to say.

    Parameters
    ----------
    runs : list of RunData
    kin : list of KinStates

    Returns
    -------
    numpy.ndarray, shape (6,), or None
        m, Iz, d11, d22, d33, xg.
    """
    us: list = []
    rs: list = []
    tus: list = []
    trs: list = []
    for run, ks in zip(runs, kin):
        if len(ks.t) < 10 or len(run.t_thrust) < 2:
            continue
        a, b = thrust_on_grid(run, ks.t)
        nu = ks.nu()
        us.append(nu[:, 0])
        rs.append(nu[:, 2])
        tus.append(a)
        trs.append(b)
    if not us:
        return None
    u, r, tu, tr = (np.concatenate(x) for x in (us, rs, tus, trs))
    moving = np.abs(u) > max(0.2, 0.3 * float(np.nanmax(np.abs(u))) if np.isfinite(u).any() else 0.2)
    turning = np.abs(r) > math.radians(3.0)
    if moving.sum() < 20 or turning.sum() < 20:
        return None
    d11 = float(np.median(np.abs(tu[moving])) / np.median(np.abs(u[moving])))
    d33 = float(np.median(np.abs(tr[turning])) / np.median(np.abs(r[turning])))
    if not (math.isfinite(d11) and math.isfinite(d33) and d11 > 0 and d33 > 0):
        return None
    return np.array([2.0 * d11, d33, d11, 2.0 * d11, d33, 0.0])


__all__ = ["VelocityFitResult", "fit_velocity_error", "data_scales", "extended_start", "HORIZONS_S", "Structure",
           "PAPER", "EXTENDED"]
