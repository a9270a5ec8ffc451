"""Settings of the state estimator (frozen, keyword-only, range-checked)."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

from ..errors import ConfigError

MODELS = ("kinematic", "dynamic")

# Process-noise intensities (continuous white noise driving the velocity states) that
# suit a small USV; ``tune=True`` replaces them by the innovation-likelihood optimum.
DEFAULT_Q = {
    # random-walk accelerations: m^2/s^5 for a_n, a_e (NED); rad^2/s^5 for r_dot
    # (q_r 2e-3 where the log's yaw-moment steps add their own jumps of r_dot, see
    # yaw_jump_radps2; without them r_dot must wander faster: Q_R_KINEMATIC_NO_JUMPS)
    "kinematic": {"q_uv": 1e-4, "q_r": 2e-3},
    # model error of eq. (3) driven by the recorded thrust: m^2/s^3 on u, v; rad^2/s^3 on r
    "dynamic": {"q_uv": 1e-5, "q_r": 1e-5},
}

Q_R_KINEMATIC_NO_JUMPS = 0.01

DELAY_SENSORS = ("gnss", "compass")
"""Sensors whose latency the estimator can apply and estimate (``<name>_delay_s``)."""


@dataclass(frozen=True, kw_only=True)
class EstimateSettings:
    """How to estimate the state of a run.

    All fields are keyword-only; the object is frozen and range-checked on creation.

    Parameters
    ----------
    model : {"kinematic", "dynamic"}, default "kinematic"
        ``kinematic``: n, e, psi, over-ground velocity v_n, v_e and r, driven by
        random-walk accelerations; output u, v are body velocities over ground; needs no
        vessel. ``dynamic``: the paper's (1)+(3) driven by the recorded thrust; u, v
        relative to the water when current states are on.
    current : bool or None, default None
        Estimate a random-walk water current (n, e); ``None`` means on for the dynamic
        model and off for the kinematic one (where it is not observable, so True is an
        error there).
    q_uv, q_r : float or None, default None
        Process-noise intensities (None: the model's default, see ``DEFAULT_Q``):
        kinematic model on the accelerations a_n, a_e in m^2/s^5 and on r_dot in
        rad^2/s^5; dynamic model on u, v in m^2/s^3 and on r in rad^2/s^3. > 0.
    q_current : float, default 1e-6
        Random-walk intensity of the current, m^2/s^3, > 0.
    gps_noise_m : float or None, default None
        One-sigma GNSS position noise in m, overriding the log's covariance columns
        (None: use the log, falling back to ``gps_fallback_m`` where it has none).
    compass_noise_rad : float or None, default None
        One-sigma compass noise in rad, overriding the log's ``std_rad`` column (None: use
        the log, falling back to ``compass_fallback_rad``).
    gps_fallback_m : float, default 2.0
        One-sigma GNSS noise in m for fixes without a usable covariance.
    local_noise_m : float, default 0.3
        One-sigma noise in m of local positions in metres (``/local/position``: an INS pose,
        motion capture) without a variance of their own.
    compass_fallback_rad : float, default radians(3)
        One-sigma compass noise in rad for headings without a usable std.
    compass_offset_rad : float, default 0.0
        Compass reading minus true heading of the hull (mounting), rad, in [-2 pi, 2 pi]:
        the heading fused is ``heading_measured - compass_offset_rad``. A dual-antenna GNSS
        heading whose baseline sits 70 deg clockwise of the keel reads 70 deg more than the
        hull's heading: offset +70 deg (``usvlog estimate --heading-offset 70``).
    heading_offset_auto : bool, default False
        Detect a constant mounting offset of the heading against the course over ground
        (:func:`usvlog.model.heading_offset.detect_heading_offset`) and, when one is
        found, use it instead of ``compass_offset_rad`` (``--heading-offset auto``).
    declination_rad : float, default 0.0
        Magnetic declination, east positive, added to ``magnetic`` headings, rad.
    yaw_rate_topic : str or None, default None
        Optional channel with column ``r_radps`` (gyro) used as a yaw-rate measurement.
    yaw_rate_noise_radps : float, default 0.01
        One-sigma noise of that yaw rate, rad/s.
    gate_probability : float, default 0.9999
        Chi-square probability of the NIS gate, in [0.5, 1] (1.0 turns the gate off).
    max_consecutive_rejects : int, default 50
        After this many rejections in a row of one sensor its next measurement is
        accepted anyway (so a filter that lost track recovers); >= 1.
    yaw_jump_radps2 : float, default 0.25
        Kinematic model: one-sigma jump of the yaw acceleration in rad/s^2 when the
        recorded yaw moment steps by its largest magnitude in the log (0: off; see
        ``layout.yaw_jump_variance``).
    sway_damping : bool or None, default None
        Kinematic model in the body frame with an estimated sway damping k in 1/s
        (u_dot = a_x + r v, v_dot = a_y - k v - r u; 10 states): u, v 2-3x better in a
        zig-zag. ``None``: on for the kinematic model (True is an error for the dynamic
        one). Identification's own smoother keeps the 9-state model (see
        ``usvlog.identify.smooth``).
    smoother : bool, default True
        Run the RTS smoother (else the state is the forward filter's).
    tune : bool, default False
        Pick q_uv, q_r (and q_current) by maximising the innovation likelihood.
    fast : bool, default True
        Numba-compiled filter and smoother (False: the filterpy reference path).
    output_step_s : float, default 0.01
        The output grid step in s (also the prediction step), in [1e-4, 1].
    gnss_velocity_noise_mps : float, default 0.1
        One-sigma noise of each NED component of ``/gnss/velocity`` (speed and course over
        ground), m/s; fused by the kinematic model when there is no heading (GNSS only).
    gps_only : bool, default False
        Fuse no heading even when the log has one (a rough or doubtful compass). Without a
        usable heading channel (none, dead, or still while the track turns) the estimate
        is GNSS-only anyway.
    gnss_delay_s : float, default 0.0
        GNSS latency in s, in [-1, 5]: a fix (and a GNSS velocity) stamped t describes the
        boat at t - gnss_delay_s (see ``usvlog.estimate.latency`` to estimate it).
    compass_delay_s : float, default 0.0
        Compass latency in s, in [-1, 5], likewise for ``/compass/heading``.
    estimate_delays : tuple of str, default ()
        Sensors (``"gnss"``, ``"compass"``) whose latency is estimated from the data by
        maximising the innovation likelihood (``usvlog.estimate.latency``); the value
        above is kept where the data do not determine it.

    Raises
    ------
    usvlog.errors.ConfigError
        If a value is out of range or the options contradict each other.
    """

    model: str = "kinematic"
    current: bool | None = None
    q_uv: float | None = None
    q_r: float | None = None
    q_current: float = 1e-6
    gps_noise_m: float | None = None
    compass_noise_rad: float | None = None
    gps_fallback_m: float = 2.0
    local_noise_m: float = 0.3
    compass_fallback_rad: float = math.radians(3.0)
    compass_offset_rad: float = 0.0
    heading_offset_auto: bool = False
    declination_rad: float = 0.0
    yaw_rate_topic: str | None = None
    yaw_rate_noise_radps: float = 0.01
    gate_probability: float = 0.9999
    max_consecutive_rejects: int = 50
    yaw_jump_radps2: float = 0.25
    sway_damping: bool | None = None
    smoother: bool = True
    tune: bool = False
    fast: bool = True
    output_step_s: float = 0.01
    gnss_velocity_noise_mps: float = 0.1
    gps_only: bool = False
    gnss_delay_s: float = 0.0
    compass_delay_s: float = 0.0
    estimate_delays: tuple[str, ...] = ()

    def __post_init__(self):
        if self.model not in MODELS:
            raise ConfigError(f"estimate model {self.model!r} is not one of {', '.join(MODELS)}")
        if self.sway_damping is None:  # default: on for the kinematic model
            object.__setattr__(self, "sway_damping", self.model == "kinematic")
        if self.sway_damping and self.model != "kinematic":
            raise ConfigError("sway_damping is an option of the kinematic model")
        if self.model == "kinematic" and self.current:
            raise ConfigError("the kinematic model cannot estimate a current (GPS alone does not "
                              "separate it from the boat's own velocity); use --model dynamic")
        for name in ("q_uv", "q_r", "gps_noise_m", "compass_noise_rad"):
            v = getattr(self, name)
            if v is not None and not (math.isfinite(v) and v > 0):
                raise ConfigError(f"estimate setting {name} = {v} must be a finite number > 0")
        for name in ("q_current", "gps_fallback_m", "local_noise_m", "compass_fallback_rad", "yaw_rate_noise_radps",
                     "gnss_velocity_noise_mps"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(f"estimate setting {name} = {v} must be a finite number > 0")
        for name in ("compass_offset_rad", "declination_rad"):
            v = getattr(self, name)
            if not (math.isfinite(v) and abs(v) <= 2 * math.pi):
                raise ConfigError(f"estimate setting {name} = {v} must be an angle in [-2 pi, 2 pi] rad")
        if not (math.isfinite(self.yaw_jump_radps2) and self.yaw_jump_radps2 >= 0):
            raise ConfigError(f"yaw_jump_radps2 = {self.yaw_jump_radps2} must be a finite number >= 0")
        if not (0.5 <= self.gate_probability <= 1.0):
            raise ConfigError(f"gate_probability = {self.gate_probability} must be in [0.5, 1]")
        if self.max_consecutive_rejects < 1:
            raise ConfigError(f"max_consecutive_rejects = {self.max_consecutive_rejects} must be >= 1")
        if not (1e-4 <= self.output_step_s <= 1.0):
            raise ConfigError(f"output_step_s = {self.output_step_s} must be in [1e-4, 1] s")
        for name in ("gnss_delay_s", "compass_delay_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and -1.0 <= v <= 5.0):
                raise ConfigError(f"estimate setting {name} = {v} must be a latency in [-1, 5] s")
        names = self.estimate_delays
        object.__setattr__(self, "estimate_delays", (names,) if isinstance(names, str) else tuple(names))
        for name in self.estimate_delays:
            if name not in DELAY_SENSORS:
                raise ConfigError(f"estimate_delays: {name!r} is not one of {', '.join(DELAY_SENSORS)}")

    @property
    def use_current(self) -> bool:
        """Whether current states are estimated (``current``, or the model's default)."""
        return bool(self.model == "dynamic" if self.current is None else self.current)

    @property
    def q_uv_value(self) -> float:
        """``q_uv`` or the model's default (m^2/s^5 kinematic, m^2/s^3 dynamic)."""
        return DEFAULT_Q[self.model]["q_uv"] if self.q_uv is None else self.q_uv

    @property
    def q_r_value(self) -> float:
        """``q_r`` or the model's default (rad^2/s^5 kinematic, rad^2/s^3 dynamic)."""
        return DEFAULT_Q[self.model]["q_r"] if self.q_r is None else self.q_r

    def to_dict(self) -> dict:
        """All fields as a plain dict with the defaults resolved.

        ``current``, ``q_uv`` and ``q_r`` hold the values in effect (never None); used for
        provenance and ``--json`` output.
        """
        d = asdict(self)
        d["current"] = self.use_current
        d["q_uv"], d["q_r"] = self.q_uv_value, self.q_r_value
        return d
