"""Campaign drift test: false alarms on seasons without change, detection of a 10 % step.

    python benchmarks/bench_drift.py [--seasons 200] [--e2e 20] [--day-sd 0] [--against REV] [--seed 1]

Two kinds of season, each one vessel with 4-10 run dates (1-14 days apart) and 1-4 runs a
date (mostly 2-4):

* **parameter level** (``--seasons``, fast): per run and parameter, ``truth * (1 + s e)``
  with ``e`` Student-t with 4 degrees of freedom scaled to unit variance (the occasional
  3-5 sigma run the real identification shows), ``s`` the parameter's run-to-run relative
  scatter (measured below) times a per-run excitation factor (log-normal, 30 %). The stated
  standard error is that sigma divided by an overconfidence factor: 1 (honest) for a quarter
  of the estimates, else log-normal about 2.5 (1.5-4 typically) — what 10 real 90 s runs
  showed (their scatter was 1.5-3.1 times their median stated error: Iz 1.1 %, d11 1.7 %,
  d22 18 %, d33 1.1 %, xg 6.5 % of the value; m, fixed in those runs, is given 3 %). All six
  parameters are tested, so a season is 6 parameters x (dates - 1) candidate changes.
  ``--day-sd F`` adds a common offset per date of F times each parameter's scatter (weather
  of the day: runs of one date are then not independent; the test assumes they are).
* **end to end** (``--e2e N``, ~0.25 s a run): N seasons without change and N with a +10 %
  step in d11, 4-6 dates x 2-3 runs of 90 s ``excitation`` runs (GPS 0.5 m, compass 1 deg,
  the campaign test's boat ``alpha``), each identified by ``usvlog.identify`` as the
  campaign does (output error, 25 % held out, m fixed at 33 kg, no current): 5 parameters.

A false alarm is a season in which any parameter is reported changed (the rate is per
vessel). A detection is the stepped parameter reported changed; "at the right dates" also
names the two dates the step fell between. Rates are printed with 95 % Clopper-Pearson
intervals. ``--against REV`` runs the parameter-level seasons through ``drift.py`` of an older
commit too (each parameter tested alone, as that version did), for comparison.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
import types
from pathlib import Path

import numpy as np
from scipy import stats

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests" / "campaign"))

from usvlog.campaign.drift import vessel_drift  # noqa: E402

DAY = 86_400 * 10**9
T0 = 1_780_300_800 * 10**9   # 2026-06-01 00:00 UTC
TRUTH = {"m": 33.0, "Iz": 10.0, "d11": 5.0, "d22": 5.0, "d33": 5.0, "xg": 0.1}
REL_SD = {"m": 0.03, "Iz": 0.011, "d11": 0.017, "d22": 0.18, "d33": 0.011, "xg": 0.065}
STEP = 0.10


def ci(k: int, n: int) -> str:
    lo, hi = stats.binomtest(k, n).proportion_ci(0.95, method="exact")
    return f"{100 * k / n:5.1f} % [{100 * lo:4.1f}, {100 * hi:5.1f}] ({k}/{n})"


def season_layout(rng, dates=(4, 10), runs=(1, 2, 3, 4), p_runs=(0.1, 0.3, 0.3, 0.3)):
    """Run start times (ns) and each run's date index."""
    nd = int(rng.integers(dates[0], dates[1] + 1))
    day = np.cumsum(rng.integers(1, 15, nd))
    per = rng.choice(runs, nd, p=p_runs)
    di = np.repeat(np.arange(nd), per)
    minutes = np.concatenate([np.sort(rng.integers(0, 480, k)) for k in per])
    t = T0 + day[di] * DAY + (9 * 60 + minutes) * 60 * 10**9
    return t, di


def step_gap(rng, di):
    """A date gap with >= 2 runs on each side (the first date after the step), or None."""
    nd = di.max() + 1
    ok = [g for g in range(1, nd) if (di < g).sum() >= 2 and (di >= g).sum() >= 2]
    return int(rng.choice(ok)) if ok else None


def param_season(rng, step_in: str | None, day_sd: float):
    """{name: (x, se)}, t_ns, the first date index after the step (or None)."""
    while True:
        t, di = season_layout(rng)
        gap = step_gap(rng, di) if step_in else None
        if not step_in or gap is not None:
            break
    n = len(t)
    out = {}
    for p, truth in TRUTH.items():
        sd = REL_SD[p] * truth * np.exp(rng.normal(0.0, 0.3, n))
        e = rng.standard_t(4, n) / np.sqrt(2.0)
        day = rng.normal(0.0, day_sd * REL_SD[p] * truth, di.max() + 1)[di]
        true = np.full(n, truth) * (1.0 + STEP * (di >= gap) if p == step_in else 1.0)
        x = true + sd * e + day
        over = np.where(rng.random(n) < 0.25, 1.0, np.maximum(1.0, np.exp(rng.normal(np.log(2.5), 0.3, n))))
        out[p] = (x, sd / over)
    return out, t, di, gap


def flagged(res: dict) -> set[str]:
    return {p for p, d in res.items() if d.drifted}


def right_dates(d, t, di, gap) -> bool:
    c = d.change
    return (c is not None and d.drifted and c.last_before_ns // DAY == t[di == gap - 1][0] // DAY
            and c.first_after_ns // DAY == t[di == gap][0] // DAY)


def old_module(rev: str):
    src = subprocess.run(["git", "show", f"{rev}:usvlog/campaign/drift.py"], cwd=ROOT, check=True,
                         capture_output=True, text=True).stdout
    mod = types.ModuleType("old_drift")
    sys.modules["old_drift"] = mod
    exec(compile(src, f"{rev}:drift.py", "exec"), mod.__dict__)
    return mod


def parameter_level(args) -> None:
    rng = np.random.default_rng(args.seed)
    old = old_module(args.against) if args.against else None
    n = args.seasons
    print(f"parameter level: {n} seasons per case, 6 parameters, 4-10 dates, 1-4 runs a date"
          f"{f', day offsets {args.day_sd:g} x scatter' if args.day_sd else ''}")
    t0 = time.perf_counter()
    alarms = old_alarms = 0
    tests = []
    for _ in range(n):
        params, t, di, _ = param_season(rng, None, args.day_sd)
        res = vessel_drift(t, params)
        alarms += bool(flagged(res))
        tests.append(next(d.change.n_dates for d in res.values() if d.change) if any(
            d.change for d in res.values()) else 0)
        if old is not None:
            old_alarms += any(old.parameter_drift(p, t, x, se).drifted for p, (x, se) in params.items())
    print(f"  no change: false alarms (any parameter)  {ci(alarms, n)}; "
          f"{np.mean(tests):.1f} candidate dates a season on average")
    if old is not None:
        print(f"  no change, drift.py of {args.against} (each parameter alone): {ci(old_alarms, n)}")
    for p in TRUTH:
        hit = right = other = 0
        for _ in range(n):
            params, t, di, gap = param_season(rng, p, args.day_sd)
            res = vessel_drift(t, params)
            f = flagged(res)
            hit += p in f
            right += right_dates(res[p], t, di, gap)
            other += bool(f - {p})
        print(f"  +10 % step in {p:3s} ({100 * REL_SD[p]:4.1f} % scatter): detected {ci(hit, n)}, "
              f"at the right dates {ci(right, n)}; another parameter flagged {ci(other, n)}")
    print(f"  ({time.perf_counter() - t0:.1f} s)")


def end_to_end(args) -> None:
    from usvlog.cli.common import one_blas_thread

    one_blas_thread()
    import dataclasses
    import datetime as dt

    from season import M_KG, vessels

    import usvlog
    from usvlog.sim.simulate import SensorSettings, SimSettings, simulate

    base = vessels()["alpha"]
    sens = SensorSettings(gps_noise_m=0.5, compass_noise_deg=1.0)
    rng = np.random.default_rng(args.seed + 1)
    names = [p for p in TRUTH if p != "m"]
    n = args.e2e
    print(f"end to end: {n} seasons per case, 90 s excitation runs identified as the campaign does "
          f"({', '.join(names)}; m fixed)")
    t0 = time.perf_counter()
    seed = 5000
    counts = {"none": 0, "hit": 0, "right": 0, "other": 0}
    runs = unusable = 0
    for case in ("none", "d11"):
        for _ in range(n):
            while True:
                t, di = season_layout(rng, dates=(4, 6), runs=(2, 3), p_runs=(0.5, 0.5))
                gap = step_gap(rng, di) if case == "d11" else None
                if case == "none" or gap is not None:
                    break
            vals = {p: ([], []) for p in names}
            t_ok: list[int] = []
            for ti, d in zip(t, di):
                factor = 1.0 + STEP if gap is not None and d >= gap else 1.0
                v = dataclasses.replace(base, params=dataclasses.replace(base.params, d11=base.params.d11 * factor))
                start = dt.datetime.fromtimestamp(int(ti) / 1e9, tz=dt.UTC).isoformat()
                seed += 1
                log = simulate("excitation", SimSettings(vessel=v, duration_s=90.0, sensors=sens, start_utc=start),
                               seed=seed)
                runs += 1
                try:
                    idf = usvlog.identify(log, None, method="output-error", holdout=0.25, fix={"m": M_KG},
                                          current=False)
                except usvlog.UsvlogError:   # unusable: the campaign leaves the run out too
                    unusable += 1
                    continue
                t_ok.append(ti)
                for p in names:
                    se = idf.stderr_.get(p)
                    vals[p][0].append(getattr(idf.params_, p))
                    vals[p][1].append(np.nan if se is None else se)
            res = vessel_drift(np.array(t_ok), {p: (np.array(x), np.array(s)) for p, (x, s) in vals.items()})
            f = flagged(res)
            if case == "none":
                counts["none"] += bool(f)
            else:
                counts["hit"] += "d11" in f
                counts["right"] += right_dates(res["d11"], t, di, gap)
                counts["other"] += bool(f - {"d11"})
    print(f"  no change: false alarms (any parameter)  {ci(counts['none'], n)}")
    print(f"  +10 % step in d11: detected {ci(counts['hit'], n)}, at the right dates {ci(counts['right'], n)}; "
          f"another parameter flagged {ci(counts['other'], n)}")
    print(f"  ({runs} runs, {unusable} of them unusable and left out as the campaign does; "
          f"{time.perf_counter() - t0:.0f} s)")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seasons", type=int, default=200)
    ap.add_argument("--e2e", type=int, default=20, help="end-to-end seasons per case (0: none)")
    ap.add_argument("--day-sd", type=float, default=0.0)
    ap.add_argument("--against", help="also the parameter-level seasons through drift.py of this git revision")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    if args.seasons:
        parameter_level(args)
    if args.e2e:
        end_to_end(args)


if __name__ == "__main__":
    main()
