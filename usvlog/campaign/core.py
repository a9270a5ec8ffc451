"""A campaign: many runs through the stages on Dask, the table, drift across runs, joint fits, the report.

:func:`run_campaign` is what ``usvlog campaign`` (and :func:`usvlog.campaign`) calls. The
steps: find the sources and their vessels; key each run by content and settings; skip the
runs finished before (their ``row.json``); run the rest as Dask tasks; write
``runs.parquet`` (also when interrupted, with what finished); test every parameter of each
vessel for drift; with ``joint``, fit one model per vessel from all its usable runs and
validate it leave-one-run-out; write the report.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ..choices import PARAM_NAMES
from ..errors import ConfigError, StorageError
from ..io.atomic import write_text_atomic
from . import columns as C
from .drift import ParameterDrift, vessel_drift
from .engine import ClusterInfo, Runner
from .table import to_frame, write_table
from .tasks import (
    LOG_FILE,
    RunSettings,
    RunSpec,
    Stages,
    expand_sources,
    failed_row,
    finished_row,
    make_spec,
    read_vessel_map,
    run_one,
    source_hashes,
    vessel_for,
)

SUMMARY_FILE = "campaign.json"
JOINT_FILE = "joint.parquet"


@dataclass(frozen=True, kw_only=True)
class JointFit:
    """One model per vessel from all its usable runs, validated leave-one-run-out.

    Attributes
    ----------
    vessel : str
        Vessel name.
    runs : tuple of str
        Run ids fitted together.
    params, stderr : dict of str to float
        The joint fit's parameters and standard errors (SI).
    verdict : str
        ``usable``, ``caveats`` or ``unusable``; ``reasons`` the findings.
    reasons : tuple of str
    loro : pandas.DataFrame
        Leave-one-run-out: one row per run (``run_id``, ``fit_u_pct`` ... ``fit_track_pct``,
        the model fitted on the other runs freely run through this one's thrust), or a
        ``reason`` when that fit failed.
    vessel_file : str or None
        The joint model's vessel TOML (``DIR/joint/<vessel>.toml``).
    error : str or None
        Why the joint fit failed (then the other fields are empty).
    """

    vessel: str
    runs: tuple[str, ...]
    params: dict
    stderr: dict
    verdict: str
    reasons: tuple[str, ...]
    loro: pd.DataFrame
    vessel_file: str | None
    error: str | None = None

    def to_dict(self) -> dict:
        """JSON-ready summary, with the leave-one-run-out rows."""
        return {"vessel": self.vessel, "runs": list(self.runs), "params": self.params, "stderr": self.stderr,
                "verdict": self.verdict, "reasons": list(self.reasons), "vessel_file": self.vessel_file,
                "error": self.error, "leave_one_run_out": json.loads(self.loro.to_json(orient="records"))}


@dataclass(kw_only=True)
class CampaignResult:
    """What a campaign did and found.

    Attributes
    ----------
    out : pathlib.Path
        The campaign directory.
    table : pandas.DataFrame
        ``runs.parquet``: one row per run (columns :data:`usvlog.campaign.columns.SCHEMA`).
    drift : dict
        {vessel: {parameter: ParameterDrift}} over each vessel's usable runs.
    joint : dict
        {vessel: JointFit} with ``joint``, else empty.
    executed : int
        Run tasks done now (0 when every run was finished before).
    reused : int
        Runs whose finished outputs were found and kept.
    cluster : ClusterInfo or None
        Where the tasks ran (None when no task ran).
    files : dict
        Output name -> path (``table``, ``summary``, ``report``, ``rrd``, ...).
    """

    out: Path
    table: pd.DataFrame
    drift: dict = field(default_factory=dict)
    joint: dict = field(default_factory=dict)
    executed: int = 0
    reused: int = 0
    cluster: ClusterInfo | None = None
    files: dict = field(default_factory=dict)

    @property
    def failed(self) -> int:
        """Runs with a failed stage."""
        return int((self.table["status"] == C.FAILED).sum())

    @property
    def unusable(self) -> int:
        """Runs whose identification cannot be used."""
        return int((self.table["verdict"] == C.UNUSABLE).sum())

    def findings(self) -> list[str]:
        """One line per drifted parameter, then per vessel whose parameters are consistent."""
        out: list[str] = []
        for v, by in self.drift.items():
            hits = [d for d in by.values() if d.drifted]
            out.extend(f"{v}: {d.describe()}" for d in hits)
            if not hits:
                nd = max((d.dates for d in by.values()), default=0)
                out.append(f"{v}: no parameter changed beyond its uncertainty across {nd} date{'s' if nd != 1 else ''}"
                           f" ({max((d.consistency.n for d in by.values()), default=0)} usable runs)")
        return out

    def to_dict(self) -> dict:
        """JSON-ready summary (what ``usvlog campaign --json`` prints and ``campaign.json`` holds)."""
        return {"out": str(self.out), "runs": int(len(self.table)), "executed": self.executed, "reused": self.reused,
                "failed": self.failed, "unusable": self.unusable,
                "cluster": None if self.cluster is None else vars(self.cluster),
                "drift": {v: {p: d.to_dict() for p, d in by.items()} for v, by in self.drift.items()},
                "joint": {v: j.to_dict() for v, j in self.joint.items()},
                "findings": self.findings(),
                "failures": [{"source": s, "reason": r} for s, r in
                             zip(self.table["source"], self.table["reason"]) if isinstance(r, str)],
                "files": {k: str(p) for k, p in self.files.items()}}


def plan_runs(sources, out: Path, settings: RunSettings, *, vessel=None, vessel_map=None) -> list[RunSpec]:
    """The runs of a campaign: sources found, vessels assigned, content hashed, keys made.

    Parameters
    ----------
    sources : sequence of str or os.PathLike
        Files, directories, globs.
    out : pathlib.Path
        Campaign directory.
    settings : RunSettings
        What each run goes through.
    vessel : str or os.PathLike, optional
        One vessel TOML for every run.
    vessel_map : str or os.PathLike, optional
        A vessel map TOML (:func:`usvlog.campaign.tasks.read_vessel_map`).

    Returns
    -------
    list of RunSpec
    """
    if vessel is not None and vessel_map is not None:
        raise ConfigError("--vessel and --vessel-map do not go together")
    vmap = read_vessel_map(vessel_map) if vessel_map is not None else []
    vfile = str(Path(vessel).resolve()) if vessel is not None else None
    if vfile is not None and not Path(vfile).is_file():
        raise ConfigError(f"--vessel {vessel}: no such file")
    specs = []
    srcs = expand_sources(sources)
    for src, sha in zip(srcs, source_hashes(srcs, out)):
        if vmap:
            name, f = vessel_for(src, vmap)
        else:
            name, f = (Path(vfile).stem, vfile) if vfile else ("", None)
        specs.append(make_spec(src, sha, settings, out, name, f))
    return specs


def usable(table: pd.DataFrame) -> pd.DataFrame:
    """Rows whose identification can be used: status ok and a verdict that is not unusable."""
    ok = (table["status"] == C.OK) & table["verdict"].isin([C.USABLE, C.CAVEATS]).fillna(False)
    return table[ok.astype(bool)]


def drift_by_vessel(table: pd.DataFrame, **kw) -> dict[str, dict[str, ParameterDrift]]:
    """{vessel: {parameter: ParameterDrift}} from the usable runs of the table.

    Parameters fixed in the identification (no standard error) are left out. A vessel's
    parameters are tested together: the correction covers every parameter at every date.

    Parameters
    ----------
    table : pandas.DataFrame
        The campaign table.
    **kw
        Passed to :func:`usvlog.campaign.drift.vessel_drift`.
    """
    ok = usable(table)
    out: dict[str, dict[str, ParameterDrift]] = {}
    for v, g in ok.groupby(ok["vessel"].fillna(""), sort=True):
        t = g["start_utc"].to_numpy(dtype="datetime64[ns]").astype(np.int64)
        params = {}
        for p in PARAM_NAMES:
            se = g[f"{p}_se"].to_numpy(dtype=float, na_value=np.nan)
            if not np.isfinite(se).any() or not (se[np.isfinite(se)] > 0).any():
                continue
            params[p] = (g[p].to_numpy(dtype=float, na_value=np.nan), se)
        out[str(v) or "(unnamed)"] = vessel_drift(t, params, **kw)
    return out


def joint_one(item: tuple, settings: RunSettings, stages: Stages) -> dict:
    """One fit of a vessel's joint model (a Dask task): on ``fit`` logs, validated on ``validate``.

    ``item`` is (vessel file or None, list of log paths to fit, log path to validate on or
    None, the vessel TOML to write or None). Returns the identification's columns, or
    ``reason`` when it failed.
    """
    vfile, fit, val, out = item
    try:
        idf = stages.identify(list(fit), out, vessel=vfile, method=settings.method, validate=val,
                              fix=dict(settings.fix), current=settings.current, force=True)
    except Exception as err:  # one failed fit is a row with its reason
        return C.failure_columns("identify", err)
    return C.identify_columns(idf)


def _joint(runner: Runner, table: pd.DataFrame, out: Path, settings: RunSettings, stages: Stages,
           vessel_files: dict[str, str | None], on_result) -> dict[str, JointFit]:
    ok = usable(table)
    items: list[tuple] = []
    owner: list[tuple[str, str | None]] = []
    (out / "joint").mkdir(exist_ok=True)
    for v, g in ok.groupby(ok["vessel"].fillna(""), sort=True):
        ids = list(g["run_id"])
        logs = [str(out / "runs" / r / LOG_FILE) for r in ids]
        if len(ids) < 2:
            continue
        vf = vessel_files.get(str(v))
        items.append((vf, logs, None, str(out / "joint" / f"{v or 'unnamed'}.toml")))
        owner.append((str(v), None))
        for i, r in enumerate(ids):
            items.append((vf, logs[:i] + logs[i + 1:], logs[i], None))
            owner.append((str(v), r))
    res = runner.map(joint_one, items, settings, stages, on_result=on_result)
    fits: dict[str, JointFit] = {}
    for v in dict.fromkeys(o[0] for o in owner):
        rows = [(o[1], r) for o, r in zip(owner, res) if o[0] == v]
        full = next(r for run, r in rows if run is None)
        loro = pd.DataFrame([{"run_id": run, **{k: r.get(k) for k in ("fit_u_pct", "fit_v_pct", "fit_r_pct",
                                                                      "fit_track_pct", "reason")}}
                             for run, r in rows if run is not None])
        err = full.get("reason") if full.get("d11") is None else None   # failed, or refused as unusable
        why = full.get("verdict_reasons")
        fits[v] = JointFit(vessel=v, runs=tuple(r for r, _ in rows if r is not None),
                           params={p: full.get(p) for p in PARAM_NAMES},
                           stderr={p: full.get(f"{p}_se") for p in PARAM_NAMES},
                           verdict=full.get("verdict") or C.UNUSABLE, reasons=tuple(why.split("; ")) if why else (),
                           loro=loro, vessel_file=None if err else str(out / "joint" / f"{v or 'unnamed'}.toml"),
                           error=err)
    return fits


def run_campaign(sources, out, *, stages: Stages, settings: RunSettings | None = None, vessel=None,
                 vessel_map=None, workers: int | None = None, scheduler: str | None = None, joint: bool = False,
                 sequential: bool = False, report: bool = True, progress: Callable[[str], None] | None = None,
                 on_plan: Callable[[int, int], None] | None = None,
                 on_row: Callable[[dict], None] | None = None) -> CampaignResult:
    """Run a campaign (see the module docstring).

    Parameters
    ----------
    sources : sequence of str or os.PathLike
        Files, directories and globs of field logs (any importable format, or canonical MCAP).
    out : str or os.PathLike
        Campaign directory (created; a second campaign into it resumes the first).
    stages : Stages
        The stage functions (the public API's).
    settings : RunSettings, optional
        Stages and their options (default :class:`RunSettings`).
    vessel, vessel_map : str or os.PathLike, optional
        See :func:`plan_runs`.
    workers : int, optional
        Worker processes of the local Dask cluster (default: the core count).
    scheduler : str, optional
        Address of a running Dask scheduler instead.
    joint : bool
        Fit one model per vessel from its usable runs, validated leave-one-run-out.
    sequential : bool
        Run in this process without Dask (measurements, debugging).
    report : bool
        Write ``campaign.html``, its PNGs and ``campaign.rrd``.
    progress : callable, optional
        Receives one-line notes (cluster and dashboard address, files written).
    on_plan : callable, optional
        Called with (runs to do, runs finished before) before the first task.
    on_row : callable, optional
        Called with each run's row as it finishes (and with each joint fit's).

    Returns
    -------
    CampaignResult

    Raises
    ------
    KeyboardInterrupt
        After writing ``runs.parquet`` with every run finished so far.
    """
    settings = settings or RunSettings()
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise StorageError(f"{out}: output is not a directory")
    out.mkdir(parents=True, exist_ok=True)
    say = progress or (lambda s: None)
    specs = plan_runs(sources, out, settings, vessel=vessel, vessel_map=vessel_map)
    done = {s.key: r for s in specs if (r := finished_row(s)) is not None}
    todo = [s for s in specs if s.key not in done]
    if on_plan:
        on_plan(len(todo), len(done))
    rows: dict[str, dict] = dict(done)

    def started(info: ClusterInfo) -> None:
        where = f"local cluster of {info.workers} processes" if info.local else f"scheduler {info.scheduler}"
        say(f"dask: {where}; dashboard {info.dashboard or '(none)'}")

    def finished(i: int, row: dict) -> None:
        rows[todo[i].key] = row
        if on_row:
            on_row(row)

    result = CampaignResult(out=out, table=to_frame([]))
    with Runner(workers=workers, scheduler=scheduler, sequential=sequential, on_start=started) as runner:
        try:
            runner.map(run_one, todo, settings, stages, keys=[f"run-{s.key[:20]}" for s in todo], on_result=finished,
                       on_error=lambda i, err: failed_row(todo[i], err))
        finally:   # also on Ctrl-C: the table holds every run finished so far
            table = to_frame([rows[s.key] for s in specs if s.key in rows])
            result.files["table"] = write_table(table, out)
        result.table, result.executed, result.reused = table, len(todo), len(done)
        result.drift = drift_by_vessel(table)
        if joint:
            vfiles = {s.vessel: s.vessel_file for s in specs}
            result.joint = _joint(runner, table, out, settings, stages, vfiles,
                                  on_result=(lambda i, r: on_row(r)) if on_row else None)
            if result.joint:
                jt = pd.concat([j.loro.assign(vessel=v) for v, j in result.joint.items()], ignore_index=True)
                from ..io.atomic import atomic_path  # heavy: already loaded (atomic writes)

                with atomic_path(out / JOINT_FILE, force=True) as tmp:
                    jt.to_parquet(tmp, index=False)
                result.files["joint"] = out / JOINT_FILE
        result.cluster = runner.info
    if report:
        from .report import write_campaign_report  # heavy: matplotlib, rerun

        result.files.update(write_campaign_report(result, progress=say))
    result.files["summary"] = out / SUMMARY_FILE
    write_text_atomic(out / SUMMARY_FILE, json.dumps(result.to_dict(), indent=1, default=_json_default) + "\n",
                      force=True)
    return result


def _json_default(x: Any):
    if isinstance(x, (np.integer, np.floating)):
        return x.item()
    if isinstance(x, np.bool_):
        return bool(x)
    return str(x)


__all__ = ["CampaignResult", "JointFit", "drift_by_vessel", "joint_one", "plan_runs", "run_campaign", "usable"]
