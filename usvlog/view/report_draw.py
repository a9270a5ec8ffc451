"""Drawing the report's figures to PNG bytes.

:func:`_drawn` draws one figure (:mod:`usvlog.view.report_figures`) and renders it with its
caption (what its legend names). :func:`draw_all` draws every figure of the page, one after
another. (A forked copy of the process once drew a share of them: a 1-hour report was no faster
for it, so it was taken out; docs/performance.md.)
"""

from __future__ import annotations

from .report_plot import _labels, _render


def _drawn(title: str, make) -> tuple[str, bytes] | None:
    """(caption, PNG bytes) of one figure, or None when the log lacks what it needs."""
    fig = make()
    if fig is None:
        return None
    return f"{title}: " + "; ".join(_labels(fig)), _render(fig)


def draw_all(figs) -> list[tuple[str, bytes] | None]:
    """Every figure of ``figs`` (as :func:`figures` lists them) drawn, in order: (caption, PNG
    bytes), or None for one the log cannot give."""
    return [_drawn(title, make) for _name, title, make, *_rest in figs]
