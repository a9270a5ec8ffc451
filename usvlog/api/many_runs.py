"""Many runs at once: recorded datasets re-run and gated on their baselines (``usvlog regress``)
and a campaign of runs through the stages on Dask (``usvlog campaign``).
"""

from __future__ import annotations

import difflib
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from ..errors import ConfigError, StorageError
from ._common import PathLike, Progress, _say
from .analysis import estimate, identify
from .controller import replay
from .data_in import import_log, load, save

if TYPE_CHECKING:  # annotations and docstring links only: importing these at run time pulls numpy and pandas
    import os  # noqa: F401  (named in the docstrings: the API reference links it)

    from ..regress.stages import ScenarioOutcome


# -----------------------------------------------------------------------------
# regress
# -----------------------------------------------------------------------------

def regress(paths: Sequence[PathLike] | None = None, *, update: bool = False, junit: PathLike | None = None,
            force: bool = False, jobs: int | None = None, progress: Progress = None,
            on_start: Callable[[list[Path]], None] | None = None,
            on_outcome: Callable[[ScenarioOutcome], None] | None = None, workers: int | None = None,
            scheduler: str | None = None) -> list[ScenarioOutcome]:
    """Re-run recorded datasets through estimate/identify/replay and gate on baselines (``usvlog regress``).

    Parameters
    ----------
    paths : sequence of str or os.PathLike, optional
        Regression scenario files (TOML with ``[dataset]``) or directories of them
        (default: the shipped ``replay/``).
    update : bool
        Accept the current metrics as the new baselines (rewrites the baseline files; the
        differences go to ``progress``).
    junit : str or os.PathLike, optional
        Also write JUnit XML for a CI system (its place is checked before any scenario runs).
    force : bool
        Replace an existing ``junit`` file.
    jobs : int, optional
        Deprecated alias of ``workers`` (it ran a process pool of its own before the campaign
        engine did the parallel runs).
    progress : callable, optional
        Receives the unified diff of each baseline that ``update`` changes.
    on_start : callable, optional
        Called with the list of scenario files once they are found and their datasets checked,
        before the first runs.
    on_outcome : callable, optional
        Called with each scenario's outcome as it finishes.
    workers : int, optional
        Run the scenarios as Dask tasks on a local cluster of this many processes (the
        campaign engine, :class:`usvlog.campaign.engine.Runner`); without it and without
        ``scheduler`` they run one after the other in this process.
    scheduler : str, optional
        Run them on a running Dask scheduler (``tcp://host:8786``) instead.

    Returns
    -------
    list of ScenarioOutcome
        One per scenario: metrics, the checks against the baseline, seconds, error; an outcome
        ``failed`` when a metric regressed or the run failed.
    """
    from ..campaign.engine import Runner  # the campaign engine runs the scenarios (dask only once tasks run)
    from ..io.atomic import check_output, write_text_atomic  # heavy: the regression stages pull the library
    from ..regress.baselines import (
        find_regress_scenarios,
        format_baseline,
        load_regress_scenario,
        read_baseline,
        write_baseline,
    )
    from ..regress.gate import junit_xml
    from ..regress.stages import accept
    from ..resources import replay_dir

    if jobs is not None:   # the deprecated name of workers
        import warnings  # only for the deprecated option

        warnings.warn("regress(jobs=N) is deprecated: use workers=N (the campaign engine's local Dask cluster)",
                      DeprecationWarning, stacklevel=2)
        if workers is not None and workers != jobs:
            raise ConfigError(f"--jobs {jobs} and --workers {workers} differ (--jobs is the old name of --workers)")
        workers = jobs
    parallel = workers is not None or bool(scheduler)
    runner = Runner(workers=workers, scheduler=scheduler, sequential=not parallel,   # options checked here
                    on_start=lambda info: _say(progress, f"dask: {info.scheduler}; dashboard "
                                                         f"{info.dashboard or '(none)'}"))
    if junit:  # the report's place is checked before the scenarios run, not after
        check_output(junit, force, parent=True)
    found = find_regress_scenarios(list(paths) if paths else [replay_dir()])
    if not found:
        raise ConfigError("no regression scenarios found (a scenario has a [dataset] section)")
    _check_datasets(found, shipped=not paths)
    if on_start:
        on_start(found)
    with runner:   # no cluster starts for the sequential path
        outcomes: list[ScenarioOutcome] = runner.map(_regress_one, [str(p) for p in found],
                                                     on_result=(lambda i, o: on_outcome(o)) if on_outcome else None)
    if update:
        for p, o in zip(found, outcomes):
            if o.error:
                continue
            scn = load_regress_scenario(p)
            old = read_baseline(scn.baseline)
            new = accept(o, old)
            before = format_baseline(old).splitlines()
            after = format_baseline(new).splitlines()
            if before != after:
                _say(progress, "".join(difflib.unified_diff([x + "\n" for x in before], [x + "\n" for x in after],
                                                            str(scn.baseline), str(scn.baseline) + " (new)")))
                scn.baseline.parent.mkdir(parents=True, exist_ok=True)
                write_baseline(scn.baseline, new, header=f"Accepted metrics of regression scenario {scn.name}.\n"
                               f"Dataset: {scn.dataset.name}. Rewrite with: usvlog regress {p.name} --update")
    if junit:
        checks = [c for o in outcomes for c in o.checks]
        write_text_atomic(junit, junit_xml(checks, {o.name: o.seconds for o in outcomes},
                                           {o.name: o.error for o in outcomes if o.error}), force=force)
    return outcomes


def _regress_one(path: str) -> ScenarioOutcome:
    """Load a scenario and its baseline, run it (top level: runs in worker processes)."""
    from ..regress.baselines import load_regress_scenario, read_baseline  # heavy: the regression stages
    from ..regress.stages import run_scenario

    scn = load_regress_scenario(path)
    return run_scenario(scn, read_baseline(scn.baseline))


def _check_datasets(paths, *, shipped: bool) -> None:
    """Every scenario's recorded run must exist: a missing one is the user's error, before any work."""
    from ..regress.baselines import load_regress_scenario  # heavy: the regression stages

    scns = [load_regress_scenario(p) for p in paths]
    missing = [s for s in scns if not s.dataset.exists()]
    if not missing:
        return
    hint = ""
    if shipped and len(missing) == len(scns):
        hint = ("; the shipped scenarios' datasets are in tests/data/ of a source checkout, not in the installed "
                "package: run usvlog regress in a checkout, or give your own scenarios")
    raise StorageError(f"{missing[0].dataset}: dataset of scenario {missing[0].name} not found "
                       f"({len(missing)} of {len(scns)} scenarios miss theirs){hint}")


# -----------------------------------------------------------------------------
# campaign
# -----------------------------------------------------------------------------

def campaign(sources, out: PathLike, *, vessel=None, vessel_map=None, stages: Sequence[str] | None = None,
             scheduler: str | None = None, workers: int | None = None, joint: bool = False,
             estimate_model: str = "kinematic", method: str = "output-error", holdout: float = 0.25,
             fix: dict[str, float] | None = None, current: bool = True, scenario: str | None = None,
             sequential: bool = False, report: bool = True, progress: Progress = None,
             on_plan: Callable[[int, int], None] | None = None, on_row: Callable[[dict], None] | None = None):
    """Take many runs through the stages on Dask, find parameter drift, write one report (``usvlog campaign``).

    Each run is one Dask task that calls the API's :func:`import_log` (or :func:`load`),
    :func:`estimate`, :func:`identify` and :func:`replay`; a run is keyed by its content and
    the settings, so a second campaign into the same ``out`` skips the finished runs.

    Parameters
    ----------
    sources : sequence of str or os.PathLike
        Field logs of any importable format or canonical MCAP logs: files, directories
        (their files) and globs.
    out : str or os.PathLike
        Campaign directory: ``runs.parquet``, ``runs/<run_id>/`` (``log.mcap``,
        ``estimate.mcap``, ``vessel.toml``, ``row.json``), ``campaign.html``, the drift PNGs,
        ``campaign.rrd``, ``campaign.json``.
    vessel : Vessel TOML path, optional
        The vessel of every run (thruster map, start values).
    vessel_map : path, optional
        A TOML of ``[vessel.NAME]`` tables with ``file`` and ``match`` (source patterns).
    stages : sequence of str, optional
        From ``import``, ``estimate``, ``identify``, ``replay`` (default ``import``,
        ``estimate``, ``identify``; ``replay`` also when ``scenario`` is given).
    scheduler : str, optional
        Address of a running Dask scheduler (``tcp://host:8786``); the workers must see
        the sources and ``out`` at the same paths.
    workers : int, optional
        Processes of the local Dask cluster (default: the core count), one thread each.
    joint : bool
        Also fit one model per vessel from all its usable runs, validated leave-one-run-out.
    estimate_model, method, holdout, fix, current, scenario
        The stages' options: :func:`estimate` ``model``; :func:`identify` ``method``,
        ``holdout`` (validation fit % on the last fraction of each run), ``fix`` (SI),
        ``current``; :func:`replay` ``scenario`` (giving one adds the replay stage; a
        listed ``replay`` without it replays ``paper-circle``).
    sequential : bool
        Run in this process without Dask.
    report : bool
        Write the HTML report, its PNGs and the Rerun recording.
    progress : callable, optional
        Receives one-line notes (the cluster and its dashboard address, files written).
    on_plan : callable, optional
        Called with (runs to do, runs finished before) before the first task.
    on_row : callable, optional
        Called with each run's row (a dict of the table's columns) as it finishes.

    Returns
    -------
    usvlog.campaign.core.CampaignResult
        ``table`` (``runs.parquet``), ``drift`` ({vessel: {parameter: ParameterDrift}}),
        ``joint``, ``executed`` and ``reused`` run counts, ``files``.
    """
    from ..campaign.core import run_campaign  # heavy: numpy, pandas; dask only once tasks run
    from ..campaign.tasks import RunSettings, Stages

    settings = RunSettings(stages=tuple(stages) if stages else RunSettings().stages, estimate_model=estimate_model,
                           method=method, holdout=holdout, fix=dict(fix or {}), current=current, scenario=scenario)
    fns = Stages(load=load, import_log=import_log, save=save, estimate=estimate, identify=identify, replay=replay)
    return run_campaign(list(sources) if isinstance(sources, (list, tuple)) else [sources], out, stages=fns,
                        settings=settings, vessel=vessel, vessel_map=vessel_map, workers=workers,
                        scheduler=scheduler, joint=joint, sequential=sequential, report=report,
                        progress=progress, on_plan=on_plan, on_row=on_row)
