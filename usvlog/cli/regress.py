"""``usvlog regress``: re-run every recorded dataset's scenario and gate on its baseline."""

from __future__ import annotations

import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from ..errors import ConfigError, StorageError
from ..io.atomic import check_output, write_text_atomic
from ..regress.baselines import (
    find_regress_scenarios,
    format_baseline,
    load_regress_scenario,
    read_baseline,
    write_baseline,
)
from ..regress.gate import junit_xml
from ..regress.stages import ScenarioOutcome, accept, run_scenario
from ..resources import replay_dir
from .common import print_json, stage


def register(sub) -> None:
    p = sub.add_parser("regress", help="re-run recorded datasets through estimate/identify/replay and "
                                       "compare with accepted baselines")
    p.add_argument("paths", nargs="*", help="scenario files or directories (default: the shipped replay/)")
    p.add_argument("--update", action="store_true", help="accept the current metrics as the new baselines")
    p.add_argument("--junit", default=None, metavar="FILE", help="write JUnit XML for a CI system")
    p.add_argument("--json", action="store_true", help="print the results as JSON")
    p.add_argument("--jobs", type=int, default=1, help="scenarios run in this many parallel processes (default 1)")
    p.set_defaults(func=run)


def run_one(path: str) -> ScenarioOutcome:
    """Load a scenario and its baseline, run it (top level: runs in worker processes)."""
    scn = load_regress_scenario(path)
    return run_scenario(scn, read_baseline(scn.baseline))


def check_datasets(paths, *, shipped: bool) -> None:
    """Every scenario's recorded run must exist: a missing one is the user's error, before any work."""
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


def format_table(outcomes: list[ScenarioOutcome]) -> str:
    lines = [f"{'scenario':<18} {'metric':<34} {'baseline':>12} {'now':>12} {'change':>11}  verdict"]
    for o in outcomes:
        if o.error:
            lines.append(f"{o.name:<18} {'(run)':<34} {'':>12} {'':>12} {'':>11}  ERROR: {o.error}")
            continue
        for c in o.checks:
            b = "-" if c.baseline is None else f"{c.baseline:.6g}"
            n = "-" if c.now is None else f"{c.now:.6g}"
            d = "-" if c.change is None else f"{c.change:+.3g}"
            lines.append(f"{o.name:<18} {c.metric:<34} {b:>12} {n:>12} {d:>11}  {c.verdict}")
    fails = [c for o in outcomes for c in o.checks if c.failed]
    errs = [o for o in outcomes if o.error]
    lines.append("")
    for c in fails:
        lines.append(f"REGRESSION {c.scenario}: {c.message}")
    n_checks = sum(len(o.checks) for o in outcomes)
    lines.append(f"{len(outcomes)} scenarios, {n_checks} metrics: {len(fails)} regressed, {len(errs)} errors "
                 f"({sum(o.seconds for o in outcomes):.1f} s)")
    return "\n".join(lines)


def _progress(total: int):
    try:
        from tqdm import tqdm

        return tqdm(total=total, desc="regress", unit="scenario", file=sys.stderr, leave=False)
    except ImportError:  # pragma: no cover
        return None


def run(args) -> int:
    if args.jobs < 1:
        raise ConfigError(f"--jobs {args.jobs} must be >= 1")
    if args.junit:  # the report's place is checked before the scenarios run, not after
        check_output(args.junit, True, parent=True)
    paths = find_regress_scenarios(args.paths or [replay_dir()])
    if not paths:
        raise ConfigError("no regression scenarios found (a scenario has a [dataset] section)")
    check_datasets(paths, shipped=not args.paths)
    bar = _progress(len(paths))
    outcomes: list[ScenarioOutcome] = []
    if args.jobs == 1 or len(paths) == 1:
        for p in paths:
            outcomes.append(run_one(str(p)))
            if bar:
                bar.update(1)
    else:
        with ProcessPoolExecutor(max_workers=args.jobs) as ex:
            for o in ex.map(run_one, [str(p) for p in paths]):
                outcomes.append(o)
                if bar:
                    bar.update(1)
    if bar:
        bar.close()
    if args.update:
        for p, o in zip(paths, outcomes):
            if o.error:
                continue
            scn = load_regress_scenario(p)
            old = read_baseline(scn.baseline)
            new = accept(o, old)
            before = format_baseline(old).splitlines()
            after = format_baseline(new).splitlines()
            if before != after:
                import difflib

                stage("".join(difflib.unified_diff([x + "\n" for x in before], [x + "\n" for x in after],
                                                   str(scn.baseline), str(scn.baseline) + " (new)")))
                scn.baseline.parent.mkdir(parents=True, exist_ok=True)
                write_baseline(scn.baseline, new, header=f"Accepted metrics of regression scenario {scn.name}.\n"
                               f"Dataset: {scn.dataset.name}. Rewrite with: usvlog regress {p.name} --update")
    if args.junit:
        checks = [c for o in outcomes for c in o.checks]
        write_text_atomic(args.junit, junit_xml(checks, {o.name: o.seconds for o in outcomes},
                                                {o.name: o.error for o in outcomes if o.error}), force=True)
    if args.json:
        print_json({"scenarios": [o.to_dict() for o in outcomes],
                    "failed": any(o.failed for o in outcomes)})
    else:
        print(format_table(outcomes))
    if args.update:
        return 1 if any(o.error for o in outcomes) else 0
    return 1 if any(o.failed for o in outcomes) else 0


__all__ = ["run_one", "format_table", "Path"]
