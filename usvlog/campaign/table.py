"""The campaign table: one row per run, written to ``DIR/runs.parquet`` atomically.

Columns and kinds are :data:`usvlog.campaign.columns.SCHEMA` (``start_utc`` is a UTC
timestamp); read it back with ``pandas.read_parquet("DIR/runs.parquet")``.
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from ..io.atomic import atomic_path
from .columns import SCHEMA

TABLE_FILE = "runs.parquet"

_DTYPES = {"str": "string", "int": "Int64", "float": "float64", "bool": "boolean"}


def to_frame(rows: list[dict]) -> pd.DataFrame:
    """Rows (dicts of plain values) -> the table, columns in :data:`SCHEMA` order, sorted by start time.

    Parameters
    ----------
    rows : list of dict
        One per run; missing columns are missing values, extra keys are dropped.

    Returns
    -------
    pandas.DataFrame
        One row per run; ``start_utc`` as ``datetime64[ns, UTC]``.
    """
    cols = {}
    for name, kind in SCHEMA.items():
        vals = [r.get(name) for r in rows]
        if kind == "time":
            cols[name] = pd.to_datetime(pd.array([v if v is not None else pd.NA for v in vals], dtype="Int64"),
                                        unit="ns", utc=True).as_unit("ns")
        else:
            cols[name] = pd.array(vals, dtype=_DTYPES[kind])
    df = pd.DataFrame(cols)
    return df.sort_values(["start_utc", "source"], na_position="last", kind="stable").reset_index(drop=True)


def write_table(df: pd.DataFrame, out_dir) -> Path:
    """Write ``df`` to ``out_dir/runs.parquet`` atomically (replacing an older table).

    Returns
    -------
    pathlib.Path
        The file written.
    """
    p = Path(out_dir) / TABLE_FILE
    with atomic_path(p, force=True) as tmp:
        df.to_parquet(tmp, index=False)
    return p


__all__ = ["TABLE_FILE", "to_frame", "write_table"]
