"""The map and the local view of one log: GPS fixes, tracks, the path, the boat, the controller overlays.

:func:`draw_tracks` puts the GPS fixes (and those the estimator rejected), the desired path
and every state track (estimate, truth, what-if run) on the map (GeoPoints / GeoLineStrings,
when the log has a datum) and in the local 2D view (x = east, y = -north), then the boat over
time. :func:`draw_controllers` adds, per controller channel, the closest point and the carrot
at each tick, the guidance lines between them and the heading / desired heading / course
arrows. Both are methods of :class:`usvlog.view.rrd_writer._Writer` (``self`` is the writer);
tracks and per-tick overlays are thinned to :data:`OVERLAY_HZ`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import pandas as pd
import rerun as rr

from ..log.fieldlog import FieldLog
from . import data as vd
from .rrd_style import _col

if TYPE_CHECKING:
    from .rrd_writer import _Writer

OVERLAY_HZ = vd.OVERLAY_HZ
TRACK_LABELS = {"estimate": "smoothed estimate", "truth": "truth (simulated)", "whatif": "what-if run"}


def draw_tracks(self: _Writer) -> None:
    """GPS fixes, the desired path and the state tracks on the map and in the local view; the boat over time."""
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
        self.tag(e, n, vd.fixes_name(log), self.color("gps"))
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
        k = self.thin(t)
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
    k = self.thin(t)
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


def draw_controllers(self: _Writer) -> None:
    """Per controller: closest point, carrot, guidance lines and heading arrows at each tick."""
    ext = _extent(self.log)
    arrow = float(np.clip(0.08 * ext, 0.5, 10.0))
    ctls = vd.controllers(self.log)
    shown = next((c[1] for c in ctls if c[1] != "whatif"), ctls[0][1] if ctls else None)
    for _topic, label, f, sf, desc in ctls:
        t = np.asarray(f.index.to_numpy(), dtype=np.int64)
        k = self.thin(t)
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
