"""The report's HTML page: its head (status, warnings, metrics, sections, events) and its figures.

:func:`_page_head` builds everything above the figures from what the log says of its runs
(:mod:`usvlog.view.report_runs`): the title with a short status, the status paragraph, the
warnings first, the metrics (path following as ``usvlog replay`` printed them, the baseline
log's, the log's own), the estimate's section (consistency table, import audit), the
identification's (parameters, intervals, verdict), the findings of ``usvlog check``
(:mod:`usvlog.view.findings`), the manoeuvres (:mod:`usvlog.view.manoeuvres`) and the events.
:func:`_page_figures` adds each figure with its caption and lists those not drawn.
:func:`usvlog.view.report.write_report` joins the two.
"""

from __future__ import annotations

import html
from pathlib import Path

from ..choices import PARAM_NAMES
from ..log.fieldlog import FieldLog, format_time
from ..log.summary import format_health, health_from_provenance
from . import data as vd
from . import findings as vfind
from . import manoeuvres as vman
from .report_runs import (
    SAME_TRACK_M,
    _json,
    _latest,
    _steered_track,
    _whatif_track,
    estimate_status,
    identification,
    identification_verdict,
    path_metrics,
    replay_record,
    same_track,
)
from .windowed import findings_of, manoeuvres_of

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
    ahead = res.get("fit_percent_ahead") or {}
    if ahead:   # k-step-ahead: restarted from the measured state every H s (what the verdict's caveat reads)
        parts.append("<p>Predicted ahead: " + "; ".join(
            f"{h} s: " + ", ".join(f"{c} {v:.1f} %" for c, v in sorted(ahead[h].items()))
            for h in sorted(ahead, key=float)) + ".</p>")
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
    parts += vfind.html_section(findings_of(log))
    parts += vman.html_section(manoeuvres_of(log)[0])
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
