"""Identification speed on a 1-hour log: equation error and output error (prints figures).

Each figure is the whole ``usvlog.api.identify`` call (the ``usvlog identify`` verb on a log
already in memory: the fit and the vessel TOML written), CPU seconds of this process and wall
seconds, with the load average (the machine may be shared: CPU seconds are the figure to
compare, wall seconds grow with the load). BLAS runs in one thread, as the verb runs it (set
``OPENBLAS_NUM_THREADS`` to choose otherwise). The numba kernels are compiled (or loaded from
their cache) by a warm-up fit on a 2-minute log first, not counted.
Output error includes everything it does by default: its candidates fitted on the first 70 %,
their validation on the last 30 %, and the refit of the chosen one on all the data; it is timed
twice, on one core (``USVLOG_THREADS=1``) and as the verb runs by default (with a spare CPU the
candidates are fitted two at a time in threads): the same numbers, wall time falls only where
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

    python benchmarks/bench_identify.py [--duration-s 3600] [--model paper|extended|both]
"""

from __future__ import annotations

import argparse
import os
import sys  # noqa: E402
import tempfile
import time
from pathlib import Path  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout

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


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--duration-s", type=float, default=3600.0)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--model", choices=("paper", "extended", "both"), default="paper")
    args = ap.parse_args()
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
