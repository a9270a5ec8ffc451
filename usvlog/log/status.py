"""The estimate's status as stored in a log: ``ok``, ``degraded`` (with reasons) or ``failed``.

``usvlog estimate`` writes one metadata record, :data:`META_ESTIMATE_STATUS`, next to the
``/estimate/*`` channels; later stages (``view``, ``report``, identification) read it back
with :func:`estimate_status` to flag or refuse what the estimator could not vouch for::

    {"status": "ok" | "degraded" | "failed",
     "mode": "gnss+compass" | "gps-only",
     "reasons": JSON list of str}      # why degraded or failed, in plain words

Pure: no I/O, metadata dicts in and out.
"""

from __future__ import annotations

import json
from dataclasses import dataclass

from .fieldlog import FieldLog

META_ESTIMATE_STATUS = "usvlog.estimate.status"
STATUSES = ("ok", "degraded", "failed")


@dataclass(frozen=True)
class EstimateStatus:
    """What the estimator said of the estimate stored in a log.

    Attributes
    ----------
    status : str
        ``ok``, ``degraded`` (usable, with reasons: GNSS only, re-initialisations,
        inconsistent sensors) or ``failed`` (not to be used).
    mode : str
        ``gnss+compass`` or ``gps-only``.
    reasons : tuple of str
        Plain-word reasons (empty for ``ok``).
    """

    status: str
    mode: str
    reasons: tuple[str, ...] = ()

    def to_record(self) -> dict[str, str]:
        """The metadata record ({key: text}) stored under :data:`META_ESTIMATE_STATUS`."""
        return {"status": self.status, "mode": self.mode, "reasons": json.dumps(list(self.reasons))}

    def headline(self) -> str:
        """One line for the top of a report or the console, e.g. ``estimate DEGRADED (gps-only): ...``."""
        tail = "; ".join(self.reasons)
        return f"estimate {self.status.upper()} ({self.mode})" + (f": {tail}" if tail else "")


def status_from_metadata(meta: dict) -> EstimateStatus | None:
    """The estimate status in a log's metadata records (None when it has none).

    Parameters
    ----------
    meta : dict
        Metadata records ``{name: {key: text}}`` (``FieldLog.meta``).

    Returns
    -------
    EstimateStatus or None
        None for a log without an estimate (or one written by an older usvlog); a record
        with an unknown status reads as ``failed`` (it cannot be vouched for).
    """
    rec = meta.get(META_ESTIMATE_STATUS)
    if not rec:
        return None
    try:
        reasons = json.loads(rec.get("reasons") or "[]")
    except json.JSONDecodeError:
        reasons = [str(rec.get("reasons"))]
    if not isinstance(reasons, list):
        reasons = [str(reasons)]
    status = rec.get("status", "")
    if status not in STATUSES:
        reasons = [f"unknown estimate status {status!r}", *map(str, reasons)]
        status = "failed"
    return EstimateStatus(status=status, mode=rec.get("mode", ""), reasons=tuple(str(r) for r in reasons))


def estimate_status(log: FieldLog) -> EstimateStatus | None:
    """The status of the estimate stored in ``log`` (see :func:`status_from_metadata`).

    Parameters
    ----------
    log : FieldLog

    Returns
    -------
    EstimateStatus or None
    """
    return status_from_metadata(log.meta)


def set_estimate_status(log: FieldLog, status: EstimateStatus) -> None:
    """Store ``status`` in ``log``'s metadata (replacing an earlier one).

    Parameters
    ----------
    log : FieldLog
    status : EstimateStatus
    """
    log.meta[META_ESTIMATE_STATUS] = status.to_record()
