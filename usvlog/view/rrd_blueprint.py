"""The viewer's layout for what the writers drew, stored in the .rrd as its default blueprint.

Left: the map and local-NED tabs (with side-by-side views for several runs) over the events;
right: surge speed and heading in sight, the other series in tabs, each plot titled by what it
holds (:func:`series_title`) and ranged to its data with room for the legend
(:func:`y_range`); the map zoomed to the tracks (:func:`map_zoom`).
"""

from __future__ import annotations

import math
from collections import defaultdict
from typing import TYPE_CHECKING

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

if TYPE_CHECKING:
    from .rrd_writer import _Writer


SERIES_VIEWS = [  # (key, title: its unit; the series it holds are appended from what was drawn)
    ("u", "Surge speed (m/s)"), ("psi", "Heading (deg, wrapped)"), ("cross_track", "Cross-track error (m)"),
    ("v", "Sway speed (m/s)"), ("r", "Yaw rate (deg/s)"), ("tau_u", "Surge force tau_u (N)"),
    ("tau_r", "Yaw moment tau_r (N m)"), ("nis", "NIS (normalised innovation squared)"),
    ("current", "Water current (m/s)"), ("saturation", "Thrusters saturated (0/1)"),
    ("fit_u", "Identification: u (m/s)"), ("fit_v", "Identification: v (m/s)"),
    ("fit_r", "Identification: r (deg/s)"),
]
# the smallest y span a plot shows (in its unit), so a nearly constant series is not blown up to noise
MIN_SPAN = {"psi": 20.0, "u": 0.2, "v": 0.1, "r": 5.0, "cross_track": 0.5, "tau_u": 2.0, "tau_r": 1.0, "nis": 2.0,
            "current": 0.1, "fit_u": 0.2, "fit_v": 0.1, "fit_r": 5.0}
FIXED_RANGE = {"psi": (-185.0, 185.0), "saturation": (-0.1, 1.1)}
LEGEND_ROOM = 0.35   # head room above the data, as a fraction of the span, where the legend sits


def series_title(key: str, base: str, names: list[str], max_names: int = 5) -> str:
    """A plot's title from what it holds: ``Surge speed (m/s): u estimate, u truth, u_d control``."""
    uniq = list(dict.fromkeys(names))
    if not uniq:
        return base
    if len(uniq) > max_names:
        return f"{base}: {', '.join(uniq[:max_names])} and {len(uniq) - max_names} more"
    return f"{base}: {', '.join(uniq)}"


def y_range(key: str, lo: float, hi: float) -> tuple[float, float]:
    """The y range of a plot holding values in [lo, hi]: at least ``MIN_SPAN``, with room for the legend
    above the data (fixed for a heading that wraps, -180 to 180 degrees, and the 0/1 saturation flag)."""
    if key in FIXED_RANGE and not (key == "psi" and hi - lo < 300.0):   # a heading that never wraps: fitted
        a, b = FIXED_RANGE[key]
        return a, b + LEGEND_ROOM * (b - a)
    span = max(hi - lo, MIN_SPAN.get(key, 0.0), 1e-9)
    mid = 0.5 * (lo + hi)
    a, b = mid - 0.55 * span, mid + 0.55 * span
    return a, b + LEGEND_ROOM * (b - a)


def map_zoom(boxes: np.ndarray, pixels: float = 500.0) -> float:
    """OpenStreetMap zoom level at which the boxes' extent spans about ``pixels`` pixels."""
    lat0, lon0 = boxes[:, 0].min(), boxes[:, 1].min()
    lat1, lon1 = boxes[:, 2].max(), boxes[:, 3].max()
    c = math.cos(math.radians(0.5 * (lat0 + lat1)))
    span = max((lat1 - lat0) * 111_320.0, (lon1 - lon0) * 111_320.0 * c, 20.0)   # metres
    # at zoom z one 256-px tile spans 40 075 km cos(lat) / 2^z, i.e. 156 543 m cos(lat) / 2^z per pixel
    return float(np.clip(math.log2(156_543.03 * c * pixels / span), 2.0, 21.0))


def build_blueprint(writers: list[_Writer]) -> rrb.Blueprint:
    """The viewer layout for what the writers drew.

    Left: map and local-NED tabs (plus side-by-side views for several runs) over the
    event log; right: surge speed and heading series, the others in tabs. The time
    panel starts on ``time`` for one log and ``elapsed`` for several.
    """
    views: dict[str, list[str]] = defaultdict(list)
    for w in writers:
        for k, v in w.views.items():
            views[k].extend(v)
    spatial: list = []
    if views["map"]:
        boxes = [b for w in writers for b in w.geo_box]
        zoom = map_zoom(np.array(boxes)) if boxes else None
        spatial.append(rrb.MapView(name="Map", origin="/", contents=views["map"], zoom=zoom))
    if views["local"]:
        title = "Local NED (m), north up" + (", all runs" if len(writers) > 1 else "")
        hidden = {p: rrb.EntityBehavior(visible=False) for w in writers for p in w.hidden}
        spatial.append(rrb.Spatial2DView(name=title, origin="/", contents=views["local"], overrides=hidden))
        if len(writers) > 1:
            side = [rrb.Spatial2DView(name=f"{w.name}: local", origin="/", contents=w.views["local"])
                    for w in writers if w.views.get("local")]
            spatial.append(rrb.Horizontal(*side, name="Side by side"))
    left: list = []
    if spatial:
        left.append(rrb.Tabs(*spatial, name="Tracks"))
    if views["events"]:
        left.append(rrb.TextLogView(name="Events", origin="/", contents=views["events"]))
    # u and psi always in sight; the rest in tabs, the cross-track error first
    timeline = "elapsed" if len(writers) > 1 else "time"
    whole = [rrb.VisibleTimeRange(timeline, start=rrb.TimeRangeBoundary.infinite(),
                                  end=rrb.TimeRangeBoundary.infinite())]   # all the data, wherever the cursor is
    spans = [w.log.time_range() for w in writers]
    if len(writers) > 1:
        t_lo, t_hi = 0, max(b - a for a, b in spans)
    else:
        t_lo, t_hi = spans[0]
    axis_x = rrb.TimeAxis(view_range=rr.TimeRange(start=rrb.TimeRangeBoundary.absolute(nanos=int(t_lo)),
                                                  end=rrb.TimeRangeBoundary.absolute(nanos=int(t_hi))))
    series = {}
    for key, base in SERIES_VIEWS:
        if not views[key]:
            continue
        names = [n for w in writers for n in w.series.get(key, [])]
        rs = [w.ranges[key] for w in writers if key in w.ranges]
        lo, hi = min(r[0] for r in rs), max(r[1] for r in rs)
        series[key] = rrb.TimeSeriesView(
            name=series_title(key, base, names), origin="/", contents=views[key], time_ranges=whole, axis_x=axis_x,
            axis_y=rrb.ScalarAxis(range=y_range(key, lo, hi)),
            plot_legend=rrb.PlotLegend(rrb.Corner2D.RightTop, visible=True))
    right = [series[k] for k in ("u", "psi") if k in series]
    rest = [v for k, v in series.items() if k not in ("u", "psi")]
    if rest:
        right.append(rrb.Tabs(*rest, name="More series"))
    cols = []
    if left:
        cols.append(rrb.Vertical(*left, row_shares=[3, 1][:len(left)]))
    if right:
        cols.append(rrb.Vertical(*right))
    if not cols:
        cols = [rrb.TextLogView(name="Events", origin="/")]
    return rrb.Blueprint(rrb.Horizontal(*cols, column_shares=[1, 1][:len(cols)]),
                         rrb.TimePanel(timeline=timeline, play_state="paused"), collapse_panels=False)
