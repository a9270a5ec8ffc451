"""An online EKF for closed-loop simulation ("controller on EKF estimates at 100 Hz").

Runs the same compiled prediction and gated update as the offline estimator
(:mod:`.kernels`), one call at a time.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import ConfigError
from ..model.vessel import Vessel
from . import kernels
from .layout import chi2_quantile, initial_covariance, process_noise, state_size
from .settings import Q_R_KINEMATIC_NO_JUMPS, EstimateSettings


class OnlineEKF:
    """Recursive EKF on the vessel model (dynamic by default) or the kinematic model.

    ``predict(dt, tau_u, tau_r)`` propagates with the applied forces (ignored by the
    kinematic model); ``update_gnss`` / ``update_heading`` apply a measurement through
    the chi-square gate and return True when it was accepted. ``x`` is the state of
    :mod:`.kernels`: dynamic [n, e, psi, u, v, r] (+ [c_n, c_e] with current states);
    kinematic [n, e, psi, v_n, v_e, r, a_n, a_e, r_dot] (with sway damping [n, e, psi, u, v,
    r, a_x, a_y, r_dot, k]). ``P`` is its covariance.

    Parameters
    ----------
    vessel : Vessel
        Vessel whose model drives the dynamic prediction.
    settings : EstimateSettings, optional
        Model, process noise and gate (default ``EstimateSettings(model="dynamic")``).
        With the kinematic model and no ``q_r``, r_dot wanders at
        ``Q_R_KINEMATIC_NO_JUMPS`` (no yaw-moment steps are known ahead).
    x0 : array_like, optional
        Initial state of ``state_size(settings)`` entries in SI units (default zeros).
    P0 : array_like, optional
        Initial covariance (default :func:`.layout.initial_covariance`).

    Attributes
    ----------
    nx : int
        Number of states.
    last_nis : float
        Normalised innovation squared of the last update (NaN before the first).

    Raises
    ------
    usvlog.errors.ConfigError
        If ``x0`` has the wrong length.
    """

    def __init__(self, vessel: Vessel, settings: EstimateSettings | None = None, *,
                 x0=None, P0=None):
        self.settings = settings or EstimateSettings(model="dynamic")
        s = self.settings
        self.vessel = vessel
        self.nx = state_size(s)
        self._model = (kernels.DYNAMIC if s.model == "dynamic" else
                       kernels.KINEMATIC_SWAY if s.sway_damping else kernels.KINEMATIC)
        self._prm = vessel.params.as_array()
        # one call at a time: no yaw-moment steps known ahead, r_dot wanders on its own
        q_r = Q_R_KINEMATIC_NO_JUMPS if s.model == "kinematic" and s.q_r is None else None
        self._q = process_noise(s, q_r=q_r)
        self._x = np.zeros(self.nx) if x0 is None else np.array(x0, float).copy()
        if self._x.shape != (self.nx,):
            raise ConfigError(f"OnlineEKF: x0 must have {self.nx} entries")
        self._P = initial_covariance(s) if P0 is None else np.array(P0, float).copy()
        self._gates = np.array([chi2_quantile(s.gate_probability, d) for d in kernels.SENSOR_DIM])
        self._rej = [0] * len(kernels.SENSORS)
        self._w = kernels.Work(self.nx)
        self.last_nis = math.nan

    @property
    def x(self) -> np.ndarray:
        """A copy of the state, shape (nx,), SI units (m, rad, m/s, rad/s, ...)."""
        return self._x.copy()

    @property
    def P(self) -> np.ndarray:
        """A copy of the state covariance, shape (nx, nx)."""
        return self._P.copy()

    def predict(self, dt: float, tau_u: float = 0.0, tau_r: float = 0.0) -> None:
        """Propagate state and covariance over ``dt`` (one Euler step of the model).

        Parameters
        ----------
        dt : float
            Step in s; nothing happens unless ``dt > 0``.
        tau_u : float, default 0.0
            Surge force applied over the step, N (dynamic model only).
        tau_r : float, default 0.0
            Yaw moment applied over the step, N m (dynamic model only).
        """
        if not dt > 0:
            return
        w = self._w
        kernels.predict(self._x, self._P, float(tau_u), float(tau_r), float(dt), self._prm, self._model,
                        self._q, 0.0, w.xo, w.Po, w.Phi, w.f, w.F, w.tmp)
        self._x[:] = w.xo
        self._P[:] = w.Po

    def _update(self, kind, z0, z1, R00, R01, R11) -> bool:
        w = self._w
        force = self._rej[kind] >= self.settings.max_consecutive_rejects
        ok = kernels.update(self._x, self._P, kind, float(z0), float(z1), float(R00), float(R01),
                            float(R11), self._gates[kind], force, w.res, w.K, w.tmp2)
        self.last_nis = float(w.res[2])
        self._rej[kind] = 0 if ok else self._rej[kind] + 1
        return bool(ok)

    def update_gnss(self, n_m: float, e_m: float, var_m2: float) -> bool:
        """Gated update with a position fix in the local NED frame.

        Parameters
        ----------
        n_m, e_m : float
            North and east position in m.
        var_m2 : float
            Variance of each coordinate in m^2 (no cross-covariance).

        Returns
        -------
        bool
            True when the fix passed the gate (or was forced after
            ``max_consecutive_rejects`` rejections) and was applied.
        """
        return self._update(kernels.GNSS, n_m, e_m, var_m2, 0.0, var_m2)

    def update_heading(self, psi_rad: float, var_rad2: float) -> bool:
        """Gated update with a true heading.

        Parameters
        ----------
        psi_rad : float
            Heading in rad, clockwise from north (wrapped against the state).
        var_rad2 : float
            Its variance in rad^2.

        Returns
        -------
        bool
            True when the heading was applied (see :meth:`update_gnss`).
        """
        return self._update(kernels.COMPASS, psi_rad, 0.0, var_rad2, 0.0, 0.0)

    def update_yaw_rate(self, r_radps: float, var: float) -> bool:
        """Gated update with a gyro yaw rate.

        Parameters
        ----------
        r_radps : float
            Yaw rate in rad/s.
        var : float
            Its variance in rad^2/s^2.

        Returns
        -------
        bool
            True when the yaw rate was applied (see :meth:`update_gnss`).
        """
        return self._update(kernels.YAW_RATE, r_radps, 0.0, var, 0.0, 0.0)
