"""CSV logs, one chunk of rows at a time: cells to numbers and times, rows to role streams.

An empty cell means "no sample of that stream at this time", never zero; a cell that does not
parse is skipped and counted (``csv_bad_value``), as is a row whose time is unusable
(``csv_bad_time``). A GNSS fix needs both latitude and longitude in the row, a position both
north and east, a thrust sample both commands (a row with one of a pair is counted).
:class:`Chunker` keeps what carries from one chunk to the next (whether the time is relative,
its first value, the thrust unit once guessed, held GNSS positions). The file itself, the mapping
and the guesses made from its first rows are :mod:`usvlog.io.importers.csvlog`'s.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from .core import text_column
from .held import Held, held_mask
from .thrust_guess import guess_thrust_unit

VALUE_ROLES = ("lat_deg", "lon_deg", "alt_m", "heading_deg", "heading_rad", "thrust_left", "thrust_right",
                "yaw_rate_degps", "yaw_rate_radps", "speed_mps", "course_deg", "thrust_left_dir",
                "thrust_right_dir", "local_n", "local_e")
_NAN_TEXT = {"nan", "NaN", "NAN", "-nan", "+nan", "n/a", "NA", "null", "None"}


def numeric_cells(col: pd.Series, role: str, header: str, line0: int, report) -> tuple[np.ndarray, np.ndarray]:
    """(values, present) of one chunk column; unparseable non-empty cells are counted and absent."""
    dt = col.dtype
    if pd.api.types.is_numeric_dtype(dt) and not pd.api.types.is_bool_dtype(dt):
        v = col.to_numpy(dtype=float, na_value=np.nan)
        return v, ~np.isnan(v)
    s = col.astype("str")
    s = s.where(col.notna(), "")
    text = s.str.strip()
    v = pd.to_numeric(text, errors="coerce").to_numpy(dtype=float, na_value=np.nan)
    empty = (text == "").to_numpy()
    nan_text = text.isin(_NAN_TEXT).to_numpy()
    bad = np.isnan(v) & ~empty & ~nan_text
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        report.skip("csv_bad_value", int(bad.sum()),
                    where=f"line {line0 + i}: column {header!r} value {text.iloc[i][:40]!r}")
    return v, ~empty & ~bad


_NS_PER = {"s": 1_000_000_000, "ms": 1_000_000, "us": 1_000, "ns": 1}
ROLE_NS = {"time_s": 1e9, "time_ms": 1e6, "time_us": 1e3, "time_ns": 1.0}   # ns per tick of a time role
TIME_ROLES = ("time_ns", "time_s", "time_ms", "time_us", "time_iso")


def datetimes_ns(arr: np.ndarray) -> np.ndarray:
    """datetime64 values (any of s/ms/us/ns: pandas picks the resolution) -> int64 ns since
    the epoch; -1 for NaT and for times before 1970 or past what int64 ns holds (2262)."""
    unit = np.datetime_data(arr.dtype)[0]
    per = _NS_PER[unit]
    v = arr.view(np.int64)
    ok = ~np.isnat(arr) & (v >= 0) & (v < np.iinfo(np.int64).max // per)
    return np.where(ok, np.where(ok, v, 0) * per, -1).astype(np.int64)


def times_ns(col: pd.Series, kind: str, start_ns: int | None, report, header: str, line0: int,
           state: dict) -> np.ndarray:
    """Record times in ns (int64); rows with no usable time get -1."""
    if kind == "time_iso" or (kind == "time_s" and not pd.api.types.is_numeric_dtype(col.dtype)
                              and state.get("iso", None) is not False):
        num = pd.to_numeric(col, errors="coerce") if kind == "time_s" else None
        if num is not None and num.notna().sum() >= max(1, int(0.5 * col.notna().sum())):
            state["iso"] = False
            return times_ns(num, "time_s", start_ns, report, header, line0, state)
        state["iso"] = True
        ts = pd.to_datetime(col.astype("str"), format="ISO8601", utc=True, errors="coerce")
        return datetimes_ns(ts.dt.tz_localize(None).to_numpy())
    if kind == "time_ns" and pd.api.types.is_integer_dtype(col.dtype) and not state.get("relative"):
        t = col.to_numpy(dtype=np.int64)
        return np.where(t >= 0, t, -1)
    v, present = numeric_cells(col, kind, header, line0, report) if not pd.api.types.is_numeric_dtype(col.dtype) \
        else (col.to_numpy(dtype=float, na_value=np.nan), col.notna().to_numpy())
    if kind == "time_ns" and not state.get("relative"):
        t = np.where(present & np.isfinite(v), v, -1.0)
        return t.astype(np.int64)
    ns_per = ROLE_NS[kind]
    if "first" not in state:
        fin = v[np.isfinite(v) & (v >= 0)]
        if len(fin):
            state.setdefault("relative", bool(np.median(fin) * ns_per < 1e17))   # 1e8 s: before 1973
            state["first"] = float(fin[0])   # --start-utc is the time of the first sample
            if state["relative"] and start_ns is None:
                report.guesses["start_utc"] = "1970-01-01T00:00:00Z"
                report.note(f"time column {header!r} is relative and no --start-utc was given: "
                            "times start at the Unix epoch")
    rel = state.get("relative", False)
    with np.errstate(invalid="ignore", over="ignore"):
        # relative times to the ns; epoch times (float64: ~0.2 us resolution in seconds) to the us
        t = np.round(v * ns_per) if rel else np.round(v * (ns_per / 1000))
        ok = np.isfinite(t) & (t >= 0) & (t < (2**62 if rel else 2**62 / 1000))
        ti = np.where(ok, t, -1).astype(np.int64)
        if not rel:
            ti = np.where(ok, ti * 1000, -1)
    if rel:
        first = int(round(state.get("first", 0.0) * ns_per)) if start_ns is not None else 0
        ti = np.where(ok, ti - first + int(start_ns or 0), -1)
        ti = np.where(ti >= 0, ti, -1)
    return ti


def _both(pres: dict, a: str, b: str, good_t: np.ndarray, report, reason: str) -> np.ndarray:
    """Rows with a good time and both columns of a pair (lat/lon, left/right); rows with one are counted."""
    none = np.zeros(len(good_t), bool)
    pa, pb = pres.get(a, none) & good_t, pres.get(b, none) & good_t
    report.skip(reason, int(np.sum(pa ^ pb)))
    return pa & pb


class Chunker:
    """One chunk of rows -> a batch of role streams (state: relative time, thrust unit)."""

    def __init__(self, mapping: dict, time_role: str, opts, report, *, state: dict | None = None,
                 held: Held | None = None):
        self.mapping = mapping
        self.time_role = time_role
        self.start_ns = opts.start_utc_ns
        self.thrust_unit = opts.thrust_unit
        self.report = report
        self.state: dict = dict(state or {})
        self.held = held
        self.hold_state = None

    def batch(self, chunk: pd.DataFrame, line0: int) -> dict:
        """The role streams of one chunk of rows (``line0``: the file's line of its first row, for
        the messages): ``{stream: {column: array}}`` for the streams the mapping feeds (``gnss``,
        ``local``, ``heading``, ``yaw_rate``, ``velocity``, ``thrust``), bad cells and rows counted
        in the report."""
        mapping, time_role, report = self.mapping, self.time_role, self.report
        n = len(chunk)
        t = times_ns(chunk[mapping[time_role]], time_role, self.start_ns, report, mapping[time_role], line0,
                   self.state)
        good_t = t >= 0
        vals, pres = {}, {}
        for role in VALUE_ROLES:
            if role in mapping:
                vals[role], pres[role] = numeric_cells(chunk[mapping[role]], role, mapping[role], line0, report)
        any_val = np.zeros(n, bool)
        for role in pres:
            any_val |= pres[role]
        bad_t = ~good_t & any_val
        if bad_t.any():
            i = int(np.flatnonzero(bad_t)[0])
            report.skip("csv_bad_time", int(bad_t.sum()),
                        where=f"line {line0 + i}: time {str(chunk[mapping[time_role]].iloc[i])[:40]!r}")
        batch = {}
        if "lat_deg" in pres or "lon_deg" in pres:
            both = _both(pres, "lat_deg", "lon_deg", good_t, report, "gnss_incomplete")
            g = {"t_ns": t[both], "lat_deg": vals["lat_deg"][both], "lon_deg": vals["lon_deg"][both]}
            if "alt_m" in vals:
                g["alt_m"] = np.where(pres["alt_m"][both], vals["alt_m"][both], np.nan)
            if self.held is not None:
                g["held"], self.hold_state = held_mask(g["t_ns"], [g["lat_deg"], g["lon_deg"]],
                                                       self.held.update_s, self.hold_state)
            batch["gnss"] = g
        if "local_n" in pres or "local_e" in pres:
            both = _both(pres, "local_n", "local_e", good_t, report, "local_incomplete")
            batch["local"] = {"t_ns": t[both], "n_m": vals["local_n"][both], "e_m": vals["local_e"][both],
                              "frame_id": text_column(int(both.sum()), f"csv {self.mapping['local_n']}/"
                                                                       f"{self.mapping['local_e']} (north/east m)")}
        for role, scale in (("heading_deg", np.pi / 180.0), ("heading_rad", 1.0)):
            if role in pres:
                m = pres[role] & good_t
                batch["heading"] = {"t_ns": t[m], "heading_rad": vals[role][m] * scale,
                                    "reference": text_column(int(m.sum()), "true")}
                break
        for role, scale in (("yaw_rate_degps", np.pi / 180.0), ("yaw_rate_radps", 1.0)):
            if role in pres:
                m = pres[role] & good_t
                batch["yaw_rate"] = {"t_ns": t[m], "r_radps": vals[role][m] * scale}
                break
        if "speed_mps" in pres:
            m = pres["speed_mps"] & good_t
            v = {"t_ns": t[m], "sog_mps": vals["speed_mps"][m]}
            if "course_deg" in pres:
                v["cog_rad"] = np.where(pres["course_deg"][m], np.radians(vals["course_deg"][m]), np.nan)
            batch["velocity"] = v
        if "thrust_left" in pres or "thrust_right" in pres:
            both = _both(pres, "thrust_left", "thrust_right", good_t, report, "thrust_incomplete")
            left = vals["thrust_left"][both] if "thrust_left" in vals else np.zeros(0)
            right = vals["thrust_right"][both] if "thrust_right" in vals else np.zeros(0)
            if self.thrust_unit is None and both.any():
                self.thrust_unit = guess_thrust_unit(left, right)
                report.guesses["thrust_unit"] = self.thrust_unit
            batch["thrust"] = {"t_ns": t[both], "left": left, "right": right,
                               "unit": text_column(int(both.sum()), self.thrust_unit or "newton")}
            for role, col in (("thrust_left_dir", "left_dir"), ("thrust_right_dir", "right_dir")):
                if role in vals:   # direction flags: an empty cell is forward (0)
                    batch["thrust"][col] = np.where(pres[role][both], vals[role][both], 0.0)
        return batch
