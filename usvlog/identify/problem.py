"""The multiple-shooting problem of the output-error fit: runs cut into segments, residuals, sensitivities.

:class:`Problem` cuts each run's thrust grid into segments of ``segment_s`` seconds, orders
the measurements (GPS north/east, compass heading, and optionally smoothed ground velocity
and yaw rate) by segment, and indexes the residual rows; :meth:`Problem.simulate`
integrates every segment from its own initial state with the compiled kernel
(:func:`usvlog.identify.shoot.shoot`), and :meth:`Problem.residuals` /
:meth:`Problem.jac_rows` turn its states and sensitivities into noise-weighted residuals
and their Jacobian. The fit itself is :func:`usvlog.identify.output.fit_output_error`.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace

import numpy as np

from .._cpu import spare_cpu
from ..model.frames import ssa
from .data import RunData, coarse_thrust
from .shoot import NS, SENS_CUR_E, SENS_CUR_N, no_rows, shoot

MAX_DT = 0.05
# residual rows: GPS north, east; compass heading; ground velocity north, east; yaw rate
R_N, R_E, R_PSI, R_VN, R_VE, R_R = range(6)
SENSOR_OF_ROW = np.array([0, 0, 1, 2, 2, 3], np.int8)
SENSORS = ("gps", "compass", "velocity", "yaw_rate")
# one-sigma of the smoothed velocities as measurements (m/s, rad/s) before reweighting
VEL_SIGMA = (0.05, 0.02)
MAX_STIFFNESS = 50.0    # 1/s: a velocity time constant under 20 ms is no boat's
DIVERGED = 1e3          # |u|, |v| (m/s) or |r| (rad/s) beyond this: the simulation diverged
JAC_MAX = 1e30          # |d(weighted residual)/d(x0, parameter)| beyond this: the sensitivities grew
                        # exponentially (a diverging linearisation); its products would overflow
BAD_RESIDUAL = 1e6      # weighted residual of a measurement whose simulation diverged (Jacobian row 0)



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
    ``edges``: per run its segments' boundaries (indices into its coarse grid, first and last
    included), default :func:`segment_edges` (a block of a run: :func:`problem_blocks`).
    """

    def __init__(self, runs: list[RunData], segment_s: float, velocities=None,
                 vel_sigma: tuple[float, float] = VEL_SIGMA, edges=None):
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
            cuts = segment_edges(t, segment_s) if edges is None else edges[ri]
            for a, b in zip(cuts[:-1], cuts[1:]):
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
                    m_kind.append(np.full(len(tt), sensor, np.int8))
                    m_val.append(val)
                    m_sig.append(sig)
                    m_seg.append(np.full(len(tt), k, np.int32))
            tg.append(t)
            tu.append(run.tau_u)
            tr.append(run.tau_r)
            off += n
        self.runs = runs
        self.n_runs = len(runs)
        # one run: its own coarse arrays (concatenating one array would copy it)
        self.tg, self.tau_u, self.tau_r = ((a[0] if len(a) == 1 else np.concatenate(a)) for a in (tg, tu, tr))
        self.seg_i0 = np.array(seg_i0, np.int64)
        self.seg_i1 = np.array(seg_i1, np.int64)
        self.seg_run = np.array(seg_run, np.int64)
        t = np.concatenate(m_t)
        kind = np.concatenate(m_kind)
        val = np.concatenate(m_val)
        sig = np.concatenate(m_sig)
        seg = np.concatenate(m_seg)
        order = np.lexsort((t, seg))
        self.meas_t, self.kind, self.meas_seg = t[order], kind[order], seg[order]
        val, sig = val[order], sig[order]   # made into the residual rows' values and noise below
        self.meas_ptr = np.searchsorted(self.meas_seg, np.arange(len(seg_i0) + 1)).astype(np.int64)
        self.n_seg = len(seg_i0)
        gi = np.flatnonzero(self.kind == 0)
        ci = np.flatnonzero(self.kind == 1)
        vi = np.flatnonzero(self.kind == 2)
        # residual rows: (measurement index, quantity): R_N, R_E (GPS), R_PSI (compass),
        # R_VN, R_VE (ground velocity), R_R (yaw rate); indices int32 and quantities int8 (a
        # dozen arrays of a row each, whole-run: the same numbers in less memory)
        r_meas = np.concatenate([gi, gi, ci, vi, vi, vi]).astype(np.int32)
        r_state = np.concatenate([np.full(len(gi), R_N, np.int8), np.full(len(gi), R_E, np.int8),
                                  np.full(len(ci), R_PSI, np.int8), np.full(len(vi), R_VN, np.int8),
                                  np.full(len(vi), R_VE, np.int8), np.full(len(vi), R_R, np.int8)])
        r_seg = self.meas_seg[r_meas]
        o = np.argsort(r_seg, kind="stable")
        self.r_meas, self.r_state, self.r_seg = r_meas[o], r_state[o], r_seg[o]
        self.r_sensor = SENSOR_OF_ROW[self.r_state]   # 0 gps, 1 compass, 2 ground velocity, 3 yaw rate
        col = np.array([0, 1, 0, 0, 1, 2])[self.r_state]
        self.r_val = val[self.r_meas, col]
        self.r_sig0 = np.where(self.r_sensor == 2, vel_sigma[0], np.where(self.r_sensor == 3, vel_sigma[1],
                                                                         sig[self.r_meas]))
        self.r_start = np.searchsorted(self.r_seg, np.arange(self.n_seg + 1))
        # each run's residual rows, r_run_start[i]:r_run_start[i + 1] (segments are in run order)
        self.r_run_start = np.searchsorted(self.seg_run[self.r_seg], np.arange(self.n_runs + 1))
        self.n_res = len(self.r_meas)
        self.r_srow = self.r_meas * 6 + np.minimum(self.r_state, 2)   # its state in out_x.reshape(-1)
        self.r_psi = np.flatnonzero(self.r_state == R_PSI).astype(np.int32)    # heading rows (wrapped)
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
        self.e_dst = np.concatenate([pos, self.n_res + np.arange(4 * len(vmeas))])[o].astype(np.int32)
        self.e_q = np.concatenate([np.minimum(self.r_state[pos], 2), np.tile(np.arange(2, 6), len(vmeas))])[o] \
            .astype(np.int8)
        # residual row, -1 velocity
        self.e_res = np.concatenate([pos, np.full(4 * len(vmeas), -1)])[o].astype(np.int32)
        self.e_ptr = np.searchsorted(e_meas[o], np.arange(len(self.meas_t) + 1)).astype(np.int64)
        # the velocity measurements, the run of each, and per velocity row quantity (vn, ve, r)
        # its rows and their measurements' positions in vmeas
        self.v_meas, self.v_run = vmeas, self.seg_run[self.meas_seg[vmeas]]
        self.v_rows = tuple(np.flatnonzero(self.r_state == q) for q in (R_VN, R_VE, R_R))
        self.v_k = tuple(np.searchsorted(vmeas, self.r_meas[rr]) for rr in self.v_rows)
        self._set_weights(1.0 / self.r_sig0)
        self._rows: np.ndarray | None = None
        self.threads: bool | None = None
        """Integrate the segments in two threads (the same numbers; default: with more than one
        CPU and segment)."""

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

        # earns its place (issue 32): a 1-hour `usvlog identify` 14 % faster with the second thread
        # (median of 4 paired on/off runs, -6 to 20 %, load 2.3-2.9); docs/performance.md
        threads = self.threads
        if threads is None:
            threads = spare_cpu() and self.n_seg > 1
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

    def free_rows(self) -> None:
        """Let go of :meth:`simulate`'s sensitivity rows (a whole-run buffer; the next call with
        ``sens`` makes it again)."""
        self._rows = None

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


def segment_edges(t: np.ndarray, segment_s: float) -> list[int]:
    """Boundaries (indices into the grid ``t``, first and last included) of a run's segments:
    every ``segment_s`` from its start, the last one taking a remainder under half a segment."""
    edges = [0]
    tcut = t[0] + segment_s
    while tcut < t[-1] - 0.5 * segment_s:
        edges.append(int(np.searchsorted(t, tcut)))
        tcut += segment_s
    edges.append(len(t) - 1)
    return sorted(set(edges))


BLOCK_S = 1800.0
"""Log time (s) of a block of :func:`problem_blocks`: the output-error fit holds one block's
sensitivities, states and Jacobian at a time (~60 MB an hour of log when whole)."""


def problem_blocks(runs: list[RunData], segment_s: float, velocities=None, vel_sigma: tuple[float, float] = VEL_SIGMA,
                   block_s: float = BLOCK_S) -> list[tuple[Problem, int]]:
    """The runs' segments (those of ``Problem(runs, segment_s, velocities)``) in blocks of whole
    segments of about ``block_s`` s of one run each: (the block's Problem, its run's index).

    A block keeps its run's thrust from its first segment's start to its last one's end
    (the coarse grid's samples, views) and the measurements in between, up to but not at its
    end where another block follows (at it in the run's last block): each measurement in one
    block, in the segment the whole run's Problem has it in."""
    out = []
    for ri, run in enumerate(runs):
        run = coarse_run(run)
        vel = velocities[ri] if velocities is not None else None
        t = run.t_thrust
        edges = segment_edges(t, segment_s)
        per = max(1, int(round(block_s / segment_s)))
        for j in range(0, len(edges) - 1, per):
            cuts = edges[j:j + per + 1]
            a, b = cuts[0], cuts[-1]
            last = b == len(t) - 1
            lo, hi = t[a], t[b]
            g, c = (_Within(tt).select(lo, hi, last) for tt in (run.t_gps, run.t_compass))
            part = replace(run, t_thrust=t[a:b + 1], tau_u=run.tau_u[a:b + 1], tau_r=run.tau_r[a:b + 1],
                           t_gps=run.t_gps[g], n_gps=run.n_gps[g], e_gps=run.e_gps[g], sigma_gps=run.sigma_gps[g],
                           t_compass=run.t_compass[c], psi_compass=run.psi_compass[c],
                           sigma_compass=run.sigma_compass[c])
            v = None
            if vel is not None:
                sv = _Within(vel[0]).select(lo, hi, last)
                v = [tuple(x[sv] for x in vel)]
            out.append((Problem([part], segment_s, v, vel_sigma, edges=[[i - a for i in cuts]]), ri))
    return out


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



def _fmt(theta) -> str:
    return "(" + ", ".join(f"{x:.4g}" for x in np.ravel(np.asarray(theta, float))) + ")"
