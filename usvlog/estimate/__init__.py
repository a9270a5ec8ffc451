"""State estimation: EKF (filterpy reference, numba fast path) + extended RTS smoother.

    from usvlog.estimate import EstimateSettings, estimate, EstimateResult
    result = estimate(log, EstimateSettings(model="dynamic"), vessel)
    result.state        # /estimate/state columns, indexed by t_ns
    result.to_log(log)  # the log plus /estimate/state and /estimate/innovations
"""

from .core import EstimateResult, estimate
from .layout import INNOVATION_TOPIC, STATE_COLUMNS, STATE_TOPIC
from .online import OnlineEKF
from .problem import build_problem
from .report import EstimateReport, SensorReport
from .settings import DEFAULT_Q, MODELS, EstimateSettings

__all__ = ["EstimateSettings", "EstimateResult", "EstimateReport", "SensorReport", "OnlineEKF",
           "estimate", "build_problem", "STATE_COLUMNS", "STATE_TOPIC", "INNOVATION_TOPIC",
           "DEFAULT_Q", "MODELS"]
