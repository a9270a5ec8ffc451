"""Write a canonical log as one merged CSV, the way field loggers often do.

One row per distinct time stamp; each stream fills only its own columns, other cells
stay empty (no sample), exactly the shape ``usvlog import`` reads back.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from ..log.fieldlog import FieldLog
from .atomic import atomic_path
from .export import write_csv

COLUMNS = {  # topic -> {canonical column: CSV header}
    "/gnss/fix": {"lat_deg": "lat_deg", "lon_deg": "lon_deg"},
    "/compass/heading": {"heading_rad": "heading_rad"},
    "/thrust/command": {"left": "thrust_left", "right": "thrust_right"},
}


def write_merged_csv(log: FieldLog, path, *, force: bool = False) -> pd.DataFrame:
    """Merge the GNSS, compass and thrust channels on ``t_ns`` into one CSV; returns the frame.

    Parameters
    ----------
    log : FieldLog
        Missing or empty channels are left out.
    path : str or os.PathLike
        Output CSV, written atomically.
    force : bool, default False
        Overwrite an existing file.

    Returns
    -------
    pandas.DataFrame
        Indexed by ``t_ns`` (int ns since the Unix epoch); columns lat_deg, lon_deg,
        heading_rad, thrust_left, thrust_right (empty where that stream has no sample).

    Raises
    ------
    usvlog.errors.OutputExistsError
        If ``path`` exists and ``force`` is False.
    usvlog.errors.StorageError
        If the file cannot be written.
    """
    parts = []
    for topic, cols in COLUMNS.items():
        f = log.get(topic)
        if f is None or not len(f):
            continue
        parts.append(f[list(cols)].rename(columns=cols))
    merged = pd.concat(parts, axis=1, sort=True) if parts else pd.DataFrame(index=pd.Index([], name="t_ns"))
    merged.index = pd.Index(np.asarray(merged.index, dtype=np.int64), name="t_ns")
    with atomic_path(path, force=force) as tmp:
        write_csv(merged, tmp)   # shortest text that reads back as the same double, empty where no sample
    return merged
