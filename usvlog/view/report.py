"""A static report: an HTML page with PNG figures that answer the questions of each kind of run.

* every run: a status line first (the estimate's consistency verdict, the identification's
  verdict, whether a replayed run follows its scenario's path), the warnings, the metrics
  (path-following metrics exactly as ``usvlog replay`` printed them, with their window), and
  the findings of ``usvlog check`` as a table (:mod:`usvlog.view.findings`);
* an estimated run: raw GPS fixes (points) against the smoothed track, surge speed, heading
  and yaw rate with their 1-sigma bands, the sensors' consistency table and the import's
  sensor health audit;
* an identified run: the parameters with standard errors and 95 % intervals, the verdict,
  and the fit figures (measured against simulated u, v, r and track);
* a replayed or closed-loop run: figures in the style of the paper's Fig. 1 (path and
  trajectory), Fig. 2 (yaw and surge speed errors, sway speed) and Fig. 5 (speed and heading,
  actual and desired), compared with a baseline log or the what-if run.

Every figure has a title, axis units and a legend outside the axes; its caption lists what
is drawn (and nothing else). Figures whose channels the log lacks, or that would hold no
finite value, are left out and listed as such on the page.
"""

from __future__ import annotations

import contextlib
import html
import io
import json
import math
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..choices import PARAM_NAMES
from ..errors import ConfigError, OutputExistsError, StorageError
from ..io.atomic import atomic_dir, atomic_path, deferred_signals
from ..log.fieldlog import FieldLog, format_time
from ..log.status import estimate_status as stored_estimate_status
from ..log.summary import format_health, health_from_provenance
from ..model.frames import ssa
from . import data as vd
from . import findings as vfind
from . import manoeuvres as vman
from .forked import Forked as _Forked
from .forked import two_cores as _two_cores

if TYPE_CHECKING:
    from ..replay import TrackingMetrics

PAGE = "report.html"
FIGURES = ("fig1_track.png", "fig2_errors.png", "fig4_path.png", "fig5_speed_heading.png",
           "estimate_series.png", "fit_velocities.png", "fit_track.png")
SAME_TRACK_M = 1e-3    # two tracks closer than this everywhere are the same run

AXES_NOTE = {
    "paper": "Plane figures are drawn as in the paper: X (north) to the right, Y (east) up, which is the "
             "mirror image of a map (usvlog report --axes map draws them north up).",
    "map": "Plane figures are drawn as a map: north up, east to the right.",
}


def check_report_outputs(out_dir, force: bool) -> Path:
    """Check before any work that the report can be written into ``out_dir``.

    Returns
    -------
    pathlib.Path
        ``out_dir`` (it may not exist yet).

    Raises
    ------
    usvlog.errors.StorageError
        If ``out_dir`` exists and is not a directory.
    usvlog.errors.OutputExistsError
        If the page or a figure already exists and ``force`` is False.
    """
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise StorageError(f"{out}: output is not a directory")
    if not force:
        for name in (PAGE, *FIGURES):
            if (out / name).exists():
                raise OutputExistsError(f"{out / name}: output exists (use --force to overwrite)")
    return out


def _plt():
    try:
        import matplotlib  # optional dependency: the report extra
    except ImportError as err:
        raise ConfigError("usvlog report needs matplotlib: pip install 'usvlog[report]'") from err

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt  # after choosing the non-interactive backend

    plt.rcParams.update({"font.size": 10, "axes.grid": True, "grid.alpha": 0.3, "figure.dpi": 110,
                         "savefig.bbox": "tight"})
    return plt


# -----------------------------------------------------------------------------
# what the stages said: one small function each
# -----------------------------------------------------------------------------

def _latest(log: FieldLog, producer: str) -> dict | None:
    for rec in reversed(log.provenance):
        if rec.get("producer") == producer:
            return rec
    return None


def _json(rec: dict | None, key: str):
    if rec is None:
        return None
    try:
        return json.loads(rec.get(key) or "null")
    except (TypeError, ValueError):
        return None


def estimate_status(log: FieldLog) -> tuple[str, list[str]] | None:
    """The estimate's verdict for the report's first line: ``("ok" | "degraded" | "failed", reasons)``.

    ``failed``: ``/estimate/state`` holds no finite position, or the estimator stored that
    status; otherwise the status the estimator stored in the log (:mod:`usvlog.log.status`:
    GNSS only, re-initialisations, inconsistent sensors), or for an older log its consistency
    findings (the provenance record's ``warnings``, from
    :meth:`usvlog.estimate.EstimateReport.consistency`); None for a log without an estimate.
    """
    est = vd.nonempty(log, "/estimate/state")
    rep = _json(_latest(log, "usvlog estimate"), "report") or {}
    stored = stored_estimate_status(log)
    if est is None and not rep and stored is None:
        return None
    if stored is not None:
        rep = {**rep, "status": {"level": stored.status,
                                 "reasons": ([f"GNSS only ({stored.mode})"] if stored.mode == "gps-only"
                                             and not any("GNSS" in r for r in stored.reasons) else [])
                                 + list(stored.reasons)}}
    st = rep.get("status") if isinstance(rep.get("status"), dict) else None
    reasons = [str(w) for w in (st or {}).get("reasons", rep.get("warnings", [])) if isinstance(w, str)]
    if est is not None and "n_m" in est.columns:
        finite = np.isfinite(est["n_m"].to_numpy(dtype=float)) & np.isfinite(est["e_m"].to_numpy(dtype=float))
        if not finite.any():
            return "failed", ["the estimate holds no finite position"] + reasons
    if st is not None and st.get("level") in ("ok", "degraded", "failed"):
        return str(st["level"]), reasons
    return ("degraded" if reasons else "ok"), reasons


def identification(log: FieldLog) -> dict | None:
    """The identification's result as ``usvlog identify --json`` reports it (params, stderr, ci95,
    verdict, ...), from the log's ``usvlog identify`` provenance record; None without one.

    A record without the full result (an older log) gives ``{"params": ...}`` only.
    """
    rec = _latest(log, "usvlog identify")
    if rec is None:
        return None
    res = _json(rec, "result")
    if isinstance(res, dict):
        return res
    settings = _json(rec, "settings") or {}
    return {"params": settings.get("params", {}), "method": settings.get("method")}


def identification_verdict(res: dict) -> tuple[str, list[str]]:
    """(``usable`` | ``usable with caveats`` | ``unusable``, reasons) of an identification result.

    A result carrying a verdict level (``verdict`` as ``Identifier.to_dict()`` gives it, with
    ``reasons``; ``verdict_level``; or a ``verdict`` dict with ``level``) is taken as it is;
    otherwise the verdict lines decide: none means usable, lines mean caveats.
    """
    v = res.get("verdict")
    if isinstance(v, str):   # Identifier.to_dict(): the level, and its reasons in plain words
        return v, [str(x) for x in res.get("reasons", [])]
    if isinstance(v, dict):
        return str(v.get("level", "usable with caveats")), [str(x) for x in v.get("reasons", [])]
    lines = [str(x) for x in (v or [])]
    if isinstance(res.get("verdict_level"), str):
        return res["verdict_level"], lines
    return ("usable with caveats" if lines else "usable"), lines


def replay_record(log: FieldLog) -> dict | None:
    """The latest replay's metrics as stored by ``usvlog replay`` (``ReplayMetrics.to_dict``), or None."""
    m = _json(_latest(log, "usvlog replay"), "metrics")
    return m if isinstance(m, dict) else None


def path_metrics(log: FieldLog, start_s: float | None = None) -> list[tuple[str, str, TrackingMetrics]]:
    """[(controller label, description, metrics)] of every controller channel of the log.

    The replayed and what-if controllers' metrics are the ones ``usvlog replay`` computed and
    printed (stored with the log); other controller channels are measured with the same
    function (:func:`usvlog.replay.tracking_metrics_of`) over the same window: ``start_s``, else
    the replay's, else the whole run.
    """
    controllers = vd.controllers(log)
    if not controllers:
        return []
    from ..replay import TrackingMetrics, tracking_metrics_of  # heavy: the closed loop; only a log with controllers

    rec = replay_record(log)
    stored = {}
    if rec is not None:
        for label, key in (("replay", "replay"), ("whatif", "whatif")):
            if isinstance(rec.get(key), dict):
                stored[label] = TrackingMetrics.from_dict(rec[key])
    if start_s is None:
        start_s = stored["replay"].start_s if "replay" in stored else 0.0
    out = []
    for _topic, label, f, _sf, desc in controllers:
        m = stored.get(label)
        if m is None and "cross_track_m" in f.columns:
            m = tracking_metrics_of(f, start_s)
        if m is not None:
            out.append((label, desc, m))
    return out


# -----------------------------------------------------------------------------
# figures
# -----------------------------------------------------------------------------

def _seconds(t_ns, t0):
    return (np.asarray(t_ns, dtype=np.int64) - t0) / 1e9


def _col(frame, name):
    return np.asarray(frame[name].to_numpy(), dtype=float)


def _finite(*arrays) -> bool:
    ok = None
    for a in arrays:
        m = np.isfinite(np.asarray(a, dtype=float))
        ok = m if ok is None else ok & m
    return ok is not None and bool(ok.any())


def _wrap_deg(psi_rad):
    """Heading in degrees, (-180, 180], with NaN where it wraps, so no line crosses the plot."""
    d = np.degrees(ssa(np.asarray(psi_rad, dtype=float)))
    out = d.copy()
    jump = np.abs(np.diff(d)) > 180.0
    out[1:][jump] = np.nan
    return out


def _legend(ax, **kw):
    """The legend right of the axes, where it covers no data (nothing when nothing is labelled)."""
    h, lab = ax.get_legend_handles_labels()
    if h:
        ax.legend(h, lab, loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0, fontsize=8,
                  framealpha=0.9, **kw)


def _labels(fig) -> list[str]:
    out: list[str] = []
    for ax in fig.axes:
        for lab in ax.get_legend_handles_labels()[1]:
            if lab not in out:
                out.append(lab)
    return out


def _main_controller(log: FieldLog):
    """(label, controller frame, steered state frame, description) the report speaks of."""
    for _topic, label, f, sf, desc in vd.controllers(log):
        if label != "whatif":
            return label, f, sf, desc
    return None


def _steered_track(log: FieldLog):
    """(t, n, e) of the boat the controller steered (or the best state we have), or None."""
    mc = _main_controller(log)
    f = mc[2] if mc is not None and mc[2] is not None and "n_m" in mc[2].columns else None
    if f is None:
        b = vd.boat_state(log)
        f = b[1] if b else None
    if f is None:
        return None
    return f.index.to_numpy(), _col(f, "n_m"), _col(f, "e_m")


class _Axes:
    """How a plane figure maps (north, east) to the page.

    ``paper``: as in the paper's figures, X (north) to the right and Y (east) up, which is
    the mirror image of a map; ``map``: east to the right and north up.
    """

    def __init__(self, mode: str):
        if mode not in ("paper", "map"):
            raise ValueError(f"axes {mode!r} is not 'paper' or 'map'")
        self.mode = mode

    def xy(self, n, e):
        return (n, e) if self.mode == "paper" else (e, n)

    def label(self, ax):
        ax.set_aspect("equal", adjustable="datalim")
        if self.mode == "paper":
            ax.set_xlabel("X, north (m)")
            ax.set_ylabel("Y, east (m)")
        else:
            ax.set_xlabel("East (m)")
            ax.set_ylabel("North (m)")


def _run_label(log: FieldLog, default: str) -> str:
    """'controller (9)-(10)' / 'baseline PI/PID' from the log's provenance, else ``default``."""
    for rec in reversed(log.provenance):
        try:
            ctl = json.loads(rec.get("settings", "{}")).get("controller")
        except (ValueError, AttributeError):
            ctl = None
        if ctl == "full":
            return "controller (9)-(10)"
        if ctl == "baseline":
            return "baseline PI/PID"
        if isinstance(ctl, str) and ctl:
            return ctl
    return default


def _whatif_label(log: FieldLog) -> str:
    rec = replay_record(log) or {}
    ctl = rec.get("whatif_controller")
    return {"full": "what-if run, controller (9)-(10)", "baseline": "what-if run, baseline PI/PID"}.get(
        ctl, "what-if run")


def same_track(a, b, tol_m: float = SAME_TRACK_M) -> bool:
    """True when two (t_ns, n, e) tracks are the same run: over their common time, every position
    of ``b`` (interpolated at ``a``'s times) is within ``tol_m`` metres of ``a``'s."""
    ta, na, ea = a
    tb, nb, eb = b
    lo, hi = max(ta[0], tb[0]), min(ta[-1], tb[-1])
    sel = (ta >= lo) & (ta <= hi)
    if sel.sum() < 2 or (hi - lo) < 0.9 * min(ta[-1] - ta[0], tb[-1] - tb[0]):
        return False
    x = (ta[sel] - lo).astype(float)
    xb = (tb - lo).astype(float)
    dn = na[sel] - np.interp(x, xb, nb)
    de = ea[sel] - np.interp(x, xb, eb)
    d = np.hypot(dn, de)
    return bool(np.all(np.isfinite(d)) and d.max() <= tol_m)


def _whatif_track(log):
    wi = vd.nonempty(log, "/replay/whatif/state")
    if wi is None or "n_m" not in wi.columns:
        return None
    return wi.index.to_numpy(), _col(wi, "n_m"), _col(wi, "e_m")


def _comparison(log, baseline):
    """(what is compared in Fig. 1 and Fig. 2): a list of (key, label, controller frame, state frame, track)."""
    out = []
    wi_track = _whatif_track(log)
    if baseline is not None:
        bmc = _main_controller(baseline)
        bt = _steered_track(baseline)
        if bmc is not None or bt is not None:
            lab = _run_label(baseline, "baseline")
            same = wi_track is not None and bt is not None and same_track(bt, wi_track)
            out.append(("baseline", f"{lab} (baseline log" + (", = the what-if run)" if same else ")"),
                        bmc[1] if bmc else None, bmc[2] if bmc else None, bt))
            if same:
                return out
    if wi_track is not None:
        wc = vd.nonempty(log, "/replay/whatif/controller")
        out.append(("whatif", _whatif_label(log), wc, vd.nonempty(log, "/replay/whatif/state"), wi_track))
    return out


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
        ax.plot(*xy(g[3][keep], g[4][keep]), ".", color="0.55", ms=2.5, alpha=0.6, label="GPS fixes (raw)", zorder=1)
        if (~keep).any():
            ax.plot(*xy(g[3][~keep], g[4][~keep]), "x", color="C3", ms=6, label="GPS fixes rejected", zorder=5)
    tru = vd.nonempty(log, "/truth/state")
    if tru is not None and "n_m" in tru.columns and _finite(_col(tru, "n_m")):
        ax.plot(*xy(_col(tru, "n_m"), _col(tru, "e_m")), "--", color="k", lw=0.9, label="truth (simulated)",
                zorder=3)
    if have_est:
        n, e = _col(est, "n_m"), _col(est, "e_m")
        ax.plot(*xy(n, e), "-", color="C0", lw=1.4, label="smoothed estimate", zorder=4)
        _start_marker(ax, xy, n, e, "C0")
        vman.draw_on_track(ax, xy, log, vman.of_log(log))   # each standard manoeuvre, numbered as in its table
    if path is not None:
        ax.plot(*xy(path[:, 0], path[:, 1]), ":", color="C1", lw=1.4, label="desired path (dotted)", zorder=2)
    axes.label(ax)
    ax.set_title("Track: raw GPS fixes and the smoothed estimate" if have_est else "Track: raw GPS fixes")
    if have_est and "current_n_mps" in est.columns:
        cn_a, ce_a = _col(est, "current_n_mps"), _col(est, "current_e_mps")
        ok_c = np.isfinite(cn_a) & np.isfinite(ce_a)
        if ok_c.any():
            cn, ce = float(cn_a[ok_c].mean()), float(ce_a[ok_c].mean())
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


def band_envelope(t, lo, hi, n_bins: int):
    """The band between ``lo`` and ``hi`` over ``t`` reduced to its envelope in ``n_bins`` equal
    slices of ``t``'s span: per slice, the lowest ``lo`` and the highest ``hi`` at its first and
    last sample (a slice narrower than a pixel covers what its samples cover). A run of
    non-finite samples stays one NaN sample, so the band breaks where it broke.

    Parameters
    ----------
    t : numpy.ndarray
        Sample times, increasing (any unit, e.g. s).
    lo, hi : numpy.ndarray
        Lower and upper edge at each sample (same unit as each other).
    n_bins : int
        Number of slices.

    Returns
    -------
    tuple of numpy.ndarray
        (t, lo, hi) of the envelope: at most ``2 n_bins`` samples plus one per break; the
        first and last finite samples keep their times, every ``lo`` is a sample's ``lo``
        and every ``hi`` a sample's ``hi``.
    """
    t, lo, hi = (np.asarray(a, dtype=float) for a in (t, lo, hi))
    ok = np.isfinite(t) & np.isfinite(lo) & np.isfinite(hi)
    span = t[-1] - t[0]
    b = np.minimum((n_bins * (t - t[0]) / span).astype(np.int64), n_bins - 1) if span > 0 else np.zeros(len(t), int)
    start = np.r_[True, (b[1:] != b[:-1]) | (ok[1:] != ok[:-1])]
    first = np.nonzero(start)[0]
    last = np.r_[first[1:] - 1, len(t) - 1]
    g_ok = ok[first]
    g_lo = np.minimum.reduceat(np.where(ok, lo, np.inf), first)
    g_hi = np.maximum.reduceat(np.where(ok, hi, -np.inf), first)
    tt = np.column_stack([t[first], t[last]]).ravel()
    ll = np.repeat(np.where(g_ok, g_lo, np.nan), 2)
    uu = np.repeat(np.where(g_ok, g_hi, np.nan), 2)
    keep = np.repeat(g_ok, 2) | np.tile([True, False], len(first))   # one NaN sample per break
    return tt[keep], ll[keep], uu[keep]


BAND_BINS_PER_PX = 4   # slices of a band per pixel of its axes' width


def _band(ax, t, lo, hi, **kw):
    """``ax.fill_between(t, lo, hi, **kw)``, its polygon reduced to the axes' resolution first
    (:func:`band_envelope`, four slices per pixel): matplotlib fills a band's polygon vertex by
    vertex (a filled path is never simplified), an hour at 100 Hz in 0.4 s per band."""
    n_bins = int(BAND_BINS_PER_PX * ax.get_window_extent().width)
    if len(t) > 2 * n_bins:
        t, lo, hi = band_envelope(t, lo, hi, n_bins)
    return ax.fill_between(t, lo, hi, **kw)


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


def _render(fig) -> bytes:
    """The figure as PNG bytes (the files are written only once every figure has rendered)."""
    buf = io.BytesIO()
    try:
        fig.savefig(buf, format="png")
    finally:
        _plt().close(fig)
    return buf.getvalue()


def _drawn(title: str, make) -> tuple[str, bytes] | None:
    """(caption, PNG bytes) of one figure, or None when the log lacks what it needs."""
    fig = make()
    if fig is None:
        return None
    return f"{title}: " + "; ".join(_labels(fig)), _render(fig)


# CPU seconds to draw each figure of a 1-hour log (benchmarks/bench_view.py --figures LOG, best of 3, on an
# estimated, a replayed and an identified run) and the channels it draws from (none: not drawn, costs nothing)
FIGURE_COST = {"fig4_path.png": 0.33, "estimate_series.png": 0.83, "fit_velocities.png": 0.52,
               "fit_track.png": 0.19, "fig1_track.png": 0.20, "fig2_errors.png": 0.56, "fig5_speed_heading.png": 0.40}
_CONTROLLED = tuple(t for t, _label, _state, _desc in vd.CONTROLLERS)
FIGURE_CHANNELS = {"fig4_path.png": ("/estimate/state", "/gnss/fix"), "estimate_series.png": ("/estimate/state",),
                   "fit_velocities.png": ("/identify/fit",), "fit_track.png": ("/identify/fit",),
                   "fig1_track.png": _CONTROLLED, "fig2_errors.png": _CONTROLLED,
                   "fig5_speed_heading.png": _CONTROLLED}
PAGE_COST = 0.08   # the page's text (metrics, events), built while the copy draws


def figure_costs(figs, log: FieldLog | None = None) -> list[float]:
    """The expected cost of each figure of ``figs`` (relative; :data:`FIGURE_COST`), 0 for one
    whose channels ``log`` lacks; a figure not in the table costs the table's mean."""
    mean = sum(FIGURE_COST.values()) / len(FIGURE_COST)
    out = []
    for name, *_rest in figs:
        needs = FIGURE_CHANNELS.get(name)
        if log is not None and needs is not None and not any(vd.nonempty(log, t) is not None for t in needs):
            out.append(0.0)
        else:
            out.append(FIGURE_COST.get(name, mean))
    return out


def share(costs: list[float], own: float = 0.0) -> list[int]:
    """Indices of the figures a second process draws: the costliest first, each to the process
    with less to do (this one starts with ``own``, e.g. the page), ties to the second.

    Parameters
    ----------
    costs : list of float
        Expected cost of each figure (any unit, e.g. CPU s).
    own : float, default 0.0
        Work this process has besides its figures (same unit).

    Returns
    -------
    list of int
        Increasing indices into ``costs``; empty when a second process would get nothing.
    """
    mine, theirs = own, 0.0
    out = []
    for i in sorted(range(len(costs)), key=lambda i: (-costs[i], i)):
        if costs[i] <= 0.0:
            continue
        if theirs <= mine:
            out.append(i)
            theirs += costs[i]
        else:
            mine += costs[i]
    return sorted(out)


def draw_all(figs, *, log: FieldLog | None = None, meanwhile=None) -> list[tuple[str, bytes] | None]:
    """Every figure of ``figs`` (as :func:`figures` lists them) drawn: (caption, PNG bytes), or
    None for one the log cannot give, in order.

    matplotlib's drawing holds the GIL, so on a machine with a second CPU (Linux) a forked
    copy of the process draws some of the figures while this one draws the others and then
    runs ``meanwhile()`` (e.g. the page's text): shared by their expected cost
    (:func:`figure_costs` of ``log``, :func:`share`). A figure depends only on the log and
    matplotlib's settings, both the same in the copy, so the bytes are those drawn here; when
    the copy fails, its figures are drawn here after all.
    """
    n = len(figs)
    out: list[tuple[str, bytes] | None] = [None] * n
    theirs = share(figure_costs(figs, log), PAGE_COST if meanwhile is not None else 0.0) \
        if n > 1 and _two_cores() else []
    child = _Forked(lambda: [_drawn(figs[i][1], figs[i][2]) for i in theirs]) if theirs else None
    try:
        for i in range(n):
            if i not in theirs:
                out[i] = _drawn(figs[i][1], figs[i][2])
        if meanwhile is not None:
            meanwhile()
    except BaseException:
        if child is not None:
            child.stop()
        raise
    if child is not None:
        got = child.result()
        for k, i in enumerate(theirs):
            out[i] = got[k] if got is not None else _drawn(figs[i][1], figs[i][2])
    return out


def figures(log: FieldLog, *, baseline: FieldLog | None = None, axes: str = "paper"):
    """[(file name, title, make, needs)] of the report's figures, in page order.

    ``make()`` returns a matplotlib Figure, or None when the log lacks the channels (``needs``
    says which) or they hold no finite value. Tests and the page use the same list.
    """
    plt = _plt()
    ax_mode = _Axes(axes)
    path = vd.path_polyline(log)
    return [
        ("fig4_path.png", "Track (Fig. 4 style)", lambda: _fig_measured(plt, log, path, axes=ax_mode),
         "finite /estimate/state or /gnss/fix (a closed-loop run without an estimate: its track is Fig. 1)"),
        ("estimate_series.png", "Estimated speed, heading and yaw rate", lambda: _fig_estimate_series(plt, log),
         "finite /estimate/state"),
        ("fit_velocities.png", "Identification fit: velocities", lambda: _fig_fit_velocities(plt, log),
         "/identify/fit (usvlog identify --out-log)"),
        ("fit_track.png", "Identification fit: track", lambda: _fig_fit_track(plt, log, ax_mode),
         "/identify/fit (usvlog identify --out-log)"),
        ("fig1_track.png", "Path following (Fig. 1 style)",
         lambda: _fig_track(plt, log, path, baseline=baseline, axes=ax_mode),
         "a controller channel (/control/state or /replay/controller) and a state"),
        ("fig2_errors.png", "Tracking errors (Fig. 2 style)", lambda: _fig_errors(plt, log, baseline),
         "a controller channel (/control/state or /replay/controller)"),
        ("fig5_speed_heading.png", "Speed and heading (Fig. 5 style)", lambda: _fig_speed_heading(plt, log),
         "a controller channel and a state channel"),
    ]


def write_report(log: FieldLog | list[FieldLog], out_dir, force: bool = False, *, baseline: FieldLog | None = None,
                 axes: str = "paper", links=()) -> Path:
    """Write ``report.html`` and its PNG figures into ``out_dir``; returns the page's path.

    ``log`` may also be a pair ``[log, baseline]``. ``axes="paper"`` draws the plane figures
    as the paper does (X = north to the right, Y = east up); ``axes="map"`` draws them north up.

    What is shown depends on what the log holds (see the module's description): positions
    in m, speeds in m/s, angles in degrees, time in s from the start; figures it cannot
    draw are listed on the page with the channels they need.

    The report is complete or absent: every figure is rendered first, then a new ``out_dir``
    (or one holding only an earlier report) is built as a hidden sibling directory and
    renamed into place. A directory that also holds other files keeps them: the report's
    files are written to temporary files there and renamed together at the end (figures an
    earlier report drew and this one does not are removed).

    Parameters
    ----------
    log : FieldLog or list of FieldLog
        The run, or ``[log]`` / ``[log, baseline]``.
    out_dir : str or os.PathLike
        Directory for ``report.html`` and the PNGs (created if missing).
    force : bool, default False
        Overwrite existing report files.
    baseline : FieldLog, optional
        A run to compare with in Fig. 1 and Fig. 2 (drawn solid, this log dashed, as in the paper).
    axes : {"paper", "map"}, default "paper"
        Orientation of the plane figures.
    links : sequence of (str, str), optional
        (relative URL, text) of related pages, listed under the title.

    Returns
    -------
    pathlib.Path
        Path of ``report.html``.

    Raises
    ------
    usvlog.errors.ConfigError
        If more than two logs are given, or matplotlib is not installed (the ``report``
        extra).
    ValueError
        If ``axes`` is not ``paper`` or ``map``.
    usvlog.errors.OutputExistsError
        If a report file exists and ``force`` is False.
    usvlog.errors.StorageError
        If ``out_dir`` is not a directory or cannot be created or written.
    """
    if isinstance(log, (list, tuple)):  # [log, baseline]
        if not 1 <= len(log) <= 2:
            raise ConfigError(f"a report takes one log and at most one baseline, got {len(log)} logs")
        log, baseline = log[0], (log[1] if len(log) == 2 else baseline)
    out = check_report_outputs(out_dir, force)
    shown, missing, pngs = [], [], []
    figs = figures(log, baseline=baseline, axes=axes)
    head: list[str] = []
    drawn_all = draw_all(figs, log=log, meanwhile=lambda: head.extend(_page_head(log, baseline, links)))
    for (name, title, _make, needs), drawn in zip(figs, drawn_all):
        if drawn is None:
            missing.append((title, needs))
            continue
        caption, png = drawn
        pngs.append((name, png))
        shown.append((name, caption))
    page_text = "\n".join(head + _page_figures(shown, missing, AXES_NOTE[axes]))   # _html, its head built above
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise StorageError(f"{out}: cannot create directory {out.parent} ({err.strerror})") from err
    if not out.exists() or _only_report_files(out):
        # ownership and --force were checked above: an existing directory holds only a report
        with atomic_dir(out, force=True) as tmp:
            for name, data in pngs:
                (tmp / name).write_bytes(data)
            (tmp / PAGE).write_text(page_text, encoding="utf-8")
        return out / PAGE
    with contextlib.ExitStack() as stack:  # a shared directory: every file to a temporary first
        tmps = [(stack.enter_context(atomic_path(out / name, force=force)), data) for name, data in pngs]
        tmps.append((stack.enter_context(atomic_path(out / PAGE, force=force)), page_text.encode()))
        for tmp, data in tmps:
            tmp.write_bytes(data)
        with deferred_signals():  # then all renamed together, stale figures of an earlier report removed
            for name in FIGURES:
                if name not in dict(pngs):
                    with contextlib.suppress(FileNotFoundError):
                        (out / name).unlink()
            stack.close()
    return out / PAGE


def _only_report_files(out: Path) -> bool:
    """True when ``out`` is a real directory holding nothing but a report's files (so it may be replaced)."""
    if out.is_symlink() or not out.is_dir():
        return False
    names = {PAGE, *FIGURES}
    return all(e.name in names and e.is_file() for e in out.iterdir())


PARAM_UNITS = {"m": "kg", "Iz": "kg m^2", "d11": "kg/s", "d22": "kg/s", "d33": "kg m^2/s", "xg": "m"}


def _table(head, rows, cls="") -> str:
    e = html.escape
    out = [f"<table class='{cls}'><tr>" + "".join(f"<th>{e(h)}</th>" for h in head) + "</tr>"]
    for r in rows:
        out.append("<tr>" + "".join(f"<td class='num'>{e(str(c))}</td>" if i and _numeric(c) else
                                    f"<td>{e(str(c))}</td>" for i, c in enumerate(r)) + "</tr>")
    out.append("</table>")
    return "".join(out)


def _numeric(c) -> bool:
    try:
        float(str(c).replace("+-", "").split()[0])
    except (ValueError, IndexError):
        return False
    return True


def _status_line(log: FieldLog) -> tuple[str, list[str]]:
    """(the short status for the title, the sentences of the status paragraph)."""
    short, parts = [], []
    st = estimate_status(log)
    if st is not None:
        level, reasons = st
        if level != "ok":
            short.append(f"estimate {level.upper()}")
        parts.append(f"Estimate: {level}" + (f" ({'; '.join(reasons)})" if reasons else ""))
    res = identification(log)
    if res is not None:
        level, reasons = identification_verdict(res)
        if level != "usable":
            short.append(f"identification {level}")
        parts.append(f"Identification: {level}" + (f" ({len(reasons)} caveat(s), below)" if reasons else ""))
    rec = replay_record(log)
    if rec is not None:
        off = [w for w in rec.get("warnings", []) if isinstance(w, str)]
        if off:
            short.append("replay NOT on the scenario's path")
        parts.append("Replay: " + ("does not follow the scenario's path" if off else "follows the scenario's path"))
    return ", ".join(short), parts


def _metrics_section(log, baseline) -> list[str]:
    e = html.escape
    parts = ["<h2 id='metrics'>Metrics</h2>"]
    pm = path_metrics(log)
    rec = replay_record(log) or {}
    off = bool(rec.get("warnings"))
    if pm:
        rows = []
        groups: dict[tuple, list[str]] = {}   # runs with the very same numbers (a replay of the closed loop) once
        for label, desc, m in pm:
            note = " (NOT on the scenario's path: not a path-following measure)" if off and label == "replay" else ""
            groups.setdefault(tuple(m.display()), []).append(desc + note)
        for disp, descs in groups.items():
            rows += [(" = ".join(descs), name, value, unit) for name, value, unit in disp]
        window = pm[0][2].window
        parts.append(f"<h3>Path following, over [{e(window)}]</h3>"
                     "<p>The same numbers as <code>usvlog replay</code> prints (its --json holds them in "
                     "radians); the window is in each name.</p>")
        parts.append(_table(("run", "metric", "value", "unit"), rows, "pathmetrics"))
    if baseline is not None:
        start = pm[0][2].start_s if pm else None
        bm = path_metrics(baseline, start)
        wi, bt = _whatif_track(log), _steered_track(baseline)
        if wi is not None and bt is not None and same_track(bt, wi):
            parts.append("<h3>Baseline log</h3><p>The baseline log is the what-if run (the same track within "
                         f"{SAME_TRACK_M * 1000:g} mm): its metrics are the what-if run's above.</p>")
        elif bm:
            rows = [(f"baseline: {desc}", name, value, unit) for _l, desc, m in bm for name, value, unit in m.display()]
            parts.append(f"<h3>Baseline log ({e(Path(baseline.source).name if baseline.source else 'baseline')})"
                         "</h3>")
            parts.append(_table(("run", "metric", "value", "unit"), rows, "baselinemetrics"))
    descs = tuple(f"{d}:" for _t, _l, _f, _s, d in vd.controllers(log))
    rows = [r for r in vd.metrics(log) if not r[0].startswith(descs)]   # tracking metrics: above, once
    if rows:
        parts.append("<h3>Log</h3>")
        parts.append(_table(("metric", "value", "unit"), rows, "logmetrics"))
    return parts


def _estimate_section(log) -> list[str]:
    st = estimate_status(log)
    if st is None:
        return []
    e = html.escape
    level, reasons = st
    parts = [f"<h2 id='estimate'>Estimate: {e(level)}</h2>"]
    if reasons:
        parts.append("<ul>" + "".join(f"<li>{e(r)}</li>" for r in reasons) + "</ul>")
    rep = _json(_latest(log, "usvlog estimate"), "report") or {}
    sens = rep.get("sensors") or {}
    if sens:
        parts.append("<p>Consistency: the mean NIS of a sensor whose noise is stated right is near its "
                     "dimension.</p>")
        rows = [(s, r.get("accepted"), r.get("rejected"), r.get("skipped", 0),
                 f"{r.get('mean_nis', float('nan')):.3f}", r.get("dim")) for s, r in sens.items()]
        parts.append(_table(("sensor", "accepted", "rejected", "skipped", "mean NIS", "expected (dim)"), rows,
                            "consistency"))
    if rep:
        parts.append(f"<p>GNSS dropouts bridged by prediction: {int(rep.get('dropouts_bridged', 0))}; "
                     f"model {e(str(rep.get('model')))}.</p>")
    h = health_from_provenance(log.provenance)
    parts.append("<h3>Sensor health (import audit)</h3>")
    if h:
        parts.append("<pre>" + e("\n".join(format_health(h))) + "</pre>")
    else:
        parts.append("<p>No import audit in this log (it was not imported from a field source).</p>")
    return parts


def _identification_section(log) -> list[str]:
    res = identification(log)
    if res is None:
        return []
    e = html.escape
    level, reasons = identification_verdict(res)
    parts = [f"<h2 id='identification'>Identification: {e(level)}</h2>",
             f"<p>Method: {e(str(res.get('method') or '?'))}"
             + (f"; fit computed on {e(str(res['fit_percent_on']))}" if res.get("fit_percent_on") else "") + ".</p>"]
    params, se, ci = res.get("params") or {}, res.get("stderr") or {}, res.get("ci95") or {}
    rows = []
    for k in [p for p in PARAM_NAMES if p in params] + [p for p in params if p not in PARAM_NAMES]:
        v, lo_hi = params[k], ci.get(k)
        rows.append((k, f"{v:.5g}", PARAM_UNITS.get(k, ""), f"{se[k]:.2g}" if k in se else "",
                     f"{lo_hi[0]:.4g} .. {lo_hi[1]:.4g}" if lo_hi else ""))
    parts.append(_table(("parameter", "value", "unit", "std. error", "95 % interval"), rows, "params"))
    cur = res.get("current_ne_mps")
    if cur:
        parts.append("<p>Water current (north, east): " + "; ".join(f"{c[0]:+.3f}, {c[1]:+.3f} m/s" for c in cur)
                     + ".</p>")
    fp = res.get("fit_percent") or {}
    if fp:
        parts.append("<p>Fit: " + ", ".join(f"{k} {v:.1f} %" for k, v in fp.items()) + ".</p>")
    parts.append("<h3>Verdict</h3>")
    parts.append("<ul class='verdict'>" + ("".join(f"<li>{e(r)}</li>" for r in reasons) if reasons else
                                           "<li>no caveat</li>") + "</ul>")
    return parts


def _html(log, baseline, shown, missing, axes_note: str, links=()) -> str:
    return "\n".join(_page_head(log, baseline, links) + _page_figures(shown, missing, axes_note))


def _page_head(log, baseline, links=()) -> list[str]:
    """The page's parts before its figures (status, warnings, metrics, sections, events)."""
    e = html.escape
    title = f"usvlog report: {Path(log.source).name if log.source else 'log'}"
    short, status = _status_line(log)
    head = title + (f" ({short})" if short else "")
    tr = log.time_range()
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>{e(head)}</title>",
             "<style>body{font-family:sans-serif;max-width:1000px;margin:2em auto;color:#222}"
             "figure{margin:1.5em 0}img{max-width:100%;border:1px solid #ddd}"
             "table{border-collapse:collapse;margin:0.5em 0}td,th{border:1px solid #ccc;padding:3px 8px;"
             "text-align:left}td.num{text-align:right;font-variant-numeric:tabular-nums}"
             ".bad{color:#b00}</style></head><body>",
             f"<h1{' class=bad' if short else ''}>{e(head)}</h1>"]
    if status:
        parts.append("<p id='status'>" + " &middot; ".join(e(s) for s in status) + "</p>")
    warn = vd.warnings(log) + [f"replay: {w}" for w in (replay_record(log) or {}).get("warnings", [])
                               if isinstance(w, str)]
    if warn:   # first, where nobody misses it: the figures below rest on these
        parts.append("<div class='warn' style='border:2px solid #c00;padding:0.5em 1em'><h2>Warnings</h2><ul>"
                     + "".join(f"<li>{e(w)}</li>" for w in warn) + "</ul></div>")
    if tr:
        base = (" &middot; baseline: " + e(Path(baseline.source).name)
                if baseline is not None and baseline.source else "")
        parts.append(f"<p>{e(format_time(tr[0]))} to {e(format_time(tr[1]))} UTC{base}</p>")
    if links:
        parts.append("<p>See also: " + ", ".join(f"<a href='{e(u)}'>{e(t)}</a>" for u, t in links) + "</p>")
    parts += _metrics_section(log, baseline)
    parts += _estimate_section(log)
    parts += _identification_section(log)
    parts += vfind.html_section(vfind.of_log(log))
    parts += vman.html_section(vman.of_log(log))
    ev = vd.events_once(log)
    if ev:
        parts.append(f"<h2>Events ({len(ev)})</h2><ul class='events'>")
        t0 = tr[0] if tr else 0
        for x in ev[:200]:
            parts.append(f"<li>{(x.t_ns - t0) / 1e9:8.2f} s{' [WARN]' if x.level == 'WARN' else ''}: {e(x.text)}</li>")
        if len(ev) > 200:
            parts.append(f"<li>... {len(ev) - 200} more</li>")
        parts.append("</ul>")
    return parts


def _page_figures(shown, missing, axes_note: str) -> list[str]:
    """The page's parts from its figures on: each figure with its caption, those not drawn."""
    e = html.escape
    parts = ["<h2>Figures</h2>", f"<p>{e(axes_note)}</p>"]
    for name, caption in shown:
        parts.append(f"<figure><img src='{e(name)}' alt='{e(caption)}'><figcaption>{e(caption)}</figcaption></figure>")
    if missing:
        parts.append("<h3>Not drawn (the log lacks the channels, or they hold no finite value)</h3><ul>")
        for caption, needs in missing:
            parts.append(f"<li>{e(caption)}: needs {e(needs)}</li>")
        parts.append("</ul>")
    parts.append("</body></html>\n")
    return parts
