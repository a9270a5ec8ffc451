"""How well can any linear smoother recover the yaw rate from the compass alone?

    python benchmarks/estimate_limits.py [--duration-s 300]

On seeded excitation runs (as in benchmarks/accuracy_estimate.py) the Wiener smoother
error of r from a 2 deg, 20 Hz compass, given the true spectrum of r (its periodogram:
an oracle no estimator has; and that periodogram smoothed over 5 bins), with the
kinematic smoother's figures beside it: without and with the yaw-moment steps of the
thrust record (``yaw_jump_radps2``). The Wiener error bounds every linear
time-invariant smoother of the compass, whatever its process model; only knowing when
r_dot jumps (a time-varying process noise) gets below it.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from usvlog.estimate import EstimateSettings, estimate  # noqa: E402
from usvlog.estimate.settings import Q_R_KINEMATIC_NO_JUMPS  # noqa: E402
from usvlog.sim.simulate import SimSettings, simulate  # noqa: E402


def wiener_rms(x: np.ndarray, dt: float, noise_var: float, smooth_bins: int) -> float:
    """RMS error of the non-causal Wiener estimate of x from white measurements of its
    integral (noise_var per sample, sample step dt)."""
    n = len(x)
    f = np.fft.rfftfreq(n, dt)
    sx = np.abs(np.fft.rfft(x - x.mean())) ** 2 * dt / n            # two-sided density
    sx = np.convolve(sx, np.ones(smooth_bins) / smooth_bins, mode="same")
    sn = noise_var * dt * (2 * np.pi * f) ** 2                       # on the derivative
    err = sx * sn / (sx + sn + 1e-300)
    return math.sqrt(2 * err[1:].sum() * (f[1] - f[0]))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--duration-s", type=float, default=300.0)
    d = ap.parse_args().duration_s
    print("r RMS error, deg/s: Wiener (oracle periodogram / smoothed 5 bins), kinematic smoother")
    for seed in (3, 4, 5):
        log = simulate("excitation", SimSettings(duration_s=d), seed=seed)
        truth, comp = log["/truth/state"], log["/compass/heading"]
        sd = float(comp["std_rad"].iloc[0])
        dt = float(np.median(np.diff(np.asarray(comp.index, np.int64)))) * 1e-9
        r = truth["r_radps"].reindex(comp.index).to_numpy()
        errs = []
        for s in (EstimateSettings(yaw_jump_radps2=0.0, q_r=Q_R_KINEMATIC_NO_JUMPS), EstimateSettings()):
            res = estimate(log, s)
            tr = truth.reindex(res.state.index)
            errs.append(math.degrees(float(np.sqrt(np.mean((res.state["r_radps"] - tr["r_radps"]) ** 2)))))
        w1, w5 = (math.degrees(wiener_rms(r, dt, sd ** 2, k)) for k in (1, 5))
        print(f"  seed {seed}: {w1:.2f} / {w5:.2f}   kinematic smoother without / with the steps "
              f"{errs[0]:.2f} / {errs[1]:.2f}")


if __name__ == "__main__":
    main()
