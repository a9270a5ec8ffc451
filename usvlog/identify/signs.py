"""Signs and scales of a run's channels, decided from the data before any fit.

Names are not physics (``DESIGN.md``, "Traps"): on one boat more thrust on the channel called
"left" turned it to port; PWM channels can be reversed; a yaw rate logged in deg/s can sit in a
rad/s column. A fit started on such a log finds negative inertias or gives up. These checks
look at how the boat responded:

* :func:`thrust_yaw_sign`: does the yaw rate follow the differential thrust's yaw moment
  tau_r = arm (T_left - T_right) (usvlog: more port thrust turns to starboard, r > 0)?
* :func:`surge_sign`: does forward thrust speed the boat up?
* :func:`heading_rate_agreement`: does a separate yaw-rate signal match the compass heading's
  rate, in sign and scale?

The response checks fit a first-order model y_dot = a x - b y + c in integral form over
consecutive windows of a few seconds (see :func:`thrust_yaw_sign`). Pure numpy: arrays in,
frozen dataclasses out; times in s, SI units.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

T_MIN = 4.0            # |t| of the gain below this: the sign is not determined
MIN_WINDOWS = 10       # fewer windows than this: not determined
RESPONSE_WINDOW_S = 2.0   # of the yaw (surge) response fit: a fraction of a small boat's time constant
HEADING_WINDOW_S = 5.0    # of the heading check: heading changes well above a ~2 deg compass noise
DEG = math.pi / 180.0


@dataclass(frozen=True, kw_only=True)
class SignCheck:
    """Result of :func:`thrust_yaw_sign` and :func:`surge_sign`.

    ``channel``: ``"yaw"`` or ``"surge"``; ``sign``: +1 the response follows the input as
    usvlog's convention says, -1 it follows the input reversed, 0 not determined;
    ``t_stat``: t-statistic of the gain a; ``correlation``: partial correlation of the
    response's change with the input's impulse, the response's own decay accounted for
    (``t / sqrt(t^2 + dof)``, -1..1); ``gain``: a (rad/s^2 per N m or m/s^2 per N, about
    1 / inertia); ``decay_per_s``: b; ``n_windows``, ``duration_s``: the data used;
    ``message``: the verdict in plain words.
    """

    channel: str
    sign: int
    t_stat: float
    correlation: float
    gain: float
    decay_per_s: float
    n_windows: int
    duration_s: float
    message: str

    def to_dict(self) -> dict:
        """The fields as a JSON-ready dict."""
        return asdict(self)


@dataclass(frozen=True, kw_only=True)
class RateCheck:
    """Result of :func:`heading_rate_agreement`.

    ``sign``: +1 the yaw-rate signal turns the way the heading does, -1 reversed, 0 not
    determined; ``scale``: the signal per true heading rate (1 when right, 57.3 for deg/s
    in a rad/s column, 0.0175 the other way round; negative when reversed);
    ``scale_se``: its standard error; ``bias_radps``: the signal's constant offset (gyro
    bias, rad/s of the signal); ``t_stat``; ``agree``: sign +1 and scale within 20 % of 1;
    ``n_windows``, ``duration_s``; ``message``.
    """

    sign: int
    scale: float
    scale_se: float
    bias_radps: float
    t_stat: float
    agree: bool
    n_windows: int
    duration_s: float
    message: str

    def to_dict(self) -> dict:
        """The fields as a JSON-ready dict."""
        return asdict(self)


def _increments(t, cols, window_s: float):
    """Per window of about ``window_s``: (duration, change of each column's first entry when
    ``cols[i]`` is a "level" or its trapezoid integral when an "integral").

    ``cols``: list of (values, "level" | "integral") on times ``t``. Consecutive windows share
    their end samples; windows with a gap (longer than 1.5 window_s) or under half a window are
    dropped. Returns (D (K,), list of K-arrays)."""
    t = np.asarray(t, float)
    vals = [np.asarray(v, float) for v, _ in cols]
    ok = np.isfinite(t)
    for v in vals:
        ok &= np.isfinite(v)
    t = t[ok]
    vals = [v[ok] for v in vals]
    if len(t) < 3:
        return np.zeros(0), [np.zeros(0) for _ in cols]
    if np.any(np.diff(t) < 0):
        raise ValueError("times must be sorted")
    edges = np.unique(np.searchsorted(t, t[0] + window_s * np.arange(int((t[-1] - t[0]) / window_s) + 2)))
    edges = edges[edges < len(t)]
    a, b = edges[:-1], edges[1:]
    dur = t[b] - t[a]
    keep = (dur >= 0.5 * window_s) & (dur <= 1.5 * window_s)
    out = []
    for v, (_, kind) in zip(vals, cols):
        if kind == "level":
            out.append((v[b] - v[a])[keep])
        else:
            cum = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t))])
            out.append((cum[b] - cum[a])[keep])
    return dur[keep], out


def _ols(y, X):
    """Least squares y ~ X: (coefficients, standard errors, dof), NaNs when rank-deficient."""
    scale = np.sqrt((X * X).sum(0))
    nan = np.full(X.shape[1], np.nan)
    dof = len(y) - X.shape[1]
    if dof < 1 or np.any(scale == 0):
        return nan, nan, dof
    Xs = X / scale
    coef, _, rank, sv = np.linalg.lstsq(Xs, y, rcond=None)
    if rank < X.shape[1] or sv[-1] < 1e-9 * sv[0]:
        return nan, nan, dof
    res = y - Xs @ coef
    cov = (res @ res / dof) * np.linalg.inv(Xs.T @ Xs)
    return coef / scale, np.sqrt(np.diag(cov)) / scale, dof


def _response(channel, t, x, y, window_s):
    """First-order response fit y_dot = a x - b y + c in integral form; returns the numbers
    for :class:`SignCheck` and why it is undetermined ("" when it is not)."""
    dur, (dy, ix, iy) = _increments(t, [(y, "level"), (x, "integral"), (y, "integral")], window_s)
    k, total = len(dur), float(dur.sum())
    nan = float("nan")
    if k < MIN_WINDOWS:
        return dict(channel=channel, t_stat=nan, correlation=nan, gain=nan, decay_per_s=nan, n_windows=k,
                    duration_s=total), f"only {k} windows of {window_s:g} s of data"
    if not np.ptp(ix / dur) > 0:
        what = "no differential thrust" if channel == "yaw" else "no change of surge thrust"
        return dict(channel=channel, t_stat=nan, correlation=nan, gain=nan, decay_per_s=nan, n_windows=k,
                    duration_s=total), f"{what} in {total:.0f} s"
    coef, se, dof = _ols(dy, np.stack([ix, -iy, dur], 1))
    t_a = float(coef[0] / se[0]) if np.isfinite(se[0]) and se[0] > 0 else nan
    rho = t_a / math.sqrt(t_a * t_a + dof) if math.isfinite(t_a) else nan
    out = dict(channel=channel, t_stat=t_a, correlation=rho, gain=float(coef[0]), decay_per_s=float(coef[1]),
               n_windows=k, duration_s=total)
    if not math.isfinite(t_a):
        return out, f"the input and the response are collinear over {total:.0f} s"
    if abs(t_a) < T_MIN:
        return out, f"t = {t_a:.1f}, correlation {rho:.2f} over {total:.0f} s; |t| >= {T_MIN:g} needed"
    return out, ""


def thrust_yaw_sign(t, tau_r, r, window_s: float = RESPONSE_WINDOW_S) -> SignCheck:
    """Whether the yaw rate follows the differential thrust's yaw moment, and with which sign.

    Fits r_dot = a tau_r - b r + c (the yaw row of eq. (3) with a = 1/Iz, b = d33/Iz, c a
    constant moment: thruster mismatch, wind) in integral form over consecutive windows W:
    r(t+W) - r(t) = a int tau_r - b int r + c W, by least squares. Integrals instead of a
    derivative of r: its noise averages out instead of being amplified, and each window's
    error is only the noise of r at its two ends. The -b r term keeps the fit right when a
    heading controller sets tau_r from r (closed loop: a plain correlation of r with a lagged
    tau_r then mixes the boat's response with the controller's). The sign is that of a when
    |t(a)| >= T_MIN (4), else 0. Quadratic damping and a bad estimate of Iz change a and b,
    not the sign of a.

    Parameters
    ----------
    t : array_like, shape (N,)
        Sorted times, s (gaps longer than 1.5 window_s are skipped).
    tau_r : array_like, shape (N,)
        Yaw moment arm (T_left - T_right) in N m at ``t``.
    r : array_like, shape (N,)
        Yaw rate in rad/s at ``t`` (smoothed; clockwise from above positive).
    window_s : float, default RESPONSE_WINDOW_S (2 s)

    Returns
    -------
    SignCheck
        ``channel`` "yaw"; ``sign`` -1 means left and right appear swapped (or tau_r's sign).
    """
    out, why = _response("yaw", t, tau_r, r, window_s)
    rho, dur = out["correlation"], out["duration_s"]
    if why:
        return SignCheck(sign=0, message=f"the yaw response to differential thrust is not determined ({why})", **out)
    if out["gain"] < 0:
        msg = (f"left and right thrust appear swapped: the yaw rate follows T_right - T_left "
               f"(correlation {rho:.2f} over {dur:.0f} s)")
        return SignCheck(sign=-1, message=msg, **out)
    msg = (f"the yaw rate follows T_left - T_right as expected: more port thrust turns to starboard "
           f"(correlation {rho:.2f} over {dur:.0f} s)")
    return SignCheck(sign=1, message=msg, **out)


def surge_sign(t, tau_u, u, window_s: float = RESPONSE_WINDOW_S) -> SignCheck:
    """Whether forward thrust speeds the boat up: u_dot = a tau_u - b u + c, as :func:`thrust_yaw_sign`.

    A sign of -1 means the surge thrust acts backwards: both thrusters' commands reversed
    (PWM channels or propellers), or tau_u's sign flipped on the way.

    Parameters
    ----------
    t : array_like, shape (N,)
        Sorted times, s.
    tau_u : array_like, shape (N,)
        Surge force T_left + T_right in N at ``t``.
    u : array_like, shape (N,)
        Surge speed in m/s at ``t`` (smoothed; through the water or over ground).
    window_s : float, default RESPONSE_WINDOW_S (2 s)

    Returns
    -------
    SignCheck
        ``channel`` "surge".
    """
    out, why = _response("surge", t, tau_u, u, window_s)
    rho, dur = out["correlation"], out["duration_s"]
    if why:
        return SignCheck(sign=0, message=f"the surge response to thrust is not determined ({why})", **out)
    if out["gain"] < 0:
        msg = (f"surge thrust appears reversed (both thrusters' commands or tau_u's sign): the surge speed "
               f"follows -tau_u (correlation {rho:.2f} over {dur:.0f} s)")
        return SignCheck(sign=-1, message=msg, **out)
    return SignCheck(sign=1, message=f"forward thrust speeds the boat up as expected (correlation {rho:.2f} "
                                     f"over {dur:.0f} s)", **out)


def heading_rate_agreement(t, psi, r_gyro, window_s: float = HEADING_WINDOW_S) -> RateCheck:
    """Sign and scale of a yaw-rate signal against the compass heading's own rate.

    Over consecutive windows W: psi(t+W) - psi(t) = k int r_gyro + c W (heading unwrapped), by
    least squares; the signal's scale is 1/k. The heading change is the regressand because
    the compass noise (degrees at each window end) is the larger error; the integrated gyro,
    with little noise, is the regressor (no errors-in-variables bias towards 0); c takes a
    gyro bias. Catches a reversed gyro (scale -1), deg/s logged as rad/s (57.3) and rad/s
    taken for deg/s (1/57.3).

    Parameters
    ----------
    t : array_like, shape (N,)
        Sorted times, s.
    psi : array_like, shape (N,)
        Compass heading in rad (wrapped or not; unwrapped here, so samples under ~pi apart).
    r_gyro : array_like, shape (N,)
        The yaw-rate signal at ``t``, as logged (nominally rad/s, clockwise positive).
    window_s : float, default HEADING_WINDOW_S (5 s)

    Returns
    -------
    RateCheck
    """
    psi = np.asarray(psi, float)
    good = np.isfinite(psi)
    psi_u = np.full_like(psi, np.nan)
    psi_u[good] = np.unwrap(psi[good])
    dur, (dpsi, ig) = _increments(t, [(psi_u, "level"), (r_gyro, "integral")], window_s)
    k_w, total = len(dur), float(dur.sum())
    coef, se, _ = _ols(dpsi, np.stack([ig, dur], 1)) if k_w >= MIN_WINDOWS else (np.full(2, np.nan),) * 3
    k, t_k = float(coef[0]), float(coef[0] / se[0]) if se[0] > 0 else float("nan")
    nums: dict = dict(n_windows=k_w, duration_s=total, t_stat=t_k)
    if not (math.isfinite(t_k) and abs(t_k) >= T_MIN and k != 0):
        why = (f"only {k_w} windows of {window_s:g} s" if k_w < MIN_WINDOWS else
               f"t = {t_k:.1f} over {total:.0f} s, |t| >= {T_MIN:g} needed: too few turns")
        nan = float("nan")
        return RateCheck(sign=0, scale=nan, scale_se=nan, bias_radps=nan, agree=False,
                         message=f"the yaw-rate signal's agreement with the heading is not determined ({why})", **nums)
    scale = 1.0 / k
    scale_se = float(se[0]) / (k * k)          # delta method
    bias = -float(coef[1]) * scale             # r_gyro = scale psi_dot + bias
    sign = 1 if k > 0 else -1
    agree = sign > 0 and 0.8 <= scale <= 1.25
    mag = abs(scale)
    if agree:
        what = "agrees with the heading's rate"
    elif abs(mag / (1 / DEG) - 1) < 0.2:
        what = "is about 57.3 times the heading's rate: deg/s logged as rad/s"
    elif abs(mag / DEG - 1) < 0.2:
        what = "is about 1/57.3 of the heading's rate: rad/s converted as if it were deg/s"
    elif 0.8 <= mag <= 1.25:
        what = "has the heading's rate magnitude"
    else:
        what = f"is {mag:.3g} times the heading's rate: a wrong unit or scale factor"
    if sign < 0:
        what += (", and reversed: it turns the other way from the heading (gyro mounted upside down or "
                 "counter-clockwise positive)")
    msg = f"the yaw-rate signal {what} (scale {scale:.3g} +- {scale_se:.2g} over {total:.0f} s)"
    return RateCheck(sign=sign, scale=scale, scale_se=scale_se, bias_radps=bias, agree=agree, message=msg, **nums)


__all__ = ["SignCheck", "RateCheck", "thrust_yaw_sign", "surge_sign", "heading_rate_agreement"]


@dataclass(frozen=True, kw_only=True)
class ChannelCheck:
    """Result of :func:`channel_signs`: each thruster channel's effect on surge and yaw.

    ``surge_t``/``yaw_t``: t-statistics of each channel's gain ((left, right)); usvlog's
    convention expects surge gains > 0 for both, the yaw gain > 0 for left and < 0 for right.
    ``verdict``: ``"ok"``, ``"left reversed"``, ``"right reversed"``, ``"both reversed"``,
    ``"swapped"`` or ``"undetermined"``; ``message`` in plain words.
    """

    surge_t: tuple[float, float]
    yaw_t: tuple[float, float]
    verdict: str
    n_windows: int
    duration_s: float
    message: str

    def to_dict(self) -> dict:
        """The fields as a JSON-ready dict."""
        return asdict(self)


def _channel_t(t, fl, fr, y, window_s) -> tuple[tuple[float, float], int, float]:
    """t-statistics of (left, right) in y_dot = a_l F_l + a_r F_r - b y + c (integral form)."""
    dur, (dy, il, ir, iy) = _increments(t, [(y, "level"), (fl, "integral"), (fr, "integral"), (y, "integral")],
                                        window_s)
    nan = float("nan")
    if len(dur) < MIN_WINDOWS:
        return (nan, nan), len(dur), float(dur.sum())
    coef, se, _dof = _ols(dy, np.stack([il, ir, -iy, dur], 1))
    ts = tuple(float(c / s) if np.isfinite(s) and s > 0 else nan for c, s in zip(coef[:2], se[:2]))
    return (ts[0], ts[1]), len(dur), float(dur.sum())


def channel_signs(t, f_left, f_right, u, r, window_s: float = RESPONSE_WINDOW_S) -> ChannelCheck:
    """Whether each thruster channel turns and pushes the boat the way its side says (reversed, swapped).

    Fits the yaw response to the two channels separately, in integral form as
    :func:`thrust_yaw_sign`: r(t+W) - r(t) = g_l int F_l + g_r int F_r - d int r + e W, and the
    same for u. usvlog's convention: the left channel turns to starboard (g_l > 0), the right one
    to port (g_r < 0), both push forward. The yaw gains' signs (both |t| >= T_MIN) name the fault:
    (+, -) as expected; (-, -) the left channel reversed; (+, +) the right one reversed; (-, +)
    left and right swapped, or both reversed when the total thrust also drives the boat
    backwards (the surge gain of F_l + F_r < 0 with |t| >= T_MIN). A single channel is called
    reversed only when its own surge gain does not clearly say forward. The yaw gains are the
    strong evidence (t ~ 20 on a 300 s run against ~ 3-5 for one channel's surge: the sway-yaw
    coupling); anything less clear is "undetermined".

    Parameters
    ----------
    t : array_like, shape (N,)
        Sorted times, s.
    f_left, f_right : array_like, shape (N,)
        Each channel's force as recorded (or mapped from its command), N.
    u, r : array_like, shape (N,)
        Surge speed (m/s) and yaw rate (rad/s), smoothed.
    window_s : float, default RESPONSE_WINDOW_S

    Returns
    -------
    ChannelCheck
    """
    fl, fr = np.asarray(f_left, float), np.asarray(f_right, float)
    su, k, dur = _channel_t(t, fl, fr, u, window_s)
    sy, _, _ = _channel_t(t, fl, fr, r, window_s)
    total, _ = _response("surge", t, fl + fr, u, window_s)
    st = total["t_stat"]

    def sign(x: float) -> int:   # +-1 when determined, else 0
        return int(math.copysign(1.0, x)) if math.isfinite(x) and abs(x) >= T_MIN else 0

    yl, yr, s_sum = sign(sy[0]), sign(sy[1]), sign(st)
    stats = (f"yaw t {sy[0]:.1f}/{sy[1]:.1f}, surge t {su[0]:.1f}/{su[1]:.1f} (left/right), "
             f"{st:.1f} (total) over {dur:.0f} s")
    if (yl, yr) == (1, -1):
        verdict, msg = "ok", f"each thruster channel turns the boat as its side says ({stats})"
    elif (yl, yr) == (-1, -1) and sign(su[0]) <= 0:
        verdict, msg = "left reversed", (f"the left thruster channel appears reversed: a positive command drives it "
                                         f"backwards ({stats})")
    elif (yl, yr) == (1, 1) and sign(su[1]) <= 0:
        verdict, msg = "right reversed", (f"the right thruster channel appears reversed: a positive command drives "
                                          f"it backwards ({stats})")
    elif (yl, yr) == (-1, 1) and s_sum < 0:
        verdict, msg = "both reversed", ("both thruster channels push the boat backwards for a positive command "
                                         f"({stats})")
    elif (yl, yr) == (-1, 1):
        verdict, msg = "swapped", f"left and right appear swapped ({stats})"
    else:
        verdict, msg = "undetermined", f"the channels' signs are not determined ({stats})"
    return ChannelCheck(surge_t=su, yaw_t=sy, verdict=verdict, n_windows=k, duration_s=dur, message=msg)
