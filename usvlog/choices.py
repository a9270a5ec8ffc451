"""Names a user chooses from, defined once and light (standard library only).

The library validates its arguments against these, and the command line offers them as
``choices`` when it builds its parser, which must not import numpy or pandas (so that
``usvlog --help`` stays fast).
"""

from __future__ import annotations

PARAM_NAMES = ("m", "Iz", "d11", "d22", "d33", "xg")
"""Parameters of the paper's model (3): mass m (kg), yaw inertia Iz (kg m^2), damping d11, d22
(kg/s), d33 (kg m^2/s) and the longitudinal centre of gravity xg (m)."""

THRUST_UNITS = ("newton", "normalized", "pwm_us", "counts")
"""Units of recorded thruster commands: force in N, -1..1, an RC pulse width in microseconds, or
integer counts of a controller (e.g. -255..255 or 0..200, full scale given by ``--thrust-range``)."""

IMPORT_FORMATS = ("csv", "nmea", "ros1", "ros2", "dataflash", "ulog")
"""Field log formats ``usvlog import`` reads (``auto`` detects one from the content)."""

IDENTIFY_METHODS = ("output-error", "equation-error", "filter-error")
"""Identification methods of :class:`usvlog.identify.Identifier`."""

__all__ = ["IDENTIFY_METHODS", "IMPORT_FORMATS", "PARAM_NAMES", "THRUST_UNITS"]
