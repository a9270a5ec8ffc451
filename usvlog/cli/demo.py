"""``usvlog demo``: the whole pipeline on a built-in simulated run.

Every stage of usvlog adds itself here, so the demo always shows what the tool does.

Outputs follow the ``--force`` rule of every verb, with one allowance: a re-run replaces the
files an earlier demo wrote, when it can prove they are its own. The demo records each file
it writes, with its SHA-256, in ``OUT/.usvlog-demo.json``; a file the demo would write that
exists and is not recorded there with that content (another program's, or edited since) is
refused without ``--force``. Other files in the directory are never touched.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

from ..choices import PARAM_NAMES
from ..errors import OutputExistsError, StorageError
from .common import stage
from .replay import format_metrics

MARKER = ".usvlog-demo.json"
FILES = ("excitation.mcap", "merged.csv", "imported.mcap", "estimate.mcap", "identified.toml", "paper-circle.mcap",
         "paper-circle-replay.mcap", "demo.rrd", "estimate.rrd")
DIRS = ("csv", "report")


def register(sub) -> None:
    p = sub.add_parser("demo", help="run the whole pipeline on a built-in simulated run")
    p.add_argument("--out", default="usvlog-demo",
                   help="output directory (default: usvlog-demo); a re-run replaces the files an earlier demo "
                        f"wrote there (listed with their checksums in {MARKER}), other existing outputs only "
                        "with --force")
    p.add_argument("--force", action="store_true", help="overwrite existing outputs the demo did not write")
    p.add_argument("--seed", type=int, default=1, help="random seed of the simulated excitation run (default 1)")
    p.add_argument("--duration-s", type=float, default=600.0,
                   help="length of the simulated excitation run in seconds (default 600)")
    p.set_defaults(func=run)


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


class Owned:
    """The demo's own files in its output directory, proven by their SHA-256 in ``OUT/.usvlog-demo.json``.

    Parameters
    ----------
    out : pathlib.Path
        The demo's output directory.
    """

    def __init__(self, out: Path):
        self.out = out
        try:
            files = json.loads((out / MARKER).read_text(encoding="utf-8"))["files"]
            self.files = {str(k): str(v) for k, v in files.items()}
        except (OSError, ValueError, KeyError, TypeError, AttributeError):
            self.files = {}

    def _rel(self, path: Path) -> str:
        return path.relative_to(self.out).as_posix()

    def targets(self) -> list[Path]:
        """Every existing path a run of the demo may replace."""
        found = [self.out / f for f in FILES]
        for d in DIRS:
            p = self.out / d
            found += sorted(x for x in p.rglob("*") if not x.is_dir()) if p.is_dir() and not p.is_symlink() else [p]
        return [p for p in found if p.exists() or p.is_symlink()]

    def check(self, force: bool) -> None:
        """Refuse (without ``force``) an existing output that an earlier demo did not write as it is now.

        Raises
        ------
        usvlog.errors.OutputExistsError
            Naming the first such file.
        """
        if force:
            return
        for p in self.targets():
            rel = self._rel(p)
            if p.is_symlink() or not p.is_file() or self.files.get(rel) != _sha256(p):
                raise OutputExistsError(f"{p}: output exists and is not a file an earlier usvlog demo wrote "
                                        f"(not in {self.out / MARKER} with this content; use --force to overwrite)")

    def claim(self, *names: str) -> None:
        """Record the files (or every file under the directories) ``names`` as the demo's own."""
        from ..io.atomic import write_text_atomic  # the standard library only, kept out of --help's imports

        for name in names:
            p = self.out / name
            for f in sorted(x for x in p.rglob("*") if x.is_file()) if p.is_dir() else [p]:
                self.files[self._rel(f)] = _sha256(f)
        self.files = {k: v for k, v in self.files.items() if (self.out / k).is_file()}
        text = json.dumps({"written_by": "usvlog demo", "files": dict(sorted(self.files.items()))}, indent=1)
        write_text_atomic(self.out / MARKER, text + "\n", force=True)


class _Stages:
    """Numbers the demo's stages as they run."""

    def __init__(self):
        self.n = 0

    def __call__(self, msg: str) -> None:
        self.n += 1
        stage(f"[{self.n}] {msg}")


def run(args) -> int:
    from ..check import check_log  # heavy: imported only when the verb runs
    from ..estimate import EstimateSettings, estimate
    from ..io.export import export_log
    from ..io.mcap import read_log, write_log
    from ..log.summary import format_summary, summarize
    from ..sim.simulate import SimSettings, simulate
    from ..trials import find_manoeuvres

    out = Path(args.out)
    settings = SimSettings(duration_s=args.duration_s, current_mps=0.2, current_dir_deg=60.0)  # checked first
    if out.exists() and not out.is_dir():
        raise StorageError(f"{out}: output is not a directory")
    own = Owned(out)
    own.check(args.force)  # before any work: outputs that are not the demo's own need --force
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise StorageError(f"{out}: cannot create directory ({err.strerror})") from err
    step = _Stages()
    raw = out / "excitation.mcap"
    step(f"simulate: excitation run, {args.duration_s:.0f} s, 0.2 m/s current -> {raw}")
    write_log(simulate("excitation", settings, seed=args.seed), raw, force=True)
    own.claim("excitation.mcap")
    step("inspect")
    log = raw_log = read_log(raw)   # read once: identification fits this same run below
    print(format_summary(summarize(log)))
    step("check: sensors, heading, thrusters and run content (usvlog check)")
    print(check_log(log).table())
    _import_stage(log, out, step)
    own.claim("merged.csv", "imported.mcap")
    est_path = out / "estimate.mcap"
    step(f"estimate: dynamic model + current, EKF + RTS smoother -> {est_path}")
    result = estimate(log, EstimateSettings(model="dynamic"))
    print(result.report.format())
    log = result.to_log(log)
    write_log(log, est_path, force=True)
    own.claim("estimate.mcap")
    step("manoeuvres: the standard manoeuvres found in the run (usvlog manoeuvres)")
    tr = log.time_range()
    print(find_manoeuvres(result.state, log["/thrust/command"], int(tr[0]) if tr else 0).format())
    step(f"export -> {out / 'csv'}")
    export_log(log, out / "csv", fmt="csv", force=True)
    own.claim("csv")
    step("identify: output error on the simulated run (true vs identified)")
    identified = identify_stage(raw_log, out, fit_on=log)
    own.claim("identified.toml")
    replayed = _control_stages(out, step)
    own.claim("paper-circle.mcap", "paper-circle-replay.mcap")
    _view_stages(out, step, excitation=identified, replayed=replayed)
    own.claim("demo.rrd", "estimate.rrd", "report")
    stage(f"done: results in {out}/")
    return 0


def _import_stage(log, out: Path, step) -> None:
    """The run as one merged logger CSV, imported again: the same samples come back."""
    import numpy as np  # heavy: imported only when the verb runs

    # heavy (numpy, pandas, numba): imported only when the verb runs
    from ..io.importers import import_file
    from ..io.mcap import read_log
    from ..io.mergedcsv import write_merged_csv
    from ..model.frames import ssa

    merged = out / "merged.csv"
    imported = out / "imported.mcap"
    step(f"import: the run as one merged logger CSV {merged} -> usvlog import -> {imported}")
    write_merged_csv(log, merged, force=True)
    thrust_unit = str(log["/thrust/command"]["unit"].iloc[0])
    res = import_file(merged, vessel=log.vessel, thrust_unit=thrust_unit, out=imported, force=True)
    back = read_log(imported)
    for topic, col in (("/gnss/fix", "lat_deg"), ("/gnss/fix", "lon_deg"), ("/compass/heading", "heading_rad"),
                       ("/thrust/command", "left")):
        a, b = log[topic], back[topic]
        same_t = len(a) == len(b) and bool((a.index == b.index).all())
        err = float(np.max(np.abs(ssa(b[col].to_numpy() - a[col].to_numpy())) if col == "heading_rad" else
                           np.abs(b[col].to_numpy() - a[col].to_numpy()))) if same_t else float("nan")
        print(f"import    {topic:<18} {col:<12} {len(b):>7} of {len(a):>7} samples, same times: {same_t}, "
              f"max |diff| {err:.3g}")
    print(f"import    skipped records: {dict(res.report.skipped) or 'none'}")


def identify_stage(log, out: Path, fit_on=None):
    """Identify the model from ``log``, write ``identified.toml``, print the parameters and the
    verdict; returns ``fit_on`` (default ``log``) with the ``/identify/fit`` channel and the result."""
    from ..api import fit_log  # heavy: imported only when the verb runs
    from ..identify import Identifier
    from ..io.atomic import write_text_atomic

    idf = Identifier("output-error").fit([log])
    write_text_atomic(out / "identified.toml", idf.to_vessel().to_toml(), force=True)
    true = log.vessel.params.to_dict()
    ee = idf.equation_error_.to_dict()
    print("parameter      true  identified   +-stderr   error %   (equation error)")
    for k in PARAM_NAMES:
        v = getattr(idf.params_, k)
        print(f"  {k:<5} {true[k]:9.4g} {v:11.5g} {idf.stderr_[k]:10.2g} {100 * (v / true[k] - 1):+8.2f}"
              f"   ({ee[k]:.4g})")
    cn, ce = idf.current_[0]
    print(f"  current north {cn:+.3f} east {ce:+.3f} m/s (true +0.100 +0.173)")
    fp = idf.validation_fit_percent_()
    print(f"  validation on the held-out last 30 %: fit u {fp['u']:.1f} %, v {fp['v']:.1f} %, r {fp['r']:.1f} %")
    print(f"  verdict: {idf.verdict_}")
    for v in idf.reasons_:
        print(f"  - {v}")
    return fit_log(idf, log if fit_on is None else fit_on)


def _control_stages(out: Path, step):
    """Section IV closed loop, gain check, replay with a baseline what-if; returns the replayed log."""
    from ..control.gains import check_gains  # heavy: imported only when the verb runs
    from ..io.mcap import write_log
    from ..replay import replay_log
    from ..sim.closed_loop import simulate_scenario
    from ..sim.scenario import load_scenario

    scen = load_scenario("paper-circle")
    circ = out / "paper-circle.mcap"
    step(f"simulate paper-circle: the paper's Section IV closed loop, {scen.sim.duration_s:.0f} s -> {circ}")
    log = simulate_scenario(scen)
    write_log(log, circ, force=True)
    log.source = str(circ)   # the file it now is, as read_log would name it
    step("gains: Theorem 3.1 for the paper's gains")
    chk = check_gains(scen.sim.vessel.params, scen.gains)
    print(chk.verdict)
    print("eigenvalues of A_e: " + ", ".join(f"{z.real:.4f}{z.imag:+.4f}j" for z in chk.eigenvalues))
    rep = out / "paper-circle-replay.mcap"
    step(f"replay paper-circle open loop, what-if with the PI/PID baseline -> {rep}")
    res = replay_log(log, scen, whatif_controller="baseline")   # the run just written, not read back
    write_log(res.log, rep, force=True)
    res.log.source = str(rep)
    print(format_metrics(res.metrics))
    return res.log


def _view_stages(out: Path, step, *, excitation, replayed) -> None:
    """Rerun recordings of both runs and the report with the paper's figures."""
    from ..view.report import write_report  # heavy: imported only when the verb runs
    from ..view.rrd import to_rrd

    rrd = out / "demo.rrd"
    step(f"view: paper-circle replay (track, guidance, what-if, errors) -> {rrd} "
          f"(open it with: rerun {rrd})")
    to_rrd(replayed, rrd, names=["paper_circle"], force=True)
    est_rrd = out / "estimate.rrd"
    step(f"view: excitation run with its estimate and identification fit -> {est_rrd}")
    to_rrd(excitation, est_rrd, names=["excitation"], force=True)
    rep = out / "report"
    step(f"report: the excitation run (raw GPS vs estimate, identification and its verdict) -> "
         f"{rep / 'report.html'}; the paper's Fig. 1, 2, 5 for paper-circle (what-if: baseline PI/PID) -> "
         f"{rep / 'paper-circle' / 'report.html'}")
    write_report(replayed, rep / "paper-circle", force=True)
    write_report(excitation, rep, force=True,
                 links=[("paper-circle/report.html", "paper-circle replay: the paper's Fig. 1, 2 and 5")])
