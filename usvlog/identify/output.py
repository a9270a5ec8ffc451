"""Output-error identification by multiple shooting.

The model (eqs. (1)+(3), constant current per run) is integrated from the recorded
thrust over segments of ``segment_s`` seconds, each from its own free initial state, and
fitted to the raw measurements: GPS north/east and compass heading (ssa residual), each
weighted by its noise. The segment initial states are nuisance parameters eliminated by
variable projection: for given model parameters and currents each segment's initial state
is solved by Gauss-Newton, and :func:`scipy.optimize.least_squares` sees the projected
Jacobian (so its normal matrix is the marginal information of the parameters of interest;
standard errors come from it scaled by the residual variance).
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace

import numpy as np
from scipy.linalg import qr as scipy_qr
from scipy.optimize import least_squares

from .._cpu import spare_cpu
from ..errors import FitFailed
from ..model.frames import ssa
from ..model.vessel import PARAM_NAMES
from .data import RunData, coarse_thrust
from .shoot import NS, SENS_CUR_E, SENS_CUR_N, no_rows, shoot

MAX_DT = 0.05
OUTLIER_SIGMA = 5.0
# residual rows: GPS north, east; compass heading; ground velocity north, east; yaw rate
R_N, R_E, R_PSI, R_VN, R_VE, R_R = range(6)
SENSOR_OF_ROW = np.array([0, 0, 1, 2, 2, 3])
SENSORS = ("gps", "compass", "velocity", "yaw_rate")
# one-sigma of the smoothed velocities as measurements (m/s, rad/s) before reweighting
VEL_SIGMA = (0.05, 0.02)
VEL_STEP_S = 0.5        # spacing of the velocity measurements (s)
MAX_STIFFNESS = 50.0    # 1/s: a velocity time constant under 20 ms is no boat's
DIVERGED = 1e3          # |u|, |v| (m/s) or |r| (rad/s) beyond this: the simulation diverged
JAC_MAX = 1e30          # |d(weighted residual)/d(x0, parameter)| beyond this: the sensitivities grew
                        # exponentially (a diverging linearisation); its products would overflow
BAD_RESIDUAL = 1e6      # weighted residual of a measurement whose simulation diverged (Jacobian row 0)


@dataclass(frozen=True, kw_only=True)
class OutputErrorResult:
    """Result of :func:`fit_output_error`.

    ``theta``: all six parameters m (kg), Iz (kg m^2), d11, d22 (kg/s), d33 (kg m^2/s),
    xg (m), fixed ones included; ``free``: names of the fitted ones; ``currents``
    (n_runs, 2): north, east in m/s (zeros when not fitted); ``cov``: covariance of
    [free parameters, currents] with row names ``names`` (``current_n_<i>``,
    ``current_e_<i>``); ``cond``: condition number of the column-scaled projected
    Jacobian; ``sigma2``: residual variance factor (1 when the noise model is right);
    ``rms``: RMS of the noise-weighted residuals per sensor (``gps``, ``compass``);
    ``n_residuals``; ``x0s`` (n_segments, 6): each segment's fitted initial state
    [n (m), e (m), psi (rad), u (m/s), v (m/s), r (rad/s)]; ``nfev``: model evaluations;
    ``outliers``: measurements dropped as outliers, per sensor; ``diverged``: the model's
    simulation left the finite range at the solution (a failed fit, not a number).
    """

    theta: np.ndarray          # all six model parameters (fixed ones included)
    free: tuple[str, ...]      # names of fitted model parameters
    currents: np.ndarray       # (n_runs, 2) north, east m/s (zeros when not fitted)
    cov: np.ndarray            # covariance of [free params, currents (if fitted)]
    names: tuple[str, ...]     # names of the covariance's rows
    cond: float                # condition number of the column-scaled projected Jacobian
    sigma2: float              # residual variance factor (1 when the noise model is right)
    rms: dict                  # whitened-residual RMS per sensor
    n_residuals: int
    x0s: np.ndarray            # per-segment initial states
    nfev: int
    outliers: dict | None = None  # measurements dropped as outliers, per sensor
    diverged: bool = False     # the simulation left the finite range at the solution


def coarse_run(run: RunData) -> RunData:
    """The run with its thrust averaged over steps of about MAX_DT s (:func:`coarse_thrust`:
    the same impulse over each step; measurements unchanged).

    Parameters
    ----------
    run : RunData

    Returns
    -------
    RunData
        ``run`` itself when its thrust steps are MAX_DT or longer already.
    """
    t, tu, tr = coarse_thrust(run.t_thrust, run.tau_u, run.tau_r, MAX_DT)
    if len(t) == len(run.t_thrust):
        return run
    return replace(run, t_thrust=t, tau_u=tu, tau_r=tr)


class Problem:
    """Runs cut into segments, measurements ordered by segment, residual rows indexed.

    ``velocities``: per run None or (t (s), vn, ve (m/s, over ground), r (rad/s)) smoothed
    velocities, fitted alongside the raw GPS and compass (residual rows of sensor groups 2:
    ground velocity, 3: yaw rate) with one-sigma ``vel_sigma`` (m/s, rad/s).

    The model is integrated on the runs' thrust averaged over steps of about MAX_DT
    (:func:`coarse_thrust`: the same impulse, one RK4 step per MAX_DT instead of one per
    thrust record); ``runs`` keeps those coarse runs (segment indices refer to their grids).
    """

    def __init__(self, runs: list[RunData], segment_s: float, velocities=None,
                 vel_sigma: tuple[float, float] = VEL_SIGMA):
        runs = [coarse_run(r) for r in runs]
        tg, tu, tr = [], [], []
        seg_i0: list[int] = []
        seg_i1: list[int] = []
        seg_run: list[int] = []
        m_t, m_kind, m_val, m_sig, m_seg = [], [], [], [], []
        off = 0
        for ri, run in enumerate(runs):
            t = run.t_thrust
            n = len(t)
            vel = velocities[ri] if velocities is not None else None
            within = _Within(run.t_gps), _Within(run.t_compass), _Within(vel[0] if vel is not None else np.zeros(0))
            edges = [0]
            tcut = t[0] + segment_s
            while tcut < t[-1] - 0.5 * segment_s:
                edges.append(int(np.searchsorted(t, tcut)))
                tcut += segment_s
            edges.append(n - 1)
            edges = sorted(set(edges))
            for a, b in zip(edges[:-1], edges[1:]):
                ta, tb = t[a], t[b]
                g, c, sv = (w.select(ta, tb, b == n - 1) for w in within)
                k = len(seg_i0)
                seg_i0.append(off + a)
                seg_i1.append(off + b)
                seg_run.append(ri)
                # measurement times relative to the concatenated grid
                sensors = [(0, run.t_gps[g], np.stack([run.n_gps[g], run.e_gps[g], 0 * run.n_gps[g]], 1),
                            run.sigma_gps[g]),
                           (1, run.t_compass[c], np.stack([run.psi_compass[c], 0 * run.psi_compass[c],
                                                           0 * run.psi_compass[c]], 1), run.sigma_compass[c])]
                if vel is not None:
                    tv = vel[0][sv]
                    sensors.append((2, tv, np.stack([vel[1][sv], vel[2][sv], vel[3][sv]], 1), np.ones(len(tv))))
                for sensor, tt, val, sig in sensors:
                    m_t.append(tt)
                    m_kind.append(np.full(len(tt), sensor))
                    m_val.append(val)
                    m_sig.append(sig)
                    m_seg.append(np.full(len(tt), k))
            tg.append(t)
            tu.append(run.tau_u)
            tr.append(run.tau_r)
            off += n
        self.runs = runs
        self.n_runs = len(runs)
        self.tg = np.concatenate(tg)
        self.tau_u = np.concatenate(tu)
        self.tau_r = np.concatenate(tr)
        self.seg_i0 = np.array(seg_i0, np.int64)
        self.seg_i1 = np.array(seg_i1, np.int64)
        self.seg_run = np.array(seg_run, np.int64)
        t = np.concatenate(m_t)
        kind = np.concatenate(m_kind)
        val = np.concatenate(m_val)
        sig = np.concatenate(m_sig)
        seg = np.concatenate(m_seg)
        order = np.lexsort((t, seg))
        self.meas_t, self.kind, self.val = t[order], kind[order], val[order]
        self.sig, self.meas_seg = sig[order], seg[order]
        self.meas_ptr = np.searchsorted(self.meas_seg, np.arange(len(seg_i0) + 1)).astype(np.int64)
        self.n_seg = len(seg_i0)
        gi = np.flatnonzero(self.kind == 0)
        ci = np.flatnonzero(self.kind == 1)
        vi = np.flatnonzero(self.kind == 2)
        # residual rows: (measurement index, quantity): R_N, R_E (GPS), R_PSI (compass),
        # R_VN, R_VE (ground velocity), R_R (yaw rate)
        r_meas = np.concatenate([gi, gi, ci, vi, vi, vi])
        r_state = np.concatenate([np.full(len(gi), R_N), np.full(len(gi), R_E), np.full(len(ci), R_PSI),
                                  np.full(len(vi), R_VN), np.full(len(vi), R_VE), np.full(len(vi), R_R)])
        r_seg = self.meas_seg[r_meas]
        o = np.argsort(r_seg, kind="stable")
        self.r_meas, self.r_state, self.r_seg = r_meas[o], r_state[o], r_seg[o]
        self.r_sensor = SENSOR_OF_ROW[self.r_state]   # 0 gps, 1 compass, 2 ground velocity, 3 yaw rate
        col = np.array([0, 1, 0, 0, 1, 2])[self.r_state]
        self.r_val = self.val[self.r_meas, col]
        self.r_sig0 = np.where(self.r_sensor == 2, vel_sigma[0], np.where(self.r_sensor == 3, vel_sigma[1],
                                                                         self.sig[self.r_meas]))
        self.r_start = np.searchsorted(self.r_seg, np.arange(self.n_seg + 1))
        # each run's residual rows, r_run_start[i]:r_run_start[i + 1] (segments are in run order)
        self.r_run_start = np.searchsorted(self.seg_run[self.r_seg], np.arange(self.n_runs + 1))
        self.n_res = len(self.r_meas)
        self.r_srow = self.r_meas * 6 + np.minimum(self.r_state, 2)   # its state in out_x.reshape(-1)
        self.r_psi = np.flatnonzero(self.r_state == R_PSI)    # heading rows (wrapped)
        # the sensitivity rows the kernel writes (shoot's row_*), per measurement: each GPS and
        # compass residual row's own (of state n, e or psi), weighted as its residual with the
        # sign of d(residual) = -d(state), in that row; each velocity measurement's rows psi,
        # u, v, r unweighted into 4 rows of its own below the n_res (jac_rows makes the
        # velocity residual rows of them)
        pos = np.flatnonzero(self.r_state < R_VN)
        vmeas = np.flatnonzero(self.kind == 2)
        self.n_vmeas = len(vmeas)
        e_meas = np.concatenate([self.r_meas[pos], np.repeat(vmeas, 4)])
        o = np.argsort(e_meas, kind="stable")
        self.e_dst = np.concatenate([pos, self.n_res + np.arange(4 * len(vmeas))])[o]
        self.e_q = np.concatenate([np.minimum(self.r_state[pos], 2), np.tile(np.arange(2, 6), len(vmeas))])[o]
        self.e_res = np.concatenate([pos, np.full(4 * len(vmeas), -1)])[o]   # residual row, -1 velocity
        self.e_ptr = np.searchsorted(e_meas[o], np.arange(len(self.meas_t) + 1)).astype(np.int64)
        # the velocity measurements, the run of each, and per velocity row quantity (vn, ve, r)
        # its rows and their measurements' positions in vmeas
        self.v_meas, self.v_run = vmeas, self.seg_run[self.meas_seg[vmeas]]
        self.v_rows = tuple(np.flatnonzero(self.r_state == q) for q in (R_VN, R_VE, R_R))
        self.v_k = tuple(np.searchsorted(vmeas, self.r_meas[rr]) for rr in self.v_rows)
        self._set_weights(1.0 / self.r_sig0)
        self._rows: np.ndarray | None = None
        self.threads: bool | Callable[[], bool] | None = None
        """Integrate the segments in two threads (the same numbers; default: with more than one
        CPU and segment); a callable is asked at each :meth:`simulate` (True: with a spare CPU)."""

    def set_sensor_scale(self, scales) -> None:
        """Scale each sensor group's stated noise (residual weight 1 / (sigma scale)), e.g. by its
        scatter; ``scales``: one factor per group (gps, compass, ground velocity, yaw rate)."""
        self._set_weights(1.0 / (self.r_sig0 * np.asarray(scales, float)[self.r_sensor]))

    def _set_weights(self, r_w) -> None:
        self.r_w = r_w
        self.e_w = np.where(self.e_res >= 0, -r_w[self.e_res], 1.0)   # the kernel's row weights

    def simulate(self, theta, currents, x0s, sens=True):
        """Integrate every segment and sample it at the measurement times.

        Parameters
        ----------
        theta : array_like, shape (6,)
            m, Iz, d11, d22, d33, xg (SI).
        currents : array_like, shape (n_runs, 2)
            Current north, east per run, m/s.
        x0s : array_like, shape (n_seg, 6)
            Initial state of each segment [n, e, psi, u, v, r] (m, rad, m/s, rad/s).
        sens : bool, default True
            Also integrate the sensitivities.

        Returns
        -------
        out_x : numpy.ndarray, shape (n_meas, 6)
            States at the measurement times.
        rows : numpy.ndarray, shape (n_res + 4 n_vel, NS)
            Sensitivity rows (to [x0 (6), theta (6), current (2)]) for :meth:`jac_rows`: the
            first n_res are each GPS and compass residual row's (its state's times minus its
            weight), then the rows psi, u, v, r of each velocity measurement (shape (0, NS)
            when ``sens`` is False). The problem's own buffer: the next call overwrites it.
        """
        seg_cur = np.ascontiguousarray(currents[self.seg_run], float)
        x0s = np.ascontiguousarray(x0s, float)
        theta = np.asarray(theta, float)
        out_x = np.zeros((len(self.meas_t), 6))
        if sens:
            # one buffer per problem: every call writes the same rows (those of the measurement
            # times), so it need not be zeroed again (MB per call on an hour of log)
            rows = self._rows
            if rows is None:
                rows = self._rows = np.zeros((self.n_res + 4 * self.n_vmeas, NS))
            args = (self.e_ptr, self.e_dst, self.e_q, self.e_w, rows)
        else:
            args = no_rows()
            rows = args[-1]
        dt = max_step(theta)

        def run(a: int, b: int) -> None:   # segments a..b-1 (they write their own rows only)
            shoot(self.tg, self.tau_u, self.tau_r, self.seg_i0[a:b], self.seg_i1[a:b], x0s[a:b], theta,
                  seg_cur[a:b], self.meas_t, self.meas_ptr[a:b + 1], dt, sens, out_x, *args)

        threads = self.threads
        if threads is None or callable(threads):
            threads = (threads is None or threads()) and spare_cpu() and self.n_seg > 1
        if not threads:
            run(0, self.n_seg)
            return out_x, rows
        # two halves of about equal grid steps, the later one in a second thread
        steps = np.cumsum(self.seg_i1 - self.seg_i0)
        half = int(np.clip(np.searchsorted(steps, 0.5 * steps[-1]) + 1, 1, self.n_seg - 1))
        with ThreadPoolExecutor(max_workers=1) as pool:
            later = pool.submit(run, half, self.n_seg)
            run(0, half)
            later.result()
        return out_x, rows

    def residuals(self, out_x, currents):
        """Noise-weighted residuals (measured - simulated) of every residual row; heading wrapped.

        ``currents`` (n_runs, 2): north, east in m/s (the ground velocity includes them)."""
        sim = out_x.reshape(-1).take(self.r_srow)     # state min(row's quantity, 2) at its measurement
        if self.n_vmeas:   # once per velocity measurement, then into its three rows
            x, c, s = self._vel_states(out_x)
            u, v = x[:, 3], x[:, 4]
            cur = np.asarray(currents, float)[self.v_run]
            for rr, kk, q in zip(self.v_rows, self.v_k, (c * u - s * v + cur[:, 0], s * u + c * v + cur[:, 1],
                                                         x[:, 5])):
                sim[rr] = q[kk]
        d = self.r_val - sim
        d[self.r_psi] = ssa(d[self.r_psi])
        d *= self.r_w
        return d

    def jac_rows(self, rows, out_x):
        """d(residual)/d(sensitivity columns), shape (n_res, NS), from :meth:`simulate`'s
        ``rows`` (its first n_res rows, completed in place: the velocity rows made here)."""
        J = rows[:self.n_res]
        if self.n_vmeas:   # once per velocity measurement, then into its three rows
            x, c, s = self._vel_states(out_x)
            u, v = x[:, 3], x[:, 4]
            Sv = rows[self.n_res:].reshape(self.n_vmeas, 4, NS)   # rows psi, u, v, r of each
            dvn = (-s * u - c * v)[:, None] * Sv[:, 0] + c[:, None] * Sv[:, 1] - s[:, None] * Sv[:, 2]
            dve = (c * u - s * v)[:, None] * Sv[:, 0] + s[:, None] * Sv[:, 1] + c[:, None] * Sv[:, 2]
            dvn[:, SENS_CUR_N] += 1.0
            dve[:, SENS_CUR_E] += 1.0
            for rr, kk, q in zip(self.v_rows, self.v_k, (dvn, dve, Sv[:, 3])):
                J[rr] = q[kk] * -self.r_w[rr, None]
        return J

    def _vel_states(self, out_x):
        """States at the velocity measurements and the cosine and sine of their heading."""
        x = out_x[self.v_meas]
        return x, np.cos(x[:, 2]), np.sin(x[:, 2])

    def seg_sum(self, a):
        """Sum of per-residual-row values over each segment's rows (first axis), shape (n_seg, ...).

        A segment without residual rows (no measurement inside it: a gap in the GNSS and
        compass, a short window) sums to zero. (``np.add.reduceat`` alone would give it its
        neighbour's first row, or fail on the last one's start past the end.)"""
        a = np.asarray(a)
        start, stop = self.r_start[:-1], self.r_start[1:]
        if self.n_seg and start[-1] >= len(a):   # empty segments at the end: a zero row to start at
            a = np.concatenate([a, np.zeros((1,) + a.shape[1:], a.dtype)])
        out = np.add.reduceat(a, start, axis=0)
        empty = stop <= start
        if empty.any():
            out[empty] = 0
        return out

    def seg_gram(self, a, b):
        """Per segment a_k^T b_k over its residual rows: ``a`` (n_res, p), ``b`` (n_res, q) ->
        (n_seg, p, q) (:meth:`seg_sum` of the rows' outer products, without forming them)."""
        out = np.empty((self.n_seg, a.shape[1], b.shape[1]))
        for k in range(self.n_seg):
            i, j = self.r_start[k], self.r_start[k + 1]
            out[k] = a[i:j].T @ b[i:j]
        return out

    def initial_states(self, states_fn):
        """x0 per segment from a function t (per run, s) -> states (n, 6)."""
        x0 = np.zeros((self.n_seg, 6))
        for k in range(self.n_seg):
            run = self.seg_run[k]
            i0 = self.seg_i0[k] - sum(len(r.t_thrust) for r in self.runs[:run])
            x0[k] = states_fn(run, self.runs[run].t_thrust[i0])
        return x0


class _Within:
    """The samples of a time series inside a segment [ta, tb) ([ta, tb] for the last one):
    a slice when the times are sorted (two binary searches), else a mask; the same samples in
    the same order either way."""

    def __init__(self, t: np.ndarray):
        self.t = t
        self.sorted = bool(np.all(t[1:] >= t[:-1]))

    def select(self, ta: float, tb: float, last: bool):
        t = self.t
        if self.sorted:
            return slice(int(np.searchsorted(t, ta, "left")), int(np.searchsorted(t, tb, "right" if last else "left")))
        return (t >= ta) & ((t < tb) | (last & (t <= tb)))


def stiffness(theta) -> float:
    """Fastest decay rate of the model's velocities, 1/s: max(d11/m, d22/m, d33/(Iz - m xg^2))."""
    m, Iz, d11, d22, d33, xg = np.asarray(theta, float)
    iz = Iz - m * xg * xg
    return float(max(d11 / m, d22 / m, d33 / iz if iz > 0 else np.inf))


def max_step(theta) -> float:
    """Integration sub-step (s): MAX_DT, shorter for stiff parameters (RK4 stays stable)."""
    k = stiffness(theta)
    return float(min(MAX_DT, 1.0 / k)) if np.isfinite(k) and k > 0 else MAX_DT


def _inner(prob: Problem, theta, currents, x0s, max_iter=10, tol=1e-7):
    """Solve each segment's initial state (Gauss-Newton, per-segment step halving);
    return residuals, sensitivity rows, initial states and the per-segment normal matrices."""
    x0s = x0s.copy()
    seg_cost_prev = None
    step = np.zeros_like(x0s)
    for it in range(max_iter + 1):
        out_x, rows = prob.simulate(theta, currents, x0s)
        if not np.abs(out_x[:, 3:]).max(initial=0.0) <= DIVERGED:   # one pass when none diverged (or NaN)
            out_x[np.any(np.abs(out_x[:, 3:]) > DIVERGED, axis=1)] = np.nan
        r = prob.residuals(out_x, currents)
        if not np.isfinite(r.sum()):   # a sum is finite only when every term is (one pass, no mask)
            r[~np.isfinite(r)] = BAD_RESIDUAL
        # sensitivities beyond the finite range (or NaN): those rows count as diverged too
        huge = None if (rows.max(initial=0.0) <= JAC_MAX and rows.min(initial=0.0) >= -JAC_MAX) else \
            ~(np.abs(prob.jac_rows(rows, out_x)).max(axis=1, initial=0.0) <= JAC_MAX)
        if huge is not None:
            r[huge] = BAD_RESIDUAL
        seg_cost = prob.seg_sum(r * r)
        if seg_cost_prev is not None:
            worse = seg_cost > seg_cost_prev * (1 + 1e-12)
            if worse.any() and it < max_iter:
                x0s[worse] -= 0.5 * step[worse]
                step[worse] *= 0.5
                step[~worse] = 0.0
                if np.abs(step[worse]).max() > 1e-10:
                    continue
        J = prob.jac_rows(rows, out_x)
        if huge is not None:
            J[huge] = 0.0
        if not np.isfinite(J.sum()):
            J[~np.isfinite(J)] = 0.0
        Jx = J[:, :6]
        JtJ = prob.seg_gram(Jx, Jx)
        JtJ += (1e-9 * np.trace(JtJ, axis1=1, axis2=2)[:, None, None] + 1e-12) * np.eye(6)
        if it == max_iter or (seg_cost_prev is not None and
                              np.sum(seg_cost_prev) - np.sum(seg_cost) <= tol * np.sum(seg_cost)):
            return r, J, x0s, JtJ
        Jtr = prob.seg_gram(Jx, r[:, None])[:, :, 0]
        step = -np.linalg.solve(JtJ, Jtr[:, :, None])[:, :, 0]
        # Gauss-Newton's predicted decrease of r.r is -Jtr.step: stop when it is negligible
        if -np.sum(Jtr * step) <= 1e-2 * tol * np.sum(seg_cost):
            return r, J, x0s, JtJ
        seg_cost_prev = seg_cost
        x0s = x0s + step
    return r, J, x0s, JtJ


class _VP:
    """Variable-projection objective over [free model params, currents per run]."""

    def __init__(self, prob: Problem, theta0, free_mask, fit_current, x0s, currents0):
        self.prob = prob
        self.theta0 = np.asarray(theta0, float)
        self.free = np.asarray(free_mask, bool)
        self.fit_current = fit_current
        self.x0s = x0s.copy()
        self.currents0 = np.asarray(currents0, float)
        self._key = None
        self._ckey: bytes | None = None
        self._c: tuple[np.ndarray, np.ndarray] = (np.zeros((0, 0)), np.zeros(0))   # compress_lsq of _J, _r
        self._A = np.zeros((0, 1))   # [_J r]: _J is its view
        self.nfev = 0
        self.diverged = False

    def unpack(self, p):
        theta = self.theta0.copy()
        nf = int(self.free.sum())
        theta[self.free] = p[:nf]
        cur = p[nf:].reshape(-1, 2) if self.fit_current else self.currents0
        return theta, cur

    def pack(self, theta, cur):
        p = list(np.asarray(theta)[self.free])
        if self.fit_current:
            p += list(np.asarray(cur).ravel())
        return np.array(p, float)

    def _eval(self, p):
        key = p.tobytes()
        if key == self._key:
            return
        theta, cur = self.unpack(p)
        if (theta[0] <= 0 or theta[1] <= 0 or np.any(theta[2:5] <= 0)
                or theta[1] - theta[0] * theta[5] ** 2 <= 1e-3 * theta[1]
                or stiffness(theta) > MAX_STIFFNESS):   # outside the model's domain
            self._key, self._r = key, np.full(self.prob.n_res, 1e3)
            self._A = np.zeros((self.prob.n_res, len(p) + 1))
            self._J = self._A[:, :-1]
            self.diverged = True
            return
        with np.errstate(over="ignore", invalid="ignore"):
            r, J, x0s, JtJ = _inner(self.prob, theta, cur, self.x0s)
        self.diverged = bool(np.any(np.abs(r) >= BAD_RESIDUAL))
        self.nfev += 1
        if np.all(np.isfinite(r)):
            self.x0s = x0s
        prob = self.prob
        # global Jacobian columns, written into one array: the free parameters', then each
        # run's current (its rows, contiguous, from the current's columns; zero elsewhere);
        # one more column for the residuals, written by _compress (compress_lsq's [J r])
        nf = int(self.free.sum())
        A = np.empty((prob.n_res, len(p) + 1))
        G = A[:, :-1]
        G[:, :nf] = J[:, 6:12] if nf == 6 else J[:, 6:12][:, self.free]
        if self.fit_current:
            for ri in range(prob.n_runs):
                c, a, b = nf + 2 * ri, prob.r_run_start[ri], prob.r_run_start[ri + 1]
                G[:a, c:c + 2] = 0.0
                G[a:b, c:c + 2] = J[a:b, 12:14]
                G[b:, c:c + 2] = 0.0
        # project out the segment initial states (in place: G is this call's own array)
        Jx = J[:, :6]
        with np.errstate(over="ignore", invalid="ignore"):
            JtG = prob.seg_gram(Jx, G)
            coef = np.linalg.solve(JtJ, JtG)   # (nseg, 6, P); JtJ is regularised: positive definite
            for k in range(prob.n_seg):
                a, b = prob.r_start[k], prob.r_start[k + 1]
                G[a:b] -= Jx[a:b] @ coef[k]
        if not (np.isfinite(G.sum()) and np.isfinite(r.sum())):   # overflow: as outside the domain
            self._key, self._r = key, np.full(prob.n_res, 1e3)
            self._A = np.zeros((prob.n_res, len(p) + 1))
            self._J = self._A[:, :-1]
            self.diverged = True
            return
        self._key, self._r, self._J, self._A = key, r, G, A

    def fun(self, p):
        self._eval(p)
        r = self._r
        return np.where(np.isfinite(r), r, 1e6)

    def jac(self, p):
        self._eval(p)
        return self._J

    def _compress(self, p):
        self._eval(p)
        if self._ckey != self._key:
            self._ckey = self._key
            A = self._A           # [J r] in one array without copying J
            A[:, -1] = self.fun(p)
            self._c = _compress_stacked(A)

    def fun_small(self, p):
        """:meth:`fun` compressed to P + 1 rows (:func:`compress_lsq`): the same cost, gradient
        and Gauss-Newton matrix for :func:`scipy.optimize.least_squares` at a fraction of its
        work per iteration (its decompositions of the full Jacobian cost more than the rest)."""
        self._compress(p)
        return self._c[1]

    def jac_small(self, p):
        """:meth:`jac` compressed alike (:meth:`fun_small`)."""
        self._compress(p)
        return self._c[0]


def compress_lsq(J, r):
    """A least-squares problem of few columns compressed to ``P + 1`` rows with the same
    ``J^T J``, ``J^T r`` and ``r^T r`` (the triangular factor of [J r]: Q^T of the problem).

    Parameters
    ----------
    J : numpy.ndarray, shape (N, P)
        Jacobian (finite).
    r : numpy.ndarray, shape (N,)
        Residuals (finite).

    Returns
    -------
    (numpy.ndarray, numpy.ndarray)
        ``Jc`` (P + 1, P) and ``rc`` (P + 1,); ``Jc^T Jc = J^T J``, ``Jc^T rc = J^T r``,
        ``rc^T rc = r^T r``. From the Cholesky factor of the column-scaled Gram matrix when
        it is well conditioned, else from a QR decomposition. Numbers so large that their
        products overflow are scaled first (the same factor).

    Raises
    ------
    usvlog.errors.FitFailed
        If ``J`` or ``r`` is not finite.
    """
    return _compress_stacked(np.column_stack([J, r]))


def _compress_stacked(A):
    """:func:`compress_lsq` of ``A`` = [J r] (N, P + 1), C-contiguous.

    Raises :class:`~usvlog.errors.FitFailed` when ``A`` is not finite."""
    with np.errstate(over="ignore", invalid="ignore"):
        gram = A.T @ A
    if not np.isfinite(gram).all():
        if not np.isfinite(A).all():
            raise FitFailed("the fit's Jacobian or residuals are not finite (its simulation diverged)")
        # finite but so large that the products overflow: the same factor of the column-scaled problem
        s = np.abs(A).max(axis=0)
        s[s == 0] = 1.0
        Jc, rc = _compress_stacked(np.ascontiguousarray(A / s))
        R = np.column_stack([Jc, rc]) * s
        return np.ascontiguousarray(R[:, :-1]), np.ascontiguousarray(R[:, -1])
    d = np.sqrt(np.diag(gram))
    d[d == 0] = 1.0
    gs = gram / np.outer(d, d)
    ev = np.linalg.eigvalsh(gs)
    R = None
    if ev[0] > 1e-10 * ev[-1]:
        try:
            R = np.linalg.cholesky(gs).T * d      # A = Q R, R upper triangular
        except np.linalg.LinAlgError:
            R = None
    if R is None:
        R = scipy_qr(A, mode="r")[0][:A.shape[1]]
        if R.shape[0] < A.shape[1]:
            R = np.vstack([R, np.zeros((A.shape[1] - R.shape[0], A.shape[1]))])
    return np.ascontiguousarray(R[:, :-1]), np.ascontiguousarray(R[:, -1])


_PARAM_LO = np.array([1e-3, 1e-4, 1e-6, 1e-6, 1e-6, -np.inf])   # lower bounds of m, Iz, d11, d22, d33, xg


def _check_fit_input(runs: list[RunData], theta, currents) -> None:
    """FitFailed unless the start is finite and every run has thrust to integrate over."""
    if len(theta) != 6 or not np.all(np.isfinite(theta)):
        raise FitFailed(f"the start values {_fmt(theta)} are not six finite numbers")
    if not np.all(np.isfinite(currents)):
        raise FitFailed("the start currents are not finite")
    if not runs:
        raise FitFailed("no runs to fit")
    for i, r in enumerate(runs):
        if len(r.t_thrust) < 2 or not r.t_thrust[-1] > r.t_thrust[0]:
            raise FitFailed(f"run {i} ({r.source or 'log'}): less than two thrust samples in the fitted time: "
                            "nothing to integrate")


def _fmt(theta) -> str:
    return "(" + ", ".join(f"{x:.4g}" for x in np.ravel(np.asarray(theta, float))) + ")"


def _bounds(free_mask, n_cur, max_current=np.inf):
    """Box of [free params, currents]: inertias and damping positive, |current| per axis bounded."""
    lo = _PARAM_LO[free_mask]
    hi = np.full(len(lo), np.inf)
    return (np.concatenate([lo, np.full(n_cur, -max_current)]), np.concatenate([hi, np.full(n_cur, max_current)]))


def _group_scales(prob: Problem, robust, vel_weight: float) -> np.ndarray:
    """Noise scale per sensor group: the robust scatter, and for the velocity groups a factor
    that gives them ``vel_weight`` times the weight of the position rows in total."""
    out = np.asarray(robust, float).copy()
    n_pos = int(np.sum(prob.r_sensor <= 1))
    for k in (2, 3):
        n_k = int(np.sum(prob.r_sensor == k))
        if n_k and vel_weight > 0:
            out[k] /= np.sqrt(vel_weight * n_pos / (2 * n_k))
        elif n_k:
            out[k] = 1e12   # weight zero
    return out


def velocity_samples(t, vn, ve, r, step_s: float = VEL_STEP_S):
    """Every ``step_s`` of smoothed ground velocity (north, east, m/s) and yaw rate (rad/s) at
    times ``t`` (s), as the velocity measurements of :func:`fit_output_error`."""
    t = np.asarray(t, float)
    k = max(1, int(round(step_s / max(float(np.median(np.diff(t))), 1e-9)))) if len(t) > 1 else 1
    return t[::k], np.asarray(vn, float)[::k], np.asarray(ve, float)[::k], np.asarray(r, float)[::k]


def fit_output_error(runs: list[RunData], theta0, x0_fn, *, free_mask=None, fit_current=True,
                     currents0=None, segment_s=300.0, warm_segment_s=60.0, reweight=True,
                     max_nfev=60, verbose=0, warm_span_s=None, velocities=None, vel_weight=0.0,
                     max_current_mps=np.inf, threads: bool | Callable[[], bool] | None = None
                     ) -> OutputErrorResult:
    """Fit the model parameters (and per-run currents) to GPS and compass by output error.

    ``theta0``: starting (m, Iz, d11, d22, d33, xg); ``x0_fn(run_index, t_s) -> (6,)``
    initial-state guesses (n, e, psi, u, v, r) for segment starts.

    Parameters
    ----------
    runs : list of RunData
    theta0 : array_like, shape (6,)
        Starting m (kg), Iz (kg m^2), d11, d22 (kg/s), d33 (kg m^2/s), xg (m); fixed
        parameters keep these values.
    x0_fn : callable
        ``x0_fn(run_index, t_s)`` -> initial-state guess [n (m), e (m), psi (rad),
        u (m/s), v (m/s), r (rad/s)] at ``t_s`` s of that run.
    free_mask : array_like of bool, shape (6,), optional
        Which parameters to fit (default all).
    fit_current : bool, default True
        Fit a constant current per run.
    currents0 : array_like, shape (n_runs, 2), optional
        Starting (or, unfitted, fixed) currents north, east in m/s (default zeros).
    segment_s : float, default 300.0
        Segment length in s of the final fit.
    warm_segment_s : float, default 60.0
        Segment length in s of a warm-up fit (used when 0 < warm_segment_s < segment_s).
    reweight : bool, default True
        After each stage weight each sensor by its robust residual scatter.
    max_nfev : int, default 60
        Evaluation limit of each least-squares stage.
    verbose : int, default 0
        Passed to :func:`scipy.optimize.least_squares`.
    warm_span_s : float, optional
        Fit the warm-up stage only on the first ``warm_span_s`` s of each run.
    velocities : list, optional
        Per run None or (t (s), vn, ve (m/s over ground), r (rad/s)) smoothed velocities
        (:func:`velocity_samples`), fitted too so that a wrong current cannot buy a better
        position fit with absurd dynamics.
    vel_weight : float, default 0.0
        Total weight of the velocity rows relative to the GPS and compass rows (0: not fitted).
    max_current_mps : float, default inf
        Bound on each current component, m/s.
    threads : bool or callable, optional
        :attr:`Problem.threads` of its problems: integrate the segments in two threads
        (default: when a second CPU is spare; a callable is asked before each integration,
        e.g. by fits running in parallel: True once the others are done).

    Returns
    -------
    OutputErrorResult
        Standard errors come from the GPS and compass rows only (the velocities are
        derived from them: counting them again would overstate the information).
        ``diverged`` is True when the model's simulation left the finite range at the end.

    Raises
    ------
    usvlog.errors.FitFailed
        The start is not finite, a run has less than two thrust samples, there is no GNSS
        fix or compass heading to fit, or the fit's numbers left the finite range. (A
        simulation that diverges at some trial parameters is not an error: the fit steps
        back; at the solution it is ``diverged``.)
    """
    free = np.ones(6, bool) if free_mask is None else np.asarray(free_mask, bool)
    cur = np.zeros((len(runs), 2)) if currents0 is None else np.asarray(currents0, float)
    cur = np.clip(cur, -max_current_mps, max_current_mps)
    theta = np.asarray(theta0, float).copy()
    _check_fit_input(runs, theta, cur)
    # a free start below its bound (a near-zero mass or damping from a poor equation-error fit)
    # starts at the bound: the warm-up's box about the start stays a box
    theta = np.where(free, np.maximum(theta, _PARAM_LO * 1.01), theta)
    nfev = 0
    stages = [warm_segment_s, segment_s] if warm_segment_s and warm_segment_s < segment_s else [segment_s]
    robust = np.ones(4)
    x0_kin = x0_fn

    def problem(rr, seg_s):
        out = Problem(rr, seg_s, velocities if vel_weight > 0 else None)
        out.threads = threads
        return out

    for si, seg_s in enumerate(stages):
        last = si == len(stages) - 1
        runs_s = runs
        if not last and warm_span_s:
            # the warm-up only needs to get close: fit it on the first warm_span_s of each run
            runs_s = [r.window(r.t_thrust[0], r.t_thrust[0] + warm_span_s) for r in runs]
        prob = problem(runs_s, seg_s)
        if prob.n_res == 0:
            raise FitFailed("no GNSS fix or compass heading inside the fitted time: nothing to fit")
        prob.set_sensor_scale(_group_scales(prob, robust, vel_weight))
        x0s = prob.initial_states(x0_fn)
        vp = _VP(prob, theta, free, fit_current, x0s, cur)
        p0 = vp.pack(theta, cur)
        lo, hi = _bounds(free, len(p0) - int(free.sum()), max_current_mps)
        p0 = np.clip(p0, lo + 1e-9, hi)
        if not last:
            # keep the warm-up stage near the start: short segments leave slow modes weak
            th_lo = np.where(theta > 0, theta / 3, -1.0)
            th_hi = np.where(theta > 0, theta * 3, 1.0)
            th_lo[5], th_hi[5] = -abs(theta[5]) - 0.3, abs(theta[5]) + 0.3
            nf = int(free.sum())
            lo = lo.copy()
            hi = hi.copy()
            lo[:nf], hi[:nf] = np.maximum(th_lo[free], lo[:nf]), th_hi[free]
            p0 = np.clip(p0, lo + 1e-9, hi - 1e-9)
        sol = least_squares(vp.fun_small, p0, jac=vp.jac_small, bounds=(lo, hi), x_scale="jac", method="trf",
                            ftol=1e-8 if last else 1e-6, xtol=1e-8 if last else 1e-6,
                            gtol=1e-8 if last else 1e-6, max_nfev=max_nfev, verbose=verbose)
        nfev += vp.nfev
        theta, cur = vp.unpack(sol.x)
        vp._eval(sol.x)
        if reweight:   # each sensor weighted by its own (robust) residual scatter from here on
            robust = robust * np.asarray(_robust_scale(prob, vp._r))
        # capture initial states for the next stage
        x0_prev = (prob, vp.x0s.copy())

        theta_prev, cur_prev = theta.copy(), cur.copy()

        def x0_fn(run, t, _p=x0_prev, _theta=theta_prev, _cur=cur_prev):
            if t > _p[0].runs[run].t_thrust[-1] - 1.0:
                return x0_kin(run, t)
            return _state_at(_p[0], _p[1], _theta, _cur, run, t)
    # outliers (GPS jumps, compass glitches): drop measurements beyond OUTLIER_SIGMA robust
    # sigmas and solve again from where it stands (same segments, warm initial states)
    outliers = {"gps": 0, "compass": 0}
    for _ in range(3):
        sc = np.asarray(_robust_scale(prob, vp._r))
        bad = (np.abs(vp._r) > OUTLIER_SIGMA * sc[prob.r_sensor]) & (prob.r_sensor <= 1)
        if not bad.any():
            break
        runs, n_gps, n_comp = _drop_measurements(prob, runs, bad)
        outliers["gps"] += n_gps
        outliers["compass"] += n_comp
        prob = problem(runs, stages[-1])
        prob.set_sensor_scale(_group_scales(prob, robust, vel_weight))
        vp = _VP(prob, theta, free, fit_current, vp.x0s, cur)
        p0 = vp.pack(theta, cur)
        lo, hi = _bounds(free, len(p0) - int(free.sum()), max_current_mps)
        sol = least_squares(vp.fun_small, np.clip(p0, lo + 1e-9, hi), jac=vp.jac_small, bounds=(lo, hi), x_scale="jac",
                            method="trf", ftol=1e-8, xtol=1e-8, gtol=1e-8, max_nfev=max_nfev, verbose=verbose)
        nfev += vp.nfev
        theta, cur = vp.unpack(sol.x)
        vp._eval(sol.x)
    r, G = vp._r, vp._J
    diverged = bool(vp.diverged)
    pos = prob.r_sensor <= 1          # the raw measurements carry the information
    r, G = r[pos], G[pos]
    n_res = len(r)
    n_par = G.shape[1] + 6 * prob.n_seg
    sigma2 = float(r @ r) / max(n_res - n_par, 1)
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        colnorm = np.linalg.norm(G, axis=0)
        colnorm[colnorm == 0] = 1.0
        Gs = G / colnorm
        ok = bool(np.all(np.isfinite(Gs)) and np.all(np.isfinite(colnorm)) and np.isfinite(sigma2) and len(Gs))
        cond = float(np.linalg.cond(Gs)) if ok else float("inf")
        cov = sigma2 * np.linalg.pinv(Gs.T @ Gs) / np.outer(colnorm, colnorm) if np.isfinite(cond) else \
            np.full((G.shape[1], G.shape[1]), np.nan)
    names = tuple(n for n, f in zip(PARAM_NAMES, free) if f)
    if fit_current:
        names += tuple(f"current_{ax}_{i}" for i in range(len(runs)) for ax in ("n", "e"))
    rms = {k: float(np.sqrt(np.mean(vp._r[prob.r_sensor == i] ** 2)))
           for i, k in enumerate(SENSORS) if np.any(prob.r_sensor == i)}
    return OutputErrorResult(theta=theta, free=tuple(n for n, f in zip(PARAM_NAMES, free) if f),
                             currents=np.asarray(cur, float) if fit_current else np.zeros((len(runs), 2)),
                             cov=cov, names=names, cond=cond, sigma2=sigma2, rms=rms, n_residuals=n_res,
                             x0s=vp.x0s, nfev=nfev, outliers=outliers, diverged=diverged)


def _robust_scale(prob: Problem, r) -> tuple[float, ...]:
    """Per-sensor-group scatter of whitened residuals, 1.4826 median |r| (sigma for Gaussian noise)."""
    out = []
    for k in range(4):
        a = np.abs(r[prob.r_sensor == k])
        out.append(float(1.4826 * np.median(a)) if len(a) else 1.0)
    return tuple(x or 1.0 for x in out)


def _drop_measurements(prob: Problem, runs: list[RunData], bad_rows) -> tuple[list[RunData], int, int]:
    """Runs without the measurements behind the flagged residual rows."""
    m = np.unique(prob.r_meas[bad_rows])
    run_of = prob.seg_run[prob.meas_seg[m]]
    kind, t = prob.kind[m], prob.meas_t[m]
    out = []
    for i, run in enumerate(runs):
        tg = t[(run_of == i) & (kind == 0)]
        tc = t[(run_of == i) & (kind == 1)]
        g = ~np.isin(run.t_gps, tg)
        c = ~np.isin(run.t_compass, tc)
        out.append(replace(run, t_gps=run.t_gps[g], n_gps=run.n_gps[g], e_gps=run.e_gps[g],
                            sigma_gps=run.sigma_gps[g], t_compass=run.t_compass[c],
                            psi_compass=run.psi_compass[c], sigma_compass=run.sigma_compass[c]))
    return out, int((kind == 0).sum()), int((kind == 1).sum())


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
    # the command in force at t0: the last thrust sample at or before it (a log whose thrust and
    # navigation are stamped apart, e.g. a ROS bag's, starts the free run between two commands)
    i0 = int(np.clip(np.searchsorted(run.t_thrust, t0 + 1e-9, side="right") - 1, 0, len(run.t_thrust) - 1))
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
