"""``usvlog regress``: re-run every recorded dataset's scenario and gate on its baseline."""

from __future__ import annotations

import sys
import warnings
from typing import TYPE_CHECKING

from .common import print_json, stage

if TYPE_CHECKING:  # annotations only: the regression stages import the whole library
    from ..regress.stages import ScenarioOutcome


def register(sub) -> None:
    p = sub.add_parser("regress", help="re-run recorded datasets through estimate/identify/replay and "
                                       "compare with accepted baselines")
    p.add_argument("paths", nargs="*", help="scenario files or directories (default: the shipped replay/)")
    p.add_argument("--update", action="store_true", help="accept the current metrics as the new baselines")
    p.add_argument("--junit", default=None, metavar="FILE", help="write JUnit XML for a CI system")
    p.add_argument("--force", action="store_true", help="overwrite an existing --junit file")
    p.add_argument("--json", action="store_true", help="print the results as JSON")
    p.add_argument("--jobs", type=int, default=None, metavar="N", help="deprecated: the old name of --workers")
    p.add_argument("--workers", type=int, default=None, metavar="N",
                   help="run the scenarios on a local Dask cluster of N processes (the campaign engine)")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="run the scenarios on a running Dask scheduler (tcp://host:8786)")
    p.set_defaults(func=run)


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
        from tqdm import tqdm  # optional (a progress bar), and only when the verb runs

        return tqdm(total=total, desc="regress", unit="scenario", file=sys.stderr, leave=False)
    except ImportError:  # pragma: no cover
        return None


def run(args) -> int:
    from .. import api  # heavy: imported only when the verb runs

    bar: dict = {}

    def start(paths) -> None:
        bar["total"], bar["done"], bar["bar"] = len(paths), 0, _progress(len(paths))

    def done(outcome) -> None:  # the bar goes before --update prints its baseline diffs
        bar["done"] += 1
        if bar["bar"]:
            bar["bar"].update(1)
            if bar["done"] == bar["total"]:
                bar["bar"].close()

    if args.jobs is not None:
        stage("warning: --jobs is deprecated, use --workers (the scenarios run on a local Dask cluster)")
    with warnings.catch_warnings():   # said above, once, in the CLI's words
        warnings.simplefilter("ignore", DeprecationWarning)
        outcomes = api.regress(args.paths, update=args.update, junit=args.junit, force=args.force, jobs=args.jobs,
                               progress=stage, on_start=start, on_outcome=done, workers=args.workers,
                               scheduler=args.scheduler)
    if args.json:
        print_json({"scenarios": [o.to_dict() for o in outcomes],
                    "failed": any(o.failed for o in outcomes)})
    else:
        print(format_table(outcomes))
    if args.update:
        return 1 if any(o.error for o in outcomes) else 0
    return 1 if any(o.failed for o in outcomes) else 0


__all__ = ["format_table"]
