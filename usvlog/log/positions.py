"""Positions in metres from a log's local position channel (``/local/position``).

A boat whose navigation gives positions in metres (an INS pose, odometry, motion capture)
has no GNSS fix; its positions are already north/east of an origin, which is the log's
datum when one is known (``geo``). Every stage that needs the track reads it here, so the
local channel is used the same way everywhere.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .fieldlog import FieldLog

LOCAL_TOPIC = "/local/position"
GNSS_TOPIC = "/gnss/fix"


@dataclass(frozen=True)
class LocalPositions:
    """Valid local positions: times (int64 ns), north/east (m), per-axis variance (m^2, NaN unknown).

    ``skipped`` counts records with a non-finite position; ``geo`` says the origin is the
    log's datum; ``frame`` is the first record's ``frame_id``.
    """

    t_ns: np.ndarray
    n_m: np.ndarray
    e_m: np.ndarray
    var_m2: np.ndarray
    skipped: int
    geo: bool
    frame: str


def uses_local(log: FieldLog) -> bool:
    """True when the log's positions are the local channel: it has one and no GNSS fix channel."""
    f = log.get(LOCAL_TOPIC)
    return GNSS_TOPIC not in log and f is not None and len(f) > 0


def local_positions(log: FieldLog) -> LocalPositions | None:
    """The log's local positions (None when it has no local position channel)."""
    f = log.get(LOCAL_TOPIC)
    if f is None or not len(f):
        return None
    n = f["n_m"].to_numpy(float)
    e = f["e_m"].to_numpy(float)
    var = f["var_m2"].to_numpy(float) if "var_m2" in f else np.full(len(f), np.nan)
    ok = np.isfinite(n) & np.isfinite(e)
    geo = bool(f["geo"].to_numpy(bool).any()) if "geo" in f else False
    frame = str(f["frame_id"].iloc[0]) if "frame_id" in f else "local"
    var = np.where(np.isfinite(var) & (var > 0), var, np.nan)
    return LocalPositions(t_ns=np.asarray(f.index, np.int64)[ok], n_m=n[ok], e_m=e[ok], var_m2=var[ok],
                          skipped=int((~ok).sum()), geo=geo, frame=frame)
