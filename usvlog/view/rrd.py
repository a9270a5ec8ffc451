"""Rerun visualisation of runs and replays: FieldLog(s) -> .rrd with a blueprint inside.

The only module that imports rerun. Everything is sent with ``send_columns`` (whole
arrays at once); per-row logging is some 50x slower (see benchmarks/bench_view.py).

Entity tree, one subtree per log (``name`` defaults to the log file's stem)::

    /runs/<name>/map/{gps, gps_rejected, estimate, truth, whatif, path, boat}   GeoPoints / GeoLineStrings
    /runs/<name>/local/{...same..., ctl_<ctl>/closest, ctl_<ctl>/carrot, ctl_<ctl>/arrows} 2D, x = east, y = -north
    /runs/<name>/ts/<quantity>/<series>                                       Scalars (fit/: identification)
    /runs/<name>/events                                                       TextLog
    /runs/<name>/check                                   TextLog: the findings of usvlog check, at their start
    /runs/<name>/manoeuvres (start and end of each), /runs/<name>/local/manoeuvres (its stretch)

``<ctl>`` is ``control`` (closed-loop simulation), ``replay`` (controller replayed on a
recorded run) or ``whatif``. The local 2D view draws x = east and y = -north, so with
the viewer's y axis pointing down north is up and east is right. Timeline ``time`` (UTC); with
several logs also ``elapsed`` (since each log's start, so runs recorded on different days overlay).
Tracks and per-tick overlays are thinned to at most 10 Hz; time series keep every sample.
"""

from __future__ import annotations

import contextlib
import math
import os
import re
import signal
import subprocess
import sys
import uuid
from collections import defaultdict
from pathlib import Path

import numpy as np
import pandas as pd
import rerun as rr
import rerun.blueprint as rrb

from ..errors import ConfigError, InputError
from ..io.atomic import atomic_path, check_output
from ..io.atomic import deferred_signals as _deferred
from ..log.fieldlog import FieldLog
from ..model.frames import Datum, ned_to_geodetic
from . import data as vd
from . import findings as vfind
from . import manoeuvres as vman

APP_ID = "usvlog"
OVERLAY_HZ = 10.0
DEFAULT_HOST = "127.0.0.1"

# colours of the roles (single log); several logs are coloured by run instead
TRACK_LABELS = {"estimate": "smoothed estimate", "truth": "truth (simulated)", "whatif": "what-if run"}
ROLE = {
    "gps": (150, 150, 150), "gps_rejected": (230, 30, 30), "estimate": (31, 119, 180),
    "truth": (60, 60, 60), "whatif": (148, 103, 189), "path": (255, 170, 0), "boat": (255, 90, 0),
    "closest": (40, 170, 60), "carrot": (220, 0, 200), "heading": (31, 119, 180),
    "desired": (255, 127, 14), "cog": (40, 170, 60), "recorded": (120, 120, 120),
    "control": (214, 39, 40), "replay": (140, 86, 75), "compass": (150, 150, 150),
    "n": (31, 119, 180), "e": (214, 39, 40),
}
# distinct colours of the series in one plot (Tableau 10)
SERIES_PALETTE = [(31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189), (140, 86, 75),
                  (227, 119, 194), (127, 127, 127), (188, 189, 34), (23, 190, 207)]
RUN_COLORS = [(31, 119, 180), (214, 39, 40), (44, 160, 44), (148, 103, 189), (255, 127, 14), (23, 190, 207)]


def _mix(c, w, k):
    return tuple(int(round(a * (1 - k) + b * k)) for a, b in zip(c, w))


def _safe(name: str) -> str:
    s = re.sub(r"[^A-Za-z0-9_-]+", "_", name).strip("_")
    return s or "run"


def default_names(logs: list[FieldLog]) -> list[str]:
    """Entity names of the logs: each file's stem made safe (``run<i>`` without a source),
    with ``_2``, ``_3`` ... appended to repeats."""
    out: list[str] = []
    for i, log in enumerate(logs):
        base = _safe(Path(log.source).stem) if log.source else f"run{i}"
        name, k = base, 2
        while name in out:
            name, k = f"{base}_{k}", k + 1
        out.append(name)
    return out


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
        keeps NaN samples that follow a finite one (a break in the line, e.g. where a heading wraps)."""
        y = np.asarray(y, dtype=float)
        t_ns = np.asarray(t_ns, dtype=np.int64)
        ok = np.isfinite(y)
        if not ok.any():
            return
        if gaps:   # a wrapped angle: a NaN sample breaks the line where it wraps
            t_ns, y = break_wraps(t_ns[ok], y[ok])
            ok = np.ones(len(y), bool)
        used = self.colors[view]
        if color is None or tuple(color) in used:   # every series of a plot in its own colour
            free = [c for c in SERIES_PALETTE if c not in used]
            color = free[0] if free else SERIES_PALETTE[len(used) % len(SERIES_PALETTE)]
        path = f"{self.prefix}/ts/{sub}"
        kw = {"interpolation_mode": rr.components.InterpolationMode.StepAfter} if step else {}
        if not ok.all():
            t_ns, y = t_ns[ok], y[ok]
        index, column = self.index_cols(t_ns), scalar_column(y)
        # the series before written out now, not sooner: rerun encodes it on its own thread while this one
        # was built; every sample of the log is a series sample, and rerun's pipeline would otherwise hold
        # them all until the end (1-hour log: 80 MB less at the peak)
        self.rec.flush()
        self.rec.log(path, rr.SeriesLines(colors=[color], names=[self.label(name)], widths=[width], **kw),
                     static=True)
        self.rec.send_columns(path, indexes=index, columns=column)
        self.views[view].append(path)
        self.series[view].append(name)
        used.append(tuple(color))
        fin = y[np.isfinite(y)]
        lo, hi = float(fin.min()), float(fin.max())
        r = self.ranges.setdefault(view, [lo, hi])
        r[0], r[1] = min(r[0], lo), max(r[1], hi)

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
        self.draw_tracks()
        self.draw_tags()
        self.draw_controllers()
        self.draw_series()
        self.draw_events()
        self.draw_findings()
        self.draw_manoeuvres()

    def draw_tracks(self) -> None:
        log = self.log
        g = vd.gps(log)
        if g is not None and len(g[0]):
            t, lat, lon, n, e = g
            c = (*self.color("gps"), 110)   # small and translucent, under the tracks
            on_map = bool(np.isfinite(lat).any())   # positions in metres without a datum: no map
            if on_map:
                self.static("map", "map/gps", rr.GeoPoints(lat_lon=self.note_geo(np.column_stack([lat, lon])),
                                                            radii=rr.Radius.ui_points(1.5), colors=[c]))
            self.static("local", "local/gps", rr.Points2D(np.column_stack([e, -n]), radii=rr.Radius.ui_points(1.5),
                                                          colors=[c], draw_order=5.0))
            self.tag(e, n, "GPS fixes", self.color("gps"))
            rej = vd.gps_rejections(log)
            if rej is not None and len(rej[0]):
                k = np.clip(np.searchsorted(t, rej[0]), 0, len(t) - 1)
                c = self.color("gps_rejected", "dark")
                if on_map:
                    self.static("map", "map/gps_rejected", rr.GeoPoints(
                        lat_lon=np.column_stack([lat[k], lon[k]]), radii=rr.Radius.ui_points(5.0), colors=[c]))
                self.static("local", "local/gps_rejected", rr.Points2D(
                    np.column_stack([e[k], -n[k]]), radii=rr.Radius.ui_points(5.0), colors=[c],
                    labels=[self.label("GPS rejected")], show_labels=True, draw_order=30.0))
        path = vd.path_polyline(log)
        if path is not None and self.datum is not None:
            c = self.color("path", "light")
            self.static("map", "map/path", rr.GeoLineStrings(lat_lon=[self.geo(path[:, 0], path[:, 1])],
                                                              radii=rr.Radius.ui_points(2.0), colors=[c]))
            self.static("local", "local/path", rr.LineStrips2D([np.column_stack([path[:, 1], -path[:, 0]])],
                                                               radii=rr.Radius.ui_points(1.5), colors=[c],
                                                               draw_order=10.0))
            self.tag(path[:, 1], path[:, 0], "desired path", c)
        for _topic, label, f in vd.state_tracks(log):
            t = np.asarray(f.index.to_numpy(), dtype=np.int64)
            k = vd.thin_indices(t, OVERLAY_HZ)
            n, e = np.asarray(f["n_m"].to_numpy(), float)[k], np.asarray(f["e_m"].to_numpy(), float)[k]
            ok = np.isfinite(n) & np.isfinite(e)
            n, e = n[ok], e[ok]
            if len(n) < 2:
                continue
            c = self.color(label, {"truth": "dark", "whatif": "light"}.get(label, ""))
            if self.datum is not None:
                self.static("map", f"map/{label}", rr.GeoLineStrings(lat_lon=[self.geo(n, e)],
                                                                      radii=rr.Radius.ui_points(1.5), colors=[c]))
            self.static("local", f"local/{label}", rr.LineStrips2D([np.column_stack([e, -n])],
                                                                   radii=rr.Radius.ui_points(1.0), colors=[c],
                                                                   draw_order=20.0))
            self.tag(e, n, TRACK_LABELS.get(label, label), c)
        # the boat, over time
        b = vd.boat_state(log)
        if b is not None:
            f = b[1]
            t = np.asarray(f.index.to_numpy(), dtype=np.int64)
            n, e = np.asarray(f["n_m"].to_numpy(), float), np.asarray(f["e_m"].to_numpy(), float)
        elif g is not None and len(g[0]):
            t, n, e = g[0], g[3], g[4]
        else:
            return
        k = vd.thin_indices(t, OVERLAY_HZ)
        k = k[np.isfinite(n[k]) & np.isfinite(e[k])]
        if not len(k):
            return
        c = self.color("boat", "dark")
        cols = self.index_cols(t[k])
        if self.datum is not None:
            path = f"{self.prefix}/map/boat"
            self.rec.log(path, rr.GeoPoints.from_fields(radii=rr.Radius.ui_points(7.0), colors=[c]), static=True)
            self.rec.send_columns(path, indexes=cols, columns=rr.GeoPoints.columns(positions=self.geo(n[k], e[k])))
            self.views["map"].append(path)
        path = f"{self.prefix}/local/boat"
        self.rec.log(path, rr.Points2D.from_fields(radii=rr.Radius.ui_points(7.0), colors=[c], draw_order=40.0,
                                                   labels=[self.label("boat")], show_labels=True), static=True)
        self.rec.send_columns(path, indexes=cols,
                              columns=rr.Points2D.columns(positions=np.column_stack([e[k], -n[k]])))
        self.views["local"].append(path)

    def draw_controllers(self) -> None:
        ext = _extent(self.log)
        arrow = float(np.clip(0.08 * ext, 0.5, 10.0))
        ctls = vd.controllers(self.log)
        shown = next((c[1] for c in ctls if c[1] != "whatif"), ctls[0][1] if ctls else None)
        for _topic, label, f, sf, desc in ctls:
            t = np.asarray(f.index.to_numpy(), dtype=np.int64)
            k = vd.thin_indices(t, OVERLAY_HZ)
            tk = t[k]
            cols = self.index_cols(tk)
            if label != shown:   # one controller's overlays in sight; the others toggled off in the blueprint
                self.hidden.append(f"{self.prefix}/local/ctl_{label}")
            for what, role in (("closest", "closest"), ("carrot", "carrot")):
                cn, ce = f"{what}_n_m", f"{what}_e_m"
                if cn in f.columns and ce in f.columns:
                    n = np.asarray(f[cn].to_numpy(), float)[k]
                    e = np.asarray(f[ce].to_numpy(), float)[k]
                    path = f"{self.prefix}/local/ctl_{label}/{what}"
                    self.rec.log(path, rr.Points2D.from_fields(radii=rr.Radius.ui_points(5.0), draw_order=35.0,
                                                               colors=[self.color(role, "light")],
                                                               labels=[self.label(f"{what}, {desc}")],
                                                               show_labels=True), static=True)
                    self.rec.send_columns(path, indexes=cols,
                                          columns=rr.Points2D.columns(positions=np.column_stack([e, -n])))
                    self.views["local"].append(path)
                    if label == shown and self.datum is not None:
                        ok = np.isfinite(n) & np.isfinite(e)
                        path = f"{self.prefix}/map/{what}"
                        self.rec.log(path, rr.GeoPoints.from_fields(radii=rr.Radius.ui_points(5.0),
                                                                    colors=[self.color(role, "light")]), static=True)
                        self.rec.send_columns(path, indexes=self.index_cols(tk[ok]),
                                              columns=rr.GeoPoints.columns(positions=self.geo(n[ok], e[ok])))
                        self.views["map"].append(path)
            if sf is None or "psi_rad" not in sf.columns:
                continue
            n = vd.interp(tk, sf, "n_m")
            e = vd.interp(tk, sf, "e_m")
            if {"closest_n_m", "closest_e_m", "carrot_n_m", "carrot_e_m"} <= set(f.columns):
                # the guidance at each tick: boat -> closest point on the path -> carrot
                cl_n, cl_e = _col(f, "closest_n_m")[k], _col(f, "closest_e_m")[k]
                ca_n, ca_e = _col(f, "carrot_n_m")[k], _col(f, "carrot_e_m")[k]
                strips = np.stack([np.column_stack([e, -n]), np.column_stack([cl_e, -cl_n]),
                                   np.column_stack([ca_e, -ca_n])], axis=1)   # (ticks, 3, 2)
                path = f"{self.prefix}/local/ctl_{label}/guidance"
                self.rec.log(path, rr.LineStrips2D.from_fields(radii=rr.Radius.ui_points(0.75),
                                                               colors=[self.color("carrot", "light")]), static=True)
                # the (ticks, 3, 2) array itself: rerun converts it whole, a list strip by strip
                self.rec.send_columns(path, indexes=cols, columns=rr.LineStrips2D.columns(strips=strips))
                self.views["local"].append(path)
            psi = vd.interp(tk, sf, "psi_rad", angle=True)
            dirs = [psi]
            colors = [self.color("heading")]
            if "psi_d_rad" in f.columns:
                dirs.append(np.asarray(f["psi_d_rad"].to_numpy(), float)[k])
                colors.append(self.color("desired", "light"))
            if {"u_mps", "v_mps"} <= set(sf.columns):
                cog = vd.course_over_ground(sf)
                ts = np.asarray(sf.index.to_numpy(), dtype=np.int64)
                dirs.append(vd.interp(tk, _frame_of(ts, cog), "x", angle=True))
                colors.append(self.color("cog", "dark"))
            m = len(dirs)
            ang = np.column_stack(dirs)                       # (ticks, m)
            origins = np.repeat(np.column_stack([e, -n]), m, axis=0)
            vec = arrow * np.column_stack([np.sin(ang).ravel(), -np.cos(ang).ravel()])
            ok = np.isfinite(vec).all(1) & np.isfinite(origins).all(1)
            vec[~ok] = 0.0
            origins[~ok] = 0.0
            path = f"{self.prefix}/local/ctl_{label}/arrows"
            self.rec.log(path, rr.Arrows2D.from_fields(radii=rr.Radius.ui_points(1.5)), static=True)
            self.rec.send_columns(path, indexes=cols, columns=rr.Arrows2D.columns(
                origins=origins, vectors=vec, colors=np.tile(np.array(colors, np.uint8), (len(tk), 1))
            ).partition(np.full(len(tk), m)))
            self.views["local"].append(path)

    def draw_series(self) -> None:
        log = self.log
        states = vd.state_tracks(log)
        for _topic, label, f in states:
            t = np.asarray(f.index.to_numpy(), dtype=np.int64)
            var = {"truth": "dark", "whatif": "light"}.get(label, "")
            c = self.color(label, var)
            self.scalars("u", f"u/{label}", t, f["u_mps"].to_numpy(), name=f"u {label}", color=c)
            self.scalars("v", f"v/{label}", t, f["v_mps"].to_numpy(), name=f"v {label}", color=c)
            self.scalars("r", f"r/{label}", t, np.degrees(np.asarray(f["r_radps"].to_numpy(), float)),
                         name=f"r {label}", color=c)
            psi = np.asarray(f["psi_rad"].to_numpy(), float)
            ok = np.isfinite(psi)
            if ok.any():
                self.scalars("psi", f"psi/{label}", t[ok], heading_deg(psi[ok]), name=f"psi {label}", color=c,
                             gaps=True)
            if label != "whatif":
                for comp in ("n", "e"):
                    col = f"current_{comp}_mps"
                    if col in f.columns:
                        self.scalars("current", f"current/{comp}_{label}", t, f[col].to_numpy(),
                                     name=f"current {comp.upper()} {label}",
                                     color=self.color(comp if not self.multi else label, var))
            if label == "whatif" and vd.nonempty(log, "/replay/whatif/controller") is None:
                for q, sub in (("tau_u_n", "tau_u"), ("tau_r_nm", "tau_r")):
                    if q in f.columns:
                        self.scalars(sub, f"{sub}/whatif_state", t, f[q].to_numpy(), name=f"{sub} what-if run",
                                     color=c, width=1.0)
        if not states:
            comp = vd.nonempty(log, "/compass/heading")
            if comp is not None:
                t = np.asarray(comp.index.to_numpy(), dtype=np.int64)
                h = np.asarray(comp["heading_rad"].to_numpy(), float)
                ok = np.isfinite(h)
                self.scalars("psi", "psi/compass", t[ok], heading_deg(h[ok]), name="compass heading",
                             color=self.color("compass"), gaps=True)
        rec = vd.recorded_tau(log)
        if rec is not None:
            t, tu, tr = rec
            c = self.color("recorded", "dark")
            self.scalars("tau_u", "tau_u/recorded", t, tu, name="tau_u recorded", color=c, step=True)
            self.scalars("tau_r", "tau_r/recorded", t, tr, name="tau_r recorded", color=c, step=True)
        ctls = vd.controllers(log)
        for i, (_topic, label, f, _sf, desc) in enumerate(ctls):
            t = np.asarray(f.index.to_numpy(), dtype=np.int64)
            c = self.color(label, "light")
            twin = next((lb for _tp, lb, g, _s, _d in ctls[:i] if _same_frame(f, g)), None)
            if twin is not None:   # a replay of the closed loop decides the same: drawn once, as ``twin``
                continue
            if "u_d_mps" in f.columns:   # wide and light: the boat's speed stays visible on top of it
                self.scalars("u", f"u/u_d_{label}", t, f["u_d_mps"].to_numpy(), name=f"u_d {label}", color=c,
                             width=3.0)
            if "psi_d_rad" in f.columns:
                self.scalars("psi", f"psi/psi_d_{label}", t, heading_deg(_col(f, "psi_d_rad")), name=f"psi_d {label}",
                             color=c, width=2.5, gaps=True)
            for q, sub in (("tau_u_n", "tau_u"), ("tau_r_nm", "tau_r")):
                if q in f.columns:
                    self.scalars(sub, f"{sub}/{label}", t, f[q].to_numpy(), name=f"{sub} {desc}", color=c)
            if "cross_track_m" in f.columns:
                self.scalars("cross_track", f"cross_track/{label}", t, f["cross_track_m"].to_numpy(),
                             name=f"cross-track {label}", color=self.color(label))
            if "saturated" in f.columns and np.asarray(f["saturated"].to_numpy(), bool).any():  # not flat zeros
                self.scalars("saturation", f"saturation/{label}", t,
                             np.asarray(f["saturated"].to_numpy(), bool).astype(float),
                             name=f"saturated {label}", color=self.color(label), step=True)
        fit = vd.nonempty(log, "/identify/fit")
        if fit is not None:
            t = np.asarray(fit.index.to_numpy(), dtype=np.int64)
            for q, qs, name, scale in (("u_mps", "u_sim_mps", "u", 1.0), ("v_mps", "v_sim_mps", "v", 1.0),
                                       ("r_radps", "r_sim_radps", "r", math.degrees(1.0))):
                if q in fit.columns and qs in fit.columns:
                    self.scalars(f"fit_{name}", f"fit/{name}_measured", t, _col(fit, q) * scale,
                                 name=f"{name} measured", color=self.color("recorded", "dark"), width=1.0)
                    self.scalars(f"fit_{name}", f"fit/{name}_model", t, _col(fit, qs) * scale,
                                 name=f"{name} model", color=self.color("control"), width=1.5)
        inn = vd.nonempty(log, "/estimate/innovations")
        if inn is not None and "nis" in inn.columns and "sensor" in inn.columns:
            t = np.asarray(inn.index.to_numpy(), dtype=np.int64)
            sensor = inn["sensor"].astype(str).to_numpy()
            nis = np.asarray(inn["nis"].to_numpy(), float)
            palette = [(31, 119, 180), (214, 39, 40), (44, 160, 44), (148, 103, 189)]
            for i, s in enumerate(sorted(set(sensor))):
                m = sensor == s
                c = palette[i % 4] if not self.multi else self.color(s, ["", "light", "dark"][i % 3])
                self.scalars("nis", f"nis/{_safe(s)}", t[m], nis[m], name=f"NIS {s}", color=c, width=1.0)

    def draw_events(self) -> None:
        ev = vd.events_once(self.log)
        if not ev:
            return
        path = f"{self.prefix}/events"
        t = np.array([e.t_ns for e in ev], dtype=np.int64)
        text = [self.label(e.text) for e in ev]
        self.rec.send_columns(path, indexes=self.index_cols(t),
                              columns=rr.TextLog.columns(text=text, level=[e.level for e in ev]))
        self.views["events"].append(path)


    def draw_manoeuvres(self) -> None:
        """The standard manoeuvres (measured on the stored estimate): a text entry at each one's start
        (its metrics) and end in the events view, and its stretch of the track in the local view."""
        part = vman.rerun_parts(self.log)
        if part is None:
            return
        t, text, level, strips, labels = part
        path = f"{self.prefix}/{vman.ENTITY}"
        self.rec.send_columns(path, indexes=self.index_cols(t),
                              columns=rr.TextLog.columns(text=[self.label(x) for x in text], level=level))
        self.views["events"].append(path)
        if strips:
            self.static("local", vman.TRACK_ENTITY, rr.LineStrips2D(
                strips, radii=rr.Radius.ui_points(3.0), labels=[self.label(x) for x in labels], show_labels=False))


    def draw_findings(self) -> None:
        """The findings of ``usvlog check``: one text entry per finding at its start, with its level."""
        part = vfind.rerun_parts(self.log)
        if part is None:
            return
        t, text, level = part
        path = f"{self.prefix}/{vfind.ENTITY}"
        self.rec.send_columns(path, indexes=self.index_cols(t),
                              columns=rr.TextLog.columns(text=[self.label(x) for x in text], level=level))
        self.views["events"].append(path)


def _col(frame, name) -> np.ndarray:
    return np.asarray(frame[name].to_numpy(), dtype=float)


def scalar_column(y: np.ndarray) -> rr.ComponentColumnList:
    """``rr.Scalars.columns(scalars=y)``, one scalar per row, without its per-row partition sizes
    (a float array of ones summed into the offsets: 9 of its 9.4 ms for 360k samples).

    Parameters
    ----------
    y : numpy.ndarray
        The samples (float64), one per row.

    Returns
    -------
    rerun.ComponentColumnList
        The column for ``send_columns``: the same arrow data as ``rr.Scalars.columns``.
    """
    batch = rr.Scalars.from_fields(scalars=y).as_component_batches()[0]
    return rr.ComponentColumnList([rr.ComponentColumn(batch.component_descriptor(), batch,
                                                      offsets=np.arange(len(y) + 1, dtype=np.int32))])


def heading_deg(psi_rad) -> np.ndarray:
    """Heading in degrees wrapped to [-180, 180) (what the heading plots show by default).

    Parameters
    ----------
    psi_rad : array_like
        Heading, rad (any range).

    Returns
    -------
    numpy.ndarray
        Degrees in [-180, 180).
    """
    return (np.degrees(np.asarray(psi_rad, dtype=float)) + 180.0) % 360.0 - 180.0


def break_wraps(t_ns: np.ndarray, deg: np.ndarray, limit: float = 180.0) -> tuple[np.ndarray, np.ndarray]:
    """(t_ns, deg) with a NaN sample put in half-way across every step larger than ``limit``
    degrees (a wrapped heading), so the line breaks there instead of crossing the plot."""
    jump = np.nonzero(np.abs(np.diff(deg)) > limit)[0]
    if not len(jump):
        return t_ns, deg
    t_mid = t_ns[jump] + (t_ns[jump + 1] - t_ns[jump]) // 2
    return np.insert(t_ns, jump + 1, t_mid), np.insert(deg, jump + 1, np.nan)


def _same_frame(a, b, cols=("u_d_mps", "psi_d_rad", "tau_u_n", "tau_r_nm", "cross_track_m")) -> bool:
    """True when two controller channels have the same ticks and the same decisions."""
    if len(a) != len(b) or not np.array_equal(np.asarray(a.index), np.asarray(b.index)):
        return False
    for c in cols:
        if (c in a.columns) != (c in b.columns):
            return False
        if c in a.columns and not np.allclose(_col(a, c), _col(b, c), rtol=0, atol=1e-9, equal_nan=True):
            return False
    return True


def _frame_of(t_ns, x):
    return pd.DataFrame({"x": x}, index=pd.Index(t_ns, name="t_ns"))


def _extent(log: FieldLog) -> float:
    """The larger side (m) of the box around the boat's positions and the path (10 without either)."""
    ns, es = [], []
    b = vd.boat_state(log)
    if b is not None:
        ns.append(np.asarray(b[1]["n_m"].to_numpy(), float))
        es.append(np.asarray(b[1]["e_m"].to_numpy(), float))
    p = vd.path_polyline(log)
    if p is not None:
        ns.append(p[:, 0])
        es.append(p[:, 1])
    if not ns:
        return 10.0
    n, e = (x[0] if len(x) == 1 else np.concatenate(x) for x in (ns, es))
    ok = np.isfinite(n) & np.isfinite(e)
    if not ok.any():
        return 10.0
    if not ok.all():
        n, e = n[ok], e[ok]
    return float(max(n.max() - n.min(), e.max() - e.min()))


# -----------------------------------------------------------------------------
# blueprint
# -----------------------------------------------------------------------------

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


# -----------------------------------------------------------------------------
# public API
# -----------------------------------------------------------------------------

def _recording(logs: list[FieldLog], names: list[str]) -> rr.RecordingStream:
    key = "|".join(f"{n}:{lg.time_range()}" for n, lg in zip(names, logs))
    rid = uuid.uuid5(uuid.NAMESPACE_URL, "usvlog:" + key)
    return rr.RecordingStream(APP_ID, recording_id=rid, send_properties=False)   # properties: see _name


def recording_name(names: list[str]) -> str:
    """The name the viewer lists the recording under: the runs' names (``paper_circle``, ``a + b``)."""
    return " + ".join(names)


def _name(rec: rr.RecordingStream, logs: list[FieldLog], names: list[str]) -> None:
    """Name the recording after its runs and start it at the first log's start (not the wall clock:
    the same logs give the same file)."""
    rec.send_recording_name(recording_name(names))
    tr = logs[0].time_range()
    if tr:
        rec.send_recording_start_time_nanos(int(tr[0]))


def _prepare(logs, names):
    if isinstance(logs, FieldLog):
        logs = [logs]
    logs = list(logs)
    if not logs:
        raise InputError("nothing to view: no logs given")
    if names is None:
        names = default_names(logs)
    else:
        names = [_safe(n) for n in names]
        if len(names) != len(logs) or len(set(names)) != len(names):
            raise InputError(f"need {len(logs)} distinct names, got {names}")
    for log, name in zip(logs, names):
        if log.time_range() is None:
            raise InputError(f"{log.source or name}: log has no data to view")
    return logs, names


def _draw(rec, logs, names) -> list[_Writer]:
    writers = []
    multi = len(logs) > 1
    for i, (log, name) in enumerate(zip(logs, names)):
        w = _Writer(rec, log, name, i, multi)
        w.draw()
        writers.append(w)
    return writers


def to_rrd(logs: list[FieldLog] | FieldLog, out_path, *, names: list[str] | None = None,
           force: bool = False) -> Path:
    """Write one or several logs to an .rrd file with the blueprint stored inside.

    Several logs are overlaid under ``/runs/<name>/`` (names default to the files' stems)
    and also shown side by side; the time panel then starts on the ``elapsed`` timeline.

    Parameters
    ----------
    logs : FieldLog or list of FieldLog
        Raw, estimated, replayed or simulated logs; whatever channels they hold are drawn
        (GPS and estimated/true tracks on a map and in local NED metres, controller
        overlays, time series, events).
    out_path : str or os.PathLike
        The .rrd file to write (atomically).
    names : list of str, optional
        One distinct name per log (made safe for entity paths); default
        :func:`default_names`.
    force : bool, default False
        Overwrite an existing file.

    Returns
    -------
    pathlib.Path
        The written file; open it with :func:`spawn_viewer` or :func:`serve`.

    Raises
    ------
    usvlog.errors.InputError
        If no logs are given, a log has no data, or ``names`` are not distinct or do
        not match the logs.
    usvlog.errors.OutputExistsError
        If ``out_path`` exists and ``force`` is False.
    usvlog.errors.StorageError
        If the file cannot be written.
    """
    logs, names = _prepare(logs, names)
    out = check_output(out_path, force)
    rec = _recording(logs, names)
    with atomic_path(out, force=force) as tmp:
        rec.save(tmp)
        try:
            _name(rec, logs, names)
            writers = _draw(rec, logs, names)
            # the blueprint depends on what the logs hold, so it goes in last (stored as the default)
            rec.send_blueprint(build_blueprint(writers), make_active=True, make_default=True)
            rec.flush()
        finally:
            rec.disconnect()
    return out


def viewer_command(rrd_path, *, serve: bool = False, host: str = DEFAULT_HOST, port: int | None = None,
                   grpc_port: int | None = None) -> list[str]:
    """The ``rerun`` command that opens (or serves to a browser) an .rrd file.

    Both the native viewer and the server bind ``host`` (127.0.0.1 unless given; rerun's own
    default is every interface, 0.0.0.0). ``port`` is the web viewer's HTTP port (``serve``
    only) and ``grpc_port`` the data server's port (the native viewer's is 9876).

    Parameters
    ----------
    rrd_path : str or os.PathLike
        The recording.
    serve : bool, default False
        Serve a web viewer and the data instead of opening the native viewer.
    host : str, default "127.0.0.1"
        Address every listening socket binds.
    port, grpc_port : int, optional
        TCP ports (default: rerun's, 9090 and 9876).

    Returns
    -------
    list of str
        The command (see :func:`rerun_executable`).
    """
    cmd = [*rerun_executable(), "--bind", host]
    if serve:
        cmd.append("--serve-web")
        if port is not None:
            cmd += ["--web-viewer-port", str(int(port))]
    if grpc_port is not None:
        cmd += ["--port", str(int(grpc_port))]
    cmd.append(str(rrd_path))
    return cmd


def rerun_executable() -> list[str]:
    """The rerun viewer binary shipped with rerun-sdk, found as its ``rerun`` launcher finds it.

    Run directly (not through the Python launcher, which would start it as a grandchild), so the
    process started is the viewer or server itself. Falls back to ``python -m rerun_cli``.
    """
    import importlib.util  # only to locate the binary

    if os.environ.get("RERUN_CLI_PATH"):
        return [os.environ["RERUN_CLI_PATH"]]
    spec = importlib.util.find_spec("rerun_cli")
    if spec is not None and spec.submodule_search_locations:
        pkg = Path(list(spec.submodule_search_locations)[0])
        exe = ".exe" if sys.platform.startswith("win") else ""
        for cand in (pkg / "Rerun.app" / "Contents" / "MacOS" / "Rerun", pkg / f"rerun{exe}"):
            if cand.is_file() and os.access(cand, os.X_OK):
                return [str(cand)]
    return [sys.executable, "-m", "rerun_cli"]


def display_missing(environ=None, platform: str | None = None) -> bool:
    """True on a Linux/BSD machine without a graphical session (neither DISPLAY nor WAYLAND_DISPLAY set).

    macOS and Windows always have a display for the native viewer.
    """
    env = os.environ if environ is None else environ
    plat = sys.platform if platform is None else platform
    if plat.startswith(("win", "darwin", "cygwin")):
        return False
    return not (env.get("DISPLAY") or env.get("WAYLAND_DISPLAY"))


def open_elsewhere(rrd_path) -> str:
    """The command that opens ``rrd_path`` on a machine with a display (``rerun FILE.rrd``)."""
    import shlex  # only for this message

    return f"rerun {shlex.quote(str(rrd_path))}"


def no_display_message(rrd_path) -> str:
    """The one-line error of ``--spawn`` without a display: where the recording is and how to open it."""
    return (f"--spawn: no display here (DISPLAY and WAYLAND_DISPLAY are unset), no viewer started; the recording "
            f"is {rrd_path}: open it on a machine with a display with `{open_elsewhere(rrd_path)}`, or serve it "
            f"to a browser with --serve")


def spawn_viewer(rrd_path, *, host: str = DEFAULT_HOST, grpc_port: int | None = None,
                 check_s: float = 2.0) -> subprocess.Popen:
    """Open the native viewer on an .rrd file, bound to ``host`` (127.0.0.1); it outlives this process.

    Parameters
    ----------
    rrd_path : str or os.PathLike
        The recording.
    host : str, default "127.0.0.1"
        Address the viewer's data server binds.
    grpc_port : int, optional
        Its port (default 9876).
    check_s : float, default 2.0
        Seconds to watch for a viewer that fails at once (its own messages then come before
        this error, not after the shell's prompt).

    Returns
    -------
    subprocess.Popen
        The viewer (in its own session).

    Raises
    ------
    usvlog.errors.ConfigError
        If there is no display (nothing is started: the message names the file and the command
        that opens it elsewhere), or the viewer exits with an error within ``check_s``.
    """
    if display_missing():
        raise ConfigError(no_display_message(rrd_path))
    proc = subprocess.Popen(viewer_command(rrd_path, host=host, grpc_port=grpc_port), start_new_session=True)
    try:
        rc = proc.wait(timeout=check_s)
    except subprocess.TimeoutExpired:
        return proc
    if rc != 0:
        raise ConfigError(f"--spawn: the Rerun viewer stopped at once (exit code {rc}, its messages are above); "
                          f"the recording is {rrd_path}: open it with `{open_elsewhere(rrd_path)}`")
    return proc  # it handed the file to a viewer already running, or the window was closed


def serve(rrd_path, *, host: str = DEFAULT_HOST, port: int | None = None, grpc_port: int | None = None) -> int:
    """Serve an .rrd file to a browser viewer until interrupted; returns the exit code.

    The server runs in its own process group, and however this call ends (the server exits,
    Ctrl-C, SIGTERM or SIGHUP turned into an exception by the CLI, an error) the whole group is
    stopped: SIGTERM, then SIGKILL after 10 s. Ctrl-C is the normal way to stop and returns 0;
    an interruption carrying a ``signum`` attribute (the CLI's ``Terminated``) propagates after
    the clean-up.

    Parameters
    ----------
    rrd_path : str or os.PathLike
        The recording.
    host : str, default "127.0.0.1"
        Address the web viewer and the data server bind.
    port, grpc_port : int, optional
        HTTP port of the web viewer (default 9090) and port of the data server (default 9876).

    Returns
    -------
    int
        The server's exit code, or 0 when stopped with Ctrl-C.
    """
    proc = None
    try:  # not under deferred signals: the child would inherit the blocked mask
        proc = subprocess.Popen(viewer_command(rrd_path, serve=True, host=host, port=port, grpc_port=grpc_port),
                                start_new_session=True)
        return proc.wait()
    except KeyboardInterrupt as err:
        if getattr(err, "signum", None) is not None:
            raise
        return 0
    finally:
        if proc is not None:
            _stop_group(proc)


def _stop_group(proc: subprocess.Popen, grace_s: float = 10.0) -> None:
    """Stop every process of ``proc``'s group (SIGTERM, then SIGKILL) and wait, bounded, until it is gone."""
    import time  # only on the way out

    with _deferred():  # a second Ctrl-C or SIGTERM does not cut the clean-up short
        for sig, wait_s in ((signal.SIGTERM, grace_s), (signal.SIGKILL, 5.0)):
            try:
                os.killpg(proc.pid, sig)
            except ProcessLookupError:
                break
            except PermissionError:  # pragma: no cover - a pid reused by another user's process
                break
            deadline = time.monotonic() + wait_s
            while time.monotonic() < deadline:
                with contextlib.suppress(subprocess.TimeoutExpired):
                    proc.wait(timeout=0.05)  # reaps the server (or the launcher of the fallback command)
                try:
                    os.killpg(proc.pid, 0)
                except ProcessLookupError:
                    return
                time.sleep(0.05)
        with contextlib.suppress(subprocess.TimeoutExpired):
            proc.wait(timeout=1.0)


__all__ = ["to_rrd", "build_blueprint", "viewer_command", "display_missing", "no_display_message",
           "open_elsewhere", "spawn_viewer",
           "serve", "default_names",
           "OVERLAY_HZ", "math"]
