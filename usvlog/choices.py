"""Names a user chooses from, defined once and light (standard library only).

The library validates its arguments against these, and the command line offers them as
``choices`` when it builds its parser, which must not import numpy or pandas (so that
``usvlog --help`` stays fast).
"""

from __future__ import annotations

PARAM_NAMES = ("m", "Iz", "d11", "d22", "d33", "xg")
"""Parameters of the paper's model (3): mass m (kg), yaw inertia Iz (kg m^2), damping d11, d22
(kg/s), d33 (kg m^2/s) and the longitudinal centre of gravity xg (m)."""

EXTENDED_PARAM_NAMES = ("m11", "m22", "m26", "m66", "d11", "d11q", "d22", "d22q", "d33", "d33q")
"""Parameters of the extended 3-DOF model: inertia (rigid body plus added mass) m11, m22 (kg),
m26 (kg m), m66 (kg m^2); linear damping d11, d22 (kg/s), d33 (kg m^2/s) and quadratic damping
d11q, d22q (kg/m), d33q (kg m^2)."""

MODEL_STRUCTURES = ("paper", "extended")
"""Model structures: the paper's model (3) and the extended model (separate surge/sway inertia,
linear plus quadratic damping)."""

THRUST_UNITS = ("newton", "normalized", "pwm_us", "counts")
"""Units of recorded thruster commands: force in N, -1..1, an RC pulse width in microseconds, or
integer counts of a controller (e.g. -255..255 or 0..200, full scale given by ``--thrust-range``)."""

IMPORT_FORMATS = ("csv", "nmea", "ros1", "ros2", "dataflash", "ulog")
"""Field log formats ``usvlog import`` reads (``auto`` detects one from the content)."""

IDENTIFY_METHODS = ("output-error", "equation-error", "filter-error")
"""Identification methods of :class:`usvlog.identify.Identifier`."""

IDENTIFY_MODELS = ("paper", "extended", "both")
"""Model structures ``usvlog identify --model`` fits: the paper's, the extended one, or both (compared on
the validation)."""

EXT_SCALE_FIX = ("m", "Iz", "m11", "m22", "m66")
"""Values ``--fix`` takes with ``--model extended`` (``both``: m and Iz only), one of them, to set an
unknown thrust scale: m stands for the surge inertia m11, Iz for the yaw inertia m66."""

__all__ = ["EXTENDED_PARAM_NAMES", "IDENTIFY_METHODS", "IDENTIFY_MODELS", "IMPORT_FORMATS", "MODEL_STRUCTURES",
           "PARAM_NAMES", "THRUST_UNITS", "EXT_SCALE_FIX"]
