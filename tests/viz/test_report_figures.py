"""The report's figures and tables, looked at: matplotlib objects (titles, units, legends off the
data, nothing drawn from NaN), the HTML's tables, the status line, and one image regression per
figure kind against small baseline PNGs in tests/data/figures."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from usvlog.replay import OFF_PATH, replay_log
from usvlog.sim.scenario import load_scenario
from usvlog.sim.simulate import SimSettings, simulate
from usvlog.view import report as rp
from usvlog.view.report import FIGURES, figures, write_report

from .conftest import make_view_log
from .test_metrics_consistency import tables

BASELINES = Path(__file__).resolve().parents[1] / "data" / "figures"
UPDATE = os.environ.get("USVLOG_UPDATE_FIGURES") == "1"   # rewrite the baseline PNGs (then look at them)


def _drawn(log, only=None, **kw):
    out = {}
    for name, _title, make, _needs in figures(log, **kw):
        if only is not None and name not in only:
            continue
        fig = make()
        if fig is not None:
            out[name] = fig
    return out


def _close(figs):
    rp._plt().close("all")


def _legend_outside(fig, ax, leg) -> bool:
    r = fig.canvas.get_renderer()
    return leg.get_window_extent(r).x0 >= ax.get_window_extent(r).x1 - 1.0


@pytest.fixture(scope="module")
def small_log():
    return make_view_log(duration_s=50.0)   # every channel; the speed step at 45 s


def test_every_figure_has_title_units_and_a_legend_off_the_data(small_log):
    figs = _drawn(small_log)
    assert set(figs) == set(FIGURES)   # the test log holds every channel
    try:
        for name, fig in figs.items():
            axes = [ax for ax in fig.axes if ax.lines or ax.collections]
            assert axes[0].get_title(), name
            legends = [(ax, ax.get_legend()) for ax in axes if ax.get_legend() is not None]
            assert legends and legends[0][0] is axes[0], name   # stacked panels share the first one's legend
            assert all(_legend_outside(fig, ax, leg) for ax, leg in legends), name
            for ax in axes:
                assert "(" in ax.get_ylabel() and ax.get_ylabel().rstrip().endswith(")"), (name, ax.get_ylabel())
                for line in ax.lines:
                    y = np.asarray(line.get_ydata(), float)
                    assert np.isfinite(y).any(), (name, line.get_label())   # nothing drawn from NaN alone
            assert "(s)" in axes[-1].get_xlabel() or "(m)" in axes[-1].get_xlabel(), name
    finally:
        _close(figs)


def test_raw_fixes_are_points_and_the_estimate_a_line(view_log):
    figs = _drawn(view_log, only=("fig4_path.png", "estimate_series.png"))
    try:
        ax = figs["fig4_path.png"].axes[0]
        by = {ln.get_label(): ln for ln in ax.lines}
        gps = by["GPS fixes (raw)"]
        assert gps.get_linestyle() == "None" and gps.get_marker() == "."   # points, not a scribble
        assert by["smoothed estimate"].get_linestyle() == "-"
        assert "GPS fixes rejected" in by   # the 25 m jump of the test log
        # the estimate panel: u, heading and yaw rate with a 1-sigma band each
        es = figs["estimate_series.png"]
        assert [a.get_ylabel() for a in es.axes] == ["surge speed u (m/s)", "heading (deg)", "yaw rate r (deg/s)"]
        assert all(len(a.collections) >= 1 for a in es.axes)
        psi = [ln for ln in es.axes[1].lines if ln.get_label() == "smoothed estimate"][0]
        y = np.asarray(psi.get_ydata(), float)
        assert np.nanmax(np.abs(y)) <= 180.0   # wrapped degrees
        assert np.nanmax(np.abs(np.diff(y))) < 90.0   # broken where it wraps, no stroke across the plot
    finally:
        _close(figs)


def test_whatif_identical_to_the_baseline_is_drawn_once(tmp_path):
    """The demo's case: the what-if run with the baseline controller is the baseline simulation; the
    report draws it once, says so, and does not repeat its numbers in a Baseline table."""
    from usvlog.sim.closed_loop import simulate_scenario

    scen = load_scenario("paper-circle")
    full = simulate_scenario(scen, duration_s=70.0)
    base = simulate_scenario(scen, controller="baseline", duration_s=70.0)
    replayed = replay_log(full, scen, whatif_controller="baseline").log
    figs = _drawn(replayed, baseline=base)
    try:
        labels = [ln.get_label() for ln in figs["fig1_track.png"].axes[0].lines]
        assert sum("baseline" in lb for lb in labels) == 1 and not any(lb.startswith("what-if") for lb in labels)
        assert any("= the what-if run" in lb for lb in labels)
        assert "fig4_path.png" not in figs   # no estimate: the track is Fig. 1's, not drawn twice
    finally:
        _close(figs)
    html = write_report(replayed, tmp_path / "r", baseline=base).read_text()
    assert "baselinemetrics" not in tables(html) and "its metrics are the what-if run" in html
    rows = tables(html)["pathmetrics"][1:]
    assert {r[0] for r in rows} == {"closed-loop controller = replayed controller", "what-if controller"}
    assert html.count("speed step u_d") == 0   # 70 s: before the step at 100 s
    assert "desired path (dashed)" in html     # drawn, so named


def test_speed_step_is_one_event(small_log):
    html = rp._html(small_log, None, [], [], "", ())   # the page without its figures
    assert html.count("speed step u_d 0.40 -&gt; 0.20") == 1
    assert "closed-loop controller, what-if controller: speed step" in html


def test_identified_run_shows_parameters_intervals_and_verdict(tmp_path):
    from usvlog.api import fit_log
    from usvlog.identify import Identifier

    log = simulate("excitation", SimSettings(duration_s=120.0), seed=3)
    idf = Identifier("equation-error").fit([log])
    html = write_report(fit_log(idf, log), tmp_path / "r").read_text()
    t = tables(html)["params"]
    assert t[0] == ["parameter", "value", "unit", "std. error", "95 % interval"]
    got = {r[0]: r for r in t[1:]}
    assert list(got) == ["m", "Iz", "d11", "d22", "d33", "xg"]
    assert float(got["m"][1]) == pytest.approx(idf.params_.m, rel=1e-4) and got["m"][2] == "kg"
    lo, hi = map(float, got["d11"][4].split(" .. "))
    assert lo == pytest.approx(idf.ci95_["d11"][0], rel=1e-3) and hi == pytest.approx(idf.ci95_["d11"][1], rel=1e-3)
    assert idf.verdict_ in ("usable", "usable with caveats", "unusable")
    assert f"<h2 id='identification'>Identification: {idf.verdict_}</h2>" in html
    assert idf.reasons_   # a 2-minute equation-error fit is not clean: the reasons are listed
    for v in idf.reasons_:
        assert v.replace("&", "&amp;").replace(">", "&gt;").replace("<", "&lt;").replace("'", "&#x27;")[:40] in html
    assert "src='fit_velocities.png'" in html and "src='fit_track.png'" in html


def test_all_nan_estimate_draws_nothing_and_says_failed_first(tmp_path):
    from usvlog.estimate import EstimateSettings, estimate

    log = simulate("excitation", SimSettings(duration_s=30.0), seed=2)
    est = estimate(log, EstimateSettings()).to_log(log)
    st = est["/estimate/state"].copy()
    for c in st.columns:
        if st[c].dtype.kind == "f":
            st[c] = np.nan
    est.set("/estimate/state", st)
    page = write_report(est, tmp_path / "r")
    html = page.read_text()
    title = html.split("<h1", 1)[1].split("</h1>", 1)[0]
    assert "estimate FAILED" in title
    assert "the estimate holds no finite position" in html
    drawn = {p.name for p in (tmp_path / "r").glob("*.png")}
    assert "estimate_series.png" not in drawn
    figs = _drawn(est)
    try:   # the track figure shows the GPS fixes only, no empty estimate line
        labels = [ln.get_label() for ln in figs["fig4_path.png"].axes[0].lines]
        assert "smoothed estimate" not in labels and "GPS fixes (raw)" in labels
    finally:
        _close(figs)


def test_replay_off_the_path_is_said_not_measured_as_if(tmp_path, capsys):
    """An excitation run replayed against paper-circle: warned in the metrics, on the console and
    first in the report, and its numbers marked as no path-following measure."""
    from usvlog.cli.replay import format_metrics

    log = simulate("excitation", SimSettings(duration_s=90.0), seed=2)
    res = replay_log(log, load_scenario("paper-circle"), whatif=False)
    m = res.metrics
    assert not m.follows_path and m.warnings[0].startswith(OFF_PATH)
    rc = res.log["/replay/controller"]
    xt = np.abs(rc["cross_track_m"].to_numpy())
    window = (rc.index - rc.index[0]) >= 60e9                         # paper-circle's metrics start
    assert f"median |cross-track| {np.median(xt[window]):.3g} m over t>60s" in m.warnings[0]
    text = format_metrics(m)
    assert text.splitlines()[0].startswith("warning: " + OFF_PATH) and "NOT on the scenario's path" in text
    html = write_report(res.log, tmp_path / "r").read_text()
    assert "replay NOT on the scenario&#x27;s path" in html.split("</h1>")[0]
    assert html.index(OFF_PATH.replace("'", "&#x27;")) < html.index("<h2 id='metrics'>")
    rows = tables(html)["pathmetrics"][1:]
    assert all("NOT on the scenario" in r[0] for r in rows)
    assert json.loads(res.log.provenance[-1]["metrics"])["warnings"] == list(m.warnings)


def test_a_run_on_its_path_has_no_warning():
    from usvlog.sim.closed_loop import simulate_scenario

    scen = load_scenario("paper-circle")
    m = replay_log(simulate_scenario(scen, duration_s=70.0), scen, whatif=False).metrics
    assert m.follows_path and m.warnings == ()


# -----------------------------------------------------------------------------
# image regression: one small PNG per figure kind
# -----------------------------------------------------------------------------

@pytest.fixture(scope="module")
def small_figs(small_log):
    figs = _drawn(small_log)
    yield figs
    _close(figs)


@pytest.mark.parametrize("name", FIGURES)
def test_image_regression(tmp_path, small_figs, name):
    import matplotlib.image as mpimg

    fig = small_figs[name]
    fig.set_size_inches(6.0, 4.5)
    out = tmp_path / name
    fig.savefig(out, dpi=50)   # about 400 x 230 pixels with the legend (the tight box takes it in)
    ref = BASELINES / name
    if UPDATE:
        ref.parent.mkdir(parents=True, exist_ok=True)
        ref.write_bytes(out.read_bytes())
    if not ref.exists():
        pytest.fail(f"no baseline {ref}: run with USVLOG_UPDATE_FIGURES=1 and look at it")
    a, b = mpimg.imread(out)[..., :3], mpimg.imread(ref)[..., :3]
    assert a.shape == b.shape
    diff = np.abs(a - b)
    # a small tolerance for anti-aliasing; a lost line, legend or axis changes far more pixels
    assert diff.mean() < 0.01 and (diff.max(axis=-1) > 0.25).mean() < 0.01, name


# -----------------------------------------------------------------------------
# a long band drawn at the axes' resolution
# -----------------------------------------------------------------------------

def test_band_envelope_keeps_each_slice_extremes_and_breaks():
    rng = np.random.default_rng(3)
    t = np.arange(20_000) * 0.01
    y = np.cumsum(rng.normal(0, 0.1, len(t)))
    lo, hi = y - 0.5, y + 0.5
    lo[7000:7010] = np.nan   # a break (a wrapped heading)
    n = 300
    te, le, he = rp.band_envelope(t, lo, hi, n)
    assert len(te) <= 2 * n + 2 and te[0] == t[0] and te[-1] == t[-1]
    assert np.isnan(le).sum() == 1 and np.isnan(le[np.searchsorted(te, 70.0)])
    for k in (0, 117, n - 1):   # brute force over the samples of a slice
        sel = (t >= k * t[-1] / n) & (t < (k + 1) * t[-1] / n) & np.isfinite(lo)
        m = (te >= t[sel][0]) & (te <= t[sel][-1])
        assert le[m].min() == lo[sel].min() and he[m].max() == hi[sel].max()


def test_long_band_draws_the_same_picture():
    """The band reduced to four slices per pixel against the full polygon, rasterised: what
    differs is anti-aliasing at the edges."""
    plt = rp._plt()
    rng = np.random.default_rng(4)
    t = np.arange(60_000) * 0.01
    y = np.sin(t / 40.0) * 20 + np.cumsum(rng.normal(0, 0.05, len(t)))
    imgs = []
    for draw in ("fill_between", "_band"):
        fig, ax = plt.subplots(figsize=(5.0, 2.0), dpi=80)
        if draw == "_band":
            rp._band(ax, t, y - 2.0, y + 2.0, color="C0", alpha=0.25, lw=0)
        else:
            ax.fill_between(t, y - 2.0, y + 2.0, color="C0", alpha=0.25, lw=0)
        fig.canvas.draw()
        imgs.append(np.asarray(fig.canvas.buffer_rgba())[..., :3] / 255.0)
        plt.close(fig)
    d = np.abs(imgs[0] - imgs[1])
    assert (d.max(-1) > 0.25).mean() == 0.0 and d.mean() < 1e-3
