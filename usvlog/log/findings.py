"""Findings about a log: one severity, channel, time range, evidence in numbers and action each.

Every verb that judges a log says what it found the same way: ``usvlog check`` (the checks of
:mod:`usvlog.check`), the import's sensor health audit (:func:`findings_from_health`), and
whatever a report, a view or a campaign shows of them. A :class:`Finding` is one line of
that table:

* ``severity``: ``error`` (the log or a channel cannot be used as it is: a later stage
  would give a wrong answer), ``warning`` (usable, with a defect to fix or a setting to
  give), ``info`` (a fact worth knowing: rates, what the run determines);
* ``code``: ``<check>.<what>``, e.g. ``heading.mounting_offset`` (the check is the part
  before the second dot, see :attr:`Finding.check`);
* ``channel``: the canonical topic it is about ("" for the run as a whole);
* ``t0_s``, ``t1_s``: the time range, seconds from the log's start (None: the whole run);
* ``evidence``: what was measured, with the numbers;
* ``action``: what to do about it ("" when nothing is to be done);
* ``numbers``: the evidence's numbers by name (for scripts and tests; not compared).

Output forms: :func:`format_table` (text), :func:`findings_to_dicts` (JSON) and
:func:`junit_xml` (CI). In the JUnit form each check is one testcase; an error is a
``<failure>``; a warning does **not** fail the testcase and is not ``<skipped>`` either (the
check ran): warnings and infos go to the testcase's ``<system-out>``, each line prefixed
with its severity, so a CI system shows them next to a passing test.

Pure standard library: any layer can build and print findings.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from xml.sax.saxutils import escape, quoteattr

SEVERITIES = ("error", "warning", "info")
"""The severities, most severe first."""
_RANK = {s: i for i, s in enumerate(SEVERITIES)}
GAP_WARN_S = 0.5
"""The import's gaps are a warning when the longest is at least this long (s), else an info (as
:data:`usvlog.check.sensors.GAP_MIN_S`)."""


@dataclass(frozen=True, kw_only=True)
class Finding:
    """One finding about a log (see the module docstring for the fields).

    Raises
    ------
    ValueError
        On an unknown severity, an empty code or a time range that ends before it starts.
    """

    severity: str
    code: str
    channel: str = ""
    t0_s: float | None = None
    t1_s: float | None = None
    evidence: str = ""
    action: str = ""
    numbers: Mapping[str, float] = field(default_factory=dict, compare=False, hash=False)

    def __post_init__(self):
        if self.severity not in _RANK:
            raise ValueError(f"finding severity {self.severity!r} is not one of {', '.join(SEVERITIES)}")
        if not self.code:
            raise ValueError("a finding needs a code")
        if self.t0_s is not None and self.t1_s is not None and self.t1_s < self.t0_s:
            raise ValueError(f"finding {self.code}: time range {self.t0_s} .. {self.t1_s} s ends before it starts")

    @property
    def check(self) -> str:
        """The check that made it: the code up to its second dot (``heading.offset.x`` -> ``heading.offset``)."""
        return ".".join(self.code.split(".")[:2])

    def when(self) -> str:
        """The time range in words: ``12.0-48.5 s``, ``at 12.0 s`` or ``whole run``."""
        if self.t0_s is None:
            return "whole run"
        if self.t1_s is None or self.t1_s == self.t0_s:
            return f"at {self.t0_s:.1f} s"
        return f"{self.t0_s:.1f}-{self.t1_s:.1f} s"

    def line(self) -> str:
        """The finding as one line of text (severity, code, channel, time, evidence, action)."""
        where = f" {self.channel}" if self.channel else ""
        todo = f" -> {self.action}" if self.action else ""
        return f"{self.severity.upper()} {self.code}{where} ({self.when()}): {self.evidence}{todo}"

    def to_dict(self) -> dict:
        """The fields as a JSON-ready dict (non-finite numbers as None)."""
        def num(x):
            return None if x is None or not math.isfinite(float(x)) else float(x)
        return {"severity": self.severity, "code": self.code, "check": self.check, "channel": self.channel,
                "t0_s": num(self.t0_s), "t1_s": num(self.t1_s), "evidence": self.evidence, "action": self.action,
                "numbers": {k: num(v) for k, v in self.numbers.items()}}


def sort_findings(findings: Iterable[Finding]) -> list[Finding]:
    """Most severe first; then by start time (whole-run ones first), code and channel."""
    return sorted(findings, key=lambda f: (_RANK[f.severity], -1.0 if f.t0_s is None else f.t0_s, f.code,
                                           f.channel))


def worst(findings: Iterable[Finding]) -> str | None:
    """The most severe severity among ``findings`` (None when there are none)."""
    ranks = [_RANK[f.severity] for f in findings]
    return SEVERITIES[min(ranks)] if ranks else None


def counts(findings: Iterable[Finding]) -> dict[str, int]:
    """{severity: how many}, every severity present (0 when none)."""
    out = dict.fromkeys(SEVERITIES, 0)
    for f in findings:
        out[f.severity] += 1
    return out


def _wrap(text: str, width: int) -> list[str]:
    words, lines, cur = text.split(), [], ""
    for w in words:
        if cur and len(cur) + 1 + len(w) > width:
            lines.append(cur)
            cur = w
        else:
            cur = f"{cur} {w}" if cur else w
    return lines + [cur] if cur else lines or [""]


def format_table(findings: Sequence[Finding], *, width: int = 110) -> str:
    """The findings as a text table: severity, code, channel, time, then evidence and action
    indented below each (wrapped to ``width``), and a count line at the end."""
    fs = sort_findings(findings)
    if not fs:
        return "no findings"
    heads = [(f.severity.upper(), f.code, f.channel or "-", f.when()) for f in fs]
    w = [max(len(h[i]) for h in heads + [("SEVERITY", "CHECK", "CHANNEL", "TIME")]) for i in range(4)]
    row = "  ".join("{:<%d}" % n for n in w)
    out = [row.format("SEVERITY", "CHECK", "CHANNEL", "TIME").rstrip()]
    for f, h in zip(fs, heads):
        out.append(row.format(*h).rstrip())
        out += ["    " + s for s in _wrap(f.evidence, width - 4)]
        if f.action:
            out += ["    " + ("-> " if i == 0 else "   ") + s for i, s in enumerate(_wrap(f.action, width - 7))]
    c = counts(fs)
    out.append(f"{c['error']} error(s), {c['warning']} warning(s), {c['info']} info")
    return "\n".join(out)


def findings_to_dicts(findings: Iterable[Finding]) -> list[dict]:
    """The findings (sorted) as JSON-ready dicts (:meth:`Finding.to_dict`)."""
    return [f.to_dict() for f in sort_findings(findings)]


def junit_xml(findings: Sequence[Finding], checks: Sequence[str], *, suite: str = "usvlog check") -> str:
    """JUnit XML: one testcase per check; a ``<failure>`` per testcase holding an error.

    Warnings and infos do not fail a testcase and are not ``<skipped>`` (the check ran); they
    are listed in its ``<system-out>``, one line each with its severity (see the module
    docstring). A finding whose check is not among ``checks`` gets a testcase of its own.

    Parameters
    ----------
    findings : sequence of Finding
    checks : sequence of str
        The checks that ran (e.g. ``sensors.gaps``), passed or not.
    suite : str
        The testsuite's name (the log's name is a good one).

    Returns
    -------
    str
        The XML document.
    """
    names = list(dict.fromkeys([*checks, *(f.check for f in findings)]))
    by = {n: [f for f in sort_findings(findings) if f.check == n] for n in names}
    n_fail = sum(any(f.severity == "error" for f in fs) for fs in by.values())
    parts = ['<?xml version="1.0" encoding="UTF-8"?>',
             f'<testsuites name="usvlog check" tests="{len(names)}" failures="{n_fail}" errors="0">',
             f'  <testsuite name={quoteattr(suite)} tests="{len(names)}" failures="{n_fail}" errors="0">']
    for n in names:
        fs = by[n]
        cls, _, name = n.partition(".")
        parts.append(f"    <testcase classname={quoteattr(cls)} name={quoteattr(name or cls)}>")
        errs = [f for f in fs if f.severity == "error"]
        if errs:
            msg = "; ".join(f"{f.channel + ': ' if f.channel else ''}{f.evidence}" for f in errs)
            body = "\n".join(f.line() for f in errs)
            parts.append(f"      <failure message={quoteattr(msg)}>{escape(body)}</failure>")
        rest = [f for f in fs if f.severity != "error"]
        if rest:
            parts.append(f"      <system-out>{escape(chr(10).join(f.line() for f in rest))}</system-out>")
        parts.append("    </testcase>")
    parts += ["  </testsuite>", "</testsuites>"]
    return "\n".join(parts) + "\n"


# -----------------------------------------------------------------------------
# the import's sensor health record -> findings
# -----------------------------------------------------------------------------

def _num(x) -> float:
    try:
        return float(x)
    except (TypeError, ValueError):
        return float("nan")


def _channel_findings(topic: str, ch: Mapping) -> list[Finding]:
    out = []
    status, why = ch.get("status") or "ok", ch.get("why") or ""
    moved = ch.get("written_as")
    if status == "dead":
        where = f" (written as {moved})" if moved and moved != topic else ""
        out.append(Finding(severity="error", code="sensors.dead", channel=topic,
                           evidence=f"judged dead at import: {why}{where}",
                           action="check the sensor and its wiring; the stages leave the channel out"))
    elif status == "suspect":
        out.append(Finding(severity="warning", code="sensors.dead.suspect", channel=topic,
                           evidence=f"suspect at import: {why}",
                           action="look at the channel: a sensor that does not move while the boat does is dead"))
    dis = int(ch.get("time_disorder") or 0)
    if dis:
        out.append(Finding(severity="warning", code="sensors.time_backwards", channel=topic,
                           evidence=f"{dis} of {int(ch.get('records') or 0)} records not after the one before (import)",
                           action="check the logger's clock and the time column the import chose",
                           numbers={"backwards": dis}))
    oor = int(ch.get("out_of_range") or 0)
    if oor:
        code = "thrusters.out_of_range" if topic.startswith("/thrust") else "sensors.out_of_range"
        out.append(Finding(severity="warning", code=code, channel=topic,
                           evidence=f"{oor} of {int(ch.get('records') or 0)} records outside the possible range "
                                    "(skipped at import)",
                           action="check the unit and range given at import (--thrust-unit/--thrust-range)",
                           numbers={"out_of_range": oor}))
    gaps = int(ch.get("gaps") or 0)
    if gaps:
        longest = _num(ch.get("longest_gap_s"))
        out.append(Finding(severity="warning" if longest >= GAP_WARN_S else "info", code="sensors.gaps",
                           channel=topic,
                           evidence=f"{gaps} gap(s) longer than 3 intervals at import, longest {longest:.2f} s "
                                    f"(rate {_num(ch.get('rate_hz')):.3g} Hz)",
                           action="check the sensor's connection and the logger's load",
                           numbers={"gaps": gaps, "longest_gap_s": longest}))
    rep = int(ch.get("republished") or 0)
    if rep:
        out.append(Finding(severity="info", code="sensors.republished", channel=topic,
                           evidence=f"{rep} republished duplicate(s) collapsed at import",
                           numbers={"republished": rep}))
    return out


def findings_from_health(health: Mapping | None, held: Mapping[str, int] | None = None) -> list[Finding]:
    """Findings from the import's sensor health record (:mod:`usvlog.io.importers.audit`).

    Dead channels are errors, suspect ones warnings; per channel, records out of the
    possible range, records not after the one before, and gaps (the longest at least
    :data:`GAP_WARN_S`; shorter ones an info) are warnings, republished duplicates an info;
    a decided heading mounting offset is a warning (an error from 20 deg) with its number and
    the option that applies it; commands without a known force scale a warning.

    Parameters
    ----------
    health : dict or None
        The record (``health_of(log)``); None or ``{}`` gives no findings.
    held : dict of str to int, optional
        Stream -> held repeats the import dropped (``gnss_held_repeat`` counts of its
        report), each an info.

    Returns
    -------
    list of Finding
        Sorted (:func:`sort_findings`); none carries a time range (the record has none).
    """
    out: list[Finding] = []
    health = health or {}
    for topic, ch in sorted((health.get("channels") or {}).items()):
        out += _channel_findings(topic, ch or {})
    off = health.get("heading_offset") or {}
    if off.get("decided"):
        o, s = _num(off.get("offset_deg")), _num(off.get("std_deg"))
        out.append(Finding(severity="error" if abs(o) >= 20.0 else "warning", code="heading.mounting_offset",
                           channel="/compass/heading",
                           evidence=f"heading - course over ground {o:+.1f} +- {s:.1f} deg on {off.get('runs')} "
                                    f"straight runs over {off.get('courses')} courses (import)",
                           action="apply it: usvlog estimate --heading-offset auto (or heading_offset_deg in "
                                  "the vessel file's [sensors])",
                           numbers={"offset_deg": o, "std_deg": s}))
    thr = health.get("thrust") or {}
    if thr.get("force_scale") == "unknown":
        out.append(Finding(severity="warning", code="thrusters.force_scale", channel="/thrust/command",
                           evidence=f"commands in {thr.get('unit') or 'unknown units'} with no known force scale"
                                    f"{': ' + str(thr['reason']) if thr.get('reason') else ''}",
                           action="give the vessel's thruster map (--vessel) so commands become newtons"))
    for stream, n in sorted((held or {}).items()):
        if n:
            out.append(Finding(severity="info", code="sensors.held", channel=stream,
                               evidence=f"{int(n)} sample-and-hold repeat(s) dropped at import (one row kept per "
                                        "real update)", numbers={"held_repeats": int(n)}))
    return sort_findings(out)


def findings_from_estimate(status: str, mode: str, reasons: Sequence[str]) -> list[Finding]:
    """The estimate's status (``ok``/``degraded``/``failed`` and its reasons, as stored in a log by
    :mod:`usvlog.log.status` or held by an ``EstimateReport``) as findings: one per reason, an
    error when the estimate failed (not to be used), a warning when it is degraded.

    Parameters
    ----------
    status : str
        ``ok``, ``degraded`` or ``failed``.
    mode : str
        ``gnss+compass`` or ``gps-only``.
    reasons : sequence of str
        Plain-word reasons (empty for ``ok``).

    Returns
    -------
    list of Finding
    """
    if status == "ok":
        return []
    sev = "error" if status == "failed" else "warning"
    act = ("the estimate is not to be used: fix what the reason names and estimate again" if sev == "error"
           else "usable with care: the reason says what the estimate could not vouch for")
    return [Finding(severity=sev, code=f"estimate.{status}", channel="/estimate/state",
                    evidence=f"estimate {status} ({mode}): {r}", action=act) for r in reasons]


__all__ = ["SEVERITIES", "Finding", "sort_findings", "worst", "counts", "format_table", "findings_to_dicts",
           "junit_xml", "findings_from_health", "findings_from_estimate"]
