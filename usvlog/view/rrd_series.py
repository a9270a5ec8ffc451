"""The time series of one log: speeds, heading, yaw rate, forces, cross-track error, fit, NIS.

:func:`draw_state_series` sends every state track's u, v, r and heading (and the estimated water
current) and the recorded forces, :func:`draw_series` each controller's desired speed and heading, forces,
cross-track error and saturation (a replay that decides exactly as the closed loop did is
drawn once), the identification's measured and simulated velocities, and the estimator's
NIS per sensor; each goes to the plot of its quantity (``/runs/<name>/ts/<quantity>/<series>``)
through :meth:`usvlog.view.rrd_writer._Writer.scalars`. A method of the writer (``self``).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from . import data as vd
from .rrd_style import _col, _safe

if TYPE_CHECKING:
    from .rrd_writer import _Writer


def draw_state_series(self: _Writer) -> None:
    """The time series of the state channels and the recorded forces (of a block of them, for a log
    drawn a block at a time), each to the plot of its quantity."""
    log = self.log
    for _topic, label, f in vd.state_tracks(log):
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
    rec = vd.recorded_tau(log, **self.tau_facts)
    if rec is not None:
        t, tu, tr = rec
        c = self.color("recorded", "dark")
        self.scalars("tau_u", "tau_u/recorded", t, tu, name="tau_u recorded", color=c, step=True)
        self.scalars("tau_r", "tau_r/recorded", t, tr, name="tau_r recorded", color=c, step=True)


def draw_series(self: _Writer) -> None:
    """The other time series (after :func:`draw_state_series`: the compass when no state is drawn,
    the controllers, the identification's fit, the NIS), each to the plot of its quantity."""
    log = self.log
    if not vd.state_tracks(log):
        comp = vd.nonempty(log, "/compass/heading")
        if comp is not None:
            t = np.asarray(comp.index.to_numpy(), dtype=np.int64)
            h = np.asarray(comp["heading_rad"].to_numpy(), float)
            ok = np.isfinite(h)
            self.scalars("psi", "psi/compass", t[ok], heading_deg(h[ok]), name="compass heading",
                         color=self.color("compass"), gaps=True)
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
