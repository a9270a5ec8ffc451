"""Does exit 0 mean the model can be trusted? Random boats of the paper's structure against their truth.

Each seed draws a boat (mass 6-330 kg, its yaw inertia from its length, surge time constant 1-8 s,
sway 0.5-3 s, yaw 0.5-4 s, a centre of gravity within 8 % of its length, thrusters for 1-2.5 m/s),
a current (none, or up to 0.3 m/s), a GNSS rate (1, 2, 5 or 10 Hz, the compass at twice it) and a
run length (180, 300 or 600 s); the boat goes through the manoeuvres of the shared Otter runs
(``tests/unit/otter_like.py``; the paper vessel's thrust levels, unscaled: a heavy boat is barely
excited, as a real one driven too gently is) and is identified from the paper vessel's values with
the last 30 % held out. Printed per seed: the verdict, the candidate returned, the error of m, Iz,
d11, d33 against the truth, the smoother-bias check; at the end, how many results that were not
refused have m, Iz, d11 or d33 off the truth by more than 30 % (the share at which a standard error
makes a fit unusable).

    python benchmarks/bench_identify_honesty.py [--seeds 0 40]
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # run from a checkout
sys.path.insert(0, str(ROOT / "tests" / "unit"))  # the Otter-like manoeuvres

from otter_like import otter_like_run  # noqa: E402

from usvlog.errors import UsvlogError  # noqa: E402
from usvlog.identify import Identifier  # noqa: E402
from usvlog.model.vessel import default_vessel  # noqa: E402

KEY = ("m", "Iz", "d11", "d33")


def boat(seed: int):
    """(boat, current m/s, GNSS Hz, run s) of a seed."""
    base = default_vessel()
    rng = np.random.default_rng(seed)
    k = 10 ** rng.uniform(-0.7, 1.0)
    m = 33.0 * k
    length = k ** (1 / 3)
    iz = m * (rng.uniform(0.25, 0.45) * length) ** 2
    tu, tv, tr = rng.uniform(1, 8), rng.uniform(0.5, 3), rng.uniform(0.5, 4)
    p = replace(base.params, m=m, Iz=iz, d11=m / tu, d22=m / tv, d33=iz / tr, xg=rng.uniform(-0.08, 0.08) * length)
    fwd = p.d11 * rng.uniform(1.0, 2.5) / 2
    thr = replace(base.thrusters, arm_m=0.3 * length, forward_n=fwd, reverse_n=0.6 * fwd)
    cur = float(rng.choice([0.0, rng.uniform(0.05, 0.3)]))
    return (replace(base, name="random", params=p, thrusters=thr), cur, float(rng.choice([1.0, 2.0, 5.0, 10.0])),
            float(rng.choice([180.0, 300.0, 600.0])))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, nargs=2, default=(0, 40), metavar=("FROM", "TO"))
    args = ap.parse_args()
    trusted_wrong, trusted, refused = [], 0, 0
    for seed in range(*args.seeds):
        b, cur, gps, dur = boat(seed)
        log = otter_like_run(b, duration_s=dur, seed=seed, current_mps=cur, gps_rate_hz=gps)
        try:
            idf = Identifier(holdout=0.3).fit(log, replace(default_vessel(), thrusters=b.thrusters))
        except UsvlogError as err:
            refused += 1
            print(f"{seed:3d} refused: {str(err)[:100]}", flush=True)
            continue
        err = {k: getattr(idf.params_, k) / getattr(b.params, k) - 1.0 for k in KEY}
        bias = " ".join(f"{k}{100 * v:+.0f}" for k, v in idf.smoother_bias_.items() if k in KEY)
        print(f"{seed:3d} GNSS {gps:4.0f} Hz {dur:4.0f} s {idf.verdict_:20s} {idf.chosen_.start.name[:40]:40s} "
              + " ".join(f"{k} {100 * v:+7.1f} %" for k, v in err.items()) + f" | bias {bias}", flush=True)
        if idf.verdict_ == "unusable":
            refused += 1
            continue
        trusted += 1
        if any(abs(v) > 0.3 for v in err.values()):
            trusted_wrong.append(seed)
    print(f"not refused: {trusted}, refused: {refused}; not refused with m, Iz, d11 or d33 more than 30 % off the "
          f"truth: {len(trusted_wrong)} (seeds {trusted_wrong})")


if __name__ == "__main__":
    main()
