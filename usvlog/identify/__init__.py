"""System identification of the paper's model (3): m, Iz, d11, d22, d33, xg from field logs.

``Identifier(method="output-error").fit(logs, vessel)`` -> ``params_``, ``stderr_``,
``ci95_``, ``corr_``, ``cond_``, ``current_``, ``verdict_``, ``equation_error_``;
``.validate(log)``, ``.to_vessel()``, ``.to_dict()``.
"""

from ..model.stats import fit_percent
from .equation import EquationErrorResult, fit_equation_error, regressors
from .identifier import METHODS, Identifier
from .output import OutputErrorResult, fit_output_error
from .validation import Validation

__all__ = ["Identifier", "Validation", "METHODS", "fit_percent", "fit_equation_error", "regressors",
           "EquationErrorResult", "fit_output_error", "OutputErrorResult"]
