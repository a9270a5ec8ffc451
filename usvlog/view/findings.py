"""The findings of ``usvlog check`` as the report and the Rerun recording show them.

:func:`of_log` runs the checks (:func:`usvlog.check.check_log`) on the log as the report or
the view read it, with the channels the checks read and they did not (:data:`CHECK_TOPICS`)
read from its file; :func:`html_section` is the report's
table and :func:`rerun_parts` the recording's text log: one entry per finding at its start
time (the log's start for a finding about the whole run), with its level.
"""

from __future__ import annotations

import html
from pathlib import Path

import numpy as np

from ..check import CheckResult, Smoothed, check_log
from ..errors import UsvlogError
from ..log.fieldlog import FieldLog
from ..log.findings import counts

ENTITY = "check"
"""Rerun entity of the findings' text log under a run (``/runs/<name>/check``)."""

LEVELS = {"error": "ERROR", "warning": "WARN", "info": "INFO"}
"""Finding severity -> Rerun text log level."""


CHECK_TOPICS = ("/gnss/fix", "/local/position", "/compass/heading", "/imu/yaw_rate", "/gnss/quality",
                "/gnss/velocity", "/thrust/command")
"""The channels the checks read: those the view or report did not read are read from the log's file."""


def _with_checked_channels(log: FieldLog) -> FieldLog:
    """``log``, or a shallow copy with the checked channels it lacks read from its file (the view
    leaves the compass out when it draws a state)."""
    need = [t for t in CHECK_TOPICS if t not in log]
    if not need or not log.source or not Path(log.source).is_file():
        return log
    from ..io.mcap import read_log  # heavy: the MCAP reader (only when channels are missing)

    try:
        more = read_log(log.source, topics=need)
    except UsvlogError:
        return log
    out = log.copy()
    for t in need:
        if t in more:
            out.set(t, more[t])
    return out


def of_log(log: FieldLog) -> CheckResult | None:
    """The findings about ``log`` (None for an empty log or when the checks cannot run)."""
    if log.time_range() is None:
        return None
    return checked(_with_checked_channels(log))


def checked(log: FieldLog, smoothed: Smoothed | None = None) -> CheckResult | None:
    """The findings about ``log`` as it is, no channel read from its file (None for an empty log or
    when the checks cannot run); ``smoothed``: the run smoothed before (:func:`usvlog.check.smooth`)."""
    if log.time_range() is None:
        return None
    try:
        return check_log(log, smoothed=smoothed)
    except UsvlogError:
        return None


def html_section(res: CheckResult | None) -> list[str]:
    """The report's section: one table row per finding (severity, check, channel, time range in s
    from the log's start, evidence, what to do), most severe first; nothing without findings."""
    if res is None or not res.findings:
        return []
    e = html.escape
    c = counts(res.findings)
    parts = [f"<h2 id='findings'>Findings ({c['error']} error(s), {c['warning']} warning(s), {c['info']} info)</h2>",
             "<p>From <code>usvlog check</code> on the channels this report reads; times in s from the log's "
             "start.</p>", "<table class='findings'><tr><th>severity</th><th>check</th><th>channel</th>"
             "<th>time</th><th>evidence</th><th>what to do</th></tr>"]
    for f in res.findings:
        cls = " class='bad'" if f.severity == "error" else ""
        parts.append(f"<tr{cls}><td>{e(f.severity)}</td><td>{e(f.code)}</td><td>{e(f.channel or '-')}</td>"
                     f"<td>{e(f.when())}</td><td>{e(f.evidence)}</td><td>{e(f.action)}</td></tr>")
    parts.append("</table>")
    return parts


def rerun_parts(log: FieldLog, res: CheckResult | None = None):
    """What the Rerun recording shows of the findings (the recording's writer sends it).

    Returns
    -------
    tuple or None
        ``(t_ns, texts, levels)``: one text entry per finding at its start (ns since the Unix
        epoch; the log's start for a whole-run finding), ``"<code> <channel>: <evidence> -> <action>"``,
        level ERROR / WARN / INFO; in time order. None without findings.
    """
    res = of_log(log) if res is None else res
    if res is None or not res.findings:
        return None
    rows = sorted(((res.t0_ns + round((f.t0_s or 0.0) * 1e9), f) for f in res.findings), key=lambda x: x[0])
    texts = [f"{f.code}{' ' + f.channel if f.channel else ''} ({f.when()}): {f.evidence}"
             + (f" -> {f.action}" if f.action else "") for _, f in rows]
    return np.asarray([t for t, _ in rows], np.int64), texts, [LEVELS[f.severity] for _, f in rows]


__all__ = ["ENTITY", "LEVELS", "checked", "html_section", "of_log", "rerun_parts"]
