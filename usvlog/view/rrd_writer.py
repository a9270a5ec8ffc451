"""The writer of one log: sends its arrays to the recording and remembers which view shows what.

A :class:`_Writer` holds the helpers every part uses (the colour of a role, labels, the time
columns, a scalar series, positions on the map, labels in the local view, static entities)
and what the blueprint (:mod:`usvlog.view.rrd_blueprint`) needs afterwards: the entities of
each view, the series names, their ranges, the overlays hidden by default, the map's extent.
:meth:`_Writer.draw` draws the log part by part; each part is a method written in a module of
its own: the map and local view (:mod:`usvlog.view.rrd_tracks`), the time series
(:mod:`usvlog.view.rrd_series`) and the text entries (:mod:`usvlog.view.rrd_events`). A log read a
time window at a time (:class:`usvlog.view.windowed.WindowedLog`) has its big channels' series sent
a block at a time first (:mod:`usvlog.view.rrd_windows`), then the rest drawn as for a whole log.
"""

from __future__ import annotations

from collections import defaultdict

import numpy as np
import rerun as rr

from ..log.fieldlog import FieldLog
from ..model.frames import Datum, ned_to_geodetic
from . import data as vd
from . import rrd_events, rrd_series, rrd_tracks, rrd_windows
from .rrd_style import ROLE, RUN_COLORS, SERIES_PALETTE, _mix, break_wraps, scalar_column
from .windowed import WindowedLog


class _Writer:
    """Sends one log's arrays to a recording and remembers which view wants which entity."""

    def __init__(self, rec: rr.RecordingStream, log: FieldLog, name: str, index: int, multi: bool):
        self.rec, self.log, self.name, self.index, self.multi = rec, log, name, index, multi
        self.prefix = f"/runs/{name}"
        self.views: dict[str, list[str]] = defaultdict(list)
        self.series: dict[str, list[str]] = defaultdict(list)     # view -> series names, in order
        self.ranges: dict[str, list[float]] = {}                  # view -> [min, max] of its values
        self.hidden: list[str] = []                               # entities drawn but toggled off by default
        self.colors: dict[str, list] = defaultdict(list)          # view -> colours its series use
        self.tags: list[tuple] = []                               # (x, y, label, colour) of the local view's layers
        self.geo_box: list[np.ndarray] = []   # [lat_min, lon_min, lat_max, lon_max] of what went on the map
        # a log drawn a block at a time (rrd_windows): each series' plot, colour and range settled at the end
        self.pending: dict[str, dict] | None = None   # series path -> its settings and range, in the order called
        self.dry = False                              # only note the series called (their order), send nothing
        self.carry: dict[str, tuple] = {}             # series path -> its last sample sent (where a wrap breaks)
        self.thinned = False                          # the tracks' frames are thinned to OVERLAY_HZ already
        self.tau_facts: dict = {}                     # the whole thrust channel's unit and forces (vd.recorded_tau)
        tr = log.time_range()
        self.t0 = tr[0] if tr else 0
        self.datum = log.datum
        g = vd.gps(log)
        if self.datum is None and g is not None and len(g[0]) and np.isfinite(g[1][0]):
            self.datum = Datum(lat_deg=float(g[1][0]), lon_deg=float(g[2][0]))

    # -- helpers ---------------------------------------------------------------
    def color(self, role: str, variant: str = "") -> tuple[int, int, int]:
        if not self.multi:
            c = ROLE.get(role, (100, 100, 100))
        else:
            c = RUN_COLORS[self.index % len(RUN_COLORS)]
        if variant == "light":
            c = _mix(c, (255, 255, 255), 0.45)
        elif variant == "dark":
            c = _mix(c, (0, 0, 0), 0.4)
        return c

    def label(self, s: str) -> str:
        return f"{self.name}: {s}" if self.multi else s

    def index_cols(self, t_ns: np.ndarray):
        t_ns = np.asarray(t_ns, dtype=np.int64)
        cols = [rr.TimeColumn("time", timestamp=t_ns.view("datetime64[ns]"))]   # a view: rerun copies it once
        if self.multi:  # runs recorded at different times overlay on the time since each one's start
            cols.append(rr.TimeColumn("elapsed", duration=(t_ns - self.t0).view("timedelta64[ns]")))
        return cols

    def scalars(self, view: str, sub: str, t_ns, y, *, name: str, color=None, width: float = 1.5,
                step: bool = False, gaps: bool = False) -> None:
        """One time series; ``color`` None picks the next distinct colour of the view; ``gaps``
        keeps NaN samples that follow a finite one (a break in the line, e.g. where a heading wraps).

        In a log drawn a block at a time (:attr:`pending` not None) each call sends the block's
        samples; the series' plot, colour and range are settled by :meth:`settle` at the end, in
        the order of the calls, as the whole log's drawing settles them."""
        path = f"{self.prefix}/ts/{sub}"
        if self.pending is not None:
            entry = self.pending.setdefault(path, {"args": (view, name, color, width, step)})
            if self.dry:
                return
        y = np.asarray(y, dtype=float)
        t_ns = np.asarray(t_ns, dtype=np.int64)
        ok = np.isfinite(y)
        if not ok.any():
            return
        if gaps:   # a wrapped angle: a NaN sample breaks the line where it wraps (after the last block's too)
            last = self.carry.get(path)
            if last is None:
                t_ns, y = break_wraps(t_ns[ok], y[ok])
            else:
                t_ns, y = (a[1:] for a in break_wraps(np.r_[last[0], t_ns[ok]], np.r_[last[1], y[ok]]))
            if self.pending is not None:
                self.carry[path] = (t_ns[-1], y[-1])
            ok = np.ones(len(y), bool)
        if not ok.all():
            t_ns, y = t_ns[ok], y[ok]
        index, column = self.index_cols(t_ns), scalar_column(y)
        # the series before written out now, not sooner: rerun encodes it on its own thread while this one
        # was built; every sample of the log is a series sample, and rerun's pipeline would otherwise hold
        # them all until the end (1-hour log: 80 MB less at the peak)
        self.rec.flush()
        if self.pending is None:
            self._series_lines(view, path, name, color, width, step)
        self.rec.send_columns(path, indexes=index, columns=column)
        fin = y[np.isfinite(y)]
        lo, hi = float(fin.min()), float(fin.max())
        r = self.ranges.setdefault(view, [lo, hi]) if self.pending is None else entry.setdefault("range", [lo, hi])
        r[0], r[1] = min(r[0], lo), max(r[1], hi)

    def _series_lines(self, view: str, path: str, name: str, color, width: float, step: bool) -> None:
        """A series' plot, name, colour (the next distinct one of its plot when ``color`` is None or
        taken) and line style."""
        used = self.colors[view]
        if color is None or tuple(color) in used:   # every series of a plot in its own colour
            free = [c for c in SERIES_PALETTE if c not in used]
            color = free[0] if free else SERIES_PALETTE[len(used) % len(SERIES_PALETTE)]
        kw = {"interpolation_mode": rr.components.InterpolationMode.StepAfter} if step else {}
        self.rec.log(path, rr.SeriesLines(colors=[color], names=[self.label(name)], widths=[width], **kw),
                     static=True)
        self.views[view].append(path)
        self.series[view].append(name)
        used.append(tuple(color))

    def settle(self) -> None:
        """The series sent a block at a time given their plots, colours and ranges, in the order called."""
        for path, entry in (self.pending or {}).items():
            if "range" in entry:   # a series with no finite sample is not drawn
                view, name, color, width, step = entry["args"]
                self._series_lines(view, path, name, color, width, step)
                lo, hi = entry["range"]
                r = self.ranges.setdefault(view, [lo, hi])
                r[0], r[1] = min(r[0], lo), max(r[1], hi)
        self.pending, self.carry = None, {}

    def thin(self, t_ns: np.ndarray) -> np.ndarray:
        """The rows of a track or an overlay drawn: at most :data:`usvlog.view.data.OVERLAY_HZ` a second
        (all of a frame thinned already)."""
        return np.arange(len(t_ns)) if self.thinned else vd.thin_indices(t_ns, vd.OVERLAY_HZ)

    def geo(self, n, e):
        lat, lon, _ = ned_to_geodetic(np.asarray(n, float), np.asarray(e, float), 0.0, datum=self.datum)
        return self.note_geo(np.column_stack([lat, lon]))

    def note_geo(self, latlon: np.ndarray) -> np.ndarray:
        ok = np.isfinite(latlon).all(1)
        if ok.any():
            self.geo_box.append(np.r_[latlon[ok].min(0), latlon[ok].max(0)])
        return latlon

    def tag(self, e, n, text: str, color) -> None:
        """Name a layer of the local view: a label on one of its points, each layer's at another
        place along its line (a legend drawn where the layers are, not piled up in the middle)."""
        e, n = np.asarray(e, float), np.asarray(n, float)
        ok = np.nonzero(np.isfinite(e) & np.isfinite(n))[0]
        if not len(ok):
            return
        k = ok[int((0.15 + 0.17 * len(self.tags)) % 0.95 * (len(ok) - 1))]
        self.tags.append((float(e[k]), float(-n[k]), self.label(text), tuple(color[:3])))

    def draw_tags(self) -> None:
        if self.tags:
            xy = np.array([t[:2] for t in self.tags])
            self.static("local", "local/labels", rr.Points2D(
                xy, radii=rr.Radius.ui_points(3.0), colors=[t[3] for t in self.tags],
                labels=[t[2] for t in self.tags], show_labels=True, draw_order=50.0))

    def static(self, view: str, sub: str, archetype) -> None:
        path = f"{self.prefix}/{sub}"
        self.rec.log(path, archetype, static=True)
        self.views[view].append(path)

    # -- the drawing -------------------------------------------------------------
    def draw(self) -> None:
        """Draw the log: its big channels a block at a time for a windowed log (:mod:`usvlog.view.rrd_windows`)."""
        if isinstance(self.log, WindowedLog):
            self.draw_blocks()
        else:
            self.draw_state_series()
        self.draw_tracks()
        self.draw_tags()
        self.draw_controllers()
        self.draw_series()
        self.draw_events()
        self.draw_findings()
        self.draw_manoeuvres()

    # each part in a module of its own, a method all the same
    draw_blocks = rrd_windows.draw_blocks
    draw_tracks = rrd_tracks.draw_tracks
    draw_controllers = rrd_tracks.draw_controllers
    draw_state_series = rrd_series.draw_state_series
    draw_series = rrd_series.draw_series
    draw_events = rrd_events.draw_events
    draw_manoeuvres = rrd_events.draw_manoeuvres
    draw_findings = rrd_events.draw_findings
