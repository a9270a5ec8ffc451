"""GNSS position noise from what the receiver says of its fix: NMEA GGA fix quality and HDOP (pure).

One-sigma horizontal noise per axis (m) by GGA fix quality, :data:`QUALITY_SIGMA_M`:

==========================  =====================================================
quality                     one-sigma per axis
==========================  =====================================================
1 GPS (autonomous), 3 PPS   ``max(hdop, 2/3) * 1.5 m`` (HDOP x a user range error
                            of 1.5 m; floor 1.0 m; HDOP unknown: 1.5 m)
2 DGPS, 9 SBAS (WAAS)       0.7 m x max(hdop, 1)
4 RTK fixed                 0.03 m x max(hdop, 1)
5 RTK float                 0.3 m x max(hdop, 1)
0, 6-8 and anything else    None: the caller's default
==========================  =====================================================

Where the numbers come from: GGA quality codes as NMEA 0183 defines them (1 GPS, 2 DGPS,
3 PPS, 4 RTK fixed integer, 5 RTK float, 6 dead reckoning, 7 manual, 8 simulator; 9 SBAS
by many receivers); the accuracies are typical receiver data-sheet figures turned into a
one-sigma per axis (CEP ~ 1.18 sigma): autonomous ~1.5-2.5 m CEP, SBAS/DGPS ~0.5-1 m,
RTK fixed ~0.01 m + 1 ppm of the baseline (0.03 m allows a few km of baseline and
multipath on a boat), RTK float decimetres. They are a better start than one default for
every fix, not a calibration: a log's own covariance, when it has one, wins.
"""

from __future__ import annotations

import numpy as np

QUALITY_SIGMA_M = {2: 0.7, 4: 0.03, 5: 0.3, 9: 0.7}
"""One-sigma per axis (m) at HDOP <= 1 by GGA fix quality (1 and 3 scale with HDOP, see the module)."""
QUALITY_NAMES = {1: "GPS", 2: "DGPS", 3: "PPS", 4: "RTK fixed", 5: "RTK float", 9: "SBAS"}
"""Words for the fix qualities the table knows."""
AUTONOMOUS_UERE_M = 1.5
"""User equivalent range error (m) of an autonomous fix: its sigma is HDOP x this."""
AUTONOMOUS_FLOOR_M = 1.0
"""An autonomous fix is never credited with less than this (m), whatever its HDOP."""


def gnss_sigma_from_quality(fix_quality, hdop) -> np.ndarray:
    """One-sigma horizontal position noise per axis (m) from GGA fix quality and HDOP.

    Parameters
    ----------
    fix_quality : array_like of int
        GGA fix quality per fix (-1 or anything outside the table: unknown).
    hdop : array_like of float
        Horizontal dilution of precision per fix (NaN or <= 0: unknown).

    Returns
    -------
    numpy.ndarray
        Sigma in m per fix; NaN where the quality says nothing (the caller's default).
    """
    q = np.asarray(fix_quality, float)
    h = np.asarray(hdop, float)
    h = np.where(np.isfinite(h) & (h > 0), h, np.nan)
    known = np.isfinite(h)
    out = np.full(np.broadcast(q, h).shape, np.nan)
    auto = (q == 1) | (q == 3)
    out = np.where(auto, np.maximum(np.where(known, h, 1.0) * AUTONOMOUS_UERE_M, AUTONOMOUS_FLOOR_M), out)
    for code, sigma in QUALITY_SIGMA_M.items():
        out = np.where(q == code, sigma * np.maximum(np.where(known, h, 1.0), 1.0), out)
    return out


def quality_name(code: int) -> str:
    """``RTK fixed``, ``GPS``, ... for a GGA fix quality (``quality N`` for others)."""
    return QUALITY_NAMES.get(int(code), f"quality {int(code)}")
