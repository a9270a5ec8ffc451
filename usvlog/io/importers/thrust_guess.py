"""The unit of recorded thruster commands, guessed from their values.

A log says its thrust commands are numbers; whether they are newtons, RC pulse widths,
commands normalized to +-1 or integer counts of some full scale is decided here from their
range, robustly to a few outliers (:func:`guess_thrust`). :data:`THRUST_LIMITS` are the
commands each unit accepts (the Assembler in :mod:`usvlog.io.importers.core` skips and counts
the rest). Pure numpy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

THRUST_ABSURD_N = 1e5
"""Thrust commands in newtons beyond +- this are impossible for a small USV (skipped)."""
THRUST_LIMITS: dict[str, tuple[float, float]] = {
    "newton": (-THRUST_ABSURD_N, THRUST_ABSURD_N),
    "normalized": (-1.0 - 1e-9, 1.0 + 1e-9),
    "pwm_us": (800.0, 2200.0),
}
"""Commands accepted per unit (``counts``: the ``--thrust-range``, given or guessed)."""
COUNT_FULL_SCALES = (100, 127, 200, 255, 500, 1000, 1023, 1024, 2047, 2048, 4095, 4096, 10000, 32767,
                     32768, 65535)
"""Full scales of integer command counts the guess picks from (the smallest that holds the bulk)."""
THRUST_GUESS_ROWS = 500
"""A guessed thrust unit is guessed from at least this many commands (or all, if fewer)."""


@dataclass(frozen=True)
class ThrustGuess:
    """A thrust unit guessed from the commands: unit, accepted range and why.

    Attributes
    ----------
    unit : str
        One of ``THRUST_UNITS``.
    lo, hi : float
        Commands accepted (in ``unit``); ``counts``: the range whose larger magnitude is
        the full scale.
    reason : str
        One line for the user.
    """

    unit: str
    lo: float
    hi: float
    reason: str


def guess_thrust(left, right) -> ThrustGuess:
    """Unit of thruster commands from their range, robust to a few outliers.

    The bulk is the commands between the 0.5 % and 99.5 % quantiles, after dropping gross
    outliers -- magnitudes over 10 times the 95th percentile of the non-zero magnitudes --
    so a stray -99360 among +-255 does not decide even in a short log: within 800..2200 -> ``pwm_us``; within
    +-1 -> ``normalized``; whole numbers (99 % of the bulk) -> ``counts`` with the
    smallest full scale F of :data:`COUNT_FULL_SCALES` that holds the bulk (range
    -F..F); anything else -> ``newton``.

    Parameters
    ----------
    left, right : array_like
        Commands of the two thrusters (any unit); non-finite values are ignored.

    Returns
    -------
    ThrustGuess
    """
    v = np.concatenate([np.asarray(left, float).ravel(), np.asarray(right, float).ravel()])
    v = v[np.isfinite(v)]
    if len(v) == 0:
        return ThrustGuess("newton", *THRUST_LIMITS["newton"], "no finite command: newtons assumed")
    v_all = v
    mag = np.abs(v[v != 0])
    if len(mag):
        v = v[np.abs(v) <= 10.0 * float(np.quantile(mag, 0.95, method="nearest"))]
    q_lo, q_hi = (float(x) for x in np.quantile(v, [0.005, 0.995], method="nearest"))
    bulk = v[(v >= q_lo) & (v <= q_hi)]
    span = f"{q_lo:g}..{q_hi:g}" + (f" (all: {float(v_all.min()):g}..{float(v_all.max()):g})"
                                   if v_all.min() < q_lo or v_all.max() > q_hi else "")
    if q_lo >= 800.0 and q_hi <= 2200.0:
        return ThrustGuess("pwm_us", *THRUST_LIMITS["pwm_us"], f"commands {span}: RC pulse widths (us)")
    if q_lo >= -1.0 and q_hi <= 1.0:
        return ThrustGuess("normalized", *THRUST_LIMITS["normalized"], f"commands {span}: within +-1")
    if np.mean(bulk == np.round(bulk)) >= 0.99:
        top = max(abs(q_lo), abs(q_hi))
        fs = next((float(f) for f in COUNT_FULL_SCALES if f >= top), float(math.ceil(top)))
        lo = -fs   # symmetric: a stretch of forward-only commands says nothing of reverse
        return ThrustGuess("counts", lo, fs, f"whole-number commands {span}: counts, full scale {fs:g} "
                                             f"(range {lo:g}:{fs:g}; give --thrust-range LO:HI if not)")
    return ThrustGuess("newton", *THRUST_LIMITS["newton"], f"commands {span} beyond +-1, not whole numbers: newtons")


def guess_thrust_unit(left: np.ndarray, right: np.ndarray) -> str:
    """Unit of thruster commands from their range (:func:`guess_thrust`'s unit).

    Parameters
    ----------
    left, right : array_like
        Commands of the two thrusters.

    Returns
    -------
    str
        ``pwm_us``, ``normalized``, ``counts`` or ``newton``.
    """
    return guess_thrust(left, right).unit
