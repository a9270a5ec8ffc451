"""Validation that suits field data: k-step-ahead fit, excitation and residual whiteness.

A free run over a whole field run (the fit % of :class:`usvlog.identify.validation.Validation`)
lets every unmodelled gust, wave and current change accumulate: after a few minutes the
model's heading has drifted and its velocities are compared with another manoeuvre. System
identification practice (Ljung, *System Identification*, ch. 16; MATLAB ``compare(..., k)``)
also scores the k-step-ahead prediction: the model is re-initialised from the measured
(here: smoothed) state every H seconds and predicts only H seconds ahead. A good model scores
high at short horizons; a wrong steady-state (a damping off by 20 %) shows as a fit that
falls as H grows.

Two further checks tell whether a fit % means anything:

* :func:`excited` / :func:`excited_channels`: a channel whose spread over the validation part
  is no more than its noise (sway on a straight run, yaw rate on a pure surge run) gives a fit
  % of noise, whatever the model;
* :func:`residual_whiteness`: the normalised autocorrelation of prediction residuals against
  the 99 % bounds +-2.58/sqrt(N) (MATLAB ``resid``; Ljung, sec. 16.6), with the Ljung-Box
  portmanteau statistic. Residuals that are not white leave dynamics unexplained.

Pure numpy: arrays in, plain numbers or frozen dataclasses out. Times are s from the run's
``t0_ns``; states [n (m), e (m), psi (rad), u (m/s), v (m/s), r (rad/s)].
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy.special import chdtrc

from ..model.stats import fit_percent
from .data import RunData
from .output import simulate_run
from .smooth import KinStates

# Default one-sigma noise of the smoothed states, used to decide whether a channel is excited.
# They are the order of the error of the kinematic smoother's velocities on a small boat with a
# ~1.5 m GNSS and a ~2 deg compass: 0.05 m/s is the one-sigma output-error fitting already gives
# the smoothed velocities (usvlog.identify.output.VEL_SIGMA); 0.01 rad/s (0.6 deg/s) is what a
# 2 deg compass differentiated over the smoother's few-second window leaves on the yaw rate.
NOISE_U_MPS = 0.05
NOISE_V_MPS = 0.05
NOISE_R_RADPS = 0.01
NOISE = {"u": NOISE_U_MPS, "v": NOISE_V_MPS, "r": NOISE_R_RADPS}
# A channel of pure noise has a spread (std) equal to its noise. "Excited" asks for a signal of
# its own whose spread is at least the noise's: the channel's std above sqrt(2) times the noise.
# (The best fit % a perfect model can reach on such a channel is then about 1 - 1/sqrt(2) = 29 %.)
EXCITATION_RATIO = math.sqrt(2.0)
Z99 = 2.58          # two-sided 99 % point of the standard normal (the bounds of MATLAB resid)
ALARM_RATE = 0.01   # accepted false-alarm rate of the whiteness verdict
WHITENESS_STEP_S = 5.0   # the identifier's whiteness check: prediction step (s), residuals a smoother window apart
WHITENESS_LAGS = 25      # ... and its largest lag (residuals), fewer on a short held-out part
CHANNELS = ("u", "v", "r")

Simulate = Callable[..., np.ndarray]   # (run, theta, current, x0, t0, times) -> (len(times), 6)


def _windows(run: RunData, ks: KinStates, horizon_s: float, t_from: float | None):
    """Window starts on the thrust grid and, per window, the smoothed-state times it predicts.

    Starts are t0, t0 + H, t0 + 2 H, ... moved onto the next thrust sample (a free run starts
    on the thrust grid, :func:`simulate_run`); window k predicts the smoothed-state times in
    (start_k, start_{k+1}] (the start itself would be a perfect "prediction"). Returns
    (starts (K,), times (N,), ptr (K + 1,)): window k's times are times[ptr[k]:ptr[k + 1]].
    """
    if not horizon_s > 0:
        raise ValueError(f"horizon {horizon_s} s must be > 0")
    t0 = max(run.t_thrust[0], ks.t[0]) if t_from is None else max(float(t_from), run.t_thrust[0], ks.t[0])
    t_end = min(run.t_thrust[-1], ks.t[-1])
    nominal = t0 + horizon_s * np.arange(max(int(math.ceil((t_end - t0) / horizon_s - 1e-9)), 1))
    idx = np.searchsorted(run.t_thrust, nominal - 1e-9)
    starts = np.unique(run.t_thrust[idx[idx < len(run.t_thrust)]])
    starts = starts[starts < t_end]
    times = ks.t[(ks.t > starts[0] + 1e-9) & (ks.t <= t_end + 1e-9)] if len(starts) else ks.t[:0]
    ptr = np.searchsorted(times, np.append(starts, t_end) + 1e-9)
    ptr[-1] = len(times)
    return starts, times, ptr


def _predict(run, ks, theta, current, horizon_s, t_from, simulate):
    """(t, measured, predicted, ptr, x0s) of :func:`predict_ahead`; window k predicts rows
    ptr[k]:ptr[k + 1] from the smoothed state x0s[k]."""
    cur = (float(current[0]), float(current[1]))
    starts, t, ptr = _windows(run, ks, float(horizon_s), t_from)
    x0s = ks.at(starts, cur)
    pred = np.full((len(t), 6), np.nan)
    # one free run per window: 720 windows of an hour at H = 5 s take ~0.05 s (the kernel stops at
    # the window's last time), so batching them into one kernel call would buy nothing measurable
    with np.errstate(over="ignore", invalid="ignore"):
        for k, t_k in enumerate(starts):
            a, b = ptr[k], ptr[k + 1]
            if b > a:
                pred[a:b] = simulate(run, theta, cur, x0s[k], float(t_k), t[a:b])
    pred[~np.all(np.isfinite(pred), axis=1)] = np.nan
    return t, ks.at(t, cur), pred, ptr, x0s


def predict_ahead(run: RunData, ks: KinStates, theta, current, horizon_s: float, *, t_from: float | None = None,
                  simulate: Simulate = simulate_run):
    """k-step-ahead predictions: the model re-initialised every ``horizon_s`` from the smoothed state.

    Parameters
    ----------
    run : RunData
        The run's thrust (the model is driven by ``run.tau_u``, ``run.tau_r``).
    ks : KinStates
        Smoothed states of the run (initial states and the measurement).
    theta : array_like
        Model parameters as ``simulate`` takes them (m, Iz, d11, d22, d33, xg for the paper model).
    current : (float, float)
        Current north, east in m/s (u, v relative to the water).
    horizon_s : float
        H, the prediction horizon in s.
    t_from : float, optional
        First window start in s (default: where both thrust and smoothed states begin).
    simulate : callable, default :func:`usvlog.identify.output.simulate_run`
        Free run ``simulate(run, theta, current, x0, t0, times) -> (len(times), 6)``, e.g.
        :func:`usvlog.identify.extended_oe.free_run_full` for the extended model.

    Returns
    -------
    t : numpy.ndarray, shape (N,)
        Predicted times, s (the smoothed-state grid after the first start).
    measured, predicted : numpy.ndarray, shape (N, 6)
        Smoothed and predicted [n, e, psi, u, v, r] there (prediction NaN where it diverged).
    """
    t, meas, pred, _, _ = _predict(run, ks, theta, current, horizon_s, t_from, simulate)
    return t, meas, pred


def displacement_fit_ahead(run: RunData, ks: KinStates, theta, current, horizon_s: float, *,
                           t_from: float | None = None, simulate: Simulate = simulate_run) -> float:
    """Fit % of where the boat goes in the next ``horizon_s``: the model re-initialised every H s
    from the smoothed state (:func:`predict_ahead`), its displacement (n, e) from each window's
    start scored against the smoothed one, ``100 (1 - |d - dhat| / |d - mean d|)``.

    A free run's track over minutes is the integral of every small error of speed, heading and
    current; over one horizon it says how well the model predicts the motion a path follower
    plans with. NaN when a window's prediction diverged or nothing moved.

    Parameters
    ----------
    run, ks, theta, current, horizon_s, t_from, simulate
        As :func:`predict_ahead`.

    Returns
    -------
    float
    """
    _, meas, pred, ptr, x0s = _predict(run, ks, theta, current, horizon_s, t_from, simulate)
    if len(pred) == 0 or np.isnan(pred).any():
        return float("nan")
    origin = np.repeat(x0s[:, :2], np.diff(ptr), axis=0)
    return float(fit_percent(meas[:, :2] - origin, pred[:, :2] - origin))


def fit_percent_ahead(run: RunData, ks: KinStates, theta, current, horizons_s: Sequence[float] = (5.0, 10.0, 30.0),
                      t_from: float | None = None, simulate: Simulate = simulate_run) -> dict:
    """k-step-ahead fit % of u, v, r per horizon (:func:`predict_ahead` scored with ``fit_percent``).

    For each horizon H the predictions of all windows, concatenated, are scored against the
    smoothed u, v, r: ``100 (1 - |y - yhat| / |y - mean y|)``.

    Parameters
    ----------
    run, ks, theta, current, t_from, simulate
        As :func:`predict_ahead`.
    horizons_s : sequence of float, default (5.0, 10.0, 30.0)
        Horizons H in s.

    Returns
    -------
    dict
        ``{f"{H:g}": {"u": %, "v": %, "r": %}}``, e.g. ``{"5": {...}, "10": {...}, "30": {...}}``.
        A channel's fit is NaN when it is constant (no spread to explain) or when any window's
        prediction diverged (a failed model, not a number).
    """
    out = {}
    for h in horizons_s:
        _, meas, pred = predict_ahead(run, ks, theta, current, float(h), t_from=t_from, simulate=simulate)
        diverged = bool(np.isnan(pred).any()) or len(pred) == 0
        out[f"{float(h):g}"] = {c: (float("nan") if diverged else fit_percent(meas[:, 3 + i], pred[:, 3 + i]))
                                for i, c in enumerate(CHANNELS)}
    return out


def one_step_residuals(run: RunData, ks: KinStates, theta, current, step_s: float = 0.1, *,
                       t_from: float | None = None, simulate: Simulate = simulate_run):
    """Residuals of the prediction ``step_s`` ahead: smoothed minus predicted u, v, r.

    The model is started from the smoothed state every ``step_s`` and the residual taken at
    the end of each step (non-overlapping windows; :func:`predict_ahead` with H = ``step_s``).
    About 1 s per hour of log at 0.1 s. Mind that smoothed states are themselves correlated
    over the smoother's window (seconds): residuals 0.1 s apart are not expected white even
    for the true model; test whiteness on residuals a smoother window apart (``step_s`` of a
    few s, or ``residuals[::k]``).

    Parameters
    ----------
    run, ks, theta, current, t_from, simulate
        As :func:`predict_ahead`.
    step_s : float, default 0.1
        Prediction step in s (one grid step of the smoothed states by default).

    Returns
    -------
    t : numpy.ndarray, shape (N,)
        End of each step, s.
    residuals : numpy.ndarray, shape (N, 3)
        Smoothed minus predicted u (m/s), v (m/s), r (rad/s).
    """
    t, meas, pred, ptr, _ = _predict(run, ks, theta, current, step_s, t_from, simulate)
    last = ptr[1:][ptr[1:] > ptr[:-1]] - 1      # each window's last predicted time
    return t[last], meas[last, 3:] - pred[last, 3:]


def excited(y, noise: float, ratio: float = EXCITATION_RATIO) -> bool:
    """Whether a channel varies beyond its noise: std(y) > ``ratio`` x ``noise``.

    Parameters
    ----------
    y : array_like
        The channel's samples over the validation part (non-finite ones ignored).
    noise : float
        Its noise level (one sigma, the channel's unit).
    ratio : float, default EXCITATION_RATIO (sqrt 2)
        Pure noise has std = noise; the default asks for a signal spread of at least the
        noise on top of it.

    Returns
    -------
    bool
        False when fewer than 2 finite samples.
    """
    y = np.asarray(y, float).ravel()
    y = y[np.isfinite(y)]
    return bool(len(y) > 1 and np.std(y) > ratio * noise)


def excited_channels(nu, noise: dict | None = None, ratio: float = EXCITATION_RATIO) -> dict:
    """Per channel u, v, r: whether the validation part excites it (:func:`excited`).

    Parameters
    ----------
    nu : array_like, shape (N, 3)
        u (m/s), v (m/s), r (rad/s) over the validation part (e.g. ``ks.nu(current)``).
    noise : dict, optional
        Noise per channel ("u", "v", "r"); missing ones default to NOISE_U_MPS, NOISE_V_MPS,
        NOISE_R_RADPS.
    ratio : float, default EXCITATION_RATIO

    Returns
    -------
    dict
        ``{"u": bool, "v": bool, "r": bool}``; False means the channel's fit % is noise.
    """
    return {c: e.excited for c, e in excitation(nu, noise, ratio).items()}


def smoother_noise(sd) -> dict:
    """Noise levels of u, v, r from the smoother's own one-sigma (:attr:`KinStates.sd`).

    The estimator's RTS one-sigma, with its process noise tuned to the run as identification
    tunes it, matches the smoothed states' real error against the truth: measured (error std /
    rms one-sigma) on Fossen's Otter, two runs: u 1.21 and 1.12, v 0.94 and 1.11, r 1.01 and
    1.23; on the paper's vessel u 0.92, r 1.02 (v 2.4 there: its lag, not noise). So the rms of
    that one-sigma over the validation part is the noise a channel's spread is judged against.

    Parameters
    ----------
    sd : array_like, shape (N, 3), or None
        One-sigma of u (m/s), v (m/s), r (rad/s) per sample; None: not reported.

    Returns
    -------
    dict
        ``{"u": float, "v": float, "r": float}``; the defaults (NOISE) where ``sd`` is None or
        has no finite value in a column.
    """
    if sd is None:
        return dict(NOISE)
    sd = np.asarray(sd, float)
    out = {}
    for i, c in enumerate(CHANNELS):
        col = sd[:, i][np.isfinite(sd[:, i])] if len(sd) else np.zeros(0)
        out[c] = float(np.sqrt(np.mean(col ** 2))) if len(col) else NOISE[c]
    return out


@dataclass(frozen=True, kw_only=True)
class Excitation:
    """How far the validation part moves one channel beyond its noise (:func:`excitation`).

    ``spread``: std of the channel there (its unit); ``noise``: its noise level (one sigma);
    ``excited``: ``spread > ratio x noise`` (:func:`excited`).
    """

    spread: float
    noise: float
    excited: bool

    def to_dict(self) -> dict:
        """Plain numbers for JSON."""
        return {"spread": self.spread, "noise": self.noise, "excited": self.excited}


def excitation(nu, noise: dict | None = None, ratio: float = EXCITATION_RATIO) -> dict:
    """Per channel u, v, r: its spread over the validation part against its noise.

    Parameters
    ----------
    nu : array_like, shape (N, 3)
        u (m/s), v (m/s), r (rad/s) over the validation part.
    noise : dict, optional
        Noise per channel (e.g. :func:`smoother_noise`); missing ones default to NOISE.
    ratio : float, default EXCITATION_RATIO

    Returns
    -------
    dict
        ``{"u": Excitation, "v": Excitation, "r": Excitation}``.
    """
    lv = {**NOISE, **(noise or {})}
    nu = np.asarray(nu, float)
    out = {}
    for i, c in enumerate(CHANNELS):
        y = nu[:, i][np.isfinite(nu[:, i])]
        spread = float(np.std(y)) if len(y) > 1 else 0.0
        out[c] = Excitation(spread=spread, noise=float(lv[c]), excited=excited(y, lv[c], ratio))
    return out


@dataclass(frozen=True, kw_only=True)
class WhitenessResult:
    """Result of :func:`residual_whiteness`.

    ``lags`` (1..max_lag) with ``acf``: normalised autocorrelation of the residuals there;
    ``bound``: the 99 % bound 2.58/sqrt(n) of a white sequence; ``outside``: lags with
    |acf| > bound and ``fraction_outside`` of them; ``allowed``: how many lags may be outside
    while a white sequence would exceed that count with under 1 % probability; ``white``:
    ``outside <= allowed``; ``q_stat``, ``p_value``: Ljung-Box statistic over the lags and its
    chi-square (max_lag degrees of freedom) tail probability; ``n``: finite residuals used.
    """

    lags: np.ndarray
    acf: np.ndarray
    bound: float
    outside: int
    fraction_outside: float
    allowed: int
    white: bool
    q_stat: float
    p_value: float
    n: int

    def to_dataframe(self) -> pd.DataFrame:
        """One row per lag: lag, acf, outside (|acf| > bound)."""
        return pd.DataFrame({"lag": self.lags, "acf": self.acf, "outside": np.abs(self.acf) > self.bound})


def _allowed_outside(n_lags: int, p: float = ALARM_RATE) -> int:
    """Smallest count k with P(Binomial(n_lags, p) > k) < ALARM_RATE: under whiteness each lag
    is outside its 99 % bound with probability p, (asymptotically) independently."""
    tail = 1.0
    for k in range(n_lags + 1):
        tail -= math.comb(n_lags, k) * p ** k * (1 - p) ** (n_lags - k)
        if tail < ALARM_RATE:
            return k
    return n_lags


def residual_whiteness(residuals, max_lag: int = 25) -> WhitenessResult:
    """Whiteness test of prediction residuals (MATLAB ``resid``, Ljung sec. 16.6).

    acf(k) = sum_t e_t e_{t+k} / sum_t e_t^2 of the mean-removed residuals, k = 1..max_lag,
    against +-2.58/sqrt(n); white when no more lags are outside than a white sequence would put
    there with 99 % probability (about 1 % of the lags plus the binomial allowance: 2 of 25).

    Parameters
    ----------
    residuals : array_like, shape (n,)
        One channel's residuals in time order on a uniform step (non-finite ones are dropped,
        which joins the pieces around them).
    max_lag : int, default 25
        Largest lag (samples).

    Returns
    -------
    WhitenessResult

    Raises
    ------
    ValueError
        If fewer than 2 max_lag finite residuals are given, or all are equal.
    """
    e = np.asarray(residuals, float).ravel()
    e = e[np.isfinite(e)]
    n = len(e)
    if n < 2 * max_lag or max_lag < 1:
        raise ValueError(f"whiteness: {n} finite residuals for max_lag {max_lag} (need at least {2 * max_lag})")
    e = e - e.mean()
    c0 = float(e @ e)
    if c0 <= 0:
        raise ValueError("whiteness: the residuals are constant")
    lags = np.arange(1, max_lag + 1)
    acf = np.array([float(e[:-k] @ e[k:]) / c0 for k in lags])
    bound = Z99 / math.sqrt(n)
    outside = int((np.abs(acf) > bound).sum())
    allowed = _allowed_outside(max_lag)
    q = float(n * (n + 2) * np.sum(acf ** 2 / (n - lags)))
    return WhitenessResult(lags=lags, acf=acf, bound=bound, outside=outside, fraction_outside=outside / max_lag,
                           allowed=allowed, white=outside <= allowed, q_stat=q, p_value=float(chdtrc(max_lag, q)),
                           n=n)


__all__ = ["WHITENESS_LAGS", "WHITENESS_STEP_S", "displacement_fit_ahead", "fit_percent_ahead", "predict_ahead",
           "one_step_residuals", "excited", "excited_channels", "excitation", "Excitation", "smoother_noise",
           "residual_whiteness", "WhitenessResult",
           "NOISE_U_MPS", "NOISE_V_MPS", "NOISE_R_RADPS"]
