"""Regression runs over recorded datasets: scenario -> stages -> metrics -> baseline gate.

A regression scenario is a TOML file (in ``replay/``) with a ``[dataset]`` section
naming a recorded log, the ``[stages]`` to run on it (``estimate``, ``identify``,
``replay``), each stage's settings, and the ``[baseline]`` file of accepted metrics.
Every stage is the same library call the CLI verbs make; the metrics are plain
floats, so two runs give identical numbers.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..control.gains import gains_from_dict
from ..errors import ConfigError, UsvlogError
from ..estimate import EstimateSettings, estimate
from ..identify import Identifier
from ..identify.identifier import VERDICTS
from ..io.mcap import read_log
from ..log.fieldlog import FieldLog
from ..model.frames import ssa
from ..model.stats import rms
from ..replay import replay_log
from ..sim.scenario import load_scenario
from .gate import BaselineEntry, Check, compare, updated_baseline

STAGES = ("estimate", "identify", "replay")
SECTIONS = {"scenario", "dataset", "stages", "estimate", "identify", "replay", "baseline"}


@dataclass(frozen=True, kw_only=True)
class RegressScenario:
    """One regression scenario: a recorded dataset, the stages to run on it and its baseline.

    Made from a scenario file by :func:`regress_scenario_from_dict` (paths resolved there).

    Attributes
    ----------
    name : str
        ``[scenario] name``, else the file's stem; names the scenario in reports and its
        default baseline file.
    path : pathlib.Path
        The scenario file (named in error messages; ``[replay] scenario`` is looked for
        beside it).
    description : str
        ``[scenario] description``.
    dataset : pathlib.Path
        The recorded log (canonical MCAP) the stages run on.
    made_by : str
        ``[dataset] made_by``: how the dataset was made (free text).
    stages : tuple of str
        Stages to run, in order, from :data:`STAGES` (default all three).
    estimate : dict
        Keyword arguments of :class:`~usvlog.estimate.EstimateSettings` (``[estimate]``).
    identify : dict
        Keyword arguments of :class:`~usvlog.identify.Identifier` (``[identify]``).
    replay : dict
        ``[replay]``: ``scenario`` (a closed-loop scenario TOML beside the file, or the name
        of a shipped one; required when the stage runs), optional ``gains`` (overrides of
        the scenario's gains), ``state`` (``"estimate"``: the log with the estimate stage's
        output, or ``"recorded"``) and ``whatif_model`` (``"scenario"``, or
        ``"identified"``: the identify stage's vessel).
    baseline : pathlib.Path
        The baseline file of accepted metrics (:mod:`usvlog.regress.baselines`).

    Raises
    ------
    ConfigError
        An unknown stage, or the replay stage without ``[replay] scenario``.
    """

    name: str
    path: Path
    description: str = ""
    dataset: Path
    made_by: str = ""
    stages: tuple[str, ...] = STAGES
    estimate: dict = field(default_factory=dict)
    identify: dict = field(default_factory=dict)
    replay: dict = field(default_factory=dict)
    baseline: Path

    def __post_init__(self):
        bad = [s for s in self.stages if s not in STAGES]
        if bad:
            raise ConfigError(f"{self.path}: unknown stage(s) {', '.join(bad)} (known: {', '.join(STAGES)})")
        if "replay" in self.stages and "scenario" not in self.replay:
            raise ConfigError(f"{self.path}: [replay] needs scenario = \"<closed-loop scenario TOML>\"")


def regress_scenario_from_dict(doc: dict, path: Path) -> RegressScenario:
    """Check a parsed regression scenario file and make a :class:`RegressScenario` of it.

    Parameters
    ----------
    doc : dict
        The parsed TOML: sections from :data:`SECTIONS`; ``[dataset] log`` is required,
        ``[stages] run`` lists the stages, ``[baseline] file`` defaults to
        ``baselines/<name>.toml``.
    path : pathlib.Path
        The file it was read from: the dataset and baseline paths are relative to its
        directory, and errors name it.

    Returns
    -------
    RegressScenario

    Raises
    ------
    ConfigError
        An unknown section, no ``[dataset] log``, an unknown stage, or the replay stage
        without ``[replay] scenario``.
    """
    for k in doc:
        if k not in SECTIONS:
            raise ConfigError(f"{path}: unknown section [{k}] (known: {', '.join(sorted(SECTIONS))})")
    ds = doc.get("dataset", {})
    if "log" not in ds:
        raise ConfigError(f"{path}: [dataset] needs log = \"<recorded run>.mcap\"")
    sc = doc.get("scenario", {})
    base = doc.get("baseline", {})
    name = sc.get("name", path.stem)
    return RegressScenario(
        name=name, path=path, description=sc.get("description", ""),
        dataset=(path.parent / ds["log"]).resolve(), made_by=ds.get("made_by", ""),
        stages=tuple(doc.get("stages", {}).get("run", STAGES)),
        estimate=dict(doc.get("estimate", {})), identify=dict(doc.get("identify", {})),
        replay=dict(doc.get("replay", {})),
        baseline=(path.parent / base.get("file", f"baselines/{name}.toml")).resolve())


# -----------------------------------------------------------------------------
# stages: each adds metrics (and may hand a richer log to the next stage)
# -----------------------------------------------------------------------------

@dataclass
class _Run:
    scenario: RegressScenario
    log: FieldLog                    # the dataset as recorded
    work: FieldLog                   # the dataset plus what the stages computed
    metrics: dict[str, float] = field(default_factory=dict)
    vessel: object = None            # identified vessel, when identify ran


def _rms(x) -> float:
    """RMS with NaN kept: an estimate with holes must show in the gate, not be averaged over."""
    return rms(x, omit_nonfinite=False)


def _truth_at(log: FieldLog, t_ns: np.ndarray):
    tr = log.get("/truth/state")
    if tr is None or not len(tr):
        return None
    tt = tr.index.to_numpy()
    sel = (t_ns >= tt[0]) & (t_ns <= tt[-1])
    out = {}
    for c in ("n_m", "e_m", "u_mps", "v_mps", "r_radps", "current_n_mps", "current_e_mps"):
        out[c] = np.interp(t_ns[sel], tt, tr[c].to_numpy())
    psi = np.unwrap(tr["psi_rad"].to_numpy())
    out["psi_rad"] = np.interp(t_ns[sel], tt, psi)
    return sel, out


def stage_estimate(run: _Run) -> None:
    """The estimate stage: EKF + RTS smoother over the recorded log, with ``[estimate]`` settings.

    Adds ``/estimate/state`` and ``/estimate/innovations`` to ``run.work`` and, to
    ``run.metrics``: ``estimate.<sensor>_mean_nis`` and ``estimate.<sensor>_rejected``
    per sensor and ``estimate.dropouts_bridged``. When the log has ``/truth/state``
    (simulated datasets), also the errors against it over the truth's time span:
    ``pos_rms_m`` (m), ``psi_rms_deg`` (deg), ``r_rms_degps`` (deg/s), ``u_rms_mps`` and
    ``v_rms_mps`` (m/s; over ground for the kinematic model, the truth's current added)
    and, for a model that estimates the current, ``current_err_mps`` (m/s, error of the
    mean current). RMS values keep NaN: a gap in the estimate shows in the gate.

    Parameters
    ----------
    run : _Run
        The run in progress (scenario, recorded log, working log, metrics); updated in place.

    Raises
    ------
    ConfigError
        ``[estimate]`` has an unknown key or an invalid value.
    """
    try:
        settings = EstimateSettings(**run.scenario.estimate)
    except TypeError as err:
        raise ConfigError(f"{run.scenario.path}: [estimate] {err}") from err
    res = estimate(run.log, settings)
    run.work = res.to_log(run.work)
    m = run.metrics
    for s in res.report.sensors:
        m[f"estimate.{s.sensor}_mean_nis"] = s.mean_nis
        m[f"estimate.{s.sensor}_rejected"] = float(s.rejected)
    m["estimate.dropouts_bridged"] = float(res.report.dropouts_bridged)
    st = res.state
    t = st.index.to_numpy()
    got = _truth_at(run.log, t)
    if got is None:
        return
    sel, tr = got
    e = {c: st[c].to_numpy()[sel] for c in st.columns}
    m["estimate.pos_rms_m"] = _rms(np.hypot(e["n_m"] - tr["n_m"], e["e_m"] - tr["e_m"]))
    m["estimate.psi_rms_deg"] = math.degrees(_rms(ssa(e["psi_rad"] - tr["psi_rad"])))
    m["estimate.r_rms_degps"] = math.degrees(_rms(e["r_radps"] - tr["r_radps"]))
    if settings.model == "kinematic":  # over-ground body velocities: add the current to the truth
        c, s = np.cos(tr["psi_rad"]), np.sin(tr["psi_rad"])
        u_t = tr["u_mps"] + c * tr["current_n_mps"] + s * tr["current_e_mps"]
        v_t = tr["v_mps"] - s * tr["current_n_mps"] + c * tr["current_e_mps"]
    else:
        u_t, v_t = tr["u_mps"], tr["v_mps"]
        if not np.isnan(e["current_n_mps"]).all():
            m["estimate.current_err_mps"] = float(np.hypot(
                np.mean(e["current_n_mps"] - tr["current_n_mps"]), np.mean(e["current_e_mps"] - tr["current_e_mps"])))
    m["estimate.u_rms_mps"] = _rms(e["u_mps"] - u_t)
    m["estimate.v_rms_mps"] = _rms(e["v_mps"] - v_t)


def stage_identify(run: _Run) -> None:
    """The identify stage: fit the model (3) to the recorded log with ``[identify]`` settings.

    Sets ``run.vessel`` to the identified vessel and adds to ``run.metrics``:
    ``identify.<param>`` for each parameter (m in kg, Iz in kg m^2, d11/d22 in N s/m,
    d33 in N m s/rad, xg in m), ``identify.fit_<u|v|r|track>_pct`` (% fit of the model's
    validation: the held-out part, or without one a free run on the same log),
    ``identify.warnings`` (count of the verdict's reasons) and ``identify.verdict_level``
    (0 usable, 1 usable with caveats, 2 unusable). When
    the log has ``/truth/state`` (simulated datasets), also ``identify.<param>_err_pct``
    (% of the true value), ``identify.xg_err_m`` (m) and, when the current is fitted,
    ``identify.current_err_mps`` (m/s, against the truth's mean current).

    Parameters
    ----------
    run : _Run
        The run in progress (scenario, recorded log, working log, metrics); updated in place.

    Raises
    ------
    ConfigError
        ``[identify]`` has an unknown key or an invalid value.
    InputError
        The log cannot be identified from (missing channels, too few samples, an
        impossible fit).
    """
    kw = dict(run.scenario.identify)
    try:
        ident = Identifier(**kw)
    except TypeError as err:
        raise ConfigError(f"{run.scenario.path}: [identify] {err}") from err
    ident.fit([run.log], run.log.vessel)
    run.vessel = ident.to_vessel()
    m = run.metrics
    p = ident.params_
    truth = run.log.vessel if run.log.get("/truth/state") is not None else None
    for k, v in p.to_dict().items():
        m[f"identify.{k}"] = v
        if truth is not None:
            tv = getattr(truth.params, k)
            if k == "xg":
                m["identify.xg_err_m"] = abs(v - tv)
            else:
                m[f"identify.{k}_err_pct"] = 100.0 * abs(v - tv) / abs(tv)
    if truth is not None and ident.current:
        tr = run.log["/truth/state"]
        cn, ce = ident.current_[0]
        m["identify.current_err_mps"] = float(np.hypot(cn - tr["current_n_mps"].mean(),
                                                       ce - tr["current_e_mps"].mean()))
    fp = ident.validation_fit_percent_() if ident.validations_ else ident.validate(run.log).fit_percent
    for k, v in fp.items():
        m[f"identify.fit_{k}_pct"] = float(v)
    m["identify.warnings"] = float(len(ident.reasons_))
    m["identify.verdict_level"] = float(VERDICTS.index(ident.verdict_))


def stage_replay(run: _Run) -> None:
    """The replay stage: open-loop replay and what-if run (:func:`usvlog.replay.replay_log`).

    Replays ``run.work`` (``state = "estimate"``, the default: the estimate stage's
    output) or the recorded log (``"recorded"``) with the ``[replay] scenario``'s path,
    guidance and gains (``[replay] gains`` overriding some of them). The controller's
    model and the what-if plant are the identified vessel with ``whatif_model =
    "identified"`` (when the identify stage ran), else the scenario's ``[vessel]``, the
    log's or the default one. Adds to ``run.metrics`` the tracking metrics
    in m, rad, m/s and s as ``replay.<name>`` and ``whatif.<name>`` (``start_s`` and
    ``duration_s`` left out), and ``replay.command_rms`` (command unit),
    ``replay.force_rms_n`` (N) and ``replay.decisions_max_abs`` (N, N m) when known.

    Parameters
    ----------
    run : _Run
        The run in progress (scenario, recorded log, working log, metrics); updated in place.

    Raises
    ------
    ConfigError
        An unknown ``[replay]`` key, a bad ``state`` or gains, or a scenario that cannot
        be loaded.
    InputError
        The log has no state to replay.
    """
    cfg = dict(run.scenario.replay)
    name = cfg.pop("scenario")
    scen_path = run.scenario.path.parent / name
    scen = load_scenario(scen_path if scen_path.exists() else name)  # a file beside it, or a name in replay/
    gains = None
    if "gains" in cfg:
        merged = {**{f.name: getattr(scen.gains, f.name) for f in dataclasses.fields(scen.gains)}, **cfg.pop("gains")}
        gains, _ = gains_from_dict({"gains": merged}, source=str(run.scenario.path))
    state = cfg.pop("state", "estimate")
    whatif_model = cfg.pop("whatif_model", "scenario")
    if cfg:
        raise ConfigError(f"{run.scenario.path}: [replay] has unknown key(s) {', '.join(sorted(cfg))}")
    if state not in ("estimate", "recorded"):
        raise ConfigError(f"{run.scenario.path}: [replay] state must be estimate or recorded")
    base = run.work if state == "estimate" else run.log
    vessel = run.vessel if (whatif_model == "identified" and run.vessel is not None) else None
    res = replay_log(base, scen, vessel=vessel, gains=gains)
    mt = res.metrics
    m = run.metrics
    for k, v in mt.replay.to_dict().items():
        if k.endswith(("_m", "_rad", "_mps", "_s")) and k not in ("start_s", "duration_s"):
            m[f"replay.{k}"] = float(v)
    for k in ("command_rms", "force_rms_n", "decisions_max_abs"):
        v = getattr(mt, k)
        if v is not None:
            m[f"replay.{k}"] = float(v)
    if mt.whatif is not None:
        for k, v in mt.whatif.to_dict().items():
            if k.endswith(("_m", "_rad", "_mps", "_s")) and k not in ("start_s", "duration_s"):
                m[f"whatif.{k}"] = float(v)


STAGE_FUNCS = {"estimate": stage_estimate, "identify": stage_identify, "replay": stage_replay}


# -----------------------------------------------------------------------------
# running
# -----------------------------------------------------------------------------

@dataclass(frozen=True)
class ScenarioOutcome:
    """The result of one regression scenario: its metrics and their checks against the baseline.

    Attributes
    ----------
    name : str
        The scenario's name.
    path : str
        The scenario file.
    metrics : dict
        Metric name -> value (float, in the metric's unit), sorted by name; empty on error.
    checks : tuple of usvlog.regress.gate.Check
        One per metric of the run or of the baseline; empty on error.
    seconds : float
        Wall time of the run (s).
    error : str or None
        The one-line error that stopped the run (bad dataset or settings), else None.
    """

    name: str
    path: str
    metrics: dict
    checks: tuple[Check, ...]
    seconds: float
    error: str | None = None

    @property
    def failed(self) -> bool:
        """True when the run stopped on an error or a check failed (regressed or missing)."""
        return self.error is not None or any(c.failed for c in self.checks)

    def to_dict(self) -> dict:
        """JSON-ready dict of the attributes plus ``failed``; checks as :meth:`Check.to_dict` dicts."""
        return {"name": self.name, "path": self.path, "metrics": self.metrics, "seconds": self.seconds,
                "error": self.error, "failed": self.failed, "checks": [c.to_dict() for c in self.checks]}


def run_stages(scn: RegressScenario, log: FieldLog) -> dict[str, float]:
    """Run the scenario's stages on its dataset; the metrics (pure of files)."""
    run = _Run(scenario=scn, log=log, work=log.copy())
    for stage in scn.stages:
        STAGE_FUNCS[stage](run)
    return {k: float(v) for k, v in sorted(run.metrics.items())}


def run_scenario(scn: RegressScenario, baseline: dict[str, BaselineEntry]) -> ScenarioOutcome:
    """Read the scenario's dataset, run its stages and check the metrics against ``baseline``.

    Parameters
    ----------
    scn : RegressScenario
        The scenario.
    baseline : dict
        Metric name -> accepted :class:`~usvlog.regress.gate.BaselineEntry` (empty for a
        scenario without a baseline yet: every metric is then ``new``).

    Returns
    -------
    ScenarioOutcome
        Metrics, checks and wall time. A :class:`~usvlog.errors.UsvlogError` (unreadable
        dataset, bad settings, unusable data) is caught and returned as ``error`` so the
        other scenarios still run; any other exception is a bug and propagates.
    """
    t0 = time.perf_counter()
    try:
        log = read_log(scn.dataset)
        if log.recovery is not None:   # a damaged dataset is a failure, never a baseline to compare
            return ScenarioOutcome(scn.name, str(scn.path), {}, (), time.perf_counter() - t0,
                                   f"dataset {scn.dataset} {log.recovery.one_line()}")
        metrics = run_stages(scn, log)
    except UsvlogError as err:
        return ScenarioOutcome(scn.name, str(scn.path), {}, (), time.perf_counter() - t0, str(err))
    checks = tuple(compare(scn.name, metrics, baseline))
    return ScenarioOutcome(scn.name, str(scn.path), metrics, checks, time.perf_counter() - t0)


def accept(outcome: ScenarioOutcome, old: dict[str, BaselineEntry]) -> dict[str, BaselineEntry]:
    """The baseline that accepts this outcome's metrics (tolerances kept)."""
    return updated_baseline(outcome.metrics, old, default_worse=DEFAULT_WORSE, default_tol=DEFAULT_TOL)


def _default_direction(name: str) -> str:
    leaf = name.split(".", 1)[1]
    if leaf.startswith("fit_"):
        return "smaller"
    if name.startswith("identify.") and not leaf.endswith(("_err_pct", "_err_m")) and leaf not in (
            "warnings", "verdict_level"):
        return "either"                    # a parameter moving either way is a change
    if leaf.endswith("_mean_nis"):
        return "either"                    # consistency: NIS should stay near its dimension
    if leaf in ("command_rms", "force_rms_n", "decisions_max_abs"):
        return "either"                    # a fingerprint of the controller's decisions
    return "larger"


class _Defaults(dict):
    def __init__(self, fn):
        super().__init__()
        self.fn = fn

    def get(self, key, default=None):
        return self.fn(key)


def _default_tol(name: str) -> tuple[float, float]:
    leaf = name.split(".", 1)[1]
    if leaf in ("decisions_max_abs",):
        return (1e-6, 0.0)                 # the same code makes the same decisions
    if leaf in ("command_rms", "force_rms_n"):
        return (1e-9, 1e-6)                # replayed vs recorded: any change of decisions shows
    if leaf.endswith("_rejected") or leaf in ("dropouts_bridged", "warnings", "verdict_level"):
        return (0.0, 0.0)
    if leaf.endswith("_pct") and leaf.startswith("fit_"):
        return (1.0, 0.0)                  # fit % points
    if leaf.endswith("_err_pct"):
        return (1.0, 0.1)
    return (1e-9, 0.05)


DEFAULT_WORSE = _Defaults(_default_direction)
DEFAULT_TOL = _Defaults(_default_tol)
