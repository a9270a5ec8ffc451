"""The campaign report: ``campaign.html`` with PNG drift plots, the runs table, the failures, and ``campaign.rrd``.

* ``drift_<vessel>.png``: each identified parameter against the run date, a 95 % interval
  per run, the weighted mean (consistent) or the two segment means (a step);
* the table of runs, its verdict cells coloured (usable green, caveats amber, unusable red,
  failed grey), then the failed runs with their reasons;
* ``campaign.rrd``: every run with an estimate on one map, one entity per run
  (``/runs/<run_id>``), and an ``elapsed`` timeline next to the common ``time`` one, drawn
  by :func:`usvlog.view.rrd.to_rrd`.
"""

from __future__ import annotations

import html
from pathlib import Path

import numpy as np

from ..io.atomic import write_bytes_atomic, write_text_atomic
from ..view.report import _plt, _render
from . import columns as C
from .drift import ParameterDrift
from .tasks import ESTIMATE_FILE, LOG_FILE, MAP_FILE, MAP_HZ, map_log

PAGE = "campaign.html"
RRD = "campaign.rrd"
COLOURS = {C.USABLE: "#c8ecc8", C.CAVEATS: "#fbe3a6", C.UNUSABLE: "#f4b6b6", C.FAILED: "#dddddd"}


def _safe(name: str) -> str:
    return "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in name) or "unnamed"


def drift_figure(vessel: str, drift: dict[str, ParameterDrift]) -> bytes:
    """PNG of one vessel's parameters against the run date with 95 % intervals.

    Parameters
    ----------
    vessel : str
        Vessel name (title).
    drift : dict of str to ParameterDrift
        The parameters to draw.

    Returns
    -------
    bytes
        The PNG.
    """
    plt = _plt()
    names = list(drift)
    fig, axes = plt.subplots(len(names), 1, figsize=(8, 1.9 * len(names) + 0.6), sharex=True, squeeze=False)
    for ax, p in zip(axes[:, 0], names):
        d = drift[p]
        t = d.t_ns.astype("datetime64[ns]")
        colour = "tab:red" if d.drifted else "tab:blue"
        ax.errorbar(t, d.value, yerr=d.value - d.ci95_low, fmt="o", ms=4, capsize=3, color=colour)
        if d.drifted and d.change is not None:
            k = d.change.index
            for seg, m, s in ((slice(0, k), d.change.before, d.change.before_se),
                              (slice(k, None), d.change.after, d.change.after_se)):
                ts = t[seg]
                ax.plot([ts[0], ts[-1]], [m, m], color="k", lw=1.2)
                ax.fill_between([ts[0], ts[-1]], m - 1.96 * s, m + 1.96 * s, color="k", alpha=0.12, lw=0)
            ax.set_title(d.change.describe(p), fontsize=9, loc="left")
        else:
            c = d.consistency
            ax.axhline(c.mean, color="k", lw=1.0)
            ax.axhspan(c.mean - 1.96 * c.mean_se, c.mean + 1.96 * c.mean_se, color="k", alpha=0.12, lw=0)
            ax.set_title(d.describe(), fontsize=9, loc="left")
        ax.set_ylabel(p)
    axes[-1, 0].set_xlabel("run date (UTC)")
    fig.suptitle(f"{vessel}: identified parameters per run, 95 % intervals", fontsize=11)
    fig.autofmt_xdate()
    return _render(fig)


def _cell(v) -> str:
    if v is None or (isinstance(v, float) and not np.isfinite(v)):
        return ""
    try:
        if v is np.nan or v != v:   # pandas NA / NaN
            return ""
    except (TypeError, ValueError):
        return ""
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


def _html(result, figures: list[tuple[str, str]], rrd: str | None) -> str:
    e = html.escape
    t = result.table
    parts = ["<!doctype html><html><head><meta charset='utf-8'><title>usvlog campaign</title>",
             "<style>body{font-family:sans-serif;max-width:1300px;margin:2em auto;color:#222}"
             "img{max-width:100%;border:1px solid #ddd}table{border-collapse:collapse;font-size:85%}"
             "td,th{border:1px solid #ccc;padding:2px 6px;text-align:left}"
             "td.num{text-align:right;font-variant-numeric:tabular-nums}</style></head><body>",
             f"<h1>usvlog campaign: {e(str(result.out))}</h1>",
             f"<p>{len(t)} runs: {int((t['status'] == C.OK).sum())} through every stage, {result.failed} failed, "
             f"{result.unusable} with an unusable identification; {result.executed} processed now, "
             f"{result.reused} reused from an earlier campaign.</p>"]
    parts.append("<h2>Findings</h2><ul>" + "".join(f"<li>{e(x)}</li>" for x in result.findings()) + "</ul>")
    for name, caption in figures:
        parts.append(f"<figure><img src='{e(name)}' alt='{e(caption)}'><figcaption>{e(caption)}</figcaption></figure>")
    if result.joint:
        parts.append("<h2>Joint model per vessel (leave-one-run-out validation)</h2>")
        for v, j in result.joint.items():
            if j.error:
                parts.append(f"<p>{e(v)}: joint fit failed: {e(j.error)}</p>")
                continue
            ps = ", ".join(f"{p} {_cell(j.params[p])} \u00b1 {_cell(j.stderr[p])}" for p in j.params)
            parts.append(f"<p><b>{e(v)}</b> ({len(j.runs)} runs, {e(j.verdict)}): {e(ps)}</p>")
            parts.append("<table><tr><th>left out</th><th>fit u %</th><th>fit v %</th><th>fit r %</th>"
                         "<th>fit track %</th><th>reason</th></tr>")
            for _, r in j.loro.iterrows():
                parts.append("<tr>" + "".join(f"<td class='num'>{e(_cell(r.get(k)))}</td>" for k in
                                              ("run_id", "fit_u_pct", "fit_v_pct", "fit_r_pct", "fit_track_pct",
                                               "reason")) + "</tr>")
            parts.append("</table>")
    cols = ["run_id", "vessel", "start_utc", "duration_s", "distance_m", "status", "verdict", "d11", "d11_se",
            "fit_track_pct", "estimate_consistent"]
    parts.append("<h2>Runs</h2><table><tr>" + "".join(f"<th>{e(c)}</th>" for c in cols) + "</tr>")
    for _, r in t.iterrows():
        word = C.FAILED if r["status"] == C.FAILED else r["verdict"]
        bg = COLOURS.get(word if isinstance(word, str) else "", "")
        parts.append(f"<tr style='background:{bg}'>" + "".join(
            f"<td class='num'>{e(_cell(r[c]))}</td>" for c in cols) + "</tr>")
    parts.append("</table>")
    bad = t[t["reason"].notna()]
    if len(bad):
        parts.append(f"<h2>Failed or unusable runs ({len(bad)})</h2><ul>")
        for _, r in bad.iterrows():
            parts.append(f"<li><b>{e(str(r['source']))}</b>: {e(str(r['reason']))}</li>")
        parts.append("</ul>")
    if rrd:
        parts.append(f"<p>Every run's track on one map: <code>rerun {e(rrd)}</code></p>")
    parts.append("<p>The table: <code>pandas.read_parquet('runs.parquet')</code></p></body></html>\n")
    return "\n".join(parts)


def write_campaign_report(result, *, progress=None) -> dict[str, Path]:
    """Write ``campaign.html``, one ``drift_<vessel>.png`` per vessel and ``campaign.rrd`` into the campaign directory.

    Parameters
    ----------
    result : CampaignResult
        The campaign (its table and drift).
    progress : callable, optional
        Receives a line as each file is written, and a warning when the map cannot be
        made.

    Returns
    -------
    dict
        ``report`` (the page), ``rrd`` (when written) and ``drift_<vessel>`` (each PNG).
    """
    say = progress or (lambda s: None)
    out = Path(result.out)
    files: dict[str, Path] = {}
    figures = []
    for v, drift in result.drift.items():
        if not drift:
            continue
        name = f"drift_{_safe(v)}.png"
        write_bytes_atomic(out / name, drift_figure(v, drift), force=True)
        files[f"drift_{v}"] = out / name
        figures.append((name, f"{v}: parameters against run date (95 % intervals; a step in red)"))
    rrd = _write_rrd(result, say)
    if rrd is not None:
        files["rrd"] = rrd
    write_text_atomic(out / PAGE, _html(result, figures, RRD if rrd else None), force=True)
    files["report"] = out / PAGE
    say(f"wrote {out / PAGE}")
    return files


def _write_rrd(result, say) -> Path | None:
    from ..io.mcap import read_log  # heavy: the MCAP reader, only when the map is drawn
    from ..view.rrd import to_rrd

    out = Path(result.out)
    logs, names = [], []
    for _, r in result.table.iterrows():
        d = out / "runs" / str(r["run_id"])
        # the run's own map file (written by its task); a run directory from before it: its log
        f = next((d / n for n in (MAP_FILE, ESTIMATE_FILE, LOG_FILE) if (d / n).exists()), None)
        if f is None:
            continue
        try:
            lg = read_log(f, topics=list(MAP_HZ))
        except Exception as err:  # a run whose log cannot be read back is left off the map, said once
            say(f"warning: {f}: not on the map ({err})")
            continue
        if f.name != MAP_FILE:
            lg = map_log(lg)
        if lg.time_range() is not None:
            logs.append(lg)
            names.append(str(r["run_id"]))
    if not logs:
        return None
    p = to_rrd(logs, out / RRD, names=names, force=True)
    say(f"wrote {p}")
    return p


__all__ = ["COLOURS", "PAGE", "RRD", "drift_figure", "write_campaign_report"]
