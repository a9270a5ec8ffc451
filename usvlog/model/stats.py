"""Error measures shared by identify, replay, regress and view (pure numpy).

One definition of each, with its handling of missing values stated: callers that
measure over a record with holes say so (``omit_nonfinite=True`` / finite rows only),
so a NaN never disappears into a metric by accident.
"""

from __future__ import annotations

import numpy as np


def rms(x, *, omit_nonfinite: bool = False) -> float:
    """Root mean square of every element of ``x`` (in the unit of ``x``).

    Parameters
    ----------
    x : array_like
        Values (any shape; all elements count).
    omit_nonfinite : bool
        False (default): a NaN in ``x`` makes the result NaN and an infinity makes it
        inf, so a metric over a diverged or incomplete record shows it.
        True: NaN and +-inf are left out and the RMS is over the finite elements only
        (for records whose gaps are expected, e.g. sparse channels in a report).

    Returns
    -------
    float
        NaN when no element counts (``x`` empty, or every element non-finite and omitted).
    """
    a = np.asarray(x, float).ravel()
    if omit_nonfinite:
        a = a[np.isfinite(a)]
    if a.size == 0:
        return float("nan")
    return float(np.sqrt(np.mean(a * a)))


def fit_percent(y, yhat) -> float:
    """Normalised fit, ``100 (1 - ||y - yhat|| / ||y - mean(y)||)``, in percent.

    100 is a perfect fit, 0 no better than the mean of ``y``, negative worse.

    Parameters
    ----------
    y, yhat : array_like
        Measured and predicted values, 1-D (n,) or 2-D (n, k): a 2-D fit stacks the
        columns (one norm over all of them; the mean is per column), e.g. north and east
        of a track in m.

    Returns
    -------
    float
        Over the rows where every value of ``y`` and ``yhat`` is finite (rows with a NaN
        are left out); NaN when no row is left or ``y`` is constant there.
    """
    y, yhat = np.asarray(y, float), np.asarray(yhat, float)
    n = len(y)
    ok = np.all(np.isfinite(y.reshape(n, -1)) & np.isfinite(yhat.reshape(n, -1)), axis=1)
    if not ok.any():
        return float("nan")
    y, yhat = y[ok], yhat[ok]
    den = np.linalg.norm(y - y.mean(axis=0))
    return float(100.0 * (1.0 - np.linalg.norm(y - yhat) / den)) if den > 0 else float("nan")
