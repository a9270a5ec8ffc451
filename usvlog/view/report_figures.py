"""The report's figures: one function per figure, each returning a matplotlib Figure or None.

* the paper's figures: Fig. 1 (desired path and the trajectory the controller steered, with a
  baseline log or the what-if run), Fig. 4 (raw GPS fixes against the smoothed track, the
  manoeuvres, the estimated current), Fig. 2 (yaw and surge errors, sway speed) and Fig. 5
  (speed and heading, actual and desired);
* the estimate's series: surge speed, heading and yaw rate with their 1-sigma bands;
* the identification's fit: measured against simulated velocities and track.

A function returns None when the log lacks its channels or they hold no finite value.
:func:`usvlog.view.report.figures` lists them with their file names and titles, in page
order; the helpers they share are in :mod:`usvlog.view.report_plot`, the runs they compare
in :mod:`usvlog.view.report_runs`.
"""

from __future__ import annotations

import math

import numpy as np

from ..model.frames import ssa
from . import data as vd
from . import manoeuvres as vman
from .report_plot import _Axes, _band, _col, _finite, _legend, _seconds, _wrap_deg
from .report_runs import _comparison, _main_controller, _run_label, _steered_track, path_metrics
from .windowed import WindowedLog, manoeuvres_of

# -----------------------------------------------------------------------------
# the paper's figures: Fig. 1, 4, 2 and 5
# -----------------------------------------------------------------------------

def _start_marker(ax, xy, n, e, color):
    ok = np.isfinite(n) & np.isfinite(e)
    if ok.any():
        k = np.nonzero(ok)[0][0]
        ax.plot(*xy(n[k], e[k]), "o", color=color, ms=6, mfc="none", label="start", zorder=6)


def _fig_track(plt, log, path, *, baseline, axes: _Axes):
    """Fig. 1 style: the desired path and the trajectory the controller steered, with what it is compared to."""
    mc = _main_controller(log)
    tr = _steered_track(log)
    if mc is None or tr is None or not _finite(tr[1], tr[2]):
        return None
    xy = axes.xy
    fig, ax = plt.subplots(figsize=(6.2, 5.4))
    t, n, e = tr
    ax.plot(*xy(n, e), "-", color="C0", lw=1.4, label=f"trajectory, {_run_label(log, mc[3])}", zorder=3)
    colors = {"baseline": "C3", "whatif": "C4"}
    for key, lab, _cf, _sf, track in _comparison(log, baseline):
        if track is not None and _finite(track[1], track[2]):
            ax.plot(*xy(track[1], track[2]), "-." if key == "whatif" else "-", color=colors[key], lw=1.0,
                    alpha=0.85, label=lab, zorder=2)
    if path is not None:  # on top, so the dashes show where the boat is on the path
        ax.plot(*xy(path[:, 0], path[:, 1]), "--", color="k", lw=1.2, label="desired path (dashed)", zorder=4)
    _start_marker(ax, xy, n, e, "C0")
    steps = vd.speed_steps(mc[1])
    if steps and mc[2] is not None and "n_m" in mc[2].columns:
        ts = np.array([s[0] for s in steps], dtype=np.int64)
        ax.plot(*xy(vd.interp(ts, mc[2], "n_m"), vd.interp(ts, mc[2], "e_m")), "^", color="C1", ms=7,
                label="speed step (u_d)", zorder=6)
    axes.label(ax)
    ax.set_title("Path following: desired path and trajectory")
    _legend(ax)
    return fig


def _fig_measured(plt, log, path, *, axes: _Axes):
    """Fig. 4 style: raw GPS fixes (points) against the smoothed track (and the truth, the path)."""
    g = vd.gps(log)
    est = vd.nonempty(log, "/estimate/state")
    have_est = est is not None and "n_m" in est.columns and _finite(_col(est, "n_m"), _col(est, "e_m"))
    have_gps = g is not None and _finite(g[3], g[4])
    if not (have_est or have_gps) or (not have_est and _main_controller(log) is not None):
        return None   # a closed-loop run without an estimate: Fig. 1 shows its track
    xy = axes.xy
    fig, ax = plt.subplots(figsize=(6.2, 5.4))
    if have_gps:
        rej = vd.gps_rejections(log)
        keep = np.ones(len(g[0]), bool)
        if rej is not None and len(rej[0]):
            keep = ~np.isin(g[0], rej[0])
        what = vd.fixes_name(log)
        ax.plot(*xy(g[3][keep], g[4][keep]), ".", color="0.55", ms=2.5, alpha=0.6, label=f"{what} (raw)", zorder=1)
        if (~keep).any():
            ax.plot(*xy(g[3][~keep], g[4][~keep]), "x", color="C3", ms=6, label=f"{what} rejected", zorder=5)
    tru = vd.nonempty(log, "/truth/state")
    if tru is not None and "n_m" in tru.columns and _finite(_col(tru, "n_m")):
        ax.plot(*xy(_col(tru, "n_m"), _col(tru, "e_m")), "--", color="k", lw=0.9, label="truth (simulated)",
                zorder=3)
    if have_est:
        n, e = _col(est, "n_m"), _col(est, "e_m")
        ax.plot(*xy(n, e), "-", color="C0", lw=1.4, label="smoothed estimate", zorder=4)
        _start_marker(ax, xy, n, e, "C0")
        vman.draw_on_track(ax, xy, *manoeuvres_of(log))   # each standard manoeuvre, numbered as in its table
    if path is not None:
        ax.plot(*xy(path[:, 0], path[:, 1]), ":", color="C1", lw=1.4, label="desired path (dotted)", zorder=2)
    axes.label(ax)
    raw = f"raw {vd.fixes_name(log)}"
    ax.set_title(f"Track: {raw} and the smoothed estimate" if have_est else f"Track: {raw}")
    current = (log.survey.current if isinstance(log, WindowedLog) else vd.mean_current(est)) if have_est else None
    if current is not None:   # a windowed log's current is the mean over the whole estimate, not the figure's rows
        cn, ce = current
        sp = math.hypot(cn, ce)
        if sp > 0.01:
            _current_arrow(fig, ax, *xy(cn, ce), sp)
    _legend(ax)
    return fig


def _current_arrow(fig, ax, cx, cy, sp):
    """The paper's "approximate current direction" arrow, below the axes' top-left corner."""
    bb = ax.get_window_extent()   # final: equal aspect adjusts the data limits, never the axes box
    L = 35.0  # pixels
    x0, y0 = 1.02 + L / bb.width, 0.12
    tip = (x0 + L * cx / sp / bb.width, y0 + L * cy / sp / bb.height)
    ax.annotate("", xy=tip, xytext=(x0, y0), xycoords="axes fraction", textcoords="axes fraction",
                arrowprops=dict(arrowstyle="-|>", lw=1.8, color="C2"), annotation_clip=False)
    ax.text(1.02, 0.30, f"approximate current\n({sp:.2f} m/s, estimated)", transform=ax.transAxes, color="C2",
            fontsize=8, ha="left", va="bottom")


def _fig_errors(plt, log, baseline):
    """Fig. 2 style: psi_e (deg), u_e (m/s) and v (m/s) against time, this log dashed, the comparison solid."""
    mc = _main_controller(log)
    if mc is None:
        return None
    series = [("log", _run_label(log, mc[3]), mc[1], mc[2], "--", "C0")]
    for key, lab, cf, sf, _track in _comparison(log, baseline):
        if cf is not None:
            series.append((key, lab, cf, sf, "-", {"baseline": "C3", "whatif": "C4"}[key]))
    fig, axes = plt.subplots(3, 1, figsize=(7.0, 6.4), sharex=True)
    for _key, nm, f, sf, ls, color in series:
        t0 = f.index[0]
        t = _seconds(f.index.to_numpy(), t0)
        if "psi_e_rad" in f.columns and _finite(_col(f, "psi_e_rad")):
            axes[0].plot(t, np.degrees(ssa(_col(f, "psi_e_rad"))), ls, color=color, lw=1.2, label=nm)
        if "u_e_mps" in f.columns and _finite(_col(f, "u_e_mps")):
            axes[1].plot(t, _col(f, "u_e_mps"), ls, color=color, lw=1.2, label=nm)
        if sf is not None and "v_mps" in sf.columns and _finite(_col(sf, "v_mps")):
            axes[2].plot(_seconds(sf.index.to_numpy(), t0), _col(sf, "v_mps"), ls, color=color, lw=1.2, label=nm)
    if not any(ax.lines for ax in axes):
        plt.close(fig)
        return None
    pm = path_metrics(log)
    if pm and pm[0][2].start_s > 0:
        for ax in axes:
            ax.axvline(pm[0][2].start_s, color="0.4", lw=0.8, ls=":",
                       label=f"metrics window starts (t = {pm[0][2].start_s:g} s)")
    axes[0].set_ylabel(r"yaw error $\psi_e$ (deg)")
    axes[1].set_ylabel(r"surge error $u_e$ (m/s)")
    axes[2].set_ylabel(r"sway speed $v$ (m/s)")
    axes[2].set_xlabel("time (s)")
    axes[0].set_title("Tracking errors: yaw, surge speed, and sway speed")
    _legend(axes[0])
    fig.align_ylabels(axes)
    return fig


def _fig_speed_heading(plt, log):
    """Fig. 5 style: surge speed and heading (deg, desired kept within 180 deg of the actual)."""
    mc = _main_controller(log)
    if mc is None:
        return None
    _label, f, sf, _desc = mc
    if sf is None or "u_mps" not in sf.columns:
        b = vd.boat_state(log)
        sf = b[1] if b else None
    if sf is None or not _finite(_col(sf, "u_mps")):
        return None
    t0 = f.index[0]
    fig, axes = plt.subplots(2, 1, figsize=(7.0, 5.0), sharex=True)
    ts = _seconds(sf.index.to_numpy(), t0)
    tc = _seconds(f.index.to_numpy(), t0)
    axes[0].plot(ts, _col(sf, "u_mps"), "-", color="C0", lw=1.2, label="actual")
    if "u_d_mps" in f.columns and _finite(_col(f, "u_d_mps")):
        axes[0].plot(tc, _col(f, "u_d_mps"), "--", color="C1", lw=1.4, label="desired")
    axes[0].set_ylabel("surge speed u (m/s)")
    psi = _col(sf, "psi_rad")
    ok = np.isfinite(psi)
    if "psi_d_rad" in f.columns and ok.any():
        a, d = vd.heading_pair(sf.index.to_numpy()[ok], psi[ok], f.index.to_numpy(), _col(f, "psi_d_rad"))
        axes[1].plot(ts[ok], np.degrees(a), "-", color="C0", lw=1.2, label="actual")
        axes[1].plot(tc, np.degrees(d), "--", color="C1", lw=1.4, label="desired")
    elif ok.any():
        axes[1].plot(ts[ok], np.degrees(np.unwrap(psi[ok])), "-", color="C0", lw=1.2, label="actual")
    axes[1].set_ylabel(r"yaw angle $\psi$ (deg, unwrapped)")
    axes[1].set_xlabel("time (s)")
    axes[0].set_title("Surge speed and heading: actual and desired")
    _legend(axes[0])
    _legend(axes[1])
    fig.align_ylabels(axes)
    return fig


# -----------------------------------------------------------------------------
# the estimate's series and the identification's fit
# -----------------------------------------------------------------------------

def _fig_estimate_series(plt, log):
    """Surge speed, heading and yaw rate of the estimate with 1-sigma bands (and truth, compass)."""
    est = vd.nonempty(log, "/estimate/state")
    if est is None:
        return None
    rows = [("u_mps", "surge speed u (m/s)", 1.0), ("psi_rad", "heading (deg)", None),
            ("r_radps", "yaw rate r (deg/s)", math.degrees(1.0))]
    rows = [r for r in rows if r[0] in est.columns and _finite(_col(est, r[0]))]
    if not rows:
        return None
    t0 = est.index[0]
    t = _seconds(est.index.to_numpy(), t0)
    tru = vd.nonempty(log, "/truth/state")
    comp = vd.nonempty(log, "/compass/heading")
    fig, axes = plt.subplots(len(rows), 1, figsize=(7.0, 2.0 * len(rows) + 0.8), sharex=True, squeeze=False)
    for ax, (q, ylabel, scale) in zip(axes[:, 0], rows):
        y = _col(est, q)
        sd = _col(est, q + "_std") if q + "_std" in est.columns else None
        if q == "psi_rad":
            if comp is not None and "heading_rad" in comp.columns:
                ax.plot(_seconds(comp.index.to_numpy(), t0), np.degrees(ssa(_col(comp, "heading_rad"))), ".",
                        color="0.6", ms=1.5, alpha=0.5, label="compass (raw)", zorder=1)
            yd = _wrap_deg(y)
            if sd is not None and _finite(sd):
                _band(ax, t, yd - np.degrees(sd), yd + np.degrees(sd), color="C0", alpha=0.25, lw=0,
                      label="estimate +- 1 sigma")
            ax.plot(t, yd, "-", color="C0", lw=1.0, label="smoothed estimate", zorder=3)
            if tru is not None and q in tru.columns:
                ax.plot(_seconds(tru.index.to_numpy(), t0), _wrap_deg(_col(tru, q)), "--", color="k", lw=0.8,
                        label="truth (simulated)", zorder=4)
            if np.nanmax(yd) - np.nanmin(yd) > 300.0:   # it wraps: the whole circle
                ax.set_ylim(-185, 185)
                ax.set_yticks([-180, -90, 0, 90, 180])
        else:
            if sd is not None and _finite(sd):
                _band(ax, t, (y - sd) * scale, (y + sd) * scale, color="C0", alpha=0.25, lw=0,
                      label="estimate +- 1 sigma")
            ax.plot(t, y * scale, "-", color="C0", lw=1.0, label="smoothed estimate", zorder=3)
            if tru is not None and q in tru.columns:
                ax.plot(_seconds(tru.index.to_numpy(), t0), _col(tru, q) * scale, "--", color="k", lw=0.8,
                        label="truth (simulated)", zorder=4)
        ax.set_ylabel(ylabel)
    axes[-1, 0].set_xlabel("time (s)")
    axes[0, 0].set_title("Estimate: surge speed, heading and yaw rate with 1-sigma bands")
    for ax in axes[:, 0]:
        _legend(ax)
    fig.align_ylabels(axes[:, 0])
    return fig


def _fig_fit_velocities(plt, log):
    fit = vd.nonempty(log, "/identify/fit")
    if fit is None:
        return None
    rows = [(q, s, lab, k) for q, s, lab, k in (("u_mps", "u_sim_mps", "u (m/s)", 1.0),
                                                ("v_mps", "v_sim_mps", "v (m/s)", 1.0),
                                                ("r_radps", "r_sim_radps", "r (deg/s)", math.degrees(1.0)))
            if q in fit.columns and s in fit.columns and _finite(_col(fit, q), _col(fit, s))]
    if not rows:
        return None
    t = _seconds(fit.index.to_numpy(), fit.index[0])
    fig, axes = plt.subplots(len(rows), 1, figsize=(7.0, 2.0 * len(rows) + 0.8), sharex=True, squeeze=False)
    for ax, (q, s, lab, k) in zip(axes[:, 0], rows):
        ax.plot(t, _col(fit, q) * k, "-", color="0.35", lw=1.0, label="measured (estimate)")
        ax.plot(t, _col(fit, s) * k, "--", color="C3", lw=1.2, label="identified model (simulated)")
        ax.set_ylabel(lab)
        _legend(ax)
    axes[-1, 0].set_xlabel("time (s)")
    axes[0, 0].set_title("Identification: measured vs simulated velocities")
    fig.align_ylabels(axes[:, 0])
    return fig


def _fig_fit_track(plt, log, axes: _Axes):
    fit = vd.nonempty(log, "/identify/fit")
    if fit is None or not {"n_m", "e_m", "n_sim_m", "e_sim_m"} <= set(fit.columns):
        return None
    if not _finite(_col(fit, "n_m"), _col(fit, "n_sim_m")):
        return None
    fig, ax = plt.subplots(figsize=(6.2, 5.4))
    ax.plot(*axes.xy(_col(fit, "n_m"), _col(fit, "e_m")), "-", color="0.35", lw=1.2, label="measured (estimate)")
    ax.plot(*axes.xy(_col(fit, "n_sim_m"), _col(fit, "e_sim_m")), "--", color="C3", lw=1.2,
            label="identified model (simulated)")
    axes.label(ax)
    ax.set_title("Identification: measured vs simulated track")
    _legend(ax)
    return fig
