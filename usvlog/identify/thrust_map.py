"""A thruster map identified from the data: deadband, shape and reverse/forward gain ratio.

When a log's thrust is in PWM pulse widths with no known force scale, the model is fitted
in command units (:mod:`usvlog.identify.thrust_scale`); this module finds the map those
units go through. A real ESC (Blue Robotics T200 class) gives no thrust for pulse widths
within about 1500 +- 25..36 us, more forward than reverse thrust, and a force that grows
faster than linearly with the pulse width. The map, per thruster, with o the pulse width's
offset from neutral (us) as the thruster sees it, h the deadband's half-width and S the
offset of full command (``pwm_span_us``, 400 us):

    x = sign(o) (|o| - h) / (S - h)   beyond the deadband, 0 within it,
    F = g_f s(x) for x > 0,   rho g_f s(x) for x < 0,   s(x) = (1 - q) x + q x|x|,

so full command still gives g_f forward and rho g_f reverse, and q is the shape's
quadratic share (0 linear, 1 quadratic: today's two maps). The deadband is symmetric about
neutral: the published T200 curves are (1472-1528 us at 16 V; 1476-1528 at 20 V is the
most lopsided, by one table step), a boat's reverse edge is visited far less than its
forward one, and an offset neutral would trade against rho.

Why q is fitted too: with the shape fixed to a line or a parabola from the deadband's edge,
the T200 curve is not either: least squares of the 16 V curve over offsets up to 100..400
us puts the edge of a line at 33..74 us and of a parabola at 0 us (its true edge is at 28
us), so a fixed shape makes the deadband whatever makes the shape fit. With q free the same
fit puts the edge at 27..35 us.

The fit is equation error with each equation solved for its acceleration: eq. (3)'s surge
and yaw rows (and the quadratic damping real small hulls show) read

    u_dot - v r = a_u (X_fwd + rho X_rev) - (d11/m) u + xg r^2 - (d11q/m) u|u|,
    r_dot       = a_r (X_fwd + rho X_rev)_r - (d33/Iz) r - (m xg/Iz)(v_dot + u r) - (d33q/Iz) r|r|,

with X the map's columns (the held commands through x and s, summed into tau_u and
tau_r per unit of g_f) and a_u = g_f / m, a_r = g_f / Iz. The noisy derivatives are on the
left, where noise does no harm, and only the smoothed velocities are regressors: written the
other way round (thrust on the left, :func:`usvlog.identify.thrust_ratio.reverse_ratio`),
the derivatives' noise as regressors biased the deadband of a T200 boat logged with 1.5 m
GNSS noise 5..8 us low. For fixed h and q both rows are linear in their coefficients, with
a rho of their own each; :func:`fit_thrust_map` profiles the likelihood over h (a grid of
1 us, refined to 0.1 us about its least), at each h minimising over q (a grid of 0.05, then
the parabola's vertex), and at the least solves one rho shared by both rows (a bounded
one-dimensional search). Its cost is -2 log L of Gaussian equation errors with one variance
per row; equation errors on smoothed states are correlated over many samples, so the cost
differences are divided by the residuals' integrated autocorrelation time before they are
read as chi-squared with one degree of freedom: the 95 % interval is where that is below
3.84. The deadband is *not determined* when the commands seldom came near neutral, or the
interval is wide or runs into the end of the searched range (a flat profile): the caller
then keeps the vessel's own map.

Pure numpy: arrays in, a :class:`ThrustMapFit` out.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from ..errors import FitFailed

DEADBAND_MAX_US = 80.0
"""Widest deadband half-width searched, us (T200: 28..36 us over its 10-20 V curves)."""

DEADBAND_STEP_US = 1.0
"""Grid step of the deadband profile, us (then refined by a tenth about its least)."""

REFINE_STEP_US = 0.1
"""Step of the refined grid about the coarse least, us."""

CHI2_1_95 = 3.841458820694124
"""95 % quantile of chi-squared with one degree of freedom (profile-likelihood interval)."""

DETERMINED_WIDTH_US = 20.0
"""Widest 95 % interval of a deadband that the data determine, us."""

MIN_NEAR_FRACTION = 0.02
"""Fewest command samples (fraction) within the searched range of neutral for the deadband's
edge to have been visited."""

MIN_REVERSE_FRACTION = 0.02
"""Reverse thrust below this fraction of all the thrust, without a deadband (as
:func:`usvlog.identify.thrust_ratio.reverse_ratio`): the ratio cannot be told and is held."""

SHARE_GRID = np.linspace(0.0, 1.0, 21)
"""Quadratic shares tried at each deadband (then refined by a parabola about the least)."""


@dataclass(frozen=True, kw_only=True)
class ThrustMapFit:
    """A thruster map identified from the data (:func:`fit_thrust_map`).

    Attributes
    ----------
    deadband_us : float
        Half-width h of the deadband about neutral at the profile's least, us.
    ci95_us : (float, float)
        95 % profile-likelihood interval of h, us (its ends clipped to the searched range).
    determined : bool
        Whether the data determine h (see ``why``).
    why : str
        When not determined, the reason in plain words ("" otherwise).
    quadratic_share : float
        q of the shape (1 - q) x + q x|x| at ``deadband_us`` (fixed when given).
    share_fitted : bool
        False when q was given, not fitted.
    ratio : float
        Reverse-to-forward gain ratio rho at ``deadband_us``: the one rho of both rows
        (equation error; the given prior when the data have too little reverse thrust,
        ``ratio_fitted`` False).
    ratio_fitted : bool
        Whether rho came from the data.
    ratio_ci95 : (float, float)
        95 % profile-likelihood interval of rho at ``deadband_us`` and its q (NaN when held).
    grid_us : numpy.ndarray
        Deadbands of the profile, us, ascending.
    cost : numpy.ndarray
        Profile cost at each: (-2 log L - its least) / ``inflation`` (chi-squared scale).
    share_profile, ratio_profile : numpy.ndarray
        q and rho at each deadband of the profile (rho: the two rows' own ratios, weighted
        by their thrust gain over their scatter).
    inflation : float
        Integrated autocorrelation time of the equation errors in samples (>= 1), the
        factor the cost differences were divided by.
    near_fraction : float
        Fraction of the command samples (both thrusters) within ``max_us`` of neutral.
    n : int
        Samples (rows per equation) fitted.
    max_us : float
        The searched range's end, us.
    """

    deadband_us: float
    ci95_us: tuple[float, float]
    determined: bool
    why: str = ""
    quadratic_share: float
    share_fitted: bool = True
    ratio: float
    ratio_fitted: bool = True
    ratio_ci95: tuple[float, float] = (float("nan"), float("nan"))
    grid_us: np.ndarray = field(repr=False)
    cost: np.ndarray = field(repr=False)
    share_profile: np.ndarray = field(repr=False)
    ratio_profile: np.ndarray = field(repr=False)
    inflation: float = 1.0
    near_fraction: float = float("nan")
    n: int = 0
    max_us: float = DEADBAND_MAX_US

    def to_dataframe(self) -> pd.DataFrame:
        """The profile: one row per deadband tried (``deadband_us``, ``cost``,
        ``quadratic_share``, ``ratio``), ascending."""
        return pd.DataFrame({"deadband_us": self.grid_us, "cost": self.cost,
                             "quadratic_share": self.share_profile, "ratio": self.ratio_profile})

    def to_dict(self) -> dict:
        """JSON-ready summary (no profile arrays; NaN written as None)."""
        def num(x):
            return None if x is None or not math.isfinite(x) else float(x)
        return {"deadband_us": num(self.deadband_us), "deadband_ci95_us": [num(self.ci95_us[0]),
                                                                             num(self.ci95_us[1])],
                "deadband_determined": bool(self.determined), "deadband_why": self.why or None,
                "quadratic_share": num(self.quadratic_share), "share_fitted": bool(self.share_fitted),
                "ratio": num(self.ratio), "ratio_fitted": bool(self.ratio_fitted),
                "ratio_ci95": [num(self.ratio_ci95[0]), num(self.ratio_ci95[1])],
                "inflation": num(self.inflation), "near_fraction": num(self.near_fraction), "n": int(self.n)}

    def message(self) -> str:
        """One plain line: what the data say of the deadband."""
        lo, hi = self.ci95_us
        if self.determined:
            return (f"deadband +-{self.deadband_us:.1f} us about neutral (95 % {lo:.1f}..{hi:.1f} us), shape "
                    f"{self.quadratic_share:.2f} quadratic, reverse/forward gain {self.ratio:.3g} (95 % "
                    f"{self.ratio_ci95[0]:.3g}..{self.ratio_ci95[1]:.3g})")
        return f"deadband not determined by the data: {self.why}"


def deadband_columns(offset_us, deadband_us: float, span_us: float = 400.0) -> np.ndarray:
    """One thruster's basis of the map: the forward and reverse parts of x and x|x|.

    Parameters
    ----------
    offset_us : array_like, shape (M,)
        Pulse-width offsets from neutral as the thruster sees it (a reversed channel's
        flipped), us.
    deadband_us : float
        Half-width h of the deadband, us, in [0, span_us).
    span_us : float, default 400
        Offset of full command, us.

    Returns
    -------
    numpy.ndarray, shape (M, 4)
        x+, x+|x+|, x-, x-|x-| with x = sign(o) (|o| - h) / (S - h) beyond the deadband
        (0 within, clipped to [-1, 1]), x+ = max(x, 0), x- = min(x, 0): the force is
        g_f ((1 - q) x+ + q x+|x+| + rho ((1 - q) x- + q x-|x-|)).
    """
    o = np.asarray(offset_us, dtype=float)
    x = np.sign(o) * np.clip((np.abs(o) - deadband_us) / (span_us - deadband_us), 0.0, 1.0)
    xp, xn = np.maximum(x, 0.0), np.minimum(x, 0.0)
    return np.stack([xp, xp * xp, xn, -xn * xn], -1)


def hold_average(t_cmd, y, t, dt: float) -> np.ndarray:
    """A signal held from each sample to the next, averaged over [t - dt/2, t + dt/2].

    Parameters
    ----------
    t_cmd : array_like, shape (M,)
        Sample times, s, increasing.
    y : array_like, shape (M, k)
        Values held from each sample time to the next (the last one onwards).
    t : array_like, shape (N,)
        Times of the averages, s.
    dt : float
        Width of each averaging interval, s (> 0).

    Returns
    -------
    numpy.ndarray, shape (N, k)
        The averages (before the first sample the first value is held back).
    """
    t_cmd, y, t = np.asarray(t_cmd, float), np.asarray(y, float), np.asarray(t, float)
    cum = np.concatenate([np.zeros((1, y.shape[1])), np.cumsum(y[:-1] * np.diff(t_cmd)[:, None], 0)])

    def integral(x):
        i = np.clip(np.searchsorted(t_cmd, x, side="right") - 1, 0, len(t_cmd) - 1)
        return cum[i] + y[i] * (x - t_cmd[i])[:, None]
    return (integral(t + 0.5 * dt) - integral(t - 0.5 * dt)) / dt


def equation_rows(nu, nu_dot) -> tuple[np.ndarray, np.ndarray]:
    """The surge and yaw rows of eq. (3) solved for their accelerations, without the thrust.

    Parameters
    ----------
    nu : array_like, shape (N, 3)
        Smoothed body velocity [u (m/s), v (m/s), r (rad/s)].
    nu_dot : array_like, shape (N, 3)
        Its smoothed time derivative.

    Returns
    -------
    lhs : numpy.ndarray, shape (2, N)
        u_dot - v r (m/s^2) and r_dot (rad/s^2).
    terms : numpy.ndarray, shape (2, N, 3)
        Their regressors besides the thrust: u, r^2, u|u| (surge) and r, v_dot + u r, r|r|
        (yaw).
    """
    nu, nu_dot = np.asarray(nu, float), np.asarray(nu_dot, float)
    u, v, r = nu[:, 0], nu[:, 1], nu[:, 2]
    vd, rd = nu_dot[:, 1], nu_dot[:, 2]
    lhs = np.stack([nu_dot[:, 0] - v * r, rd], 0)
    terms = np.stack([np.stack([u, r * r, u * np.abs(u)], -1), np.stack([r, vd + u * r, r * np.abs(r)], -1)], 0)
    return lhs, terms


@dataclass
class _Grams:
    """Per row (surge, yaw): the Gram matrix of [lhs, terms, the four map columns]."""

    G: np.ndarray        # (2, 1 + k + 4, 1 + k + 4)
    n: np.ndarray        # (2,) rows
    k: int               # terms per row
    rev_share: float     # |reverse columns| / |all map columns|


def _grams(lhs, terms, cols) -> _Grams:
    Gs, n, k = np.zeros(0), np.zeros(2), terms[0].shape[2]
    fwd = rev = 0.0
    for y, K, X in zip(lhs, terms, cols):
        Z = np.concatenate([y[:, :, None], K, X], 2)          # (2, N, 1 + k + 4)
        ok = np.isfinite(Z).all(axis=(0, 2))
        Z = Z[:, ok]
        G = np.einsum("eni,enj->eij", Z, Z)
        Gs = G if Gs.size == 0 else Gs + G
        n += ok.sum()
        fwd += float(np.abs(X[:, ok, :2]).sum())
        rev += float(np.abs(X[:, ok, 2:]).sum())
    total = fwd + rev
    return _Grams(G=Gs, n=n, k=k, rev_share=rev / total if total > 0 else 0.0)


def _map_vectors(k: int, q: float):
    """Selectors (length 1 + k + 4) of the forward and reverse thrust at shape q."""
    f = np.zeros(1 + k + 4)
    r = np.zeros(1 + k + 4)
    f[1 + k:3 + k] = (1.0 - q, q)
    r[3 + k:5 + k] = (1.0 - q, q)
    return f, r


def _rows(g: _Grams, thrust_cols) -> tuple[float, np.ndarray, np.ndarray]:
    """Least squares of each row's acceleration on ``thrust_cols`` (selectors) and its terms:
    (cost sum_e n_e log(RSS_e / n_e), coefficients (2, len(thrust_cols) + k), RSS (2,))."""
    k = g.k
    B = np.zeros((1 + k + 4, len(thrust_cols) + k))
    for j, c in enumerate(thrust_cols):
        B[:, j] = c
    B[1:1 + k, len(thrust_cols):] = np.eye(k)
    v = np.zeros(1 + k + 4)
    v[0] = 1.0
    coef = np.zeros((2, B.shape[1]))
    rss = np.ones(2)
    for e in range(2):
        G = g.G[e]
        lhs, rhs = B.T @ G @ B, B.T @ G @ v
        try:
            b = np.linalg.solve(lhs, rhs)
        except np.linalg.LinAlgError:
            b = np.linalg.lstsq(lhs, rhs, rcond=None)[0]
        res = v - B @ b
        coef[e] = b
        rss[e] = max(float(res @ G @ res), 1e-300)
    return float(np.sum(g.n * np.log(rss / g.n))), coef, rss


def _cost(g: _Grams, q: float, rho_fixed: float | None) -> tuple[float, float]:
    """(cost, rho) at shape q: each row with a rho of its own (the rows' weighted mean
    reported), or ``rho_fixed`` held."""
    f, r = _map_vectors(g.k, q)
    if rho_fixed is not None:
        return _rows(g, [f + rho_fixed * r])[0], rho_fixed
    cost, coef, rss = _rows(g, [f, r])
    with np.errstate(divide="ignore", invalid="ignore"):
        rhos = coef[:, 1] / coef[:, 0]
    w = g.n / rss * coef[:, 0] ** 2        # a row's weight on rho: its thrust gain over its scatter
    ok = np.isfinite(rhos) & (w > 0)
    return cost, float(np.sum(w[ok] * rhos[ok]) / np.sum(w[ok])) if ok.any() else float("nan")


def _best_share(g: _Grams, share: float | None, rho_fixed: float | None) -> tuple[float, float, float]:
    """(cost, q, rho) minimising over q in [0, 1] (or at the given q)."""
    if share is not None:
        c, rho = _cost(g, float(share), rho_fixed)
        return c, float(share), rho
    res = [_cost(g, float(q), rho_fixed) for q in SHARE_GRID]
    costs = np.array([x[0] for x in res])
    i = int(np.argmin(costs))
    best = (float(costs[i]), float(SHARE_GRID[i]), res[i][1])
    if 0 < i < len(SHARE_GRID) - 1:   # the vertex of the parabola through the least and its neighbours
        x, y = SHARE_GRID[i - 1:i + 2], costs[i - 1:i + 2]
        den = y[0] - 2 * y[1] + y[2]
        if den > 0:
            qv = float(x[1] + 0.5 * (x[1] - x[0]) * (y[0] - y[2]) / den)
            c, rho = _cost(g, qv, rho_fixed)
            if c < best[0]:
                best = (c, qv, rho)
    return best


def _shared_ratio(g: _Grams, q: float, rho0: float) -> float:
    """The one rho of both rows minimising the cost at shape q (bounded search about ``rho0``)."""
    from scipy.optimize import minimize_scalar  # local: only the final ratio needs it

    f, r = _map_vectors(g.k, q)
    lo, hi = (0.2 * rho0, 5.0 * rho0) if math.isfinite(rho0) and rho0 > 0 else (0.05, 5.0)
    out = minimize_scalar(lambda rho: _rows(g, [f + rho * r])[0], bounds=(lo, hi), method="bounded",
                          options={"xatol": 1e-4})
    return float(out.x)


def _ratio_interval(g: _Grams, q: float, rho: float, tau: float) -> tuple[float, float]:
    """95 % profile-likelihood interval of the shared rho at shape q (cost differences over
    ``tau``), from a grid of factors 0.5 .. 2 about ``rho``; an end that never crosses is NaN."""
    f, r = _map_vectors(g.k, q)
    c0 = _rows(g, [f + rho * r])[0]

    def cross(factors):
        prev = (1.0, 0.0)
        for a in factors:
            d = (_rows(g, [f + rho * a * r])[0] - c0) / tau
            if d > CHI2_1_95:
                a0, d0 = prev
                return rho * (a0 + (a - a0) * (CHI2_1_95 - d0) / (d - d0))
            prev = (a, d)
        return float("nan")
    steps = np.exp(np.linspace(0.0, math.log(2.0), 141)[1:])
    return float(cross(1.0 / steps)), float(cross(steps))


def _autocorr_time(res: np.ndarray) -> float:
    """Integrated autocorrelation time (samples, >= 1) of a residual series: 1 + 2 sum of
    its autocorrelations up to the first that is not positive."""
    r = np.asarray(res, float)
    r = r[np.isfinite(r)]
    if len(r) < 10:
        return 1.0
    r = r - r.mean()
    n = len(r)
    nfft = 1 << (2 * n - 1).bit_length()
    spec = np.fft.rfft(r, nfft)
    ac = np.fft.irfft(spec * np.conj(spec), nfft)[:n]
    if ac[0] <= 0:
        return 1.0
    ac = ac / ac[0]
    stop = np.nonzero(ac[1:] <= 0)[0]
    k = int(stop[0]) + 1 if len(stop) else n
    return max(1.0, 1.0 + 2.0 * float(ac[1:k].sum()))


def _interval(grid, delta, k_best: int, max_us: float) -> tuple[float, float, bool]:
    """The region about the least where ``delta`` <= CHI2_1_95, its ends interpolated;
    whether its upper end crossed before the searched range's end."""
    lo = grid[0]
    for i in range(k_best, 0, -1):
        if delta[i - 1] > CHI2_1_95:
            a, b = delta[i], delta[i - 1]
            lo = grid[i] - (grid[i] - grid[i - 1]) * (CHI2_1_95 - a) / (b - a)
            break
    hi, closed = grid[-1], False
    for i in range(k_best, len(grid) - 1):
        if delta[i + 1] > CHI2_1_95:
            a, b = delta[i], delta[i + 1]
            hi = grid[i] + (grid[i + 1] - grid[i]) * (CHI2_1_95 - a) / (b - a)
            closed = True
            break
    return float(max(lo, 0.0)), float(min(hi, max_us)), closed


def fit_thrust_map(t: Sequence[np.ndarray], nu: Sequence[np.ndarray], nu_dot: Sequence[np.ndarray],
                   commands: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]], *, arm_m: float,
                   span_us: float = 400.0, quadratic_share: float | None = None,
                   smooth: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
                   grid_dt: float | None = None, ratio_prior: float = 1.0,
                   max_us: float = DEADBAND_MAX_US, step_us: float = DEADBAND_STEP_US) -> ThrustMapFit:
    """Deadband, shape and reverse/forward ratio of a thruster map by an equation-error profile.

    Parameters
    ----------
    t : sequence of numpy.ndarray, each shape (N_i,)
        Per run, the uniform times of the smoothed states, s.
    nu, nu_dot : sequence of numpy.ndarray, each shape (N_i, 3)
        Per run, the smoothed body velocity [u, v, r] (relative to the water) and its
        derivative at ``t`` (:func:`equation_rows`).
    commands : sequence of (t_cmd, left_us, right_us)
        Per run, the command samples: times (s, the same origin as ``t``, increasing) and
        the port and starboard pulse-width offsets from neutral as each thruster sees it
        (us; a reversed channel's flipped), each held until the next sample.
    arm_m : float
        Lateral arm of each thruster, m (tau_r = arm (F_left - F_right)).
    span_us : float, default 400
        Offset of full command, us.
    quadratic_share : float, optional
        Hold the shape's q (0 linear, 1 quadratic); default: fitted in [0, 1].
    smooth : callable, optional
        ``smooth(t, y)`` -> y for y of shape (N, k): the smoothing the states had, applied
        to the map's columns too (default none).
    grid_dt : float, optional
        Width of the interval each state sample averages the held commands over, s
        (default the median spacing of ``t``).
    ratio_prior : float, default 1.0
        rho held when the runs have too little reverse thrust to tell it.
    max_us, step_us : float
        End and step of the deadband grid, us (0 .. max_us; refined to REFINE_STEP_US about
        its least).

    Returns
    -------
    ThrustMapFit

    Raises
    ------
    usvlog.errors.FitFailed
        If there are no runs, the arrays' lengths disagree, or there are too few finite
        samples.
    """
    if not t or not (len(t) == len(nu) == len(nu_dot) == len(commands)):
        raise FitFailed("a thruster map needs at least one run, with as many states and command records")
    lhs, terms = [], []
    for ti, a, b in zip(t, nu, nu_dot):
        a, b = np.asarray(a, float), np.asarray(b, float)
        if a.shape != (len(ti), 3) or b.shape != a.shape:
            raise FitFailed("thruster map: each run's nu and nu_dot must be (N, 3) with N its time grid's length")
        y, K = equation_rows(a, b)
        lhs.append(y)
        terms.append(K)
    for i, (tc, left, right) in enumerate(commands):
        if len(tc) < 2 or len(left) != len(tc) or len(right) != len(tc):
            raise FitFailed(f"thruster map: run {i} has {len(tc)} command sample(s) (with {len(left)} port and "
                            f"{len(right)} starboard values); it needs at least two, one of each per time")
    offs = np.concatenate([np.concatenate([np.asarray(c[1], float), np.asarray(c[2], float)]) for c in commands])
    offs = offs[np.isfinite(offs)]
    near = float(np.mean(np.abs(offs) <= max_us)) if len(offs) else 0.0

    def columns(h: float) -> list[np.ndarray]:
        out = []
        for ti, (tc, left, right) in zip(t, commands):
            ti = np.asarray(ti, float)
            L = deadband_columns(np.nan_to_num(left), h, span_us)
            R = deadband_columns(np.nan_to_num(right), h, span_us)
            dt = grid_dt if grid_dt is not None else float(np.median(np.diff(ti)))
            Y = hold_average(tc, np.concatenate([L + R, arm_m * (L - R)], 1), ti, dt)
            if smooth is not None:
                Y = smooth(ti, Y)
            out.append(np.stack([Y[:, :4], Y[:, 4:]], 0))
        return out

    cache: dict[float, tuple] = {}
    g0 = _grams(lhs, terms, columns(0.0))
    if g0.n.min() < 4 * (g0.k + 2):
        raise FitFailed(f"thruster map: only {int(g0.n.min())} finite samples to fit")
    # whether the runs tell rho: decided once (without a deadband), so every profile point has the same freedom
    rho_fixed = None if g0.rev_share >= MIN_REVERSE_FRACTION else float(ratio_prior)

    def at(h: float):
        h = round(float(h), 6)
        if h not in cache:
            g = g0 if h == 0.0 else _grams(lhs, terms, columns(h))
            cost, q, rho = _best_share(g, quadratic_share, rho_fixed)
            cache[h] = (cost, q, rho, rho_fixed is None, g)
        return cache[h]

    coarse = np.arange(0.0, max_us + 0.5 * step_us, step_us)
    costs = np.array([at(h)[0] for h in coarse])
    kc = int(np.argmin(costs))
    for h in np.arange(max(coarse[kc] - step_us, 0.0), min(coarse[kc] + step_us, max_us) + 1e-9, REFINE_STEP_US):
        at(h)
    grid = np.array(sorted(cache))
    prof = [cache[h] for h in grid]
    cost = np.array([c[0] for c in prof])
    kb = int(np.argmin(cost))
    h_best = float(grid[kb])
    _, q_best, rho_rows, rho_fitted, g_best = prof[kb]
    rho_best = _shared_ratio(g_best, q_best, rho_rows) if rho_fitted else float(ratio_prior)

    # equation errors on smoothed states are correlated: their autocorrelation time at the least
    f, r = _map_vectors(g_best.k, q_best)
    _, coef, _ = _rows(g_best, [f + rho_best * r])
    taus, weights = [], []
    for y, K, X in zip(lhs, terms, columns(h_best)):
        Z = np.concatenate([y[:, :, None], K, X], 2)
        for e in range(2):
            res = Z[e, :, 0] - coef[e, 0] * (Z[e] @ (f + rho_best * r)) - Z[e, :, 1:1 + g_best.k] @ coef[e, 1:]
            ok = np.isfinite(res)
            if ok.sum() >= 10:
                taus.append(_autocorr_time(res[ok]))
                weights.append(ok.sum())
    tau = float(np.average(taus, weights=weights)) if taus else 1.0
    delta = (cost - cost[kb]) / tau
    lo, hi, closed = _interval(grid, delta, kb, max_us)
    rho_ci = _ratio_interval(g_best, q_best, rho_best, tau) if rho_fitted else (float("nan"), float("nan"))

    why = ""
    if near < MIN_NEAR_FRACTION:
        why = (f"the commands came within {max_us:g} us of neutral in only {100 * near:.1f} % of the samples, "
               "so the deadband's edge was never visited")
    elif not closed or h_best >= max_us - 1e-9:
        why = (f"the profile is flat up to the end of the searched range ({max_us:g} us): the data do not rule "
               "out a wider deadband")
    elif hi - lo > DETERMINED_WIDTH_US:
        why = (f"the profile is flat: its 95 % interval {lo:.0f}..{hi:.0f} us is wider than "
               f"{DETERMINED_WIDTH_US:g} us")
    return ThrustMapFit(deadband_us=h_best, ci95_us=(lo, hi), determined=not why, why=why,
                        quadratic_share=float(q_best), share_fitted=quadratic_share is None, ratio=float(rho_best),
                        ratio_fitted=bool(rho_fitted), ratio_ci95=rho_ci, grid_us=grid, cost=delta,
                        share_profile=np.array([c[1] for c in prof]), ratio_profile=np.array([c[2] for c in prof]),
                        inflation=tau, near_fraction=near, n=int(g_best.n.min()), max_us=float(max_us))


__all__ = ["CHI2_1_95", "DEADBAND_MAX_US", "DEADBAND_STEP_US", "DETERMINED_WIDTH_US", "MIN_NEAR_FRACTION",
           "REFINE_STEP_US", "ThrustMapFit", "deadband_columns", "equation_rows", "fit_thrust_map", "hold_average"]
