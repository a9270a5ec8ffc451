"""Exports read back to the very values of the log (CSV through pyarrow's writer, Parquet)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from usvlog.io.export import export_log
from usvlog.log.fieldlog import FieldLog


def _frame(n: int = 5000) -> pd.DataFrame:
    rng = np.random.default_rng(7)
    x = rng.normal(size=n) * 10.0 ** rng.integers(-300, 300, n)
    x[:6] = [5e-324, -0.0, 1.7976931348623157e308, 0.1, 1 / 3, 2.0 ** -1074 * 3]
    y = rng.normal(size=n)
    y[::7] = np.nan
    t = 1_700_000_000 * 10**9 + np.arange(n, dtype=np.int64) * 100_000_001
    return pd.DataFrame({"x": x, "y": y, "ok": rng.random(n) > 0.5, "n": np.arange(n) - n // 2,
                         "frame": pd.array(['a,"b"', "plain"] * (n // 2), dtype="str")},
                        index=pd.Index(t, name="t_ns"))


@pytest.mark.parametrize("fmt", ["csv", "parquet"])
def test_export_reads_back_exactly(tmp_path, fmt):
    frame = _frame()
    log = FieldLog()
    log.channels["/a/b"] = frame
    (path,) = export_log(log, tmp_path, fmt=fmt)
    back = pd.read_csv(path, index_col="t_ns") if fmt == "csv" else pd.read_parquet(path)
    assert list(back.columns) == list(frame.columns)
    assert np.array_equal(back.index.to_numpy(), frame.index.to_numpy())
    for c in ("x", "y"):   # bit for bit (NaN where NaN; -0.0 keeps its sign)
        assert np.array_equal(back[c].to_numpy().view(np.int64), frame[c].to_numpy().view(np.int64)) or (
            np.array_equal(np.isnan(back[c]), np.isnan(frame[c]))
            and np.array_equal(back[c].dropna().to_numpy().view(np.int64), frame[c].dropna().to_numpy().view(np.int64)))
    assert back["ok"].dtype == bool and np.array_equal(back["ok"], frame["ok"])
    assert np.array_equal(back["n"], frame["n"])
    assert back["frame"].tolist() == frame["frame"].tolist()
    if fmt == "csv":
        assert path.read_text().splitlines()[0] == "t_ns,x,y,ok,n,frame"
