"""The paper's path-following controller: paths, guidance (7)-(8), prefilters, law (9)-(10), gain check."""

from .gains import (
           GainCheck,
           Gains,
           GuidanceSettings,
           check_gains,
           error_matrix,
           gains_from_dict,
)
from .guidance import closest_point, initial_theta, reference_heading
from .law import COL, NOUT, OUT_COLUMNS, Controller, speed_at
from .paths import Path, path_from_json, path_from_spec

__all__ = ["GainCheck", "Gains", "GuidanceSettings", "check_gains", "error_matrix", "gains_from_dict",
           "closest_point", "initial_theta", "reference_heading", "COL", "NOUT", "OUT_COLUMNS",
           "Controller", "speed_at", "Path", "path_from_json", "path_from_spec"]
