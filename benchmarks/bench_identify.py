"""Identification speed on a 1-hour log: equation error and output error (prints figures).

Each figure is the whole ``usvlog.api.identify`` call (the ``usvlog identify`` verb on a log
already in memory: the fit and the vessel TOML written), CPU seconds of this process and wall
seconds, with the load average (the machine may be shared: CPU seconds are the figure to
compare, wall seconds grow with the load). BLAS runs in one thread, as the verb runs it (set
``OPENBLAS_NUM_THREADS`` to choose otherwise). The numba kernels are compiled (or loaded from
their cache) by a warm-up fit on a 2-minute log first, not counted.
Output error includes everything it does by default: its candidates fitted on the first 70 %,
their validation on the last 30 %, and the refit of the chosen one on all the data; it is timed
twice, on one core (``USVLOG_THREADS=1``) and as the verb runs by default (with a spare CPU each
candidate's shooting segments in two threads): the same numbers, wall time falls only where
the second core is idle.
Before them, the shooting kernel alone (:func:`usvlog.identify.shoot.shoot` through
``Problem.simulate``) on the whole log in 300 s segments from the true states: one model
evaluation with the Jacobian rows (``simulate`` + ``jac_rows``, as each Gauss-Newton step of
the fit) and states only (as the validation's free runs), CPU and wall ms, best of 5, with
the segments in one thread and in two (the verb's default on a machine of two or more CPUs;
the same numbers: wall time falls only where the second core is idle).
``--model extended``: the extended model's candidates (output error from the paper's and from
the extended equation-error fit, and that fit), the errors those of its paper terms;
``--model both``: the paper's and the extended candidates together.

``--verb LOG.mcap``: instead, the verb as a user runs it, ``usvlog identify LOG.mcap --json
--out fit.json`` in a fresh process each time (start-up, read, fit, output): wall and CPU
seconds (user + sys) and peak RSS per run, best of ``--runs``, and the CPU of ``import
usvlog.identify`` alone (best of ``--runs``); with ``--against TREE`` (another checkout, e.g.
main's) the same for its code, the two alternated run by run (a shared machine's load hits
both alike), and whether their fit.json and stdout are byte-identical. One untimed run of
each first (numba's cache; give ``--against-cache DIR`` as that tree's NUMBA_CACHE_DIR when it
must differ from this one's).

    python benchmarks/bench_identify.py [--duration-s 3600] [--model paper|extended|both]
    python benchmarks/bench_identify.py --verb e.mcap [--runs 3] [--against TREE [--against-cache DIR]]
"""

from __future__ import annotations

import argparse
import os
import sys  # noqa: E402
import tempfile
import time
from pathlib import Path  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout

from _proc import timed_run  # noqa: E402

from usvlog.cli.common import one_blas_thread  # noqa: E402  (standard library only)

one_blas_thread()   # before numpy loads, as every usvlog verb does (OPENBLAS_NUM_THREADS set by you wins)

import numpy as np  # noqa: E402

from usvlog import api  # noqa: E402
from usvlog.identify import Identifier  # noqa: E402
from usvlog.identify.data import run_data  # noqa: E402
from usvlog.identify.output import Problem  # noqa: E402
from usvlog.model.vessel import PARAM_NAMES, VesselParams  # noqa: E402
from usvlog.sim.simulate import SimSettings, simulate  # noqa: E402


def bench_shoot(log, current) -> None:
    """Print the shooting kernel's CPU time per evaluation of the whole log (best of 5)."""
    run = run_data(log)
    prob = Problem([run], 300.0)
    tr = log["/truth/state"]
    X = tr[["n_m", "e_m", "psi_rad", "u_mps", "v_mps", "r_radps"]].to_numpy()
    tt = (tr.index.to_numpy() - run.t0_ns) / 1e9
    x0s = prob.initial_states(lambda i, t: X[min(int(np.searchsorted(tt, t - 1e-9)), len(X) - 1)])
    theta = VesselParams().as_array()
    cur = np.asarray(current, float)[None, :]

    def model(sens):
        out_x, rows = prob.simulate(theta, cur, x0s, sens=sens)
        if sens:
            prob.jac_rows(rows, out_x)

    print(f"shooting kernel, {len(prob.meas_t)} measurement times in {prob.n_seg} segments "
          f"(CPU / wall ms, best of 5):")
    for threads in (False, True):
        prob.threads = threads
        out = []
        for sens in (True, False):
            model(sens)   # compiled or loaded from the cache
            best_c = best_w = np.inf
            for _ in range(5):
                c, w = time.process_time(), time.perf_counter()
                model(sens)
                best_c, best_w = min(best_c, time.process_time() - c), min(best_w, time.perf_counter() - w)
            out.append(f"{1e3 * best_c:.1f} / {1e3 * best_w:.1f}")
        print(f"  {2 if threads else 1} thread{'s' if threads else ''}: {out[0]} with the Jacobian rows, "
              f"{out[1]} states only (load {os.getloadavg()[0]:.1f})")


def _run_child(cmd: list[str], env: dict, cwd: Path) -> tuple[float, float, float, bytes]:
    """(wall s, CPU s user + sys, peak RSS MB, stdout) of one child process."""
    r = timed_run(cmd, env, cwd)
    if r.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)}: exit {r.returncode} (cwd {cwd})")
    return r.wall_s, r.cpu_s, r.peak_rss_mb, r.stdout


def bench_verb(log: Path, runs: int, against: Path | None, against_cache: str | None) -> None:
    """Print the identify verb's wall, CPU and peak RSS (best of ``runs``, fresh processes),
    this checkout's and ``against``'s alternated, and whether their outputs are identical."""
    here = Path(__file__).resolve().parents[1]
    trees = [("this", here, os.environ.get("NUMBA_CACHE_DIR"))]
    if against is not None:
        trees.append(("against", against.resolve(), against_cache or os.environ.get("NUMBA_CACHE_DIR")))
    tmp = tempfile.TemporaryDirectory(prefix="bench-identify-verb-")
    res: dict[str, dict] = {}
    for name, tree, cache in trees:
        env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
        env["PYTHONPATH"] = str(tree)
        if cache:
            env["NUMBA_CACHE_DIR"] = cache
        cwd = Path(tmp.name) / name
        cwd.mkdir()
        res[name] = {"env": env, "cwd": cwd, "verb": [], "import": []}
    cmd = [sys.executable, "-m", "usvlog", "identify", str(log.resolve()), "--json", "--out", "fit.json", "--force"]
    imp = [sys.executable, "-c", "import time; c = time.process_time(); import usvlog.identify; "
           "print(time.process_time() - c)"]
    for r in res.values():   # numba's cache loaded (or compiled) and the bytecode written, not timed
        r["out"] = _run_child(cmd, r["env"], r["cwd"])[3]
    print(f"usvlog identify {log.name} --json --out fit.json, fresh processes, {runs} runs alternated:")
    for i in range(runs):
        for name, r in res.items():
            wall, cpu, rss, _ = _run_child(cmd, r["env"], r["cwd"])
            r["verb"].append((wall, cpu, rss))
            r["import"].append(float(_run_child(imp, r["env"], r["cwd"])[3]))
            print(f"  {name:7s} run {i + 1}: {wall:5.2f} s wall, {cpu:5.2f} s CPU, {rss:4.0f} MB peak RSS, "
                  f"import usvlog.identify {r['import'][-1]:.3f} s CPU (load {os.getloadavg()[0]:.2f})")
    for name, r in res.items():
        v = r["verb"]
        print(f"{name:7s} best: {min(x[0] for x in v):5.2f} s wall, {min(x[1] for x in v):5.2f} s CPU, "
              f"{min(x[2] for x in v):4.0f} MB; import usvlog.identify {min(r['import']):.3f} s CPU "
              f"({r['env']['PYTHONPATH']})")
    if against is not None:
        a, b = res["this"], res["against"]
        same = (a["out"] == b["out"] and (a["cwd"] / "fit.json").read_bytes() == (b["cwd"] / "fit.json").read_bytes())
        print(f"fit.json and stdout byte-identical: {'yes' if same else 'NO'}")
    tmp.cleanup()
    print(f"load average: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--duration-s", type=float, default=3600.0)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--model", choices=("paper", "extended", "both"), default="paper")
    ap.add_argument("--verb", type=Path, help="time the verb on this canonical MCAP log instead")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--against", type=Path, help="with --verb: another checkout, alternated with this one")
    ap.add_argument("--against-cache", help="with --against: its NUMBA_CACHE_DIR")
    args = ap.parse_args()
    if args.verb is not None:
        bench_verb(args.verb, args.runs, args.against, args.against_cache)
        return
    t = time.perf_counter()
    log = simulate("excitation", SimSettings(duration_s=args.duration_s, current_mps=0.2, current_dir_deg=60.0),
                   seed=args.seed)
    print(f"simulated {args.duration_s:.0f} s log in {time.perf_counter() - t:.1f} s")
    bench_shoot(log, (0.2 * np.cos(np.radians(60.0)), 0.2 * np.sin(np.radians(60.0))))
    Identifier("output-error", model=args.model).fit(  # JIT warm-up
        [simulate("excitation", SimSettings(duration_s=120.0), seed=1)])
    true = VesselParams().as_array()
    tmpdir = tempfile.TemporaryDirectory(prefix="bench-identify-")
    tmp = Path(tmpdir.name)
    saved = os.environ.get("USVLOG_THREADS")
    for method, threads in (("equation-error", saved), ("output-error", "1"), ("output-error", saved)):
        if threads is None:
            os.environ.pop("USVLOG_THREADS", None)
        else:
            os.environ["USVLOG_THREADS"] = threads
        load = os.getloadavg()[0]
        t, c = time.perf_counter(), time.process_time()
        idf = api.identify([log], tmp / f"{method}.toml", method=method, model=args.model, force=True)
        dt, dc = time.perf_counter() - t, time.process_time() - c
        err = 100 * (idf.theta_ / true - 1)
        how = "" if method == "equation-error" else f", USVLOG_THREADS={threads or 'unset'}"
        print(f"{method:15s} {dt:6.2f} s wall, {dc:6.2f} s CPU (load {load:.1f}{how})   errors %: "
              + ", ".join(f"{k} {e:+.2f}" for k, e in zip(PARAM_NAMES, err)))
        fp = idf.validation_fit_percent_()
        print(f"{'':15s} candidates: {len(idf.candidates_)}, chosen: {idf.chosen_.start.name}; validation "
              f"(last 30 %): u {fp['u']:.1f}, r {fp['r']:.1f}, track {fp['track']:.1f}; verdict: {idf.verdict_}")
        if idf.model_comparison_:
            mc = idf.model_comparison_
            print(f"{'':15s} better model: {mc['winner']} by {mc['margin']} points; returned: {mc.get('returned')}")
    if saved is None:
        os.environ.pop("USVLOG_THREADS", None)
    else:
        os.environ["USVLOG_THREADS"] = saved
    tmpdir.cleanup()
    print(f"load average: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    main()
