"""Logs with every channel the viewer and the report draw, built from a simulated truth.

The estimation, identification and controller stages are built elsewhere; these logs
carry exactly their channel names and columns (from the team's channel list), filled
from a simple closed-loop simulation of the paper's plant, so the drawing can be
checked against known values.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from usvlog.io.mcap import write_log
from usvlog.log.channels import channel_spec, frame_from_columns
from usvlog.model.frames import ssa
from usvlog.sim.plant import plant_step
from usvlog.sim.simulate import (
    SensorSettings,
    SimSettings,
    field_log_from_run,
)

R_PATH = 8.0


def _closed_loop(st: SimSettings, *, kp_psi: float, kd_psi: float, speed_step_s: float):
    """Carrot-following on a circle of radius R_PATH about the origin, clockwise seen from above."""
    n = st.n_steps
    t = np.arange(n) * st.dt_s
    prm = tuple(st.vessel.params.as_array().tolist())
    thr = st.vessel.thrusters
    cn, ce = st.current_ne
    x = (*map(float, st.eta0), *map(float, st.nu0))
    states = np.empty((n, 6))
    tu_a, tr_a = np.empty(n), np.empty(n)
    ctl = {k: np.empty(n) for k in ("theta", "closest_n_m", "closest_e_m", "carrot_n_m", "carrot_e_m",
                                   "psi_ref_rad", "psi_d_rad", "r_d_radps", "r_d_dot_radps2", "u_d_mps",
                                   "u_d_dot_mps2", "u_e_mps", "psi_e_rad", "cross_track_m", "tau_u_n",
                                   "tau_r_nm", "thrust_left_n", "thrust_right_n", "cmd_left", "cmd_right")}
    sat = np.zeros(n, bool)
    for k in range(n):
        pn, pe, psi, u, v, r = x
        th = math.atan2(pe, pn)
        c_n, c_e = R_PATH * math.cos(th), R_PATH * math.sin(th)
        th_c = th + 2.0 / R_PATH
        k_n, k_e = R_PATH * math.cos(th_c), R_PATH * math.sin(th_c)
        psi_d = math.atan2(k_e - pe, k_n - pn)
        u_d = 0.4 if t[k] < speed_step_s else 0.2
        ue = u - u_d
        pse = float(ssa(psi - psi_d))
        tau_u = st.vessel.params.d11 * u_d - 20.0 * ue
        tau_r = -kp_psi * pse - kd_psi * r
        fl, fr = thr.forces_from_tau(tau_u, tau_r)
        sfl, sfr = float(thr.saturate(fl)), float(thr.saturate(fr))
        sat[k] = (sfl != fl) or (sfr != fr)
        tu, trr = thr.tau_from_forces(sfl, sfr)
        tu, trr = float(tu), float(trr)
        for key, val in (("theta", th), ("closest_n_m", c_n), ("closest_e_m", c_e), ("carrot_n_m", k_n),
                         ("carrot_e_m", k_e), ("psi_ref_rad", psi_d), ("psi_d_rad", psi_d),
                         ("r_d_radps", 0.0), ("r_d_dot_radps2", 0.0), ("u_d_mps", u_d), ("u_d_dot_mps2", 0.0),
                         ("u_e_mps", ue), ("psi_e_rad", pse),
                         ("cross_track_m", math.hypot(pn, pe) - R_PATH), ("tau_u_n", tu), ("tau_r_nm", trr),
                         ("thrust_left_n", sfl), ("thrust_right_n", sfr), ("cmd_left", sfl), ("cmd_right", sfr)):
            ctl[key][k] = val
        states[k] = x
        tu_a[k], tr_a[k] = tu, trr
        x = plant_step(x, tu, trr, prm, st.dt_s, cn, ce, True)
    ctl["saturated"] = sat
    return t, states, tu_a, tr_a, ctl


def make_view_log(duration_s: float = 90.0, seed: int = 4):
    sens = SensorSettings(gps_dropouts=((30.0, 2.0),), gps_jumps=((50.0, 25.0),))
    st = SimSettings(duration_s=duration_s, current_mps=0.1, current_dir_deg=45.0, sensors=sens,
                     eta0=(5.0, 0.0, -2.8274), nu0=(-0.1, 0.5, 0.0))
    t, states, tu, tr, ctl = _closed_loop(st, kp_psi=6.0, kd_psi=4.0, speed_step_s=45.0)
    rng = np.random.default_rng(seed)
    log = field_log_from_run(st, t, states, tu, tr, rng, producer="test", scenario="view-test", seed=seed)
    truth = log["/truth/state"]
    t_ns = truth.index.to_numpy()
    log.set("/control/state", frame_from_columns(ctl, t_ns, channel_spec("/control/state")))
    # an estimate: truth plus small errors, with one-sigma columns
    est = {}
    for c in ("n_m", "e_m", "psi_rad", "u_mps", "v_mps", "r_radps", "current_n_mps", "current_e_mps"):
        est[c] = truth[c].to_numpy() + rng.normal(0, 0.01, len(truth))
        est[c + "_std"] = np.full(len(truth), 0.05)
    est["psi_rad"] = ssa(est["psi_rad"])
    est = {"t": t_ns / 1e9 - t_ns[0] / 1e9, **est}
    log.set("/estimate/state", frame_from_columns(est, t_ns, channel_spec("/estimate/state")))
    # innovations: GPS residuals against truth; the jump is rejected
    gps = log["/gnss/fix"]
    from usvlog.model.frames import geodetic_to_ned
    gn, ge, _ = geodetic_to_ned(gps["lat_deg"].to_numpy(), gps["lon_deg"].to_numpy(), 0.0, datum=log.datum)
    tg = gps.index.to_numpy()
    k = np.searchsorted(t_ns, tg)
    rn, re_ = gn - truth["n_m"].to_numpy()[k], ge - truth["e_m"].to_numpy()[k]
    nis = (rn ** 2 + re_ ** 2) / 1.5 ** 2
    comp = log["/compass/heading"]
    tc = comp.index.to_numpy()
    kc = np.searchsorted(t_ns, tc)
    rc = ssa(comp["heading_rad"].to_numpy() - truth["psi_rad"].to_numpy()[kc])
    nisc = (rc / math.radians(2.0)) ** 2
    ti = np.concatenate([tg, tc])
    order = np.argsort(ti, kind="stable")
    inn = {"sensor": np.array(["gnss"] * len(tg) + ["compass"] * len(tc), dtype=object)[order],
           "res_0": np.concatenate([rn, rc])[order], "res_1": np.concatenate([re_, np.full(len(tc), np.nan)])[order],
           "nis": np.concatenate([nis, nisc])[order],
           "accepted": np.concatenate([nis < 13.8, nisc < 10.8])[order]}
    log.set("/estimate/innovations", frame_from_columns(inn, ti[order],
                                                        channel_spec("/estimate/innovations")))
    # a what-if run with other gains
    t2, s2, tu2, tr2, ctl2 = _closed_loop(st, kp_psi=2.0, kd_psi=1.0, speed_step_s=45.0)
    cn, ce = st.current_ne
    wi = {"n_m": s2[:, 0], "e_m": s2[:, 1], "psi_rad": ssa(s2[:, 2]), "u_mps": s2[:, 3], "v_mps": s2[:, 4],
          "r_radps": s2[:, 5], "current_n_mps": np.full(len(t2), cn), "current_e_mps": np.full(len(t2), ce),
          "tau_u_n": tu2, "tau_r_nm": tr2}
    log.set("/replay/whatif/state", frame_from_columns(wi, t_ns, channel_spec("/replay/whatif/state")))
    log.set("/replay/whatif/controller", frame_from_columns(ctl2, t_ns, channel_spec("/replay/whatif/controller")))
    # identification fit: measured vs a slightly wrong model
    step = 10
    fit = {}
    for c, cs in (("u_mps", "u_sim_mps"), ("v_mps", "v_sim_mps"), ("r_radps", "r_sim_radps"),
                  ("n_m", "n_sim_m"), ("e_m", "e_sim_m"), ("psi_rad", "psi_sim_rad")):
        y = truth[c].to_numpy()[::step]
        fit[c] = y
        fit[cs] = y * 1.03 + 0.002
    log.set("/identify/fit", frame_from_columns(fit, t_ns[::step], channel_spec("/identify/fit")))
    ang = np.linspace(0, 2 * np.pi, 181)
    poly = np.column_stack([R_PATH * np.cos(ang), R_PATH * np.sin(ang)]).round(6).tolist()
    log.meta["usvlog.path"] = {"spec": json.dumps({"type": "circle", "radius_m": R_PATH, "center_ne": [0, 0]}),
                               "polyline_ne": json.dumps(poly)}
    return log


@pytest.fixture(scope="session")
def view_log():
    return make_view_log()


@pytest.fixture(scope="session")
def view_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("viewlogs") / "circle.mcap"
    write_log(make_view_log(duration_s=20.0), path)
    return path
