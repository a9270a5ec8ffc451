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

The report is written by :func:`write_report` here, from parts each in a module of its own:

* :mod:`usvlog.view.report_runs`: what the log says of its runs (the stages' verdicts, the
  metrics, which runs Fig. 1 and Fig. 2 compare);
* :mod:`usvlog.view.report_figures`: one function per figure (the paper's figures, the
  estimate's series, the identification's fit), listed in page order by :func:`figures`;
* :mod:`usvlog.view.report_plot`: matplotlib's set-up, the axes and legend helpers, a figure's PNG;
* :mod:`usvlog.view.report_draw`: every figure drawn, shared with a forked copy on two CPUs;
* :mod:`usvlog.view.report_page`: the HTML page;
* :mod:`usvlog.view.report_windows`: a long log's big channels decimated as they are read, for the
  figures (a :class:`usvlog.view.windowed.WindowedLog`: its numbers come from its survey).
"""

from __future__ import annotations

import contextlib
from pathlib import Path

from ..errors import ConfigError, OutputExistsError, StorageError
from ..io.atomic import atomic_dir, atomic_path, deferred_signals
from ..log.fieldlog import FieldLog
from . import data as vd
from .report_draw import draw_all
from .report_figures import (
    _fig_errors,
    _fig_estimate_series,
    _fig_fit_track,
    _fig_fit_velocities,
    _fig_measured,
    _fig_speed_heading,
    _fig_track,
)
from .report_page import _page_figures, _page_head
from .report_plot import _Axes, _plt
from .report_windows import decimated
from .windowed import NotWindowed, WindowedLog, whole

# isort: split
# names other modules import from here, their code now in the report_* modules: usvlog.campaign.report
# and usvlog.view.source take _plt and _render, the tests and benchmarks/bench_view.py the others
from .report_draw import FIGURE_COST, PAGE_COST, _drawn, _Forked, _two_cores, figure_costs, share  # noqa: F401
from .report_page import _html  # noqa: F401
from .report_plot import _band, _render, band_envelope  # noqa: F401

PAGE = "report.html"
FIGURES = ("fig1_track.png", "fig2_errors.png", "fig4_path.png", "fig5_speed_heading.png",
           "estimate_series.png", "fit_velocities.png", "fit_track.png")

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
    if isinstance(log, WindowedLog):   # its big channels read a block at a time, decimated for the figures
        try:
            log = decimated(log)
        except NotWindowed:
            log = whole(log)
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
