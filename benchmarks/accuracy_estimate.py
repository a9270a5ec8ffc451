"""RMS errors of the estimator against simulated truth (the figures in docs/estimation.md).

    python benchmarks/accuracy_estimate.py [--duration-s 300]

Runs (seeded, as in tests/unit/test_estimate.py): kinematic, without (``sway_damping=False``,
``--no-sway-damping``) and with sway damping (the default), on a still-water excitation run
(seed 3); dynamic with current states on a run with a 0.2 m/s current towards 60 deg (seed 4);
kinematic without sway damping on a run with four 30 m GPS jumps and a 20 s dropout (seed 6),
as the table rows of docs/estimation.md say; GNSS only (no compass channel): speed and course over ground of
the kinematic model on turning runs (seeds 3, 5, 11) and on the excitation zig-zag (seed 3), at
10 and 1 Hz, and the dynamic model's (true vessel) heading, course and speed at both rates; per
run and rate the course of the best linear time-invariant smoother of the fixes fitted to the
truth (``lti_course_oracle``: roughly what a vessel-free linear smoother can reach).
``--gps-only`` prints the GNSS-only table alone.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from usvlog.estimate import EstimateSettings, build_problem, estimate  # noqa: E402
from usvlog.model.frames import ssa  # noqa: E402
from usvlog.model.vessel import default_vessel  # noqa: E402
from usvlog.sim.simulate import SensorSettings, SimSettings, simulate  # noqa: E402


def errors(frame, truth) -> dict:
    tr = truth.reindex(frame.index)

    def rms(a):
        a = np.asarray(a, float)
        a = a[np.isfinite(a)]
        return float(np.sqrt(np.mean(a ** 2))) if len(a) else math.nan

    return {"pos m": rms(np.hypot(frame["n_m"] - tr["n_m"], frame["e_m"] - tr["e_m"])),
            "psi deg": math.degrees(rms(ssa(frame["psi_rad"] - tr["psi_rad"]))),
            "u m/s": rms(frame["u_mps"] - tr["u_mps"]), "v m/s": rms(frame["v_mps"] - tr["v_mps"]),
            "r deg/s": math.degrees(rms(frame["r_radps"] - tr["r_radps"])),
            "cur_n m/s": rms(frame["current_n_mps"] - tr["current_n_mps"]),
            "cur_e m/s": rms(frame["current_e_mps"] - tr["current_e_mps"])}


def table(title, res, truth) -> None:
    print(f"\n{title}")
    s, f = errors(res.state, truth), errors(res.forward, truth)
    print("  " + " ".join(f"{k:>10s}" for k in s))
    for name, e in (("smoother", s), ("forward", f)):
        print("  " + " ".join(f"{v:10.4f}" for v in e.values()) + f"  {name}")
    print("  " + res.report.format().replace("\n", "\n  "))


def over_ground(f):
    """Speed (m/s) and course (rad) over ground from psi, u, v."""
    psi, u, v = (f[c].to_numpy() for c in ("psi_rad", "u_mps", "v_mps"))
    c, s = np.cos(psi), np.sin(psi)
    return np.hypot(c * u - s * v, s * u + c * v), np.arctan2(s * u + c * v, c * u - s * v)


def gps_only(d: float) -> None:
    print("\nGNSS only (no compass channel): RMS speed over ground, course where the true speed > 0.5 m/s, heading")
    print(f"  {'run':28s} {'model':9s} {'GNSS':>6s} {'sog m/s':>8s} {'cog deg':>8s} {'psi deg':>8s}")
    for scen, seed in (("turns", 3), ("turns", 5), ("turns", 11), ("excitation", 3)):
        for rate in (10.0, 1.0):
            log = simulate(scen, SimSettings(duration_s=d, sensors=SensorSettings(gps_rate_hz=rate)), seed=seed)
            truth = log["/truth/state"]
            del log.channels["/compass/heading"]
            for model in ("kinematic", "dynamic"):
                res = estimate(log, EstimateSettings(model=model))
                tr = truth.reindex(res.state.index)
                (sog, cog), (sog_t, cog_t) = over_ground(res.state), over_ground(tr)
                m = sog_t > 0.5
                e = errors(res.state, truth)
                rms_sog = float(np.sqrt(np.mean((sog - sog_t) ** 2)))
                rms_cog = math.degrees(float(np.sqrt(np.mean(ssa(cog - cog_t)[m] ** 2))))
                print(f"  {scen + ' seed ' + str(seed):28s} {model:9s} {rate:4.0f}Hz {rms_sog:8.4f} {rms_cog:8.2f} "
                      f"{e['psi deg']:8.2f}")
            print(f"  {'':28s} {'LTI fit':9s} {rate:4.0f}Hz {'':8s} {lti_course_oracle(log, truth):8.2f}"
                  "  (oracle: linear FIR of the fixes fitted to the truth; 2nd half)")


def lti_course_oracle(log, truth, half_width_s: float = 12.0) -> float:
    """Course RMS (deg, true speed > 0.5 m/s) of the best linear time-invariant smoother of the
    GNSS fixes: one FIR of +-half_width_s on n and e, fitted to the true NED velocity by least
    squares on the first half of the run, scored on the second: an oracle for what a linear,
    vessel-free smoother of the fixes can reach in steady state (not a strict bound: another
    stretch of the run, and at 1 Hz its +-12 s window is short)."""
    pb = build_problem(log, EstimateSettings(gps_only=True), default_vessel())
    g = pb.mkind == 0
    n, e = pb.mz[g, 0], pb.mz[g, 1]
    tr = truth.reindex(pb.m_t_ns[g])
    sog_t, cog_t = over_ground(tr)
    vn, ve = sog_t * np.cos(cog_t), sog_t * np.sin(cog_t)
    L = int(round(half_width_s / (float(np.median(np.diff(pb.m_t_ns[g]))) * 1e-9)))
    idx = np.arange(L, len(n) - L)
    win = idx[:, None] + np.arange(-L, L + 1)
    An, Ae = n[win] - n[idx, None], e[win] - e[idx, None]
    h = len(idx) // 2
    w = np.linalg.lstsq(np.vstack([An[:h], Ae[:h]]), np.concatenate([vn[idx][:h], ve[idx][:h]]), rcond=None)[0]
    pn, pe, tn, te = An[h:] @ w, Ae[h:] @ w, vn[idx][h:], ve[idx][h:]
    m = np.hypot(tn, te) > 0.5
    return math.degrees(float(np.sqrt(np.mean(ssa(np.arctan2(pe, pn) - np.arctan2(te, tn))[m] ** 2))))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--duration-s", type=float, default=300.0)
    ap.add_argument("--gps-only", action="store_true", help="only the GNSS-only table")
    args = ap.parse_args()
    d = args.duration_s
    if args.gps_only:
        gps_only(d)
        return
    log = simulate("excitation", SimSettings(duration_s=d), seed=3)
    table("kinematic model without sway damping, still water (seed 3)",
          estimate(log, EstimateSettings(sway_damping=False)), log["/truth/state"])
    table("kinematic model with sway damping, still water (seed 3)",
          estimate(log, EstimateSettings(sway_damping=True)), log["/truth/state"])
    log = simulate("excitation", SimSettings(duration_s=d, current_mps=0.2, current_dir_deg=60.0), seed=4)
    table("dynamic model + current states, 0.2 m/s current (seed 4)",
          estimate(log, EstimateSettings(model="dynamic")), log["/truth/state"])
    sens = SensorSettings(gps_jumps=((40.0, 30.0), (95.0, 30.0), (170.0, 30.0), (230.0, 30.0)),
                          gps_dropouts=((120.0, 20.0),))
    log = simulate("excitation", SimSettings(duration_s=d, sensors=sens), seed=6)
    res = estimate(log, EstimateSettings(sway_damping=False))
    table("kinematic without sway damping, four 30 m GPS jumps and a 20 s dropout (seed 6)", res, log["/truth/state"])
    t0 = int(res.state.index[0])
    win = res.state.loc[t0 + int(119e9):t0 + int(141e9)]
    tr = log["/truth/state"].reindex(win.index)
    err = np.hypot(win["n_m"] - tr["n_m"], win["e_m"] - tr["e_m"])
    print(f"  largest position error through the dropout: smoother {err.max():.2f} m, "
          f"stated one-sigma at its middle {win['n_m_std'].max():.2f} m")
    gps_only(d)


if __name__ == "__main__":
    main()
