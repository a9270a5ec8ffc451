"""Manufacturers' published thrust curves behind the catalogue thruster maps (``map = "t200"``).

Pure data and numpy: the table of published points, and the curve a vessel's thrusters follow
at a given supply voltage (linear in voltage between the published curves, monotone in the
command).

Source of the T200 numbers
--------------------------
Blue Robotics, "T200 Thruster" technical details / performance charts, and the public
performance data spreadsheet "T200-Public-Performance-Data-10-20V-September-2019.xlsx"
(cad.bluerobotics.com): one sheet per supply voltage (10, 12, 14, 16, 18 and 20 V), one row
per PWM pulse width from 1100 to 1900 us in steps of 4 us, column "Force (Kg f)" (bollard
pull, 0.01 kgf resolution, negative = reverse). :data:`T200_KGF` is that column of every
sheet, unchanged, as transcribed in public CSV copies of the workbook (the 14 V column from
a second copy: one widely copied "14 V" file holds the 10 V sheet). Checked against the
published summary figures: maximum forward 3.71 / 4.52 / 5.25 / 6.02 / 6.72 kgf and maximum
reverse 2.92 / 3.52 / 4.07 / 4.59 / 5.04 kgf at 12 / 14 / 16 / 18 / 20 V, deadbands (no
thrust) 1464-1536, 1468-1532, 1472-1528, 1472-1528 and 1476-1528 us.

How the map is built from the points (nothing is fitted):

* kgf -> N with standard gravity :data:`G_MPS2` = 9.80665 m/s^2;
* within one sheet, force is linear between neighbouring published points (4 us apart);
* where a measured force steps back by 0.01-0.02 kgf as the command rises (12 V at 1104 and
  1896 us, 14 V at 1900, 18 V at 1132, 10 V at 1700) the neighbours are replaced by their
  mean (pool-adjacent-violators, least squares), so the map is monotone; every published
  point is reproduced within :data:`T200_ACCURACY_N` (0.01 kgf, the table's own resolution);
* between two published voltages the force at each PWM is linear in voltage; outside
  10-20 V the map refuses (ConfigError), it never extrapolates.

T500: Blue Robotics publishes a T500 performance workbook as well, but its per-PWM table was
not available when this module was written, and its summary figures are not copied here from
memory; ``map = "t500"`` is refused with a message saying so (:data:`UNAVAILABLE`), until its
published table is added to :data:`CATALOGUE` the same way.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from ..errors import ConfigError

G_MPS2 = 9.80665
"""Standard gravity in m/s^2: 1 kgf = 9.80665 N."""

CURVE_NEUTRAL_US = 1500.0
"""PWM pulse width (us) at the middle of the published curves' command range."""

CURVE_SPAN_US = 400.0
"""Offset (us) from :data:`CURVE_NEUTRAL_US` of full command in the published curves (1100/1900 us)."""

T200_PWM_US = tuple(range(1100, 1901, 4))
"""PWM pulse widths (us) of the rows of every T200 sheet: 1100, 1104, ..., 1900 (201 rows)."""

T200_ACCURACY_N = 0.01 * G_MPS2
"""Largest difference (N) between the T200 map and a published point it was built from."""

T200_KGF: dict[float, tuple[float, ...]] = {
    10.0: (
        -2.31, -2.30, -2.30, -2.28, -2.22, -2.18, -2.16, -2.13, -2.11, -2.05,
        -2.04, -1.99, -1.95, -1.93, -1.89, -1.84, -1.81, -1.79, -1.76, -1.71,
        -1.68, -1.65, -1.62, -1.59, -1.56, -1.54, -1.50, -1.47, -1.44, -1.41,
        -1.36, -1.33, -1.32, -1.29, -1.26, -1.22, -1.19, -1.17, -1.14, -1.10,
        -1.08, -1.06, -1.02, -0.99, -0.97, -0.93, -0.91, -0.88, -0.85, -0.83,
        -0.80, -0.78, -0.75, -0.72, -0.70, -0.67, -0.65, -0.63, -0.61, -0.58,
        -0.55, -0.53, -0.51, -0.49, -0.47, -0.44, -0.42, -0.40, -0.38, -0.35,
        -0.34, -0.31, -0.29, -0.28, -0.25, -0.24, -0.21, -0.20, -0.18, -0.16,
        -0.15, -0.14, -0.12, -0.10, -0.09, -0.07, -0.06, -0.05, -0.05, -0.03,
        0.00, 0.00, 0.00, 0.00, 0.00, 0.00, 0.00, 0.00, 0.00, 0.00,
        0.00, 0.00, 0.00, 0.00, 0.00, 0.00, 0.00, 0.00, 0.00, 0.00,
        0.00, 0.04, 0.05, 0.07, 0.08, 0.09, 0.11, 0.13, 0.15, 0.16,
        0.18, 0.20, 0.22, 0.24, 0.26, 0.29, 0.31, 0.34, 0.36, 0.39,
        0.41, 0.44, 0.47, 0.49, 0.52, 0.55, 0.58, 0.61, 0.64, 0.68,
        0.70, 0.73, 0.76, 0.80, 0.83, 0.85, 0.89, 0.92, 0.95, 0.98,
        0.97, 1.05, 1.08, 1.11, 1.17, 1.18, 1.21, 1.24, 1.27, 1.31,
        1.36, 1.41, 1.43, 1.48, 1.52, 1.55, 1.58, 1.62, 1.66, 1.69,
        1.73, 1.77, 1.80, 1.85, 1.88, 1.91, 1.99, 2.00, 2.06, 2.09,
        2.12, 2.17, 2.21, 2.27, 2.30, 2.36, 2.41, 2.45, 2.48, 2.55,
        2.58, 2.62, 2.65, 2.69, 2.74, 2.77, 2.82, 2.88, 2.89, 2.92,
        2.93,
    ),
    12.0: (
        -2.90, -2.92, -2.89, -2.83, -2.79, -2.76, -2.72, -2.67, -2.60, -2.59,
        -2.56, -2.49, -2.44, -2.43, -2.39, -2.34, -2.30, -2.25, -2.23, -2.18,
        -2.14, -2.10, -2.07, -2.01, -1.98, -1.95, -1.88, -1.85, -1.81, -1.78,
        -1.73, -1.66, -1.65, -1.61, -1.56, -1.53, -1.49, -1.47, -1.44, -1.40,
        -1.37, -1.33, -1.29, -1.28, -1.22, -1.19, -1.15, -1.12, -1.08, -1.04,
        -1.02, -0.99, -0.96, -0.93, -0.90, -0.87, -0.83, -0.79, -0.77, -0.74,
        -0.72, -0.69, -0.66, -0.64, -0.60, -0.57, -0.54, -0.52, -0.49, -0.47,
        -0.44, -0.42, -0.39, -0.37, -0.34, -0.32, -0.29, -0.27, -0.24, -0.23,
        -0.20, -0.18, -0.16, -0.15, -0.12, -0.11, -0.09, -0.07, -0.06, -0.05,
        -0.04, 0.00, 0.00, 0.00, 0.00, 0.00, 0.00, 0.00, 0.00, 0.00,
        0.00, 0.00, 0.00, 0.00, 0.00, 0.00, 0.00, 0.00, 0.00, 0.00,
        0.04, 0.05, 0.07, 0.10, 0.11, 0.13, 0.15, 0.18, 0.20, 0.22,
        0.25, 0.28, 0.31, 0.33, 0.37, 0.39, 0.43, 0.46, 0.49, 0.52,
        0.55, 0.59, 0.63, 0.65, 0.68, 0.71, 0.76, 0.79, 0.83, 0.86,
        0.89, 0.93, 0.97, 1.00, 1.04, 1.08, 1.14, 1.16, 1.20, 1.23,
        1.28, 1.31, 1.35, 1.40, 1.43, 1.48, 1.53, 1.56, 1.63, 1.67,
        1.71, 1.77, 1.82, 1.85, 1.91, 1.92, 1.96, 2.03, 2.09, 2.13,
        2.18, 2.24, 2.27, 2.33, 2.40, 2.46, 2.51, 2.56, 2.62, 2.65,
        2.71, 2.78, 2.84, 2.87, 2.93, 3.01, 3.04, 3.08, 3.16, 3.23,
        3.26, 3.32, 3.38, 3.40, 3.45, 3.50, 3.57, 3.64, 3.71, 3.69,
        3.71,
    ),
    14.0: (
        -3.52, -3.50, -3.49, -3.45, -3.40, -3.36, -3.29, -3.25, -3.19, -3.14,
        -3.10, -3.06, -3.00, -2.94, -2.88, -2.85, -2.78, -2.76, -2.69, -2.64,
        -2.59, -2.53, -2.49, -2.45, -2.41, -2.35, -2.34, -2.26, -2.20, -2.18,
        -2.12, -2.05, -2.03, -1.99, -1.91, -1.89, -1.82, -1.76, -1.72, -1.68,
        -1.63, -1.58, -1.56, -1.52, -1.48, -1.44, -1.40, -1.37, -1.32, -1.28,
        -1.24, -1.19, -1.17, -1.12, -1.09, -1.05, -1.02, -0.98, -0.95, -0.92,
        -0.88, -0.85, -0.81, -0.77, -0.74, -0.70, -0.68, -0.65, -0.62, -0.59,
        -0.55, -0.52, -0.49, -0.46, -0.43, -0.40, -0.37, -0.35, -0.32, -0.29,
        -0.26, -0.24, -0.21, -0.19, -0.16, -0.15, -0.12, -0.10, -0.08, -0.07,
        -0.05, -0.03, 0.00, 0.00, 0.00, 0.00, 0.00, 0.00, 0.00, 0.00,
        0.00, 0.00, 0.00, 0.00, 0.00, 0.00, 0.00, 0.00, 0.00, 0.05,
        0.06, 0.08, 0.10, 0.12, 0.15, 0.18, 0.20, 0.23, 0.26, 0.29,
        0.33, 0.36, 0.39, 0.43, 0.46, 0.50, 0.53, 0.58, 0.62, 0.64,
        0.69, 0.73, 0.77, 0.83, 0.85, 0.89, 0.92, 0.97, 1.00, 1.05,
        1.09, 1.14, 1.20, 1.23, 1.28, 1.32, 1.37, 1.41, 1.46, 1.51,
        1.55, 1.61, 1.65, 1.71, 1.76, 1.81, 1.85, 1.91, 1.96, 2.00,
        2.09, 2.12, 2.16, 2.25, 2.27, 2.34, 2.43, 2.50, 2.56, 2.64,
        2.66, 2.76, 2.78, 2.88, 2.93, 2.99, 3.05, 3.13, 3.19, 3.23,
        3.32, 3.36, 3.42, 3.49, 3.57, 3.62, 3.69, 3.77, 3.84, 3.92,
        3.98, 4.03, 4.11, 4.15, 4.21, 4.30, 4.38, 4.42, 4.51, 4.53,
        4.52,
    ),
    16.0: (
        -4.07, -4.05, -4.02, -3.96, -3.90, -3.87, -3.82, -3.80, -3.75, -3.71,
        -3.66, -3.59, -3.52, -3.45, -3.40, -3.31, -3.25, -3.20, -3.11, -3.04,
        -2.99, -2.94, -2.86, -2.82, -2.77, -2.71, -2.66, -2.58, -2.55, -2.51,
        -2.45, -2.38, -2.35, -2.28, -2.24, -2.20, -2.12, -2.08, -2.02, -1.98,
        -1.94, -1.86, -1.81, -1.76, -1.70, -1.67, -1.61, -1.56, -1.51, -1.49,
        -1.44, -1.40, -1.35, -1.30, -1.26, -1.20, -1.16, -1.12, -1.10, -1.05,
        -1.02, -0.98, -0.94, -0.90, -0.87, -0.82, -0.78, -0.74, -0.72, -0.68,
        -0.65, -0.62, -0.58, -0.54, -0.51, -0.48, -0.44, -0.42, -0.39, -0.35,
        -0.32, -0.29, -0.26, -0.24, -0.21, -0.18, -0.15, -0.13, -0.10, -0.09,
        -0.07, -0.05, -0.04, 0.00, 0.00, 0.00, 0.00, 0.00, 0.00, 0.00,
        0.00, 0.00, 0.00, 0.00, 0.00, 0.00, 0.00, 0.00, 0.04, 0.05,
        0.08, 0.10, 0.13, 0.15, 0.18, 0.22, 0.25, 0.29, 0.32, 0.36,
        0.40, 0.44, 0.47, 0.51, 0.56, 0.60, 0.64, 0.68, 0.72, 0.78,
        0.82, 0.87, 0.91, 0.95, 0.99, 1.03, 1.10, 1.14, 1.18, 1.24,
        1.28, 1.33, 1.39, 1.44, 1.48, 1.54, 1.59, 1.65, 1.69, 1.76,
        1.82, 1.88, 1.93, 1.99, 2.05, 2.12, 2.18, 2.22, 2.28, 2.38,
        2.43, 2.52, 2.58, 2.65, 2.73, 2.76, 2.84, 2.89, 2.98, 3.05,
        3.11, 3.17, 3.22, 3.30, 3.37, 3.42, 3.51, 3.61, 3.68, 3.74,
        3.82, 3.89, 3.96, 4.06, 4.15, 4.25, 4.30, 4.38, 4.51, 4.53,
        4.65, 4.71, 4.79, 4.84, 4.93, 5.01, 5.08, 5.14, 5.18, 5.22,
        5.25,
    ),
    18.0: (
        -4.59, -4.54, -4.53, -4.48, -4.42, -4.35, -4.35, -4.17, -4.18, -4.11,
        -4.04, -3.99, -3.91, -3.86, -3.81, -3.71, -3.68, -3.56, -3.54, -3.42,
        -3.36, -3.27, -3.19, -3.09, -3.03, -2.96, -2.88, -2.84, -2.78, -2.70,
        -2.66, -2.59, -2.53, -2.48, -2.42, -2.36, -2.32, -2.25, -2.21, -2.16,
        -2.11, -2.04, -2.00, -1.94, -1.88, -1.81, -1.76, -1.72, -1.66, -1.61,
        -1.56, -1.52, -1.47, -1.42, -1.38, -1.33, -1.27, -1.22, -1.17, -1.13,
        -1.08, -1.05, -1.01, -0.97, -0.93, -0.89, -0.86, -0.81, -0.77, -0.74,
        -0.70, -0.67, -0.64, -0.60, -0.56, -0.53, -0.49, -0.46, -0.43, -0.40,
        -0.37, -0.34, -0.30, -0.27, -0.24, -0.21, -0.18, -0.15, -0.13, -0.10,
        -0.08, -0.06, -0.05, 0.00, 0.00, 0.00, 0.00, 0.00, 0.00, 0.00,
        0.00, 0.00, 0.00, 0.00, 0.00, 0.00, 0.00, 0.00, 0.05, 0.07,
        0.09, 0.12, 0.15, 0.18, 0.21, 0.25, 0.29, 0.32, 0.36, 0.39,
        0.43, 0.47, 0.51, 0.55, 0.59, 0.63, 0.67, 0.70, 0.76, 0.80,
        0.84, 0.88, 0.92, 0.97, 1.02, 1.08, 1.13, 1.18, 1.22, 1.28,
        1.32, 1.38, 1.42, 1.49, 1.54, 1.60, 1.68, 1.74, 1.79, 1.84,
        1.92, 1.97, 2.04, 2.08, 2.17, 2.22, 2.28, 2.36, 2.43, 2.50,
        2.59, 2.64, 2.74, 2.79, 2.87, 2.93, 3.01, 3.10, 3.15, 3.21,
        3.27, 3.39, 3.46, 3.54, 3.63, 3.72, 3.79, 3.92, 4.02, 4.14,
        4.21, 4.32, 4.41, 4.54, 4.67, 4.69, 4.86, 4.92, 5.02, 5.12,
        5.21, 5.29, 5.38, 5.50, 5.60, 5.67, 5.77, 5.82, 5.90, 5.98,
        6.02,
    ),
    20.0: (
        -5.04, -4.96, -4.92, -4.84, -4.79, -4.74, -4.68, -4.58, -4.46, -4.40,
        -4.35, -4.23, -4.16, -4.12, -4.02, -3.96, -3.89, -3.81, -3.71, -3.66,
        -3.56, -3.48, -3.36, -3.29, -3.16, -3.13, -3.00, -2.94, -2.87, -2.78,
        -2.74, -2.67, -2.60, -2.54, -2.50, -2.44, -2.40, -2.31, -2.26, -2.20,
        -2.14, -2.11, -2.04, -1.97, -1.91, -1.86, -1.80, -1.73, -1.67, -1.64,
        -1.58, -1.52, -1.47, -1.41, -1.37, -1.32, -1.27, -1.22, -1.17, -1.11,
        -1.07, -1.02, -0.99, -0.94, -0.91, -0.88, -0.83, -0.78, -0.75, -0.72,
        -0.69, -0.66, -0.63, -0.59, -0.56, -0.53, -0.50, -0.47, -0.44, -0.41,
        -0.39, -0.36, -0.32, -0.29, -0.26, -0.24, -0.20, -0.17, -0.15, -0.12,
        -0.09, -0.07, -0.05, -0.04, 0.00, 0.00, 0.00, 0.00, 0.00, 0.00,
        0.00, 0.00, 0.00, 0.00, 0.00, 0.00, 0.00, 0.00, 0.06, 0.09,
        0.11, 0.15, 0.18, 0.21, 0.25, 0.29, 0.32, 0.36, 0.39, 0.43,
        0.47, 0.50, 0.54, 0.57, 0.61, 0.64, 0.66, 0.70, 0.74, 0.78,
        0.82, 0.86, 0.89, 0.93, 0.98, 1.02, 1.06, 1.12, 1.17, 1.22,
        1.28, 1.31, 1.38, 1.44, 1.53, 1.58, 1.64, 1.74, 1.80, 1.85,
        1.92, 1.98, 2.07, 2.12, 2.20, 2.25, 2.33, 2.44, 2.52, 2.61,
        2.66, 2.76, 2.83, 2.91, 2.99, 3.06, 3.13, 3.22, 3.28, 3.36,
        3.44, 3.55, 3.64, 3.72, 3.85, 3.96, 4.10, 4.21, 4.33, 4.42,
        4.55, 4.70, 4.82, 4.93, 5.02, 5.14, 5.20, 5.39, 5.52, 5.62,
        5.71, 5.82, 5.93, 6.06, 6.13, 6.26, 6.36, 6.46, 6.55, 6.62,
        6.72,
    ),
}
"""Published T200 force (kgf, negative = reverse) by supply voltage (V), one value per PWM
pulse width of :data:`T200_PWM_US`: column "Force (Kg f)" of each sheet of
T200-Public-Performance-Data-10-20V-September-2019.xlsx (Blue Robotics)."""

CATALOGUE: dict[str, tuple[tuple[int, ...], dict[float, tuple[float, ...]]]] = {
    "t200": (T200_PWM_US, T200_KGF),
}
"""Catalogue maps: name -> (PWM pulse widths in us, published force in kgf by supply voltage)."""

UNAVAILABLE = {
    "t500": ("Blue Robotics' T500 performance table is not bundled with usvlog yet (its per-PWM "
             "published data were not available to build it from); use map = \"linear\" or "
             "\"quadratic\" with forward_n/reverse_n from the T500 datasheet"),
}
"""Catalogue names that are known but have no published table here, with the reason."""

CATALOGUE_MAPS = tuple(CATALOGUE)
"""Names of the catalogue thruster maps (a ``[thrusters] map`` value)."""


def voltage_range(name: str) -> tuple[float, float]:
    """Lowest and highest supply voltage (V) a catalogue map was published at.

    Parameters
    ----------
    name : str
        Catalogue map name (:data:`CATALOGUE_MAPS`).

    Returns
    -------
    tuple of float
        ``(lowest, highest)`` in V (T200: 10.0, 20.0).

    Raises
    ------
    usvlog.errors.ConfigError
        If ``name`` is not a catalogue map.
    """
    _, sheets = _catalogue(name)
    return min(sheets), max(sheets)


def published_points(name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The published points of a catalogue map, in SI units, exactly as published.

    Parameters
    ----------
    name : str
        Catalogue map name (:data:`CATALOGUE_MAPS`).

    Returns
    -------
    supply_v : numpy.ndarray, shape (k,)
        Supply voltages of the published curves, V, ascending.
    pwm_us : numpy.ndarray, shape (n,)
        PWM pulse widths of the published rows, us, ascending.
    force_n : numpy.ndarray, shape (k, n)
        Published force of one thruster in N (kgf times :data:`G_MPS2`), negative = reverse.

    Raises
    ------
    usvlog.errors.ConfigError
        If ``name`` is not a catalogue map.
    """
    pwm, sheets = _catalogue(name)
    volts = sorted(sheets)
    return (np.array(volts, dtype=float), np.array(pwm, dtype=float),
            np.array([sheets[v] for v in volts], dtype=float) * G_MPS2)


def curve(name: str, supply_v: float) -> tuple[np.ndarray, np.ndarray]:
    """The force curve of one thruster of a catalogue map at a supply voltage.

    Parameters
    ----------
    name : str
        Catalogue map name (:data:`CATALOGUE_MAPS`).
    supply_v : float
        Supply voltage in V, within the published range (:func:`voltage_range`).

    Returns
    -------
    pwm_us : numpy.ndarray, shape (n,)
        PWM pulse widths in us, ascending (read-only).
    force_n : numpy.ndarray, shape (n,)
        Force of one thruster in N at each pulse width, non-decreasing (read-only): each
        published curve made monotone (pool-adjacent-violators), then linear in voltage
        between the two published curves around ``supply_v``.

    Raises
    ------
    usvlog.errors.ConfigError
        If ``name`` is not a catalogue map, or ``supply_v`` is not a finite number within
        the published range (the message names the range).
    """
    _catalogue(name)
    if isinstance(supply_v, bool) or not isinstance(supply_v, (int, float)) or not math.isfinite(supply_v):
        raise ConfigError(f"thruster map {name!r} needs supply_v, the supply voltage in V "
                          f"(published {_range_text(name)}), not {supply_v!r}")
    return _curve(name, float(supply_v))


def force_from_pwm(pwm_us, pwm_table, force_table):
    """Force (N) of one thruster at PWM pulse width(s), linear between the table's points.

    Pure numpy on arrays (``np.interp``; numba compiles it as written). Commands outside the
    table are held at its ends (full command).

    Parameters
    ----------
    pwm_us : float or array_like
        PWM pulse width(s) in us, in the curve's own frame (neutral 1500, full 1100/1900).
    pwm_table, force_table : numpy.ndarray
        A curve from :func:`curve`.

    Returns
    -------
    numpy.ndarray
        Force in N, of the input's shape.
    """
    return np.interp(pwm_us, pwm_table, force_table)


def pwm_from_force(force_n, pwm_table, force_table):
    """Inverse of :func:`force_from_pwm`: the PWM pulse width (us) giving force(s) in N.

    Zero force gives :data:`CURVE_NEUTRAL_US` (the middle of the deadband); a positive force
    the pulse width on the forward branch, a negative one on the reverse branch. Forces
    beyond the curve's limits give full command (1100/1900 us).

    Parameters
    ----------
    force_n : float or array_like
        Force(s) of one thruster in N.
    pwm_table, force_table : numpy.ndarray
        A curve from :func:`curve` (non-decreasing, with a deadband of zero force).

    Returns
    -------
    numpy.ndarray
        PWM pulse width(s) in us, of the input's shape; ``force_from_pwm`` of it gives the
        force back (within the limits).
    """
    f = np.asarray(force_n, dtype=float)
    i_fwd = int(np.argmax(force_table > 0.0)) - 1        # last zero before forward thrust
    i_rev = int(np.nonzero(force_table < 0.0)[0][-1]) + 1  # first zero after reverse thrust
    fwd = np.interp(f, force_table[i_fwd:], pwm_table[i_fwd:])
    rev = np.interp(f, force_table[:i_rev + 1], pwm_table[:i_rev + 1])
    return np.where(f > 0.0, fwd, np.where(f < 0.0, rev, CURVE_NEUTRAL_US))


def monotone(y) -> np.ndarray:
    """Least-squares non-decreasing sequence nearest to ``y`` (pool adjacent violators).

    Parameters
    ----------
    y : array_like, shape (n,)
        Values in order (e.g. published forces by rising PWM).

    Returns
    -------
    numpy.ndarray, shape (n,)
        ``y`` where it already rises; each run of values that steps back replaced by the
        run's mean.
    """
    blocks: list[list[float]] = []   # [sum, count] of each pooled run
    for v in np.asarray(y, dtype=float):
        blocks.append([v, 1.0])
        while len(blocks) > 1 and blocks[-2][0] / blocks[-2][1] > blocks[-1][0] / blocks[-1][1]:
            s, n = blocks.pop()
            blocks[-1][0] += s
            blocks[-1][1] += n
    return np.concatenate([np.full(int(n), s / n) for s, n in blocks])


# ---------------------------------------------------------------------------------------
def _catalogue(name: str):
    if name in UNAVAILABLE:
        raise ConfigError(f"thruster map {name!r}: {UNAVAILABLE[name]}")
    if name not in CATALOGUE:
        raise ConfigError(f"thruster map {name!r} is not in the catalogue ({', '.join(CATALOGUE)})")
    return CATALOGUE[name]


def _range_text(name: str) -> str:
    lo, hi = voltage_range(name)
    volts = ", ".join(f"{v:g}" for v in sorted(_catalogue(name)[1]))
    return f"{lo:g}..{hi:g} V (curves at {volts} V)"


@functools.lru_cache(maxsize=64)
def _curve(name: str, supply_v: float) -> tuple[np.ndarray, np.ndarray]:
    volts, pwm, force = published_points(name)
    if not (volts[0] <= supply_v <= volts[-1]):
        raise ConfigError(f"thruster map {name!r}: supply_v = {supply_v:g} V is outside the published "
                          f"range {_range_text(name)}")
    k = min(int(np.searchsorted(volts, supply_v, side="right")) - 1, len(volts) - 2)
    w = (supply_v - volts[k]) / (volts[k + 1] - volts[k])
    f = (1.0 - w) * monotone(force[k]) + w * monotone(force[k + 1])
    pwm.setflags(write=False)
    f.setflags(write=False)
    return pwm, f
