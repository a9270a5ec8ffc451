"""Drawing the report's figures to PNG bytes, on two CPUs where there are two.

:func:`_drawn` draws one figure (:mod:`usvlog.view.report_figures`) and renders it with its
caption (what its legend names). :func:`draw_all` draws every figure of the page: on a machine
with a second CPU a forked copy of the process (:mod:`usvlog.view.forked`) draws some of them
while this one draws the others and builds the page's text; :func:`share` divides them by their
expected cost (:data:`FIGURE_COST`, measured by ``benchmarks/bench_view.py``).
"""

from __future__ import annotations

from ..log.fieldlog import FieldLog
from . import data as vd
from .forked import Forked as _Forked
from .forked import two_cores as _two_cores
from .report_plot import _labels, _render


def _drawn(title: str, make) -> tuple[str, bytes] | None:
    """(caption, PNG bytes) of one figure, or None when the log lacks what it needs."""
    fig = make()
    if fig is None:
        return None
    return f"{title}: " + "; ".join(_labels(fig)), _render(fig)


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
    # earns its place (issue 32): a 1-hour `usvlog report` 15 % faster with the copy (median of 4
    # paired on/off runs, 11-16 %, load 1.2) and its peak 494 MB instead of 578; docs/performance.md
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
