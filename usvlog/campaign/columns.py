"""The one place where a stage's result object becomes columns of the campaign table.

Every stage of a run returns the object the public API returns (``usvlog.import_log`` an
ImportResult, ``usvlog.estimate`` an EstimateResult, ``usvlog.identify`` an Identifier,
``usvlog.replay`` a ReplayResult); the functions here read them and give a flat dict of
plain values (str, int, float, bool, None) for one row of ``runs.parquet``. When a stage's
result grows a field (an estimate status, an identification verdict with reasons), only
this module changes.

The column names and their kinds are :data:`SCHEMA`; :func:`empty_row` gives a row with
every column, so that a table of failed runs still has them all.
"""

from __future__ import annotations

import math
from typing import Any

from ..choices import PARAM_NAMES
from ..errors import UnusableResultError, UsvlogError

# verdict words of an identification
USABLE, CAVEATS, UNUSABLE = "usable", "caveats", "unusable"

# run status: all requested stages done / done but the identification cannot be used / a stage failed
OK, FAILED = "ok", "failed"

# verdict lines of the identifier that mean the parameters cannot be used at all
_UNUSABLE_MARKS = ("not determined", "nearly unidentifiable", "condition 1 fails")

SCHEMA: dict[str, str] = {
    # the run
    "run_id": "str", "source": "str", "sha256": "str", "vessel": "str", "start_utc": "time",
    "duration_s": "float", "distance_m": "float", "status": "str", "failed_stage": "str", "reason": "str",
    "seconds": "float",
    # import
    "format": "str", "import_records": "int", "import_skipped": "int", "health_dead": "str",
    "health_suspect": "str", "time_base": "str", "input_damage": "str",
    # usvlog check: the same findings as the verb (codes of the errors and warnings)
    "check_errors": "int", "check_warnings": "int", "check_findings": "str",
    # estimate
    "estimate_model": "str", "estimate_consistent": "bool", "estimate_warnings": "str",
    "estimate_status": "str", "estimate_mode": "str", "estimate_reinits": "int",
    "estimate_dropouts": "int",
    # standard manoeuvres (on the estimate; means over the run's manoeuvres of a kind)
    "manoeuvres": "int", "tactical_diameter_m": "float", "tactical_diameter_m_std": "float",
    "advance_m": "float", "turn_rate_degps": "float", "zigzag_overshoot_deg": "float",
    "zigzag_overshoot_deg_std": "float", "stopping_distance_m": "float", "pivot_rate_degps": "float",
    # identify
    "identify_method": "str", **{k: "float" for p in PARAM_NAMES for k in (p, f"{p}_se")},
    "verdict": "str", "verdict_reasons": "str", "fit_on": "str", "fit_u_pct": "float", "fit_v_pct": "float",
    "fit_r_pct": "float", "fit_track_pct": "float", "condition_number": "float",
    "fit_ahead_30s_u_pct": "float", "fit_ahead_30s_r_pct": "float",
    # replay
    "replay_xte_rms_m": "float", "replay_heading_rms_rad": "float", "replay_surge_rms_mps": "float",
    "replay_saturated_s": "float", "replay_command_rms": "float", "whatif_xte_rms_m": "float",
}
"""Column name -> kind (``str``, ``int``, ``float``, ``bool``, ``time``: ns since the Unix epoch)."""


def empty_row() -> dict[str, Any]:
    """A row with every column of :data:`SCHEMA` missing (None)."""
    return dict.fromkeys(SCHEMA)


def _f(x) -> float | None:
    try:
        v = float(x)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def _path_length(t_ns, n, e, every_s: float = 1.0) -> float | None:
    """Length (m) of the polyline through (n, e), one point per ``every_s`` s: GNSS noise at
    10 Hz would otherwise add more length than a slow boat covers."""
    import numpy as np  # heavy: only when a run is processed

    t, n, e = (np.asarray(a) for a in (t_ns, n, e))
    ok = np.isfinite(n) & np.isfinite(e)
    t, n, e = t[ok], n[ok], e[ok]
    if len(t) < 2:
        return None
    keep = np.r_[0, np.nonzero(np.diff((t - t[0]) // int(every_s * 1e9)))[0] + 1]
    return float(np.hypot(np.diff(n[keep]), np.diff(e[keep])).sum())


def log_columns(log) -> dict[str, Any]:
    """Start time (ns), duration (s) and track length (m, GNSS fixes 5 s apart) of a canonical log.

    Parameters
    ----------
    log : FieldLog
        The run.

    Returns
    -------
    dict
        ``start_utc``, ``duration_s``, ``distance_m`` and ``input_damage`` (the one-line
        report of a damaged file, else None).
    """
    from ..view.data import gps  # heavy: the view data helpers (numpy)

    tr = log.time_range()
    out: dict[str, Any] = {"start_utc": int(tr[0]) if tr else None,
                           "duration_s": (tr[1] - tr[0]) / 1e9 if tr else None, "distance_m": None,
                           "input_damage": log.recovery.one_line() if log.recovery is not None else None}
    g = gps(log)
    if g is not None:
        out["distance_m"] = _path_length(g[0], g[3], g[4], every_s=5.0)   # the estimate's track replaces it
    return out


def import_columns(result) -> dict[str, Any]:
    """Columns of an import: format, records, skipped records and the sensor health flags.

    Parameters
    ----------
    result : ImportResult or None
        What ``usvlog.import_log`` returned; None for a source that was already canonical.

    Returns
    -------
    dict
        ``format``, ``import_records``, ``import_skipped``, ``health_dead``,
        ``health_suspect`` (topics, ``;``-separated) and ``time_base``.
    """
    if result is None:
        return {"format": "mcap", "import_records": None, "import_skipped": 0}
    rep = result.report
    h = rep.health or {}
    return {"format": rep.format, "import_records": int(rep.records), "import_skipped": int(sum(rep.skipped.values())),
            "health_dead": ";".join(h.get("dead", [])) or None,
            "health_suspect": ";".join(h.get("suspect", [])) or None,
            "time_base": h.get("time_base")}


def estimate_columns(result) -> dict[str, Any]:
    """Columns of an estimate: model, consistency and its warnings, GNSS gaps bridged.

    Parameters
    ----------
    result : EstimateResult
        What ``usvlog.estimate`` returned.

    Returns
    -------
    dict
        ``estimate_model``, ``estimate_consistent`` (no consistency warning),
        ``estimate_warnings`` (``;``-separated), ``estimate_dropouts``, ``estimate_status``
        (ok / degraded), ``estimate_mode`` (gnss+compass / gps-only), ``estimate_reinits``
        (re-initialisations after divergence), and ``distance_m``
        along the estimated track (m; replaces the one from the GNSS fixes).
    """
    rep = result.report
    warn = list(rep.consistency())
    st = result.state
    out = {"estimate_model": rep.model, "estimate_consistent": not warn,
           "estimate_warnings": "; ".join(warn) or None, "estimate_dropouts": int(rep.dropouts_bridged),
           "estimate_status": getattr(rep, "status", None), "estimate_mode": getattr(rep, "mode", None),
           "estimate_reinits": len(getattr(rep, "reinits", ()))}
    d = _path_length(st.index.to_numpy(), st["n_m"].to_numpy(float), st["e_m"].to_numpy(float))
    if d is not None:
        out["distance_m"] = d
    return out


MANOEUVRE_COLUMNS = {"tactical_diameter_m": ("turning_circle", "tactical_diameter_m"),
                     "advance_m": ("turning_circle", "advance_m"),
                     "turn_rate_degps": ("turning_circle", "steady_turn_rate_degps"),
                     "zigzag_overshoot_deg": ("zigzag", "first_overshoot_deg"),
                     "stopping_distance_m": ("stop", "stopping_distance_m"),
                     "pivot_rate_degps": ("pivot", "yaw_rate_degps")}
"""Campaign column -> (manoeuvre kind, metric) it is the run's mean of."""


def manoeuvre_columns(state, log) -> dict[str, Any]:
    """Columns of the standard manoeuvres of a run (``usvlog manoeuvres``), measured on its estimate.

    Parameters
    ----------
    state : pandas.DataFrame
        The run's ``/estimate/state`` (``EstimateResult.state``).
    log : FieldLog
        The run (its ``/thrust/command`` and start time).

    Returns
    -------
    dict
        ``manoeuvres`` (how many), and per :data:`MANOEUVRE_COLUMNS` the mean of that metric over
        the run's manoeuvres of its kind (None without one); ``tactical_diameter_m_std`` and
        ``zigzag_overshoot_deg_std`` the one-sigma of the mean (the metrics' sigmas combined).
        Empty when the run has no thrust commands or they cannot be read (never raises a
        UsvlogError: a run without manoeuvres is no failed run).
    """
    from ..trials import find_manoeuvres  # heavy: numpy, pandas

    thrust, tr = log.get("/thrust/command"), log.time_range()
    if thrust is None or tr is None or len(thrust) < 2:
        return {}
    try:
        found = find_manoeuvres(state, thrust, int(tr[0]))
    except UsvlogError:
        return {}
    out: dict[str, Any] = {"manoeuvres": len(found)}
    for col, (kind, name) in MANOEUVRE_COLUMNS.items():
        ms = [m.metric(name) for m in found.of_kind(kind)]
        ms = [m for m in ms if m is not None]
        out[col] = _f(sum(m.value for m in ms) / len(ms)) if ms else None
        if col in ("tactical_diameter_m", "zigzag_overshoot_deg"):
            out[f"{col}_std"] = _f(math.sqrt(sum(m.std ** 2 for m in ms)) / len(ms)) if ms else None
    return out


def check_columns(log) -> dict[str, Any]:
    """Columns of ``usvlog check`` on a run: how many errors and warnings, and their codes.

    Parameters
    ----------
    log : FieldLog
        The run as imported.

    Returns
    -------
    dict
        ``check_errors``, ``check_warnings`` (counts) and ``check_findings`` (``"code@channel"``
        of each error and warning, ``; ``-separated, errors first).
    """
    from ..check import check_log  # heavy: the checks (numpy, pandas)

    found = [f for f in check_log(log).findings if f.severity in ("error", "warning")]
    return {"check_errors": sum(f.severity == "error" for f in found),
            "check_warnings": sum(f.severity == "warning" for f in found),
            "check_findings": "; ".join(f"{f.code}@{f.channel}" for f in found)}


def verdict_of(idf) -> tuple[str, list[str]]:
    """The identification's verdict word and its reasons (the identifier's ``verdict_`` level
    and ``reasons_``).

    Parameters
    ----------
    idf : Identifier
        A fitted identifier.

    Returns
    -------
    (str, list of str)
        ``"usable"`` (no finding), ``"caveats"`` (findings that leave the numbers usable
        with care) or ``"unusable"`` (a parameter not determined, a near-singular fit or
        Theorem 3.1's condition 1 failing), and the findings.
    """
    reasons = [str(x) for x in (getattr(idf, "reasons_", None) or [])]
    level = getattr(idf, "verdict_", None)
    if isinstance(level, str):   # the identifier's own three-level verdict
        return {"usable": USABLE, "usable with caveats": CAVEATS}.get(level, UNUSABLE), reasons
    reasons = [str(x) for x in (level or [])]   # an older identifier: verdict lines only
    if any(m in r for r in reasons for m in _UNUSABLE_MARKS):
        return UNUSABLE, reasons
    return (CAVEATS if reasons else USABLE), reasons


def identify_columns(idf) -> dict[str, Any]:
    """Columns of an identification: parameters with standard errors, verdict, fit %.

    Parameters
    ----------
    idf : Identifier
        What ``usvlog.identify`` returned (fitted).

    Returns
    -------
    dict
        ``identify_method``; each parameter (SI) and ``<name>_se``; ``verdict``,
        ``verdict_reasons``; ``fit_*_pct`` and ``fit_on`` (``validation``: a held-out part
        or run, else the fitted runs); ``condition_number``; ``fit_ahead_30s_u_pct`` and
        ``fit_ahead_30s_r_pct``, the 30 s-ahead prediction fit % (None when not computed).
    """
    word, reasons = verdict_of(idf)
    out: dict[str, Any] = {"identify_method": idf.method, "verdict": word,
                           "verdict_reasons": "; ".join(reasons) or None,
                           "condition_number": _f(idf.cond_)}
    for p in PARAM_NAMES:
        out[p] = _f(getattr(idf.params_, p))
        out[f"{p}_se"] = _f(idf.stderr_.get(p))
    val = idf.validation_
    fit = val.fit_percent if val is not None else idf.fit_percent_()
    out["fit_on"] = "validation" if val is not None else "fitted runs"
    for k in ("u", "v", "r", "track"):
        out[f"fit_{k}_pct"] = _f(fit.get(k))
    ahead = (getattr(idf, "fit_percent_ahead_", None) or {}).get("30") or {}   # 30 s-ahead predictions
    for k in ("u", "r"):
        out[f"fit_ahead_30s_{k}_pct"] = _f(ahead.get(k))
    return out


def replay_columns(result) -> dict[str, Any]:
    """Columns of a replay: tracking errors of the replayed controller and the what-if run.

    Parameters
    ----------
    result : ReplayResult
        What ``usvlog.replay`` returned.

    Returns
    -------
    dict
        ``replay_xte_rms_m`` (m), ``replay_heading_rms_rad`` (rad), ``replay_surge_rms_mps``
        (m/s), ``replay_saturated_s`` (s), ``replay_command_rms`` (command unit) and
        ``whatif_xte_rms_m`` (m, None without the what-if run).
    """
    m = result.metrics.to_dict()
    rep = m.get("replay") or {}
    wi = m.get("whatif") or {}
    return {"replay_xte_rms_m": _f(rep.get("cross_track_rms_m")),
            "replay_heading_rms_rad": _f(rep.get("heading_error_rms_rad")),
            "replay_surge_rms_mps": _f(rep.get("surge_error_rms_mps")),
            "replay_saturated_s": _f(rep.get("time_saturated_s")),
            "replay_command_rms": _f(m.get("command_rms")), "whatif_xte_rms_m": _f(wi.get("cross_track_rms_m"))}


def failure_columns(stage: str, err: BaseException) -> dict[str, Any]:
    """Columns of a stage that failed: ``status`` failed, the stage and a one-line reason.

    Parameters
    ----------
    stage : str
        ``import``, ``estimate``, ``identify`` or ``replay``.
    err : BaseException
        What it raised; a :class:`~usvlog.errors.UsvlogError` gives its own message, anything
        else is named an internal error with its type.

    Returns
    -------
    dict
        ``status``, ``failed_stage``, ``reason``; a failed identification also has the
        verdict ``unusable``. An identification that refuses its result
        (:class:`~usvlog.errors.UnusableResultError`) is not a failed run but an unusable
        one: status ``ok``, verdict ``unusable``, its message the reason.
    """
    text = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
    if not isinstance(err, UsvlogError):
        text = f"internal error ({type(err).__name__}): {text}"
    if stage == "identify" and isinstance(err, UnusableResultError):
        return {"status": OK, "verdict": UNUSABLE, "verdict_reasons": text, "reason": f"identify: unusable: {text}"}
    out = {"status": FAILED, "failed_stage": stage, "reason": f"{stage}: {text}"}
    if stage == "identify":
        out["verdict"] = UNUSABLE
    return out


__all__ = ["CAVEATS", "FAILED", "OK", "SCHEMA", "UNUSABLE", "USABLE", "check_columns", "empty_row",
           "estimate_columns", "failure_columns", "identify_columns", "import_columns", "log_columns",
           "manoeuvre_columns", "replay_columns", "verdict_of"]
