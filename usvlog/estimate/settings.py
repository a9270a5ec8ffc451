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


@dataclass(frozen=True, kw_only=True)
class EstimateSettings:
    """How to estimate the state of a run.

    model: ``kinematic`` (n, e, psi, over-ground velocity v_n, v_e and r, driven by
        random-walk accelerations; output u, v are body velocities over ground; needs no
        vessel) or ``dynamic`` (the paper's (1)+(3) driven by the
        recorded thrust; u, v relative to the water when current states are on).
    current: estimate a random-walk water current (n, e); ``None`` means on for the
        dynamic model and off for the kinematic one (where it is not observable).
    q_uv, q_r: process-noise intensities (None: the model's default, see DEFAULT_Q): on
        the accelerations (kinematic) or on u, v and r (dynamic);
    q_current: random-walk intensity of the current, m^2/s^3.
    gps_noise_m, compass_noise_rad: one-sigma measurement noise overriding the log's
        covariance / std columns (None: use the log, falling back to
        gps_fallback_m / compass_fallback_rad where it has none).
    compass_offset_rad: compass reading minus true heading of the hull (mounting);
    declination_rad: magnetic declination, east positive, added to ``magnetic`` headings.
    yaw_rate_topic: optional channel with column ``r_radps`` (gyro), noise yaw_rate_noise_radps.
    gate_probability: chi-square probability of the NIS gate (1.0 turns the gate off);
    max_consecutive_rejects: after this many rejections in a row of one sensor its next
        measurement is accepted anyway (so a filter that lost track recovers).
    smoother: run the RTS smoother (else the state is the forward filter's).
    yaw_jump_radps2: kinematic model: one-sigma jump of the yaw acceleration when the
        recorded yaw moment steps by its largest magnitude in the log (0: off; see
        ``core.yaw_jump_variance``).
    sway_damping: kinematic model in the body frame with an estimated sway damping k
        (u_dot = a_x + r v, v_dot = a_y - k v - r u; 10 states): u, v 2-3x better in a
        zig-zag. ``None`` (default): on for the kinematic model. Identification's own
        smoother keeps the 9-state model (see ``usvlog.identify.smooth``).
    tune: pick q_uv, q_r (and q_current) by maximising the innovation likelihood.
    fast: numba-compiled filter and smoother (False: the filterpy reference path).
    output_step_s: the output grid step (also the prediction step).
    """

    model: str = "kinematic"
    current: bool | None = None
    q_uv: float | None = None
    q_r: float | None = None
    q_current: float = 1e-6
    gps_noise_m: float | None = None
    compass_noise_rad: float | None = None
    gps_fallback_m: float = 2.0
    compass_fallback_rad: float = math.radians(3.0)
    compass_offset_rad: float = 0.0
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
        for name in ("q_current", "gps_fallback_m", "compass_fallback_rad", "yaw_rate_noise_radps"):
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

    @property
    def use_current(self) -> bool:
        return bool(self.model == "dynamic" if self.current is None else self.current)

    @property
    def q_uv_value(self) -> float:
        return DEFAULT_Q[self.model]["q_uv"] if self.q_uv is None else self.q_uv

    @property
    def q_r_value(self) -> float:
        return DEFAULT_Q[self.model]["q_r"] if self.q_r is None else self.q_r

    def to_dict(self) -> dict:
        d = asdict(self)
        d["current"] = self.use_current
        d["q_uv"], d["q_r"] = self.q_uv_value, self.q_r_value
        return d
