"""Clock offset between a receive clock and a sensor's own clock (pure).

offset = receive time - sensor time. Transport latency only ever adds to it and
comes in bursts (a serial line at 4800 baud, a busy network), so the estimate is
the median over a sliding window, with the median absolute deviation as spread.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ClockOffset:
    """A clock offset estimate.

    Attributes
    ----------
    offset_ns : int
        Receive minus sensor time, median over the window, ns.
    mad_ns : int
        Median absolute deviation of the samples, ns.
    samples : int
        Samples in the window.
    """

    offset_ns: int   # receive minus sensor time (median)
    mad_ns: int      # median absolute deviation of the samples
    samples: int     # samples in the window

    def to_dict(self) -> dict[str, str]:
        """The estimate as text values (ns) for a metadata record."""
        return {"clock_offset_ns": str(self.offset_ns), "clock_offset_mad_ns": str(self.mad_ns),
                "clock_offset_samples": str(self.samples)}


class OffsetEstimator:
    """Robust running estimate of receive-minus-sensor time over the last ``window`` pairs.

    Parameters
    ----------
    window : int
        Pairs kept (the most recent), >= 1.
    """

    def __init__(self, window: int = 600):
        if window < 1:
            raise ValueError("window must be >= 1")
        self._d: deque[int] = deque(maxlen=window)
        self.total = 0

    def add(self, receive_ns: int, sensor_ns: int) -> None:
        """One pair of times of the same sample.

        Parameters
        ----------
        receive_ns : int
            When it was received, on the receive clock (ns since the Unix epoch).
        sensor_ns : int
            Its own time stamp, on the sensor's clock (ns since the Unix epoch).
        """
        self._d.append(int(receive_ns) - int(sensor_ns))
        self.total += 1

    def estimate(self) -> ClockOffset | None:
        """The median offset and its spread over the window.

        Returns
        -------
        ClockOffset or None
            None before the first pair.
        """
        if not self._d:
            return None
        a = np.fromiter(self._d, dtype=np.int64, count=len(self._d))
        med = int(np.median(a))
        mad = int(np.median(np.abs(a - med)))
        return ClockOffset(med, mad, len(a))
