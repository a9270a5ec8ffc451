"""``usvlog campaign``: many runs through the stages on Dask, drift across the season, one report."""

from __future__ import annotations

import sys
import time

from ..choices import IDENTIFY_METHODS
from .common import print_json, stage
from .identify import parse_fix

STAGE_NAMES = ("import", "estimate", "identify", "replay")


def register(sub) -> None:
    p = sub.add_parser("campaign", help="many runs through import/estimate/identify/replay on Dask; parameter "
                                        "drift across runs; one report")
    p.add_argument("sources", nargs="+", help="field logs of any importable format or canonical MCAP logs: "
                                              "files, directories, globs")
    p.add_argument("--out", required=True, metavar="DIR", help="campaign directory (a second campaign into it "
                                                               "skips the runs finished before)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--vessel", default=None, metavar="V.toml", help="vessel TOML of every run")
    g.add_argument("--vessel-map", default=None, metavar="MAP.toml",
                   help="[vessel.NAME] tables with file = \"V.toml\" and match = [\"pattern\", ...]")
    p.add_argument("--stages", default=None,
                   help=f"comma-separated stages from {','.join(STAGE_NAMES)} (default import,estimate,identify; "
                        "replay also with --scenario)")
    h = p.add_mutually_exclusive_group()
    h.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="a running Dask scheduler (tcp://host:8786); its workers must see the files at the same paths")
    h.add_argument("--workers", type=int, default=None, metavar="N",
                   help="processes of the local Dask cluster (default: the core count)")
    p.add_argument("--joint", action="store_true",
                   help="also fit one model per vessel from all its usable runs, validated leave-one-run-out")
    p.add_argument("--method", choices=IDENTIFY_METHODS, default="output-error", help="identification method")
    p.add_argument("--holdout", type=float, default=0.25,
                   help="last fraction of each run held out for the validation fit %% (default 0.25)")
    p.add_argument("--fix", action="append", default=[], metavar="NAME=VALUE",
                   help="known parameter in SI units, e.g. m=33 (repeatable)")
    p.add_argument("--no-current", action="store_true", help="do not fit a water current")
    p.add_argument("--model", choices=["kinematic", "dynamic"], default="kinematic", help="estimation model")
    p.add_argument("--scenario", default=None,
                   help="closed-loop scenario of the replay stage (paper-circle, paper-sine or S.toml); giving one "
                        "adds the replay stage (default with replay in --stages: paper-circle)")
    p.add_argument("--no-report", action="store_true", help="write the table only (no HTML, PNGs, .rrd)")
    p.add_argument("--json", action="store_true", help="print the campaign summary as JSON")
    p.set_defaults(func=run)


class Bar:
    """One progress line on stderr: runs done, failed, unusable, reused, and the time left."""

    def __init__(self, stream=sys.stderr):
        self.stream, self.total, self.done, self.failed, self.unusable, self.reused = stream, 0, 0, 0, 0, 0
        self.t0 = time.monotonic()
        self.tty = hasattr(stream, "isatty") and stream.isatty()

    def plan(self, todo: int, reused: int) -> None:
        self.total, self.reused, self.t0 = todo, reused, time.monotonic()
        self.draw()

    def row(self, row: dict) -> None:
        if "run_id" not in row:   # a joint fit, not a run
            return
        self.done += 1
        self.failed += row.get("status") == "failed"
        self.unusable += row.get("verdict") == "unusable" and row.get("status") != "failed"
        self.draw()

    def line(self) -> str:
        n, tot = self.done, self.total
        width = 24
        fill = int(width * n / tot) if tot else width
        el = time.monotonic() - self.t0
        eta = f"{el / n * (tot - n):.0f} s left" if n and n < tot else ("done" if n >= tot else "...")
        return (f"campaign [{'#' * fill}{'.' * (width - fill)}] {n}/{tot} runs, {self.failed} failed, "
                f"{self.unusable} unusable, {self.reused} reused, {eta}")

    def draw(self) -> None:
        if self.tty:
            self.stream.write("\r" + self.line() + "\x1b[K")
            if self.done >= self.total:
                self.stream.write("\n")
        elif self.done >= self.total or self.done % max(1, self.total // 20) == 0:
            self.stream.write(self.line() + "\n")
        self.stream.flush()


def run(args) -> int:
    from .. import api  # heavy: imported only when the verb runs

    bar = Bar()
    res = api.campaign(args.sources, args.out, vessel=args.vessel, vessel_map=args.vessel_map,
                       stages=[s.strip() for s in args.stages.split(",") if s.strip()] if args.stages else None,
                       scheduler=args.scheduler,
                       workers=args.workers, joint=args.joint, estimate_model=args.model, method=args.method,
                       holdout=args.holdout, fix=parse_fix(args.fix), current=not args.no_current,
                       scenario=args.scenario, report=not args.no_report, progress=stage, on_plan=bar.plan,
                       on_row=bar.row)
    if args.json:
        print_json(res.to_dict())
        return 0
    t = res.table
    print(f"{len(t)} runs ({res.executed} processed now, {res.reused} reused): "
          f"{int((t['status'] == 'ok').sum())} through every stage, {res.failed} failed, {res.unusable} unusable")
    for line in res.findings():
        print(line)
    bad = t[t["reason"].notna()]
    for src, reason in zip(bad["source"], bad["reason"]):
        print(f"  {src}: {reason}")
    for name in ("table", "report", "rrd", "joint", "summary"):
        if name in res.files:
            print(f"{name}: {res.files[name]}")
    return 0


__all__ = ["Bar"]
