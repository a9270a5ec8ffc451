"""The estimator's vocabulary: the channels it reads, its state layout and the :class:`Problem`.

Every other module of :mod:`usvlog.estimate` builds on this one: the topic names
(:data:`INPUT_TOPICS` is what ``usvlog estimate`` decodes), the state vector of each model
(:func:`state_size`, :func:`initial_covariance`, :func:`process_noise` and the kinematic
model's yaw-jump variance), the NIS gate (:func:`chi2_quantile`), the :class:`Problem` the
filter loops run on (made by :func:`usvlog.estimate.problem.build_problem`, cut short by
:func:`head_problem`) and the checked access to a log's channels that the builders share.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from statistics import NormalDist
from typing import Literal, overload

import numpy as np
import pandas as pd

from ..errors import InputError
from ..log.fieldlog import FieldLog, format_time
from ..log.positions import LOCAL_TOPIC
from .settings import EstimateSettings

STATE_COLUMNS = ("n_m", "e_m", "psi_rad", "u_mps", "v_mps", "r_radps", "current_n_mps", "current_e_mps")
STATE_TOPIC = "/estimate/state"
INNOVATION_TOPIC = "/estimate/innovations"
GNSS_TOPIC, COMPASS_TOPIC, THRUST_TOPIC = "/gnss/fix", "/compass/heading", "/thrust/command"
YAW_RATE_TOPIC = "/imu/yaw_rate"   # fused without being asked for when no heading is
VELOCITY_TOPIC = "/gnss/velocity"  # speed and course over ground: fused by the kinematic model in NED
QUALITY_TOPIC = "/gnss/quality"    # GGA fix quality and HDOP: each fix's noise when it has no covariance
INPUT_TOPICS = (GNSS_TOPIC, COMPASS_TOPIC, THRUST_TOPIC, VELOCITY_TOPIC, YAW_RATE_TOPIC, QUALITY_TOPIC, LOCAL_TOPIC)
"""Every channel the estimator reads (the ``usvlog estimate`` verb decodes only these)."""


# initial one-sigma before the first measurements: n, e, psi, u, v, r, then the extra states
_P0_SIGMA = (10.0, 10.0, 0.5, 1.0, 1.0, 0.3)
_P0_EXTRA = {"kinematic": (0.3, 0.3, 0.3, 0.3), "dynamic": (0.3, 0.3)}  # accelerations (, k) / current
POSITION_STD_LIMIT_M = 1e4
"""A position one-sigma beyond this (m) is a filter that has lost the track, not an estimate
(the forward pass restarts from the measurements there, see ``kernels.forward``)."""


# random walk of the sway damping k of the kinematic model with sway damping, 1/s^3:
# a constant in effect
Q_SWAY_DAMPING = 1e-8


def state_size(settings: EstimateSettings) -> int:
    """9 for the kinematic model (n, e, psi, v_n, v_e, r, a_n, a_e, r_dot), 10 with sway
    damping (n, e, psi, u, v, r, a_x, a_y, r_dot, k), 6 or 8
    (with the current) for the dynamic one."""
    if settings.model == "kinematic":
        return 10 if settings.sway_damping else 9
    return 8 if settings.use_current else 6


def initial_covariance(settings: EstimateSettings) -> np.ndarray:
    """Initial state covariance before the first measurement, diagonal.

    One-sigma 10 m on n, e, 0.5 rad on psi, 1 m/s on the velocities, 0.3 rad/s on r and
    0.3 (SI units) on the extra states (accelerations, sway damping or current).

    Parameters
    ----------
    settings : EstimateSettings

    Returns
    -------
    numpy.ndarray
        Shape (nx, nx) with nx = :func:`state_size` (settings).
    """
    nx = state_size(settings)
    sig = (_P0_SIGMA + _P0_EXTRA[settings.model])[:nx]
    return np.diag(np.square(sig))


@dataclass(frozen=True)
class Problem:
    """Everything the filter loops need, as arrays (shared by both paths)."""

    t_ns: np.ndarray        # (N,) step times
    is_grid: np.ndarray     # (N,) bool: an output time
    dts: np.ndarray         # (N,) s since the previous step (0 for the first)
    taus: np.ndarray        # (N, 2) tau_u, tau_r held over the step that ends at k
    qjump: np.ndarray       # (N,) yaw-acceleration variance added at step k (kinematic)
    m_t_ns: np.ndarray      # (M,) measurement times
    mstep: np.ndarray       # (M,) step index of each measurement
    mkind: np.ndarray       # (M,) GNSS / COMPASS / YAW_RATE
    mz: np.ndarray          # (M, 2)
    mR: np.ndarray          # (M, 3) R00, R01, R11
    x0: np.ndarray
    P0: np.ndarray
    prm: np.ndarray         # vessel parameters m, Iz, d11, d22, d33, xg
    model: int
    gates: np.ndarray       # (3,) NIS thresholds per sensor
    dropouts: tuple         # ((start_ns, duration_s), ...) GNSS gaps bridged by prediction
    skipped: dict = field(default_factory=dict)   # sensor -> records skipped (non-finite, out of range)
    mode: str = "gnss+compass"   # or "gps-only": no heading measurement fused
    mode_reason: str = ""        # why GNSS only (empty with a compass)
    gnss_noise: str = ""         # where the GNSS noise came from, in words (gnss_noise_source)

    @property
    def nx(self) -> int:
        """Number of states."""
        return len(self.x0)


def _where(log: FieldLog) -> str:
    return f"{log.source}: " if log.source else ""


@overload
def _channel(log: FieldLog, topic: str, required: Literal[True] = True) -> pd.DataFrame: ...
@overload
def _channel(log: FieldLog, topic: str, required: bool) -> pd.DataFrame | None: ...
def _channel(log: FieldLog, topic: str, required: bool = True) -> pd.DataFrame | None:
    frame = log.get(topic)
    if frame is None or len(frame) == 0:
        if required:
            have = ", ".join(log.topics) or "none"
            raise InputError(f"{_where(log)}channel {topic} is missing or empty "
                             f"(the estimator needs it; channels: {have})")
        return None
    t = np.asarray(frame.index, dtype=np.int64)
    back = np.flatnonzero(np.diff(t) < 0)
    if len(back):
        i = int(back[0]) + 1
        raise InputError(f"{_where(log)}channel {topic}: time goes backwards at message {i} "
                         f"({format_time(int(t[i]))} after {format_time(int(t[i - 1]))})")
    return frame


def _col(frame: pd.DataFrame, name: str, default=np.nan) -> np.ndarray:
    if name in frame.columns:
        return np.array(frame[name].to_numpy(), dtype=float)  # a writable copy
    return np.full(len(frame), default, dtype=float)


def chi2_quantile(p: float, dof: int) -> float:
    """Quantile of the chi-square distribution with 1 or 2 degrees of freedom (the NIS
    gate of a scalar or 2-D measurement), in closed form: for 2, the exponential's
    -2 ln(1 - p); for 1, the square of the normal quantile of (1 - p) / 2 (as scipy's
    ``chi2.ppf`` to a few units in the last place, without importing scipy.stats).

    Parameters
    ----------
    p : float
        Probability in [0, 1]; 1 gives inf (no gate).
    dof : int
        1 or 2.

    Returns
    -------
    float
    """
    if p >= 1.0:
        return math.inf
    if p <= 0.0:
        return 0.0
    if dof == 2:
        return -2.0 * math.log1p(-p)
    if dof == 1:
        return NormalDist().inv_cdf(0.5 * (1.0 - p)) ** 2
    raise ValueError(f"chi2_quantile: {dof} degrees of freedom (1 or 2)")


def gps_only_settings(settings: EstimateSettings) -> EstimateSettings:
    """The settings a GNSS-only run uses: the kinematic model over ground in NED (no sway
    damping: without a heading the sway is not observable), the dynamic model unchanged."""
    if settings.model == "kinematic" and settings.sway_damping:
        return replace(settings, sway_damping=False)
    return settings


def head_problem(pb: Problem, k: int) -> Problem:
    """The first ``k`` steps of a problem and their measurements (a shorter run)."""
    if k >= len(pb.dts):
        return pb
    sel = pb.mstep < k
    return replace(pb, t_ns=pb.t_ns[:k], is_grid=pb.is_grid[:k], dts=pb.dts[:k], taus=pb.taus[:k],
                   qjump=pb.qjump[:k], m_t_ns=pb.m_t_ns[sel], mstep=pb.mstep[sel], mkind=pb.mkind[sel],
                   mz=pb.mz[sel], mR=pb.mR[sel])


def yaw_jump_variance(tau_r: np.ndarray, settings: EstimateSettings) -> np.ndarray:
    """Variance added to the kinematic model's yaw acceleration at each step (N,).

    A boat's yaw acceleration jumps when its yaw moment does (a bang-bang zig-zag, a
    thruster reversal), which a random-walk r_dot follows only slowly. Where the log
    records the thrust, a step of the yaw moment by d between two steps adds the variance
    (yaw_jump_radps2 * d / max|tau_r|)^2: scale-free in the moment, so no vessel
    parameter enters; zero without thrust, for the dynamic model (which is driven by the
    thrust itself) and with yaw_jump_radps2 = 0."""
    q = np.zeros(len(tau_r))
    if settings.model != "kinematic" or settings.yaw_jump_radps2 == 0 or len(tau_r) < 3:
        return q
    scale = float(np.max(np.abs(tau_r[1:])))
    if scale > 0:   # (in place, in the same order: one temporary instead of four)
        d = np.diff(tau_r[1:])
        np.multiply(settings.yaw_jump_radps2, d, out=d)
        np.divide(d, scale, out=d)
        np.square(d, out=q[2:])
    return q


def process_noise(settings: EstimateSettings, q_uv=None, q_r=None, q_c=None) -> np.ndarray:
    """Diagonal of the continuous process-noise intensity for the state layout: on the
    accelerations (kinematic) or on u, v, r and the current (dynamic).

    ``q_uv``, ``q_r``, ``q_c`` override the settings' values (units as in
    :class:`EstimateSettings`); returns an array of :func:`state_size` entries (0 on
    states without process noise)."""
    nx = state_size(settings)
    q = np.zeros(nx)
    i = 6 if settings.model == "kinematic" else 3
    q[i] = q[i + 1] = settings.q_uv_value if q_uv is None else q_uv
    q[i + 2] = settings.q_r_value if q_r is None else q_r
    if settings.model == "kinematic" and settings.sway_damping:
        q[9] = Q_SWAY_DAMPING
    if settings.model == "dynamic" and nx == 8:
        q[6] = q[7] = settings.q_current if q_c is None else q_c
    return q
