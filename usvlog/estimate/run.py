"""Running the filter and the smoother over a :class:`~usvlog.estimate.layout.Problem`.

:func:`run_fast` is the numba-compiled forward EKF and extended RTS smoother
(:mod:`usvlog.estimate.kernels`), the smoother's blocks re-run from checkpoints
(:func:`smooth`); :func:`run_reference_path` is
the same on the filterpy reference (:mod:`usvlog.estimate.reference`), slow, for checks. Both
return a :class:`RawRun` of arrays. :func:`forward_loglik` is the forward pass's likelihood
alone, which :func:`tune_process_noise` maximises and the latency search and the filter-error
identifier use.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..model.vessel import VesselParams
from . import kernels
from .kernels import (
    DYNAMIC,
    GNSS,
)
from .layout import POSITION_STD_LIMIT_M, Problem, head_problem, process_noise
from .settings import EstimateSettings

RowSink = Callable[[int, np.ndarray, np.ndarray, np.ndarray], None]
"""Takes a block of smoothed rows: ``sink(r0, XS, SD, PB)``, rows r0 .. r0 + len(XS) (see :func:`run_fast`)."""


@dataclass(frozen=True)
class RawRun:
    """Raw arrays of one filter (and smoother) run, on the steps of a :class:`Problem` asked for
    (every step, or the rows given to :func:`run_fast`: R of them).

    ``X``/``XS`` forward and smoothed states (R, nx), ``SDf``/``SDs`` their one-sigma,
    ``PBf``/``PBs`` their covariance block of states 2..4 (R, 3, 3; (0, 3, 3) when not
    asked for); ``innov`` (M, 4) [res_0, res_1, nis, log-likelihood term] per measurement,
    ``accepted`` (M,) 0 rejected / 1 accepted / 2 accepted after too many rejections;
    ``loglik`` their sum; ``resets`` (N,) the divergence guard's re-initialisations
    (``kernels.REINIT_*``, 0 none); ``first_bad`` the first step (of all N) whose forward or
    smoothed state or one-sigma is not finite or whose position one-sigma exceeds
    :data:`POSITION_STD_LIMIT_M`, -1 for none. Without the smoother the smoothed arrays are
    the forward ones.
    """

    X: np.ndarray          # forward posteriors (N, nx)
    SDf: np.ndarray        # their one-sigma
    PBf: np.ndarray        # their covariance block of states 2..4 (N, 3, 3)
    XS: np.ndarray         # smoothed (N, nx)
    SDs: np.ndarray
    PBs: np.ndarray
    innov: np.ndarray      # (M, 4)
    accepted: np.ndarray   # (M,) 0/1/2
    loglik: float
    resets: np.ndarray     # (N,) why the state was re-initialised at a step (kernels.REINIT_*), 0 for none
    first_bad: int = -1    # first step with an unusable state (see _check_finite), -1 for none


def run_fast(pb: Problem, q: np.ndarray, max_rej: int, smoother: bool, rows: np.ndarray | None = None,
             covariance_block: bool = True, columns: int | None = None, forward: bool = True,
             sink: RowSink | None = None) -> RawRun:
    """Forward EKF (and RTS smoother) with the numba-compiled kernels.

    Memory is that of the rows asked for, not of the steps: the smoother makes the forward
    posteriors again a block at a time from checkpoints of the forward pass (the same
    numbers; see :func:`smooth`).

    Parameters
    ----------
    pb : Problem
    q : numpy.ndarray
        Diagonal of the continuous process-noise intensity (:func:`process_noise`).
    max_rej : int
        Rejections in a row after which a sensor's next measurement is forced in.
    smoother : bool
        Run the smoother after the forward pass.
    rows : numpy.ndarray, optional
        (N,) bool: the steps whose states are returned (e.g. ``pb.is_grid``); default all.
    covariance_block : bool
        Return the covariance block of states 2..4 (``PBf``, ``PBs``).
    columns : int, optional
        Return the first ``columns`` states (and their one-sigma) only; default all.
    forward : bool
        Return the forward posteriors (``X``, ``SDf``, ``PBf``); False (with the smoother
        only): not stored, they have no rows (memory and time, when only the smoothed
        states are wanted; every other output is the same).
    sink : callable, optional
        With the smoother and ``forward`` False: the smoothed rows are handed to
        ``sink(r0, XS, SD, PB)`` a block of rows at a time (rows r0 .., from the last block
        to the first; the arrays are reused after the call) instead of being returned
        (``XS``, ``SDs``, ``PBs`` have no rows): memory of a block, not of the rows.

    Returns
    -------
    RawRun
    """
    if not (forward or smoother):
        raise ValueError("run_fast: without the smoother the forward posteriors are the result (forward=True)")
    if sink is not None and forward:
        raise ValueError("run_fast: a sink takes the smoothed rows only (smoother=True, forward=False)")
    N, nx, M = len(pb.dts), pb.nx, len(pb.mstep)
    nc = nx if columns is None else columns
    if rows is None:
        row = np.arange(N, dtype=np.int64)
    else:
        row = np.cumsum(rows, dtype=np.int64) - 1
        row[~np.asarray(rows, bool)] = -1
    R = int(row.max()) + 1 if N else 0
    npb = R if covariance_block else 0
    Rf = R if forward else 0
    X, SDf, PBf = np.empty((Rf, nc)), np.empty((Rf, nc)), np.empty((npb if forward else 0, 3, 3))
    C = -(-N // kernels.SMOOTH_BLOCK) if smoother else 0   # checkpoints, for the smoother
    CX, CP = np.empty((C, nx)), np.empty((C, nx, nx))
    CI, CF = np.empty((C, kernels.N_IST), np.int64), np.empty((C, kernels.NFS))
    innov = np.zeros((M, 4))
    acc = np.zeros(M, np.int8)
    resets = np.zeros(N, np.int8)
    bad_f, bad_s = np.full(1, -1, np.int64), np.full(1, -1, np.int64)
    args = (pb.x0, pb.P0, pb.dts, pb.taus, pb.qjump, pb.mstep, pb.mkind, pb.mz, pb.mR, pb.prm, pb.model, q, pb.gates,
            max_rej, POSITION_STD_LIMIT_M ** 2, reinit_nis(pb))
    ll = kernels.forward(*args, row if forward else np.empty(0, np.int64), X, SDf, PBf, innov, acc, resets,
                         CX, CP, CI, CF, bad_f)
    if smoother:
        Rs = R if sink is None else 0
        XS, SDs, PBs = np.empty((Rs, nc)), np.empty((Rs, nc)), np.empty((min(npb, Rs), 3, 3))
        smooth(args, (innov, acc, resets, CX, CP, CI, CF), row, XS, SDs, PBs, bad_s,
               None if sink is None else (sink, nc, npb > 0))
    else:
        XS, SDs, PBs = X, SDf, PBf
    bad = [int(b[0]) for b in (bad_f, bad_s) if b[0] >= 0]
    return RawRun(X, SDf, PBf, XS, SDs, PBs, innov, acc, float(ll), resets, min(bad) if bad else -1)


def smooth(args: tuple, run: tuple, row: np.ndarray, XS: np.ndarray, SD: np.ndarray, PB: np.ndarray,
           bad: np.ndarray, sink: tuple[RowSink, int, bool] | None = None) -> None:
    """The extended RTS smoother after ``kernels.forward``, block by block from the end.

    Each block's forward posteriors are made again from its checkpoint
    (``kernels.smooth_rerun``) and smoothed backwards (``kernels.smooth_back``), in the
    calling thread. (A second thread taking the re-runs was measured in issue 32: a 1-hour
    ``usvlog estimate`` 2.2 % slower with it, so it was taken out; docs/performance.md.)

    Parameters
    ----------
    args : tuple
        The arguments ``kernels.forward`` took before its outputs (x0 .. reinit_nis).
    run : tuple
        Its innov, accepted, resets and checkpoints CX, CP, CI, CF.
    row : numpy.ndarray
        (N,) int64: the output row of each step, -1 for none.
    XS, SD, PB : numpy.ndarray
        Outputs: smoothed states (R, columns), their one-sigma and covariance block (R, 3, 3)
        or (0, 3, 3).
    bad : numpy.ndarray
        (1,) int64: the first step whose smoothed state is unusable, -1 for none.
    sink : tuple, optional
        (sink, columns, covariance block wanted): each block's rows go to ``sink`` (see
        :func:`run_fast`) instead of XS, SD, PB.
    """
    x0, dts, pos_var_limit = args[0], args[2], args[14]
    N, nx = len(dts), len(x0)
    blocks = -(-N // kernels.SMOOTH_BLOCK)
    bad[0] = -1
    if not blocks:
        return
    b = kernels.SmoothBuffers(nx)
    xs, Ps, xpn, Ppn, Cn = np.zeros(nx), np.zeros((nx, nx)), np.zeros(nx), np.zeros((nx, nx)), np.zeros((nx, nx))
    resets = run[2]
    if sink is not None:   # a block's rows at a time, handed on
        give, nc, cov = sink
        n = kernels.SMOOTH_BLOCK
        XS, SD, PB = np.empty((n, nc)), np.empty((n, nc)), np.empty((n if cov else 0, 3, 3))
    for c in range(blocks - 1, -1, -1):
        kernels.smooth_rerun(c, *args, *run, b.BX, b.BP, b.BXp, b.BPp, b.BC)
        r0, r1 = 0, 0
        if sink is not None:
            mine = row[c * kernels.SMOOTH_BLOCK:(c + 1) * kernels.SMOOTH_BLOCK]
            mine = mine[mine >= 0]
            r0, r1 = (int(mine[0]), int(mine[-1]) + 1) if len(mine) else (0, 0)
        kernels.smooth_back(c, N, resets, b.BX, b.BP, b.BXp, b.BPp, b.BC, xs, Ps, xpn, Ppn, Cn, pos_var_limit,
                            row, r0, XS, SD, PB, bad)
        if sink is not None and r1 > r0:
            give(r0, XS[:r1 - r0], SD[:r1 - r0], PB[:r1 - r0])


REINIT_GATE_FACTOR = 100.0
"""A GNSS fix forced in after ``max_consecutive_rejects`` rejections whose NIS exceeds this
many times its gate re-initialises the filter from the measurements (it lost the track)."""


def reinit_nis(pb: Problem) -> float:
    """NIS of a forced-in GNSS fix above which the filter restarts (0: never, the gate off)."""
    g = float(pb.gates[GNSS])
    return REINIT_GATE_FACTOR * g if math.isfinite(g) else 0.0


def forward_loglik(pb: Problem, q: np.ndarray, max_rej: int) -> float:
    """Innovation log-likelihood of the forward pass (no states stored)."""
    nx, M = pb.nx, len(pb.mstep)
    none = np.empty((0, nx))
    return float(kernels.forward(pb.x0, pb.P0, pb.dts, pb.taus, pb.qjump, pb.mstep, pb.mkind, pb.mz, pb.mR,
                                 pb.prm, pb.model, q, pb.gates, max_rej, POSITION_STD_LIMIT_M ** 2, reinit_nis(pb),
                                 np.empty(0, np.int64), none, none, np.empty((0, 3, 3)), np.zeros((M, 4)),
                                 np.zeros(M, np.int8), np.zeros(len(pb.dts), np.int8), none, np.empty((0, nx, nx)),
                                 np.empty((0, kernels.N_IST), np.int64), np.empty((0, kernels.NFS)),
                                 np.empty(1, np.int64)))


def run_reference_path(pb: Problem, q: np.ndarray, max_rej: int, smoother: bool, rows: np.ndarray | None = None,
                       covariance_block: bool = True, columns: int | None = None, forward: bool = True,
                       sink: RowSink | None = None) -> RawRun:
    """As :func:`run_fast`, on the filterpy reference path (:mod:`.reference`): slow, for checks (a
    ``sink`` takes every row at once)."""
    from .reference import run_reference  # heavy: filterpy and scipy.stats, only for the reference path

    params = VesselParams(**dict(zip(("m", "Iz", "d11", "d22", "d33", "xg"), map(float, pb.prm))))
    out = run_reference(pb.x0, pb.P0, pb.dts, pb.taus, pb.qjump, pb.mstep, pb.mkind, pb.mz, pb.mR, params,
                        pb.model == DYNAMIC, q, pb.gates, max_rej, smoother,   # (kinematic: by nx)
                        POSITION_STD_LIMIT_M ** 2, reinit_nis(pb))
    X, SDf, PBf, XS, SDs, PBs, innov, acc, ll, resets = out
    bad = np.flatnonzero(_unusable(X, SDf) | _unusable(XS, SDs))
    keep = slice(None) if rows is None else np.asarray(rows, bool)
    X, SDf, XS, SDs = (a[keep, :columns] for a in (X, SDf, XS, SDs))
    PBf, PBs = (PBf[keep], PBs[keep]) if covariance_block else (PBf[:0], PBs[:0])
    if not forward and smoother:
        X, SDf, PBf = X[:0], SDf[:0], PBf[:0]
    if sink is not None:
        sink(0, XS, SDs, PBs)
        XS, SDs, PBs = XS[:0], SDs[:0], PBs[:0]
    return RawRun(X, SDf, PBf, XS, SDs, PBs, innov, acc, float(ll), resets, int(bad[0]) if len(bad) else -1)


def _unusable(X: np.ndarray, SD: np.ndarray) -> np.ndarray:
    """(N,) bool: a state or one-sigma not finite, or a position one-sigma beyond
    :data:`POSITION_STD_LIMIT_M` (as ``kernels._bad_step``)."""
    with np.errstate(invalid="ignore"):
        finite = np.isfinite(X).all(axis=1) & np.isfinite(SD).all(axis=1)
        return ~finite | (SD[:, :2] > POSITION_STD_LIMIT_M).any(axis=1)


def tune_process_noise(pb: Problem, settings: EstimateSettings, max_steps: int = 60_000) -> dict:
    """q_uv, q_r (and q_current) maximising the forward innovation likelihood.

    Searched in log10 space with Nelder-Mead on the first ``max_steps`` steps.

    Parameters
    ----------
    pb : Problem
    settings : EstimateSettings
        Model and starting intensities.
    max_steps : int, default 60000
        Only this many filter steps enter the likelihood (speed).

    Returns
    -------
    dict
        ``q_uv``, ``q_r`` (and ``q_current`` with current states) in the units of
        :class:`EstimateSettings`, ``loglik`` at the optimum, ``evaluations``.
    """
    sub = head_problem(pb, max_steps)
    nx = pb.nx
    start = [math.log10(settings.q_uv_value), math.log10(settings.q_r_value)]
    if settings.model == "dynamic" and nx == 8:
        start.append(math.log10(settings.q_current))

    def cost(z):
        z = np.clip(z, -12, 2)
        q = process_noise(settings, *(10.0 ** z))
        return -forward_loglik(sub, q, settings.max_consecutive_rejects)

    from scipy.optimize import minimize  # heavy: scipy.optimize, only when tuning

    res = minimize(cost, np.array(start), method="Nelder-Mead",
                   options={"xatol": 0.05, "fatol": 0.5, "maxfev": 120})
    z = np.clip(res.x, -12, 2)
    out = {"q_uv": float(10 ** z[0]), "q_r": float(10 ** z[1])}
    if len(z) == 3:
        out["q_current"] = float(10 ** z[2])
    out["loglik"] = float(-res.fun)
    out["evaluations"] = int(res.nfev)
    return out
