"""FieldLog.copy: shares the frames by default (documented), copies them with deep=True."""

import numpy as np
import pandas as pd

from usvlog.log.fieldlog import FieldLog


def _log() -> FieldLog:
    frame = pd.DataFrame({"x_m": [1.0, 2.0, 3.0]}, index=pd.Index(np.array([10, 20, 30], dtype=np.int64), name="t_ns"))
    log = FieldLog(channels={"/a": frame}, meta={"usvlog.datum": {"lat_deg": "1.0"}})
    log.add_provenance(producer="test")
    return log


def test_shallow_copy_shares_frames_but_not_the_channel_table_or_metadata():
    log = _log()
    cp = log.copy()
    assert cp.channels["/a"] is log.channels["/a"]  # shared: no memory spent on a copy
    cp.set("/b", log["/a"] * 2)
    cp.add_provenance(producer="second")
    cp.meta["usvlog.datum"]["lat_deg"] = "2.0"
    assert log.topics == ["/a"] and cp.topics == ["/a", "/b"]
    assert len(log.provenance) == 1 and len(cp.provenance) == 2
    assert log.meta["usvlog.datum"]["lat_deg"] == "1.0"
    cp["/a"].iloc[0, 0] = -1.0  # in place: seen by both, as the docstring says
    assert log["/a"].iloc[0, 0] == -1.0


def test_deep_copy_owns_its_frames():
    log = _log()
    cp = log.copy(deep=True)
    assert cp.equals(log)
    cp["/a"].iloc[0, 0] = -1.0
    assert log["/a"]["x_m"].tolist() == [1.0, 2.0, 3.0]
    assert cp["/a"]["x_m"].tolist() == [-1.0, 2.0, 3.0]
