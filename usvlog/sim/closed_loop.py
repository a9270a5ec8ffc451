"""The compiled closed loop: plant + guidance + controller (+ the onboard EKF) of a scenario.

:func:`closed_loop` runs the plant of :func:`usvlog.sim.plant.plant_step` (euler like the
paper's Section IV, or rk4) driven by the controller; :func:`simulate_scenario` turns a
:class:`~usvlog.sim.scenario.Scenario` into a field log with sensors (``/control/state``
and the ``usvlog.path`` metadata record added).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from .._jit import njit
from ..control.gains import Gains
from ..control.law import (
    COL,
    NOUT,
    OUT_COLUMNS,
    OUT_TAU_R,
    OUT_TAU_U,
    Controller,
    control_tick,
    speed_at,
)
from ..control.paths import Path
from ..estimate import OnlineEKF
from ..estimate.settings import EstimateSettings
from ..log.channels import channel_spec, frame_from_columns
from ..log.fieldlog import FieldLog
from ..model.frames import ssa
from ..model.vessel import Vessel
from .plant import PlantStepper, plant_advance, plant_form
from .scenario import META_PATH, Scenario
from .simulate import (
    WINDOW_STEPS,
    SimSettings,
    _header_log,
    draw_sensor_noise,
    start_ns,
    window_frames,
)


@dataclass(frozen=True)
class ClosedLoopRun:
    """A closed-loop simulation: plant states at every step, controller rows at every tick."""

    t: np.ndarray          # s from start, every plant step
    states: np.ndarray     # (N, 6) [n, e, psi (continuous), u, v, r]
    tau: np.ndarray        # (N, 2) applied (tau_u, tau_r) held over each step
    tick: np.ndarray       # plant-step index of every controller tick
    ctrl: np.ndarray       # (M, NOUT) controller rows (see usvlog.control.law.OUT_COLUMNS)
    controller_input: str  # "truth" or "ekf"
    applied: np.ndarray | None = None  # (N, 2) force the plant felt (a thruster lag); None: tau

    def to_dataframe(self):
        """Plant states and applied forces at every step (index: time in s)."""
        import pandas as pd

        cols = ["n_m", "e_m", "psi_rad", "u_mps", "v_mps", "r_radps"]
        df = pd.DataFrame(self.states, columns=cols, index=pd.Index(self.t, name="t_s"))
        df["psi_rad"] = ssa(df["psi_rad"].to_numpy())
        tau = self.tau if self.applied is None else self.applied
        df["tau_u_n"], df["tau_r_nm"] = tau[:, 0], tau[:, 1]
        return df

    def controller_dataframe(self):
        """Controller rows at every tick (columns: usvlog.control.law.OUT_COLUMNS)."""
        import pandas as pd  # only for this inspection helper

        return pd.DataFrame(self.ctrl, columns=list(OUT_COLUMNS), index=pd.Index(self.t[self.tick], name="t_s"))


@njit(nogil=True)   # replay runs it beside the open-loop replay (two cores)
def _closed_loop_kernel(state0, force0, n_steps, every, dt, u_ref, dtheta, plant_prm, current_n, current_e, rk4,
                        ctrl_state, path_kind, path_prm, gains, params, settings, thrusters, ext, ext_prm):
    """Plant (``plant_step``) + controller (``control_tick``) on the true state, compiled.

    ``state0``: the initial plant state (6-tuple); the controller ticks every ``every`` plant
    steps of ``dt`` (s); ``u_ref``, ``dtheta`` per plant step; ``plant_prm`` the plant's
    parameters (PARAM_NAMES order), ``current_n``, ``current_e`` the current (m/s, NED);
    the controller arguments as :func:`usvlog.control.law.control_tick`; ``ext`` True steps
    the plant with ``plant_step_ext`` and ``ext_prm`` (extended model and thruster lag)
    instead; ``force0`` the thruster lag's force at the start ((0, 0) at rest). Returns the
    plant states (n_steps, 6), the commanded (tau_u, tau_r) (n_steps, 2), the controller rows
    and the applied (lagged) force (n_steps, 2); states, commands and controller rows stored
    by column (transposed arrays: a column's values are contiguous, for the channel frames);
    then the plant state and the lag's force after the last step, from which a run of a
    multiple of ``every`` steps goes on (:func:`closed_loop_windows`).
    """
    x = state0
    states = np.empty((6, n_steps))
    tau = np.empty((2, n_steps))
    applied = np.empty((n_steps, 2))
    force = force0
    ctrl = np.empty((NOUT, (n_steps + every - 1) // every))
    row = np.empty(NOUT)
    xa = np.empty(6)
    tu = 0.0
    tr = 0.0
    j = 0
    for k in range(n_steps):
        if k % every == 0:
            for i in range(6):
                xa[i] = x[i]
            control_tick(xa, u_ref[k], dtheta[k], every * dt, ctrl_state, path_kind, path_prm, gains, params,
                         settings, thrusters, row)
            for i in range(NOUT):
                ctrl[i, j] = row[i]
            tu = row[OUT_TAU_U]
            tr = row[OUT_TAU_R]
            j += 1
        for i in range(6):
            states[i, k] = x[i]
        tau[0, k] = tu
        tau[1, k] = tr
        x, force, au, ar = plant_advance(x, force, tu, tr, ext, plant_prm, ext_prm, dt, current_n, current_e, rk4)
        applied[k, 0] = au
        applied[k, 1] = ar
    return states.T, tau.T, ctrl.T, applied, x, force


def closed_loop(path: Path, plant: Vessel, controller: Controller, *, duration_s: float, dt_s: float,
                integrator: str, current_ne, eta0, nu0, schedule: np.ndarray, rate_hz: float,
                estimator=None) -> ClosedLoopRun:
    """Simulate plant + controller. ``estimator(k, x_true, tau) -> x_hat`` (None: the true state).

    :func:`closed_loop_windows` in one window.
    """
    ((_k0, run),) = closed_loop_windows(path, plant, controller, duration_s=duration_s, dt_s=dt_s,
                                        integrator=integrator, current_ne=current_ne, eta0=eta0, nu0=nu0,
                                        schedule=schedule, rate_hz=rate_hz, estimator=estimator)
    return run


def closed_loop_windows(path: Path, plant: Vessel, controller: Controller, *, duration_s: float, dt_s: float,
                        integrator: str, current_ne, eta0, nu0, schedule: np.ndarray, rate_hz: float,
                        estimator=None, window_ticks: int | None = None):
    """:func:`closed_loop` a window at a time (memory: a window, not the run).

    The same arguments; ``window_ticks`` controller ticks a window (None: the whole run in
    one). Yields ``(k0, run)`` per window: the plant-step index of its first step and a
    :class:`ClosedLoopRun` of its steps (``t`` from the run's start, ``tick`` indexes into
    the window); the windows joined are :func:`closed_loop`'s run, number for number. The
    ``estimator`` is called with the run's step index ``k``.
    """
    n = int(round(duration_s / dt_s))
    every = max(1, int(round(1.0 / (rate_hz * dt_s))))
    step = n if window_ticks is None else max(1, int(window_ticks)) * every
    prm = tuple(plant.params.as_array().tolist())
    ext, ext_prm = plant_form(plant)
    ext_prm = ext_prm if ext else (0.0,) * 11
    cn, ce = float(current_ne[0]), float(current_ne[1])
    rk4 = integrator == "rk4"
    x = tuple(float(a) for a in (*eta0, *nu0))
    force = (0.0, 0.0)
    controller.reset(x)
    c = controller
    stepped = None if estimator is None else _Stepped(controller, estimator, plant, dt_s, every, (cn, ce), rk4, x)
    for k0 in range(0, max(n, 1), max(step, 1)):
        k1 = min(n, k0 + step)
        t = np.arange(k0, k1) * dt_s
        u_ref = speed_at(schedule, t)
        dtheta = speed_at(schedule, t, 2) if schedule.shape[1] > 2 else np.full(k1 - k0, c.guidance.delta_theta)
        ticks = np.arange(0, k1 - k0, every)
        if stepped is not None:
            states, tau, ctrl, applied = stepped.run(k0, k1, u_ref, dtheta, len(ticks))
            yield k0, ClosedLoopRun(t, states, tau, ticks, ctrl, "ekf", applied if ext else None)
            continue
        # compiled: the same plant_step and control_tick, no Python per step
        states, tau, ctrl, applied, x, force = _closed_loop_kernel(
            x, force, k1 - k0, every, float(dt_s), u_ref, np.ascontiguousarray(dtheta), prm, cn, ce, rk4, c.cs,
            c.path.kind, c.path.prm, c.G, c.P, c.S, c.T, ext, ext_prm)
        yield k0, ClosedLoopRun(t, states, tau, ticks, ctrl, "truth", applied if ext else None)


class _Stepped:
    """The controller on an estimate: plant and controller stepped from Python, window after
    window (the plant's state, its lagged force and the command held go on between them)."""

    def __init__(self, controller: Controller, estimator, plant: Vessel, dt_s: float, every: int, current_ne,
                 rk4: bool, x):
        self.step, self.estimator = controller.step, estimator
        self.every, self.dt_ctrl = every, every * dt_s
        self.plant_step_of = PlantStepper(plant, dt_s, current_ne, rk4)
        self.x, self.tu, self.tr = x, 0.0, 0.0

    def run(self, k0: int, k1: int, u_ref: np.ndarray, dtheta: np.ndarray, n_ticks: int):
        """Steps ``k0`` to ``k1 - 1`` of the run (``u_ref``, ``dtheta`` per step of them):
        states, commanded and applied forces per step, the controller rows per tick."""
        m = k1 - k0
        states = np.empty((m, 6))
        tau = np.empty((m, 2))
        applied = np.empty((m, 2))
        ctrl = np.empty((n_ticks, NOUT))
        x, tu, tr = self.x, self.tu, self.tr
        step, estimator, every, dt_ctrl, plant_step_of = (self.step, self.estimator, self.every, self.dt_ctrl,
                                                          self.plant_step_of)
        j = 0
        for i in range(m):
            k = k0 + i
            if k % every == 0:
                row = step(estimator(k, x, (tu, tr)), u_ref[i], dt_ctrl, ctrl[j], dtheta[i])
                tu, tr = float(row[OUT_TAU_U]), float(row[OUT_TAU_R])
                j += 1
            states[i] = x
            tau[i, 0] = tu
            tau[i, 1] = tr
            x = plant_step_of(x, tu, tr)
            applied[i] = plant_step_of.applied
        self.x, self.tu, self.tr = x, tu, tr
        return states, tau, ctrl, applied


def controller_frame(rows: np.ndarray, t_ns: np.ndarray, topic: str, thrusters, unit: str):
    """Controller rows -> a usvlog.ControllerState.v1 frame (commands in ``unit``).

    The frame's columns are views of ``rows`` (no copy: rows stored by column, as the
    compiled loops return them, give contiguous columns), plus the commands and the
    saturation flag as arrays of their own.
    """
    cols = {c: rows[:, COL[c]] for c in ("theta", "closest_n_m", "closest_e_m", "carrot_n_m", "carrot_e_m",
                                         "psi_ref_rad", "psi_d_rad", "r_d_radps", "r_d_dot_radps2", "u_d_mps",
                                         "u_d_dot_mps2", "u_e_mps", "psi_e_rad", "cross_track_m", "tau_u_n",
                                         "tau_r_nm", "thrust_left_n", "thrust_right_n")}
    cols["cmd_left"] = np.asarray(thrusters.force_to_command(cols["thrust_left_n"], unit, side="left"), float)
    cols["cmd_right"] = np.asarray(thrusters.force_to_command(cols["thrust_right_n"], unit, side="right"), float)
    cols["saturated"] = rows[:, COL["saturated"]] != 0.0
    # memory: one copy of the numbers (the rows), not a second one in a pandas 2-D block
    return frame_from_columns(cols, t_ns, channel_spec(topic), copy=False)


def command_unit(thrusters) -> str:
    """The unit simulated thruster commands are written in for a thruster map.

    Parameters
    ----------
    thrusters : usvlog.model.vessel.Thrusters
        The vessel's thrusters.

    Returns
    -------
    str
        ``"newton"`` for the ``identity`` map (commands are forces, N), else
        ``"normalized"`` (commands in [-1, 1]).
    """
    return "newton" if thrusters.map == "identity" else "normalized"


def make_controller(scen: Scenario, path: Path, vessel: Vessel | None = None, gains: Gains | None = None,
                    controller: str | None = None) -> Controller:
    """The scenario's path-following controller, with optional overrides.

    Parameters
    ----------
    scen : Scenario
        Gives the guidance settings and the defaults below.
    path : usvlog.control.paths.Path
        The path to follow (local NED, m), usually ``scen.path(datum)``.
    vessel : Vessel, optional
        The controller's model; default the scenario's simulated vessel.
    gains : Gains, optional
        Default the scenario's gains.
    controller : str, optional
        ``"full"`` (the paper's law) or ``"baseline"``; default the scenario's.

    Returns
    -------
    usvlog.control.law.Controller
        A new controller (not reset: :func:`closed_loop` resets it to the initial state).
    """
    return Controller(path, vessel or scen.sim.vessel, gains or scen.gains, scen.guidance,
                      full=(controller or scen.controller) == "full")


class EKFInTheLoop:
    """The controller's state from ``usvlog.estimate.OnlineEKF`` (dynamic model with current),
    fed with the very sensor samples the log records (GPS and compass noise drawn up front
    by ``draw_sensor_noise``), predicted with the applied forces at every controller tick.

    GPS fixes are used in local NED before the log's lat/lon rounding (1e-8 deg, ~1 mm);
    compass readings are rounded to the log's 1e-4 rad like the recorded ones.
    """

    def __init__(self, st: SimSettings, t: np.ndarray, noise: dict, dt_ctrl: float):
        sn = st.sensors
        self.ekf = OnlineEKF(st.vessel, EstimateSettings(model="dynamic", current=True),
                             x0=np.array([*st.eta0, *st.nu0, 0.0, 0.0], float))
        self.dt = dt_ctrl
        keep = noise["gps_keep"]
        off = noise["gps_noise"] + noise["gps_bias"]
        for k, dn, de in noise["gps_jumps"]:
            off[k] = off[k] + (dn, de)
        # the samples by plant step, rising (arrays, not a dict a sample: memory in the run's length)
        self.gps_k, self.gps_off = noise["gps_index"][keep], off[keep]
        self.gps_var = max(sn.gps_noise_m, 0.05) ** 2
        self.compass_bias = math.radians(sn.compass_bias_deg)
        self.compass_k, self.compass_w = noise["compass_index"], noise["compass_noise"]
        self.compass_var = max(math.radians(sn.compass_noise_deg), math.radians(0.1)) ** 2
        self.next_gps = self.next_compass = 0
        self.last = -1
        self.X: list[np.ndarray] = []
        self.S: list[np.ndarray] = []

    def __call__(self, k: int, x, tau) -> np.ndarray:
        ekf = self.ekf
        if self.last >= 0:
            ekf.predict(self.dt, tau[0], tau[1])
        gk, ck = self.gps_k, self.compass_k
        for j in range(self.last + 1, k + 1):  # samples since the previous tick, at this tick's state
            if self.next_gps < len(gk) and gk[self.next_gps] == j:
                dn, de = (float(o) for o in self.gps_off[self.next_gps])
                self.next_gps += 1
                ekf.update_gnss(x[0] + dn, x[1] + de, self.gps_var)
            if self.next_compass < len(ck) and ck[self.next_compass] == j:
                w = self.compass_bias + float(self.compass_w[self.next_compass])
                self.next_compass += 1
                ekf.update_heading(float(np.round(ssa(x[2] + w), 4)), self.compass_var)
        self.last = k
        xh = ekf.x
        self.X.append(xh)
        self.S.append(np.sqrt(np.clip(np.diag(ekf.P), 0.0, None)))
        return np.ascontiguousarray(xh[:6])

    def frame(self, t_ns: np.ndarray):
        """The estimates made at the controller ticks since the last frame (all of them at the
        first), as an ``/estimate/state`` frame; they are let go.

        Parameters
        ----------
        t_ns : numpy.ndarray of int64
            The ticks' times (ns since the Unix epoch), one per call of the estimator since
            the last frame.

        Returns
        -------
        pandas.DataFrame
            Indexed by ``t_ns``: ``n_m``, ``e_m`` (m), ``psi_rad`` (rad, wrapped to
            [-pi, pi)), ``u_mps``, ``v_mps`` (m/s), ``r_radps`` (rad/s), ``current_n_mps``,
            ``current_e_mps`` (m/s), and each one's standard deviation (``<name>_std``,
            same unit) from the EKF covariance.
        """
        X, S = np.array(self.X), np.array(self.S)
        self.X, self.S = [], []
        names = ["n_m", "e_m", "psi_rad", "u_mps", "v_mps", "r_radps", "current_n_mps", "current_e_mps"]
        cols = {c: X[:, i] for i, c in enumerate(names)}
        cols["psi_rad"] = ssa(cols["psi_rad"])
        cols.update({f"{c}_std": S[:, i] for i, c in enumerate(names)})
        return frame_from_columns(cols, t_ns, channel_spec("/estimate/state"))


def scenario_windows(scen: Scenario, *, controller: str | None = None, seed: int | None = None,
                     duration_s: float | None = None, window_steps: int | None = WINDOW_STEPS):
    """A closed-loop scenario simulated a time window at a time (memory flat in the run's length).

    The sensor noise is drawn before the first window (the whole run's, small); the plant,
    the controller (and the onboard EKF) go on from window to window
    (:func:`closed_loop_windows`): the windows' frames one after another are
    :func:`simulate_scenario`'s channels, the same numbers.

    Parameters
    ----------
    scen : Scenario
    controller : {"full", "baseline"}, optional
        Default the scenario's.
    seed : int, optional
        Default the scenario's.
    duration_s : float, optional
        Default the scenario's.
    window_steps : int or None, default :data:`usvlog.sim.simulate.WINDOW_STEPS`
        Plant steps a window (rounded down to whole controller ticks, at least one); None:
        the whole run in one window.

    Returns
    -------
    log : FieldLog
        The run's log without its channels (datum, vessel, provenance, ``usvlog.path``).
    windows : iterator of dict
        Topic -> frame of the window (:func:`scenario_topics`), windows in time order.
    """
    st = scen.sim if duration_s is None else replace(scen.sim, duration_s=duration_s)
    seed = scen.seed if seed is None else seed
    ctl_name = controller or scen.controller
    path = scen.path(st.datum)
    ctl = make_controller(scen, path, controller=ctl_name)
    rng = np.random.default_rng(seed)
    t = np.arange(st.n_steps) * st.dt_s
    noise = draw_sensor_noise(st, t, rng)   # small: the sensors' samples only
    every = max(1, int(round(1.0 / (scen.guidance.rate_hz * st.dt_s))))
    ticks = None if window_steps is None else max(1, int(window_steps) // every)
    est = None if scen.controller_input == "truth" else EKFInTheLoop(st, t, noise, every * st.dt_s)
    del t
    extra = {"controller": ctl_name, "controller_input": scen.controller_input,
             "gains": scen.gains.to_dict(), "guidance": scen.guidance.to_dict(), "path": scen.path_spec,
             "speed_schedule": [list(s) for s in scen.speed], "eta0": list(st.eta0), "nu0": list(st.nu0),
             "scenario_file": scen.source}
    log = _header_log(st, producer="usvlog simulate (closed loop)", scenario=scen.name, seed=seed,
                      extra_settings=extra)
    log.meta[META_PATH] = path.metadata()
    thr = st.vessel.thrusters

    def windows():
        t0 = start_ns(st.start_utc)
        for k0, run in closed_loop_windows(
                path, st.vessel, ctl, duration_s=st.duration_s, dt_s=st.dt_s, integrator=st.integrator,
                current_ne=st.current_ne, eta0=st.eta0, nu0=st.nu0, schedule=scen.schedule,
                rate_hz=scen.guidance.rate_hz, estimator=est, window_ticks=ticks):
            frames = window_frames(st, k0, run.t, run.states, run.tau[:, 0], run.tau[:, 1], noise, run.applied)
            t_ns = t0 + np.round(run.t[run.tick] * 1e9).astype(np.int64)
            if est is not None:  # the onboard estimate the controller ran on, as a boat's log has it
                frames["/estimate/state"] = est.frame(t_ns)
            frames["/control/state"] = controller_frame(run.ctrl, t_ns, "/control/state", thr, command_unit(thr))
            yield frames

    return log, windows()


def scenario_topics(scen: Scenario) -> list[str]:
    """The channels :func:`scenario_windows` makes for ``scen``, in the log's order."""
    return ["/truth/state", "/thrust/command", "/gnss/fix", "/compass/heading",
            *(["/estimate/state"] if scen.controller_input != "truth" else []), "/control/state"]


def simulate_scenario(scen: Scenario, *, controller: str | None = None, seed: int | None = None,
                      duration_s: float | None = None) -> FieldLog:
    """Run a closed-loop scenario into a field log (sensors, truth, /control/state, usvlog.path).

    :func:`scenario_windows` in one window.
    """
    log, windows = scenario_windows(scen, controller=controller, seed=seed, duration_s=duration_s,
                                    window_steps=None)
    for frames in windows:
        for topic, frame in frames.items():
            log.set(topic, frame)
    return log
