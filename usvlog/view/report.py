"""A static report: an HTML page with PNG figures in the style of the paper's Fig. 1, 2, 4, 5.

* Fig. 1: desired path (dashed) and trajectory (solid), equal axes, metres, north up;
* Fig. 2: yaw error psi_e, surge speed error u_e and sway speed v against time; with a
  baseline log, the log is dashed and the baseline solid, as in the paper;
* Fig. 4: desired path (dotted) and the measured/estimated trajectory (solid), with the
  mean estimated current drawn as an arrow ("approximate current direction");
* Fig. 5: surge speed and heading, actual (solid) and desired (dashed);
* identification fit: measured against simulated u, v, r and track (``/identify/fit``);
* a table of metrics.

Figures whose channels the log lacks are left out and listed as such on the page.
"""

from __future__ import annotations

import contextlib
import html
import io
import json
import math
from pathlib import Path

import numpy as np

from ..errors import ConfigError, OutputExistsError, StorageError
from ..io.atomic import atomic_dir, atomic_path, deferred_signals
from ..log.fieldlog import FieldLog, format_time
from ..model.frames import ssa
from . import data as vd

PAGE = "report.html"
FIGURES = ("fig1_track.png", "fig2_errors.png", "fig4_path.png", "fig5_speed_heading.png",
           "fit_velocities.png", "fit_track.png")


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


def _seconds(t_ns, t0):
    return (np.asarray(t_ns, dtype=np.int64) - t0) / 1e9


def _col(frame, name):
    return np.asarray(frame[name].to_numpy(), dtype=float)


def _main_controller(log: FieldLog):
    """(label, controller frame, steered state frame, description) the report speaks of."""
    for _topic, label, f, sf, desc in vd.controllers(log):
        if label != "whatif":
            return label, f, sf, desc
    return None


def _steered_track(log: FieldLog):
    """(name, t, n, e) of the boat the controller steered (or the best state we have)."""
    mc = _main_controller(log)
    if mc is not None and mc[2] is not None and "n_m" in mc[2].columns:
        f = mc[2]
        return "trajectory", f.index.to_numpy(), _col(f, "n_m"), _col(f, "e_m")
    b = vd.boat_state(log)
    if b is not None:
        return "trajectory", b[1].index.to_numpy(), _col(b[1], "n_m"), _col(b[1], "e_m")
    g = vd.gps(log)
    if g is not None and len(g[0]):
        return "GPS fixes", g[0], g[3], g[4]
    return None


def _measured_track(log: FieldLog):
    """The track as measured: the smoothed estimate, else the GPS fixes, else the truth."""
    f = vd.nonempty(log, "/estimate/state")
    if f is not None and "n_m" in f.columns:
        return "estimated trajectory", f.index.to_numpy(), _col(f, "n_m"), _col(f, "e_m")
    g = vd.gps(log)
    if g is not None and len(g[0]):
        return "GPS fixes", g[0], g[3], g[4]
    return _steered_track(log)


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
    """'full controller' / 'baseline PI/PID' from the log's provenance, else ``default``."""
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


def _fig_track(plt, log, path, *, style: str, measured: bool, baseline: FieldLog | None, axes: _Axes):
    tr = _measured_track(log) if measured else _steered_track(log)
    if tr is None:
        return None
    xy = axes.xy
    fig, ax = plt.subplots(figsize=(6.2, 6.0))
    name, t, n, e = tr
    label = name if baseline is None else f"{name}, {_run_label(log, 'this log')}"
    if name == "GPS fixes":
        ax.plot(*xy(n, e), "-", color="C0", lw=0.8, label="GPS track")
    else:
        ax.plot(*xy(n, e), "-", color="C0", lw=1.4, label=label)
    if path is not None:  # on top, so the dashes show where the boat is on the path
        ax.plot(*xy(path[:, 0], path[:, 1]), style, color="k", lw=1.2, label="desired path", zorder=4)
    ok = np.isfinite(n) & np.isfinite(e)
    if ok.any():
        k = np.nonzero(ok)[0][0]
        ax.plot(*xy(n[k], e[k]), "o", color="C0", ms=5, mfc="none", label="start", zorder=5)
    mc = _main_controller(log)
    if mc is not None and mc[2] is not None and "n_m" in mc[2].columns:
        steps = vd.speed_steps(mc[1])
        if steps:
            ts = np.array([s[0] for s in steps], dtype=np.int64)
            sn, se = vd.interp(ts, mc[2], "n_m"), vd.interp(ts, mc[2], "e_m")
            ax.plot(*xy(sn, se), "^", color="C1", ms=7, label="speed step (u_d)", zorder=6)
    if not measured:
        wi = vd.nonempty(log, "/replay/whatif/state")
        if wi is not None:
            ax.plot(*xy(_col(wi, "n_m"), _col(wi, "e_m")), "-.", color="C4", lw=1.1, label="what-if run")
        if baseline is not None:
            bt = _steered_track(baseline)
            if bt is not None:
                ax.plot(*xy(bt[2], bt[3]), "-", color="C3", lw=1.0, alpha=0.8,
                        label=f"{bt[0]}, {_run_label(baseline, 'baseline')}")
    axes.label(ax)
    if measured:
        est = vd.nonempty(log, "/estimate/state")
        if est is not None and "current_n_mps" in est.columns:
            cn_a, ce_a = _col(est, "current_n_mps"), _col(est, "current_e_mps")
            ok_c = np.isfinite(cn_a) & np.isfinite(ce_a)
            cn, ce = (float(cn_a[ok_c].mean()), float(ce_a[ok_c].mean())) if ok_c.any() else (math.nan, math.nan)
            sp = math.hypot(cn, ce)
            if np.isfinite(sp) and sp > 0.01:
                _current_arrow(fig, ax, *xy(cn, ce), sp)
    ax.legend(loc="best", fontsize=8, framealpha=0.85)
    return fig


def _current_arrow(fig, ax, cx, cy, sp):
    """The paper's "approximate current direction" arrow, in the top-left corner of the axes."""
    fig.canvas.draw()  # final axes size, so the arrow's direction is true on screen
    bb = ax.get_window_extent()
    L = 45.0  # pixels
    x0, y0 = 0.07, 0.80
    tip = (x0 + L * cx / sp / bb.width, y0 + L * cy / sp / bb.height)
    ax.annotate("", xy=tip, xytext=(x0, y0), xycoords="axes fraction", textcoords="axes fraction",
                arrowprops=dict(arrowstyle="-|>", lw=1.8, color="C2"))
    ax.text(0.03, 0.97, f"approximate current ({sp:.2f} m/s)", transform=ax.transAxes, color="C2",
            fontsize=8, ha="left", va="top", bbox=dict(fc="white", ec="none", alpha=0.8))


def _fig_errors(plt, log, baseline):
    mc = _main_controller(log)
    if mc is None:
        return None
    series = [("log", log, mc, "--")]
    if baseline is not None:
        bmc = _main_controller(baseline)
        if bmc is not None:
            series.append(("baseline", baseline, bmc, "-"))
    fig, axes = plt.subplots(3, 1, figsize=(7.0, 6.4), sharex=True)
    names = {"log": _run_label(log, "this log"), "baseline": _run_label(baseline, "baseline") if baseline else ""}
    colors = {"log": "C0", "baseline": "C3"}
    for key, lg, (_label, f, sf, desc), ls in series:
        t0 = f.index[0]
        t = _seconds(f.index.to_numpy(), t0)
        nm = names[key] if baseline is not None else _run_label(lg, desc)
        if "psi_e_rad" in f.columns:
            axes[0].plot(t, ssa(_col(f, "psi_e_rad")), ls, color=colors[key], lw=1.2, label=nm)
        if "u_e_mps" in f.columns:
            axes[1].plot(t, _col(f, "u_e_mps"), ls, color=colors[key], lw=1.2, label=nm)
        if sf is not None and "v_mps" in sf.columns:
            axes[2].plot(_seconds(sf.index.to_numpy(), t0), _col(sf, "v_mps"), ls, color=colors[key], lw=1.2,
                         label=nm)
    axes[0].set_ylabel(r"$\psi_e$ (rad)")
    axes[1].set_ylabel(r"$u_e$ (m/s)")
    axes[2].set_ylabel(r"$v$ (m/s)")
    axes[2].set_xlabel("time (s)")
    axes[0].legend(fontsize=8, loc="upper right")
    fig.align_ylabels(axes)
    return fig


def _fig_speed_heading(plt, log):
    mc = _main_controller(log)
    if mc is None:
        return None
    label, f, sf, desc = mc
    if sf is None or "u_mps" not in sf.columns:
        b = vd.boat_state(log)
        sf = b[1] if b else None
    if sf is None:
        return None
    t0 = f.index[0]
    fig, axes = plt.subplots(2, 1, figsize=(7.0, 5.0), sharex=True)
    ts = _seconds(sf.index.to_numpy(), t0)
    tc = _seconds(f.index.to_numpy(), t0)
    axes[0].plot(ts, _col(sf, "u_mps"), "-", color="C0", lw=1.2, label="actual")
    if "u_d_mps" in f.columns:
        axes[0].plot(tc, _col(f, "u_d_mps"), "--", color="C1", lw=1.4, label="desired")
    axes[0].set_ylabel("surge speed u (m/s)")
    psi = _col(sf, "psi_rad")
    ok = np.isfinite(psi)
    if "psi_d_rad" in f.columns and ok.any():
        a, d = vd.heading_pair(sf.index.to_numpy()[ok], psi[ok], f.index.to_numpy(), _col(f, "psi_d_rad"))
        axes[1].plot(ts[ok], a, "-", color="C0", lw=1.2, label="actual")
        axes[1].plot(tc, d, "--", color="C1", lw=1.4, label="desired")
    else:
        axes[1].plot(ts[ok], np.unwrap(psi[ok]), "-", color="C0", lw=1.2, label="actual")
    axes[1].set_ylabel(r"yaw angle $\psi$ (rad, unwrapped)")
    axes[1].set_xlabel("time (s)")
    axes[0].legend(fontsize=8, loc="lower right")
    axes[1].legend(fontsize=8, loc="best")
    fig.align_ylabels(axes)
    return fig


def _fig_fit_velocities(plt, log):
    fit = vd.nonempty(log, "/identify/fit")
    if fit is None:
        return None
    rows = [(q, s, lab) for q, s, lab in (("u_mps", "u_sim_mps", "u (m/s)"), ("v_mps", "v_sim_mps", "v (m/s)"),
                                          ("r_radps", "r_sim_radps", "r (rad/s)"))
            if q in fit.columns and s in fit.columns]
    if not rows:
        return None
    t = _seconds(fit.index.to_numpy(), fit.index[0])
    fig, axes = plt.subplots(len(rows), 1, figsize=(7.0, 2.1 * len(rows) + 0.6), sharex=True, squeeze=False)
    for ax, (q, s, lab) in zip(axes[:, 0], rows):
        ax.plot(t, _col(fit, q), "-", color="0.35", lw=1.0, label="measured")
        ax.plot(t, _col(fit, s), "--", color="C3", lw=1.2, label="model (simulated)")
        ax.set_ylabel(lab)
    axes[0, 0].legend(fontsize=8, loc="upper right")
    axes[-1, 0].set_xlabel("time (s)")
    axes[0, 0].set_title("Identification: measured vs simulated velocities")
    fig.align_ylabels(axes[:, 0])
    return fig


def _fig_fit_track(plt, log, axes: _Axes):
    fit = vd.nonempty(log, "/identify/fit")
    if fit is None or not {"n_m", "e_m", "n_sim_m", "e_sim_m"} <= set(fit.columns):
        return None
    fig, ax = plt.subplots(figsize=(6.2, 6.0))
    ax.plot(*axes.xy(_col(fit, "n_m"), _col(fit, "e_m")), "-", color="0.35", lw=1.2, label="measured")
    ax.plot(*axes.xy(_col(fit, "n_sim_m"), _col(fit, "e_sim_m")), "--", color="C3", lw=1.2,
            label="model (simulated)")
    axes.label(ax)
    ax.set_title("Identification: measured vs simulated track")
    ax.legend(fontsize=8, loc="lower right")
    return fig


def _render(fig) -> bytes:
    """The figure as PNG bytes (the files are written only once every figure has rendered)."""
    buf = io.BytesIO()
    try:
        fig.savefig(buf, format="png")
    finally:
        _plt().close(fig)
    return buf.getvalue()


def write_report(log: FieldLog | list[FieldLog], out_dir, force: bool = False, *, baseline: FieldLog | None = None,
                 axes: str = "paper") -> Path:
    """Write ``report.html`` and its PNG figures into ``out_dir``; returns the page's path.

    ``log`` may also be a pair ``[log, baseline]``. ``axes="paper"`` draws the plane figures
    as the paper does (X = north to the right, Y = east up); ``axes="map"`` draws them north up.

    Figures in the style of the paper's Fig. 1, 2, 4 and 5 and the identification fit
    are drawn from whatever channels the log holds (positions in m, speeds in m/s,
    angles in degrees, time in s from the start); figures it cannot draw are listed on
    the page with the channels they need.

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
        A run to compare with in Fig. 2 (drawn solid, this log dashed, as in the paper).
    axes : {"paper", "map"}, default "paper"
        Orientation of the plane figures.

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
    ax_mode = _Axes(axes)
    out = check_report_outputs(out_dir, force)
    plt = _plt()
    path = vd.path_polyline(log)
    figs = [
        ("fig1_track.png", "Fig. 1 style: desired path (dashed) and trajectory of the USV (solid)",
         lambda: _fig_track(plt, log, path, style="--", measured=False, baseline=baseline, axes=ax_mode),
         "a state channel (/estimate/state, /truth/state) or GPS fixes"),
        ("fig2_errors.png", "Fig. 2 style: yaw tracking error, surge speed tracking error and sway speed"
         + (" (this log dashed, baseline solid)" if baseline is not None else ""),
         lambda: _fig_errors(plt, log, baseline), "a controller channel (/control/state or /replay/controller)"),
        ("fig4_path.png", "Fig. 4 style: desired path (dotted) and measured trajectory (solid)",
         lambda: _fig_track(plt, log, path, style=":", measured=True, baseline=None, axes=ax_mode),
         "/estimate/state or /gnss/fix"),
        ("fig5_speed_heading.png", "Fig. 5 style: actual (solid) and desired (dashed) surge speed (top) and "
         "yaw angle (bottom)", lambda: _fig_speed_heading(plt, log), "a controller channel and a state channel"),
        ("fit_velocities.png", "Identification fit: measured vs simulated u, v, r",
         lambda: _fig_fit_velocities(plt, log), "/identify/fit"),
        ("fit_track.png", "Identification fit: measured vs simulated track",
         lambda: _fig_fit_track(plt, log, ax_mode), "/identify/fit"),
    ]
    shown, missing, pngs = [], [], []
    for name, caption, make, needs in figs:
        fig = make()
        if fig is None:
            missing.append((caption, needs))
            continue
        pngs.append((name, _render(fig)))
        shown.append((name, caption))
    page_text = _html(log, baseline, shown, missing, AXES_NOTE[axes])
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


def _html(log, baseline, shown, missing, axes_note: str) -> str:
    e = html.escape
    title = f"usvlog report: {Path(log.source).name if log.source else 'log'}"
    tr = log.time_range()
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>{e(title)}</title>",
             "<style>body{font-family:sans-serif;max-width:980px;margin:2em auto;color:#222}"
             "figure{margin:1.5em 0}img{max-width:100%;border:1px solid #ddd}"
             "table{border-collapse:collapse}td,th{border:1px solid #ccc;padding:3px 8px;text-align:left}"
             "td.num{text-align:right;font-variant-numeric:tabular-nums}</style></head><body>",
             f"<h1>{e(title)}</h1>"]
    warn = vd.warnings(log)
    if warn:   # first, where nobody misses it: the figures below rest on these
        parts.append("<div class='warn' style='border:2px solid #c00;padding:0.5em 1em'><h2>Warnings</h2><ul>"
                     + "".join(f"<li>{e(w)}</li>" for w in warn) + "</ul></div>")
    if tr:
        base = (" &middot; baseline: " + e(Path(baseline.source).name)
                if baseline is not None and baseline.source else "")
        parts.append(f"<p>{e(format_time(tr[0]))} to {e(format_time(tr[1]))} UTC{base}</p>")
    parts.append("<h2>Metrics</h2><table><tr><th>metric</th><th>value</th><th>unit</th></tr>")
    for name, value, unit in vd.metrics(log):
        parts.append(f"<tr><td>{e(name)}</td><td class='num'>{e(value)}</td><td>{e(unit)}</td></tr>")
    parts.append("</table>")
    if baseline is not None:
        parts.append("<h3>Baseline</h3><table><tr><th>metric</th><th>value</th><th>unit</th></tr>")
        for name, value, unit in vd.metrics(baseline):
            parts.append(f"<tr><td>{e(name)}</td><td class='num'>{e(value)}</td><td>{e(unit)}</td></tr>")
        parts.append("</table>")
    ev = vd.events(log)
    if ev:
        parts.append(f"<h2>Events ({len(ev)})</h2><ul>")
        t0 = tr[0] if tr else 0
        for x in ev[:200]:
            parts.append(f"<li>{(x.t_ns - t0) / 1e9:8.2f} s: {e(x.text)}</li>")
        if len(ev) > 200:
            parts.append(f"<li>... {len(ev) - 200} more</li>")
        parts.append("</ul>")
    parts.append("<h2>Figures</h2>")
    parts.append(f"<p>{e(axes_note)}</p>")
    for name, caption in shown:
        parts.append(f"<figure><img src='{e(name)}' alt='{e(caption)}'><figcaption>{e(caption)}</figcaption></figure>")
    if missing:
        parts.append("<h3>Not drawn (the log lacks the channels)</h3><ul>")
        for caption, needs in missing:
            parts.append(f"<li>{e(caption)}: needs {e(needs)}</li>")
        parts.append("</ul>")
    parts.append("</body></html>\n")
    return "\n".join(parts)
