"""matplotlib for the report: its set-up, the helpers every figure uses, and a figure's PNG.

:func:`_plt` imports matplotlib (the ``report`` extra) on the non-interactive backend with the
report's style; the helpers turn a log's columns into what the axes draw (seconds from the
start, float arrays, headings that break where they wrap), put the legend right of the axes,
map (north, east) to the page as the paper or a map does (:class:`_Axes`), and fill a long
1-sigma band at the axes' resolution (:func:`band_envelope`). :func:`_render` is the last step
of every figure (the report's, :mod:`usvlog.view.report_figures`, and the campaign's).
"""

from __future__ import annotations

import io

import numpy as np

from ..errors import ConfigError
from ..model.frames import ssa


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


def bucket_runs(b: np.ndarray, ok: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(first, last) row of each run of samples in one bucket ``b`` and of one finiteness ``ok``.

    Parameters
    ----------
    b : numpy.ndarray
        Each sample's bucket (int, non-decreasing), at least one sample.
    ok : numpy.ndarray
        Whether each sample is finite (bool).

    Returns
    -------
    tuple of numpy.ndarray
        The first and the last row index of each run, in order.
    """
    first = np.nonzero(np.r_[True, (b[1:] != b[:-1]) | (ok[1:] != ok[:-1])])[0]
    return first, np.r_[first[1:] - 1, len(b) - 1]


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
    first, last = bucket_runs(b, ok)
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


def _render(fig) -> bytes:
    """The figure as PNG bytes (the files are written only once every figure has rendered)."""
    buf = io.BytesIO()
    try:
        fig.savefig(buf, format="png")
    finally:
        _plt().close(fig)
    return buf.getvalue()
