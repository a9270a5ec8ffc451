"""Smoothed kinematic states of a run: the one place identification asks for them.

Uses the estimation package's kinematic smoother when it is installed
(``usvlog.estimate``); otherwise a local polynomial (Savitzky-Golay) smoother of the
GNSS positions and compass heading on a uniform grid. Either way the result is the
over-ground motion: positions, heading, ground velocity in NED and yaw rate.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.linalg import lstsq
from scipy.ndimage import convolve1d

from ..errors import FitFailed, UsvlogError
from ..estimate import EstimateSettings
from ..estimate.layout import STATE_TOPIC, THRUST_TOPIC
from ..estimate.problem import ThrustFrames, build_problem
from ..estimate.run import tune_process_noise
from ..estimate.windowed import WindowedEstimate
from ..model.frames import ssa
from ..model.vessel import default_vessel
from .data import RunData, run_thrust, within
from .seen import SeenLog

GRID_DT = 0.1
MIN_SAMPLES = 5   # a local cubic needs a window of at least five samples


@dataclass(frozen=True, kw_only=True)
class KinStates:
    """Smoothed over-ground states of a run on a uniform grid.

    ``t``: s from the run's ``t0_ns``; ``n``, ``e``: position in m; ``psi``: heading in
    rad, unwrapped; ``vn``, ``ve``: ground velocity north, east in m/s; ``r``: yaw rate in
    rad/s; ``source``: the smoother used (``usvlog.estimate`` or ``savgol``); ``sd``: the
    smoother's own one-sigma of u, v, r (N, 3) where it reports one (the estimator does, its
    RTS covariance; ``savgol`` does not: None).
    """

    t: np.ndarray       # s from the run's t0, uniform grid
    n: np.ndarray
    e: np.ndarray
    psi: np.ndarray     # unwrapped
    vn: np.ndarray      # ground velocity, NED
    ve: np.ndarray
    r: np.ndarray
    source: str
    sd: np.ndarray | None = field(default=None, repr=False, compare=False)   # (N, 3) one-sigma of u, v, r
    # smooths a free run (t, sim, current) as these states were smoothed (None: not possible)
    smoother: Callable | None = field(default=None, repr=False, compare=False)
    # (current, the six columns :meth:`at` interpolates) of its last call: a fit asks for the
    # states at every segment start with one current
    _cols: tuple | None = field(default=None, init=False, repr=False, compare=False)

    def nu(self, current=(0.0, 0.0)):
        """Body velocities relative to the water for a constant current (N, 3).

        Parameters
        ----------
        current : (float, float), default (0.0, 0.0)
            Current north, east in m/s.

        Returns
        -------
        numpy.ndarray, shape (N, 3)
            [u (m/s), v (m/s), r (rad/s)].
        """
        c, s = np.cos(self.psi), np.sin(self.psi)
        wn, we = self.vn - current[0], self.ve - current[1]
        return np.stack([c * wn + s * we, -s * wn + c * we, self.r], -1)

    def at(self, t, current=(0.0, 0.0)):
        """Interpolated state (n, e, psi, u, v, r) at time(s) t.

        Parameters
        ----------
        t : float or array_like
            Time(s) in s from the run's ``t0_ns``.
        current : (float, float), default (0.0, 0.0)
            Current north, east in m/s (u, v are relative to the water).

        Returns
        -------
        numpy.ndarray, shape (..., 6)
            n (m), e (m), psi (rad, unwrapped), u (m/s), v (m/s), r (rad/s).
        """
        if len(self.t) == 0:
            raise FitFailed("no smoothed states in this part of the run (no GNSS fix and compass heading "
                            "overlap there)")
        key = (float(current[0]), float(current[1]))
        last = self._cols
        if last is None or last[0] != key:
            nu = self.nu(current)
            last = (key, (self.n, self.e, self.psi, nu[:, 0], nu[:, 1], nu[:, 2]))
            object.__setattr__(self, "_cols", last)   # a cache, not state (frozen dataclass)
        return np.stack([np.interp(t, self.t, c) for c in last[1]], -1)

    def free_run_times(self, t0: float, t_thrust_end: float) -> np.ndarray:
        """Times (s) a free run is compared over: the states' from ``t0`` while there is thrust
        to drive it (up to ``t_thrust_end``, the last thrust sample, s). GNSS stamped late, or
        logged on after the thruster log ends, reaches past it: a free run there has no input."""
        return self.t[(self.t >= t0) & (self.t <= t_thrust_end)]

    def window(self, t_lo, t_hi) -> KinStates:
        """The states with ``t_lo <= t <= t_hi`` (s).

        Raises :class:`~usvlog.errors.FitFailed` when fewer than MIN_SAMPLES are there (the
        GNSS fixes and compass headings do not cover that part of the run): nothing to fit
        or validate on."""
        k = within(self.t, t_lo, t_hi)
        n = len(self.t[k])
        if n < MIN_SAMPLES:
            span = f"{t_lo:.1f} s onward" if t_hi == np.inf else f"{t_lo:.1f} .. {t_hi:.1f} s"
            raise FitFailed(f"{n} smoothed sample(s) in {span} of the run: its GNSS fixes and compass "
                            "headings do not cover that part (nothing to fit or validate on there)")
        return KinStates(t=self.t[k], n=self.n[k], e=self.e[k], psi=self.psi[k], vn=self.vn[k],
                         ve=self.ve[k], r=self.r[k], source=self.source, smoother=self.smoother,
                         sd=None if self.sd is None else self.sd[k])

    def trimmed(self) -> KinStates:
        """These states with a smoother that keeps a copy of only their own span of the recorded log
        (:meth:`usvlog.identify.seen.SeenLog.window`), not the whole run's: a window of the run
        validated on lets the rest of the log go. The same free runs are smoothed the same."""
        sm = self.smoother
        if not isinstance(sm, FreeRunSmoother) or len(self.t) == 0:
            return self
        return replace(self, smoother=sm.window(float(self.t[0]), float(self.t[-1])))

    def seen(self, t, sim, current=(0.0, 0.0)) -> np.ndarray | None:
        """A free run as these states' smoother shows it (:mod:`usvlog.identify.seen`).

        The measurements it is compared with are these states themselves, smoothed over the
        whole run (smoothed again over the free run's span alone, their start-up transient
        cost the true model of a 60 s run 70 points of u: measured, and not done).

        Parameters
        ----------
        t : numpy.ndarray, shape (N,)
            Times of the free run (s from the run's ``t0_ns``).
        sim : numpy.ndarray, shape (N, 6)
            n, e (m), psi (rad), u, v (m/s, relative to the water), r (rad/s).
        current : (float, float), default (0.0, 0.0)
            Current north, east (m/s) of the free run.

        Returns
        -------
        numpy.ndarray, shape (N, 6) or None
            The smoothed free run at ``t`` (u, v relative to ``current``); None when these
            states have no smoother to repeat or it could not smooth the free run (too
            short, not finite).
        """
        if self.smoother is None or len(t) < MIN_SAMPLES or not np.all(np.isfinite(sim)):
            return None
        try:
            ks = self.smoother(np.asarray(t, float), np.asarray(sim, float), current)
        except UsvlogError:
            return None
        return ks.at(t, current) if ks is not None and len(ks.t) >= MIN_SAMPLES else None


def _savgol_coeffs(window: int, polyorder: int, deriv: int, delta: float) -> np.ndarray:
    """Convolution coefficients of the centred local polynomial fit (scipy's ``savgol_coeffs``)."""
    if deriv > polyorder:
        return np.zeros(window)
    half, rem = divmod(window, 2)
    pos = half if rem else half - 0.5
    x = np.arange(-pos, window - pos, dtype=np.float64)[::-1]
    A = x ** np.arange(polyorder + 1, dtype=np.float64).reshape(-1, 1)
    y = np.zeros(polyorder + 1)
    y[deriv] = float(math.factorial(deriv)) / (delta ** deriv)
    return lstsq(A, y, cond=np.finfo(np.float64).eps * max(A.shape))[0]


def _polyfit(x: np.ndarray, y: np.ndarray, deg: int) -> np.ndarray:
    """Least-squares polynomial coefficients, highest power first, one column per column of y."""
    lhs = x[:, None] ** np.arange(deg + 1, dtype=x.dtype)[::-1][None, :]
    scale = np.sqrt(np.sum(lhs * lhs, axis=0))
    lhs /= scale
    c = lstsq(lhs, y, cond=x.shape[0] * np.finfo(x.dtype).eps)[0]
    return (c.T / scale).T


def _fit_edge(x, lo: int, hi: int, i_lo: int, i_hi: int, axis: int, polyorder: int, deriv: int,
              delta: float, y: np.ndarray) -> None:
    """Samples ``i_lo:i_hi`` of ``y`` from one polynomial fitted to samples ``lo:hi`` of ``x``."""
    edge = np.swapaxes(x, axis, 0)[lo:hi]
    p = _polyfit(np.arange(0, hi - lo, dtype=x.dtype), edge.reshape(edge.shape[0], -1), polyorder)
    if deriv > 0:
        n = p.shape[0]
        if n <= deriv:
            p = np.zeros_like(p[:1])
        else:
            p = p[:-deriv].copy()
            for k in range(deriv):
                p *= np.arange(n - k - 1, deriv - k - 1, -1, dtype=p.dtype).reshape((n - deriv,) + (1,) * (p.ndim - 1))
    i = np.arange(i_lo - lo, i_hi - lo, dtype=p.dtype).reshape(-1, 1)
    v = np.zeros_like(i)
    for j in range(p.shape[0]):   # Horner, as numpy's polyval
        v = v * i + p[j]
    shp = list(np.swapaxes(y, axis, 0).shape)
    np.swapaxes(y, axis, 0)[i_lo:i_hi] = (v / (delta ** deriv)).reshape(i_hi - i_lo, *shp[1:])


def savgol_filter(x, window_length: int, polyorder: int, deriv: int = 0, delta: float = 1.0,
                  axis: int = -1) -> np.ndarray:
    """Savitzky-Golay filter with polynomial edges: ``scipy.signal.savgol_filter(...,
    mode="interp")`` computed the same way, operation for operation (the same values, bit
    for bit), without importing ``scipy.signal`` (about 0.5 s of start-up, with the
    ``scipy.stats`` it loads) for the one function identification uses.

    Parameters
    ----------
    x : array_like
        The samples (on a uniform grid).
    window_length : int
        Samples in each local fit (at most ``x``'s length along ``axis``).
    polyorder : int
        Degree of the local polynomial.
    deriv : int
        Derivative order (0: the smoothed values).
    delta : float
        Sample spacing (the derivative's time unit, e.g. s).
    axis : int
        The axis along which to filter.

    Returns
    -------
    numpy.ndarray
        The filtered samples (float64, or float32 for float32 input), the shape of ``x``.
    """
    x = np.asarray(x)
    if x.dtype != np.float64 and x.dtype != np.float32:
        x = x.astype(np.float64)
    n = x.shape[axis]
    if window_length > n:
        raise ValueError("If mode is 'interp', window_length must be less than or equal to the size of x.")
    y = convolve1d(x, _savgol_coeffs(window_length, polyorder, deriv, delta), axis=axis, mode="constant")
    half = window_length // 2
    _fit_edge(x, 0, window_length, 0, half, axis, polyorder, deriv, delta, y)
    _fit_edge(x, n - window_length, n, n - half, n, axis, polyorder, deriv, delta, y)
    return y


def _odd(n):
    """The odd window length (samples) at or above ``n``, at least MIN_SAMPLES (a finite ``n``)."""
    n = max(int(n), MIN_SAMPLES)
    return n if n % 2 else n + 1


def _window(t, window_s: float, what: str) -> tuple[float, int]:
    """(sample spacing (s), odd window length) of a local cubic over ``window_s`` on the grid ``t``,
    at most the samples there are; FitFailed when they are too few or the grid is not increasing."""
    t = np.asarray(t, float)
    if len(t) < MIN_SAMPLES:
        raise FitFailed(f"{what}: {len(t)} smoothed sample(s) (at least {MIN_SAMPLES} are needed): "
                        "too short a stretch of data")
    dt = float(np.median(np.diff(t)))
    if not (math.isfinite(dt) and dt > 0):
        raise FitFailed(f"{what}: the time grid of the smoothed samples is not increasing (median step {dt} s)")
    return dt, min(_odd(min(window_s / dt, len(t))), _odd(len(t) - 2))


def savgol_states(run: RunData, *, pos_window_s=16.0, psi_window_s=6.0) -> KinStates:
    """Local cubic fits to GNSS positions and unwrapped compass heading on a 10 Hz grid."""
    if len(run.t_gps) < 2 or len(run.t_compass) < 2:
        raise FitFailed(f"{run.source or 'run'}: {len(run.t_gps)} GNSS fix(es) and {len(run.t_compass)} compass "
                        "heading(s): too few to smooth")
    t0 = max(run.t_gps[0], run.t_compass[0])
    t1 = min(run.t_gps[-1], run.t_compass[-1])
    t = np.arange(t0, t1 + 1e-9, GRID_DT)
    if len(t) < MIN_SAMPLES:
        raise FitFailed(f"{run.source or 'run'}: GNSS and compass overlap for {max(t1 - t0, 0.0):.2f} s only: "
                        "too short to smooth")
    n = np.interp(t, run.t_gps, run.n_gps)
    e = np.interp(t, run.t_gps, run.e_gps)
    psi = np.interp(t, run.t_compass, np.unwrap(run.psi_compass))
    wp, wh = _odd(pos_window_s / GRID_DT), _odd(psi_window_s / GRID_DT)
    wp, wh = min(wp, _odd(len(t) - 2)), min(wh, _odd(len(t) - 2))
    kw = dict(polyorder=3)
    return KinStates(t=t, n=savgol_filter(n, wp, **kw), e=savgol_filter(e, wp, **kw),
                     psi=savgol_filter(psi, wh, **kw),
                     vn=savgol_filter(n, wp, deriv=1, delta=GRID_DT, **kw),
                     ve=savgol_filter(e, wp, deriv=1, delta=GRID_DT, **kw),
                     r=savgol_filter(psi, wh, deriv=1, delta=GRID_DT, **kw), source="savgol")


def kinematic_states(log, run: RunData, vessel=None, *, tune: bool = False) -> KinStates:
    """Smoothed over-ground states of a run (the estimator's kinematic EKF + RTS smoother).

    The smoother's process noise is tuned to the run (``tune``: the innovation likelihood's
    maximum, :func:`usvlog.estimate.run.tune_process_noise`, where it is above the default):
    the default suits a gentle boat, and on one that accelerates hard its smoothed speed
    trails the true one by seconds.
    The states carry their smoother (:meth:`KinStates.seen`): a free run is smoothed with
    the same settings, without tuning again.
    A ``log`` without its ``/thrust/command`` channel is smoothed with the run's thrust
    (:func:`~usvlog.identify.data.run_thrust`; the fit's one copy of it).
    """
    thrust = None if THRUST_TOPIC in log else run_thrust(run)   # a log without its thrust: the run's
    settings = EstimateSettings(model="kinematic", sway_damping=False, output_step_s=GRID_DT,
                                gnss_delay_s=run.gnss_delay_s, compass_delay_s=run.compass_delay_s)
    if tune:
        # the velocities' process noise at the innovation likelihood's optimum, never below the
        # default: that was set for identification on a boat of the paper's size, and a stiffer
        # smoother lags its speed more (the fit's m comes out high), while an agile boat needs far
        # more (an 80 kg catamaran: 50x). The yaw rate's keeps its default (tuned, it moved the
        # paper vessel's fits and not the catamaran's)
        q = tune_process_noise(build_problem(log, settings, vessel or log.vessel or default_vessel(), thrust),
                               settings)
        settings = replace(settings, q_uv=max(q["q_uv"], settings.q_uv_value))
    ks, used = _smoothed(log, run.t0_ns, vessel, settings, thrust)
    if len(ks.t) < MIN_SAMPLES:
        raise FitFailed(f"{run.source or 'run'}: the smoothed states span {len(ks.t) * GRID_DT:.1f} s after the "
                        "first thrust sample: too short to identify from")
    return replace(ks, smoother=FreeRunSmoother(seen=SeenLog.of(log, run), vessel=vessel, settings=used))


@dataclass(frozen=True)
class FreeRunSmoother:
    """Smooths a free run (t, sim, current) as a run's states were smoothed (:attr:`KinStates.smoother`):
    the log the free run would have recorded (:class:`~usvlog.identify.seen.SeenLog`) through the
    same estimator with the same settings."""

    seen: SeenLog
    vessel: object
    settings: EstimateSettings

    def __call__(self, t, sim, current) -> KinStates:
        """The free run's smoothed states (:func:`_smoothed` of its log)."""
        return _smoothed(self.seen.free_run_log(t, sim, current), self.seen.t0_ns, self.vessel, self.settings,
                         self.seen.thrust_over(t))[0]

    def window(self, t_lo: float, t_hi: float) -> FreeRunSmoother:
        """The same smoother for free runs inside ``[t_lo, t_hi]`` (s) only, holding that part of the log."""
        return replace(self, seen=self.seen.window(t_lo, t_hi))


# the state columns the smoothed states are made of (the current's and one-sigmas where there)
_COLUMNS = ("n_m", "e_m", "psi_rad", "u_mps", "v_mps", "r_radps", "current_n_mps", "current_e_mps",
            "u_mps_std", "v_mps_std", "r_radps_std")


def _smoothed(log, t0_ns: int, vessel, settings: EstimateSettings, thrust: ThrustFrames | None = None
              ) -> tuple[KinStates, EstimateSettings]:
    """The estimator's smoothed states on the :data:`GRID_DT` grid from ``t0_ns`` (the run's), and
    the settings it ran with (the tuned process noise in place of ``tune``); ``thrust``: the thrust
    when not the log's own channel (:func:`~usvlog.identify.data.run_thrust`).

    The estimate's state frames are made a time window at a time (:class:`WindowedEstimate`: the
    numbers of :func:`usvlog.estimate.estimate`'s) and only the columns used here kept of each;
    its innovations are not turned into a frame."""
    est = WindowedEstimate(log, settings, vessel, thrust, _RowsInMemory())
    ts_parts: list[np.ndarray] = []
    parts: dict[str, list[np.ndarray]] = {c: [] for c in _COLUMNS}
    for frames in est.frames():
        st = frames[STATE_TOPIC]
        ts_parts.append(np.asarray(st.index, dtype=np.int64))
        for c, got in parts.items():
            if c in st:
                got.append(st[c].to_numpy(float, copy=True))   # (not a view holding the window's every column)
    used = replace(est.settings, tune=False)
    del est   # memory: its problem and smoothed rows go before the columns are joined
    ts = (np.concatenate(ts_parts) - t0_ns) / 1e9 if ts_parts else np.zeros(0)
    st = {c: np.concatenate(got) for c, got in parts.items() if got and len(got) == len(ts_parts)}
    t = np.arange(max(ts[0], 0.0), ts[-1] + 1e-9, GRID_DT) if len(ts) else np.zeros(0)
    if len(t) == 0:
        return KinStates(t=t, n=t, e=t, psi=t, vn=t, ve=t, r=t, source="usvlog.estimate"), used
    psi = np.interp(t, ts, np.unwrap(st["psi_rad"]))
    u = np.interp(t, ts, st["u_mps"])
    v = np.interp(t, ts, st["v_mps"])
    c, s = np.cos(psi), np.sin(psi)
    vn, ve = c * u - s * v, s * u + c * v
    for col, arr in (("current_n_mps", "vn"), ("current_e_mps", "ve")):
        if col in st and np.isfinite(st[col]).all():
            add = np.interp(t, ts, st[col])
            vn, ve = (vn + add, ve) if arr == "vn" else (vn, ve + add)
    sd_cols = ("u_mps_std", "v_mps_std", "r_radps_std")
    sd = (np.stack([np.interp(t, ts, st[c]) for c in sd_cols], -1)
          if all(c in st for c in sd_cols) else None)
    return KinStates(t=t, n=np.interp(t, ts, st["n_m"]), e=np.interp(t, ts, st["e_m"]), psi=psi, vn=vn, ve=ve,
                     r=np.interp(t, ts, st["r_radps"]), source="usvlog.estimate", sd=sd), used


class _RowsInMemory:
    """The smoothed rows of a :class:`WindowedEstimate` kept in arrays until its frames take them
    (its :class:`~usvlog.estimate.windowed.RowStore`): the smoother hands them on from the last
    block to the first, so the first block put has the last rows and says how many there are."""

    def __init__(self):
        self._rows: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    def put(self, r0: int, X, SD, PB) -> None:
        if self._rows is None:
            n = r0 + len(X)
            self._rows = (np.empty((n, X.shape[1])), np.empty((n, SD.shape[1])),
                          np.empty((n if len(PB) else 0, 3, 3)))
        r1 = r0 + len(X)
        for mine, got in zip(self._rows, (X, SD, PB)):
            if len(got):
                mine[r0:r1] = got   # (a copy: the smoother writes its next block into the same buffers)

    def get(self, r0: int, r1: int):
        if self._rows is None:   # no rows at all
            return np.zeros((0, 8)), np.zeros((0, 8)), np.zeros((0, 3, 3))
        X, SD, PB = self._rows
        return X[r0:r1], SD[r0:r1], PB[r0:r1]


def derivative(t, y, window_s=2.0):
    """Smoothed time derivative on a uniform grid (Savitzky-Golay, cubic).

    Raises :class:`~usvlog.errors.FitFailed` with fewer than MIN_SAMPLES samples (or a grid
    that is not increasing): there is no local cubic to fit."""
    dt, w = _window(t, window_s, "derivative")
    return savgol_filter(y, w, polyorder=3, deriv=1, delta=dt, axis=0)


def smooth_like(t, y, window_s=2.0):
    """The same local cubic smoothing without the derivative (to treat thrust like the states).

    Raises :class:`~usvlog.errors.FitFailed` as :func:`derivative`."""
    dt, w = _window(t, window_s, "smoothing")
    return savgol_filter(y, w, polyorder=3, axis=0)


def thrust_on_grid(run: RunData, t):
    """Thrust held over its samples, averaged over each grid interval centred on t."""
    if len(run.t_thrust) == 0:
        raise FitFailed(f"{run.source or 'run'}: no thrust samples in this part of the run")
    out = []
    for tau in (run.tau_u, run.tau_r):
        # cumulative integral of the zero-order-hold signal
        dt = np.diff(run.t_thrust)
        cum = np.concatenate([[0.0], np.cumsum(tau[:-1] * dt)])

        def integral(x, cum=cum, tau=tau):  # called within this iteration only
            i = np.clip(np.searchsorted(run.t_thrust, x, side="right") - 1, 0, len(run.t_thrust) - 1)
            return cum[i] + tau[i] * (x - run.t_thrust[i])
        h = 0.5 * GRID_DT
        out.append((integral(t + h) - integral(t - h)) / (2 * h))
    return out[0], out[1]


__all__ = ["FreeRunSmoother", "KinStates", "kinematic_states", "savgol_states", "savgol_filter", "derivative",
           "smooth_like", "thrust_on_grid", "ssa"]
