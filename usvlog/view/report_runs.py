"""What the log says of its runs, for the report: the stages' verdicts and which runs are compared.

The report's status line, its metrics and its sections (:mod:`usvlog.view.report_page`) and the
paper-style figures (:mod:`usvlog.view.report_figures`) ask the same questions of a log, answered
here once:

* what the stages said, from the log's provenance records: the estimate's status, the
  identification's result and verdict, the replay's metrics, and the path-following metrics
  of every controller channel;
* which run the report speaks of (the controller that steered the boat, its track and label)
  and what it is compared with in Fig. 1 and Fig. 2 (a baseline log, the what-if run).
"""

from __future__ import annotations

import json
from typing import TYPE_CHECKING

import numpy as np

from ..log.fieldlog import FieldLog
from ..log.status import estimate_status as stored_estimate_status
from . import data as vd
from .report_plot import _col

if TYPE_CHECKING:
    from ..replay import TrackingMetrics

SAME_TRACK_M = 1e-3    # two tracks closer than this everywhere are the same run


# -----------------------------------------------------------------------------
# what the stages said: one small function each
# -----------------------------------------------------------------------------

def _latest(log: FieldLog, producer: str) -> dict | None:
    for rec in reversed(log.provenance):
        if rec.get("producer") == producer:
            return rec
    return None


def _json(rec: dict | None, key: str):
    if rec is None:
        return None
    try:
        return json.loads(rec.get(key) or "null")
    except (TypeError, ValueError):
        return None


def estimate_status(log: FieldLog) -> tuple[str, list[str]] | None:
    """The estimate's verdict for the report's first line: ``("ok" | "degraded" | "failed", reasons)``.

    ``failed``: ``/estimate/state`` holds no finite position, or the estimator stored that
    status; otherwise the status the estimator stored in the log (:mod:`usvlog.log.status`:
    GNSS only, re-initialisations, inconsistent sensors), or for an older log its consistency
    findings (the provenance record's ``warnings``, from
    :meth:`usvlog.estimate.EstimateReport.consistency`); None for a log without an estimate.
    """
    est = vd.nonempty(log, "/estimate/state")
    rep = _json(_latest(log, "usvlog estimate"), "report") or {}
    stored = stored_estimate_status(log)
    if est is None and not rep and stored is None:
        return None
    if stored is not None:
        rep = {**rep, "status": {"level": stored.status,
                                 "reasons": ([f"GNSS only ({stored.mode})"] if stored.mode == "gps-only"
                                             and not any("GNSS" in r for r in stored.reasons) else [])
                                 + list(stored.reasons)}}
    st = rep.get("status") if isinstance(rep.get("status"), dict) else None
    reasons = [str(w) for w in (st or {}).get("reasons", rep.get("warnings", [])) if isinstance(w, str)]
    if est is not None and "n_m" in est.columns:
        finite = np.isfinite(est["n_m"].to_numpy(dtype=float)) & np.isfinite(est["e_m"].to_numpy(dtype=float))
        if not finite.any():
            return "failed", ["the estimate holds no finite position"] + reasons
    if st is not None and st.get("level") in ("ok", "degraded", "failed"):
        return str(st["level"]), reasons
    return ("degraded" if reasons else "ok"), reasons


def identification(log: FieldLog) -> dict | None:
    """The identification's result as ``usvlog identify --json`` reports it (params, stderr, ci95,
    verdict, ...), from the log's ``usvlog identify`` provenance record; None without one.

    A record without the full result (an older log) gives ``{"params": ...}`` only.
    """
    rec = _latest(log, "usvlog identify")
    if rec is None:
        return None
    res = _json(rec, "result")
    if isinstance(res, dict):
        return res
    settings = _json(rec, "settings") or {}
    return {"params": settings.get("params", {}), "method": settings.get("method")}


def identification_verdict(res: dict) -> tuple[str, list[str]]:
    """(``usable`` | ``usable with caveats`` | ``unusable``, reasons) of an identification result.

    A result carrying a verdict level (``verdict`` as ``Identifier.to_dict()`` gives it, with
    ``reasons``; ``verdict_level``; or a ``verdict`` dict with ``level``) is taken as it is;
    otherwise the verdict lines decide: none means usable, lines mean caveats.
    """
    v = res.get("verdict")
    if isinstance(v, str):   # Identifier.to_dict(): the level, and its reasons in plain words
        return v, [str(x) for x in res.get("reasons", [])]
    if isinstance(v, dict):
        return str(v.get("level", "usable with caveats")), [str(x) for x in v.get("reasons", [])]
    lines = [str(x) for x in (v or [])]
    if isinstance(res.get("verdict_level"), str):
        return res["verdict_level"], lines
    return ("usable with caveats" if lines else "usable"), lines


def replay_record(log: FieldLog) -> dict | None:
    """The latest replay's metrics as stored by ``usvlog replay`` (``ReplayMetrics.to_dict``), or None."""
    m = _json(_latest(log, "usvlog replay"), "metrics")
    return m if isinstance(m, dict) else None


def path_metrics(log: FieldLog, start_s: float | None = None) -> list[tuple[str, str, TrackingMetrics]]:
    """[(controller label, description, metrics)] of every controller channel of the log.

    The replayed and what-if controllers' metrics are the ones ``usvlog replay`` computed and
    printed (stored with the log); other controller channels are measured with the same
    function (:func:`usvlog.replay.tracking_metrics_of`) over the same window: ``start_s``, else
    the replay's, else the whole run.
    """
    controllers = vd.controllers(log)
    if not controllers:
        return []
    from ..replay import TrackingMetrics, tracking_metrics_of  # heavy: the closed loop; only a log with controllers

    rec = replay_record(log)
    stored = {}
    if rec is not None:
        for label, key in (("replay", "replay"), ("whatif", "whatif")):
            if isinstance(rec.get(key), dict):
                stored[label] = TrackingMetrics.from_dict(rec[key])
    if start_s is None:
        start_s = stored["replay"].start_s if "replay" in stored else 0.0
    out = []
    for _topic, label, f, _sf, desc in controllers:
        m = stored.get(label)
        if m is None and "cross_track_m" in f.columns:
            m = tracking_metrics_of(f, start_s)
        if m is not None:
            out.append((label, desc, m))
    return out


# -----------------------------------------------------------------------------
# the run the report speaks of, and what it is compared with
# -----------------------------------------------------------------------------

def _main_controller(log: FieldLog):
    """(label, controller frame, steered state frame, description) the report speaks of."""
    for _topic, label, f, sf, desc in vd.controllers(log):
        if label != "whatif":
            return label, f, sf, desc
    return None


def _steered_track(log: FieldLog):
    """(t, n, e) of the boat the controller steered (or the best state we have), or None."""
    mc = _main_controller(log)
    f = mc[2] if mc is not None and mc[2] is not None and "n_m" in mc[2].columns else None
    if f is None:
        b = vd.boat_state(log)
        f = b[1] if b else None
    if f is None:
        return None
    return f.index.to_numpy(), _col(f, "n_m"), _col(f, "e_m")


def _run_label(log: FieldLog, default: str) -> str:
    """'controller (9)-(10)' / 'baseline PI/PID' from the log's provenance, else ``default``."""
    for rec in reversed(log.provenance):
        try:
            ctl = json.loads(rec.get("settings", "{}")).get("controller")
        except (ValueError, AttributeError):
            ctl = None
        if ctl == "full":
            return "controller (9)-(10)"
        if ctl == "baseline":
            return "baseline PI/PID"
        if isinstance(ctl, str) and ctl:
            return ctl
    return default


def _whatif_label(log: FieldLog) -> str:
    rec = replay_record(log) or {}
    ctl = rec.get("whatif_controller")
    return {"full": "what-if run, controller (9)-(10)", "baseline": "what-if run, baseline PI/PID"}.get(
        ctl, "what-if run")


def same_track(a, b, tol_m: float = SAME_TRACK_M) -> bool:
    """True when two (t_ns, n, e) tracks are the same run: over their common time, every position
    of ``b`` (interpolated at ``a``'s times) is within ``tol_m`` metres of ``a``'s."""
    ta, na, ea = a
    tb, nb, eb = b
    lo, hi = max(ta[0], tb[0]), min(ta[-1], tb[-1])
    sel = (ta >= lo) & (ta <= hi)
    if sel.sum() < 2 or (hi - lo) < 0.9 * min(ta[-1] - ta[0], tb[-1] - tb[0]):
        return False
    x = (ta[sel] - lo).astype(float)
    xb = (tb - lo).astype(float)
    dn = na[sel] - np.interp(x, xb, nb)
    de = ea[sel] - np.interp(x, xb, eb)
    d = np.hypot(dn, de)
    return bool(np.all(np.isfinite(d)) and d.max() <= tol_m)


def _whatif_track(log):
    wi = vd.nonempty(log, "/replay/whatif/state")
    if wi is None or "n_m" not in wi.columns:
        return None
    return wi.index.to_numpy(), _col(wi, "n_m"), _col(wi, "e_m")


def _comparison(log, baseline):
    """(what is compared in Fig. 1 and Fig. 2): a list of (key, label, controller frame, state frame, track)."""
    out = []
    wi_track = _whatif_track(log)
    if baseline is not None:
        bmc = _main_controller(baseline)
        bt = _steered_track(baseline)
        if bmc is not None or bt is not None:
            lab = _run_label(baseline, "baseline")
            same = wi_track is not None and bt is not None and same_track(bt, wi_track)
            out.append(("baseline", f"{lab} (baseline log" + (", = the what-if run)" if same else ")"),
                        bmc[1] if bmc else None, bmc[2] if bmc else None, bt))
            if same:
                return out
    if wi_track is not None:
        wc = vd.nonempty(log, "/replay/whatif/controller")
        out.append(("whatif", _whatif_label(log), wc, vd.nonempty(log, "/replay/whatif/state"), wi_track))
    return out
