"""``usvlog check``: is this log sound, and what is wrong with the boat's sensors?

:func:`check_log` runs every check on one log and returns a :class:`CheckResult`: the
findings (:class:`usvlog.log.findings.Finding`: severity, channel, time range in seconds
from the log's start, the evidence in numbers, what to do) and the names of the checks
that ran. The checks, each a short function of a :class:`~usvlog.check.common.CheckContext`:

* :mod:`~usvlog.check.sensors`: missing, dead or frozen channels, sample-and-hold GNSS,
  rates and gaps, time going backwards, GNSS jumps, fix quality / HDOP / satellites / RTK;
* :mod:`~usvlog.check.heading`: mounting offset against the course over ground, deviation
  that varies with the heading, a disturbance that follows the thrust, a yaw-rate signal's
  sign and scale;
* :mod:`~usvlog.check.thrusters`: left/right swapped, reversed, saturated, out of range,
  deadband;
* :mod:`~usvlog.check.content`: which model parameters the run determines and which
  manoeuvre to drive next.

The import's sensor health record, when the log has one, adds its findings
(:func:`usvlog.log.findings.findings_from_health`); a check of this package that reports
the same code on the same channel replaces the import's (it has the time range).

Pure: a log in, a result out (no files, no printing).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from ..log.fieldlog import FieldLog
from ..log.findings import (
    Finding,
    counts,
    findings_from_estimate,
    findings_from_health,
    findings_to_dicts,
    format_table,
    junit_xml,
    sort_findings,
    worst,
)
from ..log.status import estimate_status
from ..model.vessel import Vessel
from . import content, heading, sensors, thrusters
from .common import CheckContext, Smoothed, smooth

CHECKS = (*sensors.CHECKS, *heading.CHECKS, *thrusters.CHECKS, *content.CHECKS)
"""Every check: (function(ctx) -> findings, the check names it reports under)."""


@dataclass(frozen=True)
class CheckResult:
    """Findings about one log.

    Attributes
    ----------
    findings : tuple of Finding
        Sorted, most severe first.
    checks : tuple of str
        The checks that ran (each a JUnit testcase), passed or not.
    source : str
        The log's name (its path, or "log").
    t0_ns : int
        The log's start (ns since the Unix epoch): the findings' times count from it.
    """

    findings: tuple[Finding, ...]
    checks: tuple[str, ...]
    source: str = "log"
    t0_ns: int = 0

    @property
    def worst(self) -> str | None:
        """The most severe finding's severity (None: no findings)."""
        return worst(self.findings)

    @property
    def exit_code(self) -> int:
        """1 when any finding is an error, else 0 (``usvlog check``'s exit code)."""
        return 1 if self.worst == "error" else 0

    def by_code(self, code: str) -> list[Finding]:
        """The findings with this code, or under it (``heading`` gives every heading finding)."""
        return [f for f in self.findings if f.code == code or f.code.startswith(code + ".")]

    def table(self) -> str:
        """The findings as a text table (:func:`usvlog.log.findings.format_table`)."""
        return format_table(self.findings)

    def junit(self) -> str:
        """The JUnit XML document (:func:`usvlog.log.findings.junit_xml`)."""
        return junit_xml(self.findings, self.checks, suite=self.source)

    def to_dict(self) -> dict:
        """JSON-ready: source, start (ns), counts per severity, exit code, checks and findings."""
        return {"source": self.source, "t0_ns": self.t0_ns, "counts": counts(self.findings),
                "exit_code": self.exit_code, "checks": list(self.checks),
                "findings": findings_to_dicts(self.findings)}


def _run(fn, names: Sequence[str], ctx: CheckContext) -> list[Finding]:
    """One check; a check that fails says so as a warning, and the others still run."""
    try:
        return list(fn(ctx))
    except Exception as err:   # a check must never take the others down
        return [Finding(severity="warning", code=names[0], evidence=f"the check could not run: "
                        f"{type(err).__name__}: {err}", action="report it with the log")]


def check_log(log: FieldLog, vessel: Vessel | None = None, *, extra: Iterable[Finding] = (),
              smoothed: Smoothed | None = None) -> CheckResult:
    """Run every check on a log.

    Parameters
    ----------
    log : FieldLog
        A canonical log (imported, simulated or loaded).
    vessel : Vessel, optional
        The boat (thruster map and limits, heading offset); default the log's own.
    extra : iterable of Finding
        Findings from elsewhere to show with these (e.g. what an in-memory import dropped).
    smoothed : Smoothed, optional
        :func:`smooth` of this log for this vessel, made before (by a caller that has it made from
        the channels it reads, before it reads the log's others: less held at once); default made
        here.

    Returns
    -------
    CheckResult
    """
    ctx = CheckContext.of(log, vessel, smoothed)
    ctx.smooth_first()
    own: list[Finding] = []
    names: list[str] = []
    for fn, ns in CHECKS:
        names += ns
        own += _run(fn, ns, ctx)
    mine = {(f.code, f.channel) for f in own}
    health = [f for f in findings_from_health(ctx.health) if (f.code, f.channel) not in mine]
    st = estimate_status(log)   # a log with an estimate: its status, in the same words as the estimate's
    est = findings_from_estimate(st.status, st.mode, st.reasons) if st is not None else []
    if st is not None:
        names.append("estimate.status")
    return CheckResult(findings=tuple(sort_findings([*own, *health, *est, *extra])), checks=tuple(names),
                       source=str(log.source or "log"), t0_ns=ctx.t0_ns)


__all__ = ["CHECKS", "CheckResult", "Smoothed", "check_log", "smooth"]
