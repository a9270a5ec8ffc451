"""Variable projection of the output-error fit: segment initial states solved, then projected out.

For given model parameters and currents, :func:`_inner` solves each segment's initial
state by Gauss-Newton (per-segment step halving); :class:`_VP` is the objective
:func:`scipy.optimize.least_squares` sees over [free model parameters, currents per run],
its Jacobian with the initial states projected out (so its normal matrix is the marginal
information of the parameters of interest), compressed to a few rows by
:func:`compress_lsq`.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import qr as scipy_qr

from ..errors import FitFailed
from .problem import BAD_RESIDUAL, DIVERGED, JAC_MAX, MAX_STIFFNESS, Problem, stiffness


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
    """Variable-projection objective over [free model params, currents per run].

    ``prob``: the Problem, or its blocks (:func:`~usvlog.identify.problem.problem_blocks`:
    (block, run index) pairs), evaluated one after another: each block's residuals kept, its
    projected Jacobian with its residual column folded into the triangular factor that
    :meth:`fun_small` and :meth:`jac_small` give (:func:`compress_lsq`, of the rows so far and
    the block's) and let go with the block's sensitivities before the next block's are made.
    The whole Jacobian (:meth:`jac`) only of a Problem given whole."""

    def __init__(self, prob: Problem | list[tuple[Problem, int]], theta0, free_mask, fit_current, x0s, currents0):
        self.whole = isinstance(prob, Problem)
        self.blocks = [(prob, np.arange(prob.n_runs))] if isinstance(prob, Problem) else \
            [(blk, np.array([ri])) for blk, ri in prob]
        self.seg_start = np.cumsum([0] + [blk.n_seg for blk, _ in self.blocks])
        self.n_res = sum(blk.n_res for blk, _ in self.blocks)
        self.theta0 = np.asarray(theta0, float)
        self.free = np.asarray(free_mask, bool)
        self.fit_current = fit_current
        self.x0s = x0s.copy()
        self.currents0 = np.asarray(currents0, float)
        self._key = None
        self._r = np.zeros(0)
        self._c: tuple[np.ndarray, np.ndarray] = (np.zeros((0, 0)), np.zeros(0))   # compress_lsq of [G r]
        self._c_pos: tuple[np.ndarray, np.ndarray] = (np.zeros((0, 0)), np.zeros(0))   # of its GPS, compass rows
        self._J = np.zeros((0, 0))   # the projected Jacobian (a Problem given whole)
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
        # the last evaluation's arrays let go first: not two alive at once
        self._key, self._r, self._J = None, np.zeros(0), np.zeros((0, 0))
        theta, cur = self.unpack(p)
        if (theta[0] <= 0 or theta[1] <= 0 or np.any(theta[2:5] <= 0)
                or theta[1] - theta[0] * theta[5] ** 2 <= 1e-3 * theta[1]
                or stiffness(theta) > MAX_STIFFNESS):   # outside the model's domain
            self._outside(key, len(p))
            return
        self.nfev += 1
        rs, x0_new, R, R_pos = [], self.x0s.copy(), None, None
        for i, (blk, runs) in enumerate(self.blocks):
            s0, s1 = self.seg_start[i], self.seg_start[i + 1]
            with np.errstate(over="ignore", invalid="ignore"):
                r, J, x0s, JtJ = _inner(blk, theta, cur[runs], self.x0s[s0:s1])
            if np.all(np.isfinite(r)):
                x0_new[s0:s1] = x0s
            A = self._projected(blk, runs, r, J, JtJ, len(p))
            if not self.whole:
                blk.free_rows()          # (made again for the block's next evaluation)
            if A is None:                # overflow: as outside the domain
                self._outside(key, len(p))
                return
            R = _fold(R, A)
            R_pos = _fold(R_pos, A[blk.r_sensor <= 1])   # the raw measurements (the covariance's rows)
            rs.append(r)
            if self.whole:
                self._J = A[:, :-1]
        self.x0s = x0_new
        self._r = rs[0] if len(rs) == 1 else np.concatenate(rs)
        self.diverged = bool(np.any(np.abs(self._r) >= BAD_RESIDUAL))
        self._key = key
        n = len(p) + 1   # (no rows at all: a zero factor)
        R = np.zeros((n, n)) if R is None else R
        R_pos = np.zeros((n, n)) if R_pos is None else R_pos
        self._c = (np.ascontiguousarray(R[:, :-1]), np.ascontiguousarray(R[:, -1]))
        self._c_pos = (np.ascontiguousarray(R_pos[:, :-1]), np.ascontiguousarray(R_pos[:, -1]))

    def _projected(self, prob: Problem, runs, r, J, JtJ, n_p: int):
        """[G r] of a block (n_res, P + 1): the global Jacobian columns (the free parameters',
        then each run's current: its rows, from the current's columns; zero elsewhere) with each
        segment's initial state projected out; None when not finite."""
        nf = int(self.free.sum())
        A = np.empty((prob.n_res, n_p + 1))
        G = A[:, :-1]
        G[:, :nf] = J[:, 6:12] if nf == 6 else J[:, 6:12][:, self.free]
        if self.fit_current:
            G[:, nf:] = 0.0
            for ri, run in enumerate(runs):
                c, a, b = nf + 2 * run, prob.r_run_start[ri], prob.r_run_start[ri + 1]
                G[a:b, c:c + 2] = J[a:b, 12:14]
        # project out the segment initial states (in place: G is this call's own array)
        Jx = J[:, :6]
        with np.errstate(over="ignore", invalid="ignore"):
            JtG = prob.seg_gram(Jx, G)
            coef = np.linalg.solve(JtJ, JtG)   # (nseg, 6, P); JtJ is regularised: positive definite
            for k in range(prob.n_seg):
                a, b = prob.r_start[k], prob.r_start[k + 1]
                G[a:b] -= Jx[a:b] @ coef[k]
        A[:, -1] = r
        return A if np.isfinite(A.sum()) else None

    def _outside(self, key, n_p: int) -> None:
        """An evaluation outside the model's domain (or whose numbers overflowed): every
        residual 1e3, the Jacobian zero."""
        self._key, self._r = key, np.full(self.n_res, 1e3)
        self._J = np.zeros((self.n_res, n_p)) if self.whole else np.zeros((0, n_p))
        self._c = (np.zeros((n_p + 1, n_p)), np.zeros(n_p + 1))
        self._c[1][-1] = np.sqrt(self._r @ self._r)
        self._c_pos = (np.zeros((n_p + 1, n_p)), np.zeros(n_p + 1))
        self.diverged = True

    def fun(self, p):
        self._eval(p)
        r = self._r
        return np.where(np.isfinite(r), r, 1e6)

    def jac(self, p):
        """The projected Jacobian (n_res, P) of a Problem given whole."""
        if not self.whole:
            raise ValueError("_VP.jac: the whole Jacobian of a problem in blocks is not kept")
        self._eval(p)
        return self._J

    def fun_small(self, p):
        """:meth:`fun` compressed to P + 1 rows (:func:`compress_lsq`): the same cost, gradient
        and Gauss-Newton matrix for :func:`scipy.optimize.least_squares` at a fraction of its
        work per iteration (its decompositions of the full Jacobian cost more than the rest)."""
        self._eval(p)
        return self._c[1]

    def jac_small(self, p):
        """:meth:`jac` compressed alike (:meth:`fun_small`)."""
        self._eval(p)
        return self._c[0]

    def jac_positions(self, p):
        """The projected Jacobian's GPS and compass rows compressed to P + 1 rows (the same
        G^T G): the information the raw measurements carry."""
        self._eval(p)
        return self._c_pos[0]


def _fold(R, A):
    """[Jc rc] of :func:`compress_lsq` of the rows of ``R`` (None: none yet) and of ``A`` ([J r],
    C-contiguous): the rows so far, as few, and a block's."""
    if len(A) == 0:
        return R
    return triangular_factor(A if R is None else np.vstack([R, A]))


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
    R = triangular_factor(A)
    return np.ascontiguousarray(R[:, :-1]), np.ascontiguousarray(R[:, -1])


def triangular_factor(A):
    """The upper triangular R (K, K) of A = Q R, ``A`` (N, K) finite: the same ``A^T A = R^T R``
    in K rows. From the Cholesky factor of the column-scaled Gram matrix when it is well
    conditioned, else from a QR decomposition (whose diagonal may be negative). Numbers so
    large that their products overflow are scaled first (the same factor).

    Raises :class:`~usvlog.errors.FitFailed` when ``A`` is not finite."""
    with np.errstate(over="ignore", invalid="ignore"):
        gram = A.T @ A
    if not np.isfinite(gram).all():
        if not np.isfinite(A).all():
            raise FitFailed("the fit's Jacobian or residuals are not finite (its simulation diverged)")
        # finite but so large that the products overflow: the same factor of the column-scaled problem
        s = np.abs(A).max(axis=0)
        s[s == 0] = 1.0
        return triangular_factor(np.ascontiguousarray(A / s)) * s
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
    return R
