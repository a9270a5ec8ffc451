"""Scenarios, closed-loop simulation, open-loop replay of recorded runs and what-if runs.

* :func:`simulate_scenario` runs a closed-loop scenario (``replay/*.toml``): the plant of
  ``usvlog.simulate.plant_step`` (euler like the paper's Section IV, or rk4) driven by the
  controller, sensors via ``usvlog.simulate.field_log_from_run``; adds ``/control/state``
  and the ``usvlog.path`` metadata record.
* :func:`replay_log` feeds a recorded run's estimated state (``/estimate/state``, or
  ``/truth/state`` for simulated logs) into guidance + controller at every controller tick
  (open loop) -> ``/replay/controller``, next to the recorded ``/thrust/command``; and
  simulates the given model with the chosen gains from the recorded initial state along the
  same path with the estimated current (what-if) -> ``/replay/whatif/state`` and
  ``/replay/whatif/controller``. Metrics: :class:`ReplayMetrics`.

Pure: no file I/O (scenario files are read by ``usvlog.io.config.load_scenario``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace

import numpy as np

from .channels import codec_for_topic, frame_from_columns
from .control.gains import Gains, GuidanceSettings, gains_from_dict
from .control._jit import njit
from .control.law import COL, NOUT, Controller, control_tick, speed_at
from .control.paths import Path, path_from_spec
from .errors import ConfigError, InputError
from .frames import ssa
from .log import FieldLog
from .simulate import SensorSettings, SimSettings, draw_sensor_noise, field_log_from_run, plant_step
from .vessel import Vessel, default_vessel, vessel_from_dict

META_PATH = "usvlog.path"
RESERVED_SECTIONS = {"dataset", "stages", "baseline"}  # added by regression scenarios
SECTIONS = {"scenario", "simulation", "vessel", "path", "gains", "guidance", "speed", "initial", "metrics"}


# -----------------------------------------------------------------------------
# scenario
# -----------------------------------------------------------------------------

@dataclass(frozen=True, kw_only=True)
class Scenario:
    """A closed-loop scenario (TOML in ``replay/``; see README)."""

    name: str
    description: str = ""
    kind: str = "closed-loop"
    sim: SimSettings = field(default_factory=SimSettings)
    seed: int = 0
    controller: str = "full"              # "full" (9)-(10) or "baseline" PI/PID
    controller_input: str = "truth"       # "truth" or "ekf"
    path_spec: dict = field(default_factory=lambda: {"type": "circle", "radius_m": 4.0})
    gains: Gains = field(default_factory=Gains)
    guidance: GuidanceSettings = field(default_factory=GuidanceSettings)
    speed: tuple[tuple[float, ...], ...] = ((0.0, 0.5),)   # (t_s, u_d[, delta_theta])
    metrics_start_s: float = 0.0
    source: str = ""
    doc: dict = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self):
        if self.controller not in ("full", "baseline"):
            raise ConfigError(f"{self.source}: controller {self.controller!r} is not full or baseline")
        if self.controller_input not in ("truth", "ekf"):
            raise ConfigError(f"{self.source}: controller_input {self.controller_input!r} is not truth or ekf")
        if not self.speed:
            raise ConfigError(f"{self.source}: [speed] schedule is empty")
        for r in self.speed:
            if len(r) not in (2, 3) or not all(math.isfinite(a) for a in r):
                raise ConfigError(f"{self.source}: [speed] schedule row {list(r)} is not [t_s, u_d] or "
                                  "[t_s, u_d, delta_theta] of finite numbers")
            if len(r) == 3 and not r[2] > 0:
                raise ConfigError(f"{self.source}: [speed] delta_theta {r[2]} must be > 0")
        ts = [s[0] for s in self.speed]
        if ts != sorted(ts):
            raise ConfigError(f"{self.source}: [speed] schedule times must increase")

    @property
    def schedule(self) -> np.ndarray:
        """(K, 3) rows [t_s, u_d, delta_theta] (delta_theta from [guidance] where not given)."""
        return np.array([(r[0], r[1], r[2] if len(r) > 2 else self.guidance.delta_theta)
                         for r in self.speed], dtype=float)

    def path(self, datum=None) -> Path:
        return path_from_spec(self.path_spec, datum=datum if datum is not None else self.sim.datum,
                              source=self.source or self.name)


def _check_keys(table: dict, allowed, where: str) -> None:
    unknown = set(table) - set(allowed)
    if unknown:
        raise ConfigError(f"{where} has unknown key(s) {', '.join(sorted(unknown))}")


def scenario_from_dict(doc: dict, *, source: str = "scenario", vessel: Vessel | None = None) -> Scenario:
    """Parsed scenario TOML -> :class:`Scenario`. ``vessel`` replaces ``[vessel] file = ...``."""
    for k, v in doc.items():
        if k not in SECTIONS | RESERVED_SECTIONS:
            raise ConfigError(f"{source}: unknown section [{k}]")
        if not isinstance(v, dict):
            raise ConfigError(f"{source}: [{k}] must be a table")
    sc = doc.get("scenario", {})
    _check_keys(sc, {"name", "description", "kind"}, f"{source}: [scenario]")
    kind = sc.get("kind", "closed-loop")
    if kind != "closed-loop":
        raise ConfigError(f"{source}: [scenario] kind {kind!r} is not closed-loop")
    sim = dict(doc.get("simulation", {}))
    sim_keys = {f.name for f in fields(SimSettings)} - {"vessel", "sensors", "eta0", "nu0", "datum"}
    _check_keys(sim, sim_keys | {"seed", "controller", "controller_input", "sensors"}, f"{source}: [simulation]")
    sens = sim.pop("sensors", {})
    _check_keys(sens, {f.name for f in fields(SensorSettings)}, f"{source}: [simulation.sensors]")
    seed = sim.pop("seed", 0)
    controller = sim.pop("controller", "full")
    cinput = sim.pop("controller_input", "truth")
    if vessel is None:
        vdoc = doc.get("vessel")
        if vdoc is None:
            vessel = default_vessel()
        else:
            if "file" in vdoc:
                raise ConfigError(f"{source}: [vessel] file = ... must be resolved by the loader")
            _check_keys(vdoc, {"name", "model", "thrusters"}, f"{source}: [vessel]")
            vessel = vessel_from_dict(vdoc, source=f"{source} [vessel]")
    init = doc.get("initial", {})
    _check_keys(init, {"eta", "nu"}, f"{source}: [initial]")
    speed = doc.get("speed", {})
    _check_keys(speed, {"schedule", "u_d"}, f"{source}: [speed]")
    if "schedule" in speed:
        sched = speed["schedule"]
    elif "u_d" in speed:
        sched = [[0.0, speed["u_d"]]]
    else:
        raise ConfigError(f"{source}: [speed] needs schedule = [[t_s, u_d], ...] or u_d")
    try:
        sched_t = tuple(tuple(float(a) for a in row) for row in sched)
    except (TypeError, ValueError) as err:
        raise ConfigError(f"{source}: [speed] schedule must be a list of [t_s, u_d] rows") from err
    metrics = doc.get("metrics", {})
    _check_keys(metrics, {"start_s"}, f"{source}: [metrics]")
    if "path" not in doc:
        raise ConfigError(f"{source}: no [path] table")
    gains, guid = gains_from_dict(doc, source)
    try:
        st = SimSettings(vessel=vessel, sensors=SensorSettings(**{k: _tuples(v) for k, v in sens.items()}),
                         eta0=tuple(float(a) for a in init.get("eta", (0.0, 0.0, 0.0))),
                         nu0=tuple(float(a) for a in init.get("nu", (0.0, 0.0, 0.0))), **sim)
        if len(st.eta0) != 3 or len(st.nu0) != 3:
            raise ConfigError("[initial] eta and nu need 3 numbers each")
        scen = Scenario(name=str(sc.get("name", source)), description=str(sc.get("description", "")),
                        kind=kind, sim=st, seed=int(seed), controller=controller, controller_input=cinput,
                        path_spec=dict(doc["path"]), gains=gains, guidance=guid, speed=sched_t,
                        metrics_start_s=float(metrics.get("start_s", 0.0)), source=source, doc=doc)
    except (TypeError, ValueError) as err:
        if isinstance(err, ConfigError) and str(err).startswith(source):
            raise
        raise ConfigError(f"{source}: {err}") from err
    scen.path()  # validate the path now
    return scen


def _tuples(v):
    return tuple(tuple(x) for x in v) if isinstance(v, list) else v


# -----------------------------------------------------------------------------
# closed loop
# -----------------------------------------------------------------------------

@dataclass(frozen=True)
class ClosedLoopRun:
    """A closed-loop simulation: plant states at every step, controller rows at every tick."""

    t: np.ndarray          # s from start, every plant step
    states: np.ndarray     # (N, 6) [n, e, psi (continuous), u, v, r]
    tau: np.ndarray        # (N, 2) applied (tau_u, tau_r) held over each step
    tick: np.ndarray       # plant-step index of every controller tick
    ctrl: np.ndarray       # (M, NOUT) controller rows (see usvlog.control.law.OUT_COLUMNS)
    controller_input: str  # "truth" or "ekf"

    def to_dataframe(self):
        """Plant states and applied forces at every step (index: time in s)."""
        import pandas as pd

        cols = ["n_m", "e_m", "psi_rad", "u_mps", "v_mps", "r_radps"]
        df = pd.DataFrame(self.states, columns=cols, index=pd.Index(self.t, name="t_s"))
        df["psi_rad"] = ssa(df["psi_rad"].to_numpy())
        df["tau_u_n"], df["tau_r_nm"] = self.tau[:, 0], self.tau[:, 1]
        return df

    def controller_dataframe(self):
        """Controller rows at every tick (columns: usvlog.control.law.OUT_COLUMNS)."""
        import pandas as pd

        from .control.law import OUT_COLUMNS

        return pd.DataFrame(self.ctrl, columns=list(OUT_COLUMNS), index=pd.Index(self.t[self.tick], name="t_s"))


@njit
def _closed_loop_kernel(x, n, every, dt, u_ref, dtheta, prm, cn, ce, rk4, cs, kind, pprm, G, P, S, T):
    """Plant (``plant_step``) + controller (``control_tick``) on the true state, compiled."""
    states = np.empty((n, 6))
    tau = np.empty((n, 2))
    ctrl = np.empty(((n + every - 1) // every, NOUT))
    xa = np.empty(6)
    tu = 0.0
    tr = 0.0
    j = 0
    for k in range(n):
        if k % every == 0:
            for i in range(6):
                xa[i] = x[i]
            control_tick(xa, u_ref[k], dtheta[k], every * dt, cs, kind, pprm, G, P, S, T, ctrl[j])
            tu = ctrl[j, 14]
            tr = ctrl[j, 15]
            j += 1
        for i in range(6):
            states[k, i] = x[i]
        tau[k, 0] = tu
        tau[k, 1] = tr
        x = plant_step(x, tu, tr, prm, dt, cn, ce, rk4)
    return states, tau, ctrl


def closed_loop(path: Path, plant: Vessel, controller: Controller, *, duration_s: float, dt_s: float,
                integrator: str, current_ne, eta0, nu0, schedule: np.ndarray, rate_hz: float,
                estimator=None) -> ClosedLoopRun:
    """Simulate plant + controller. ``estimator(k, x_true, tau) -> x_hat`` (None: the true state)."""
    n = int(round(duration_s / dt_s))
    every = max(1, int(round(1.0 / (rate_hz * dt_s))))
    dt_ctrl = every * dt_s
    t = np.arange(n) * dt_s
    u_ref = speed_at(schedule, t)
    dtheta = speed_at(schedule, t, 2) if schedule.shape[1] > 2 else np.full(n, controller.guidance.delta_theta)
    prm = tuple(plant.params.as_array().tolist())
    cn, ce = float(current_ne[0]), float(current_ne[1])
    rk4 = integrator == "rk4"
    x = tuple(float(a) for a in (*eta0, *nu0))
    states = np.empty((n, 6))
    tau = np.empty((n, 2))
    ticks = np.arange(0, n, every)
    ctrl = np.empty((len(ticks), NOUT))
    controller.reset(x)
    if estimator is None:  # compiled: the same plant_step and control_tick, no Python per step
        c = controller
        states, tau, ctrl = _closed_loop_kernel(x, n, every, float(dt_s), u_ref, np.ascontiguousarray(dtheta),
                                                prm, cn, ce, rk4, c.cs, c.path.kind, c.path.prm,
                                                c.G, c.P, c.S, c.T)
        return ClosedLoopRun(t, states, tau, ticks, ctrl, "truth")
    tu = tr = 0.0
    j = 0
    step = controller.step
    for k in range(n):
        if k % every == 0:
            xh = np.array(x) if estimator is None else estimator(k, x, (tu, tr))
            row = step(xh, u_ref[k], dt_ctrl, ctrl[j], dtheta[k])
            tu, tr = float(row[14]), float(row[15])
            j += 1
        states[k] = x
        tau[k, 0] = tu
        tau[k, 1] = tr
        x = plant_step(x, tu, tr, prm, dt_s, cn, ce, rk4)
    return ClosedLoopRun(t, states, tau, ticks, ctrl, "truth" if estimator is None else "ekf")


def controller_frame(rows: np.ndarray, t_ns: np.ndarray, topic: str, thrusters, unit: str):
    """Controller rows -> a usvlog.ControllerState.v1 frame (commands in ``unit``)."""
    cols = {c: rows[:, COL[c]] for c in ("theta", "closest_n_m", "closest_e_m", "carrot_n_m", "carrot_e_m",
                                         "psi_ref_rad", "psi_d_rad", "r_d_radps", "r_d_dot_radps2", "u_d_mps",
                                         "u_d_dot_mps2", "u_e_mps", "psi_e_rad", "cross_track_m", "tau_u_n",
                                         "tau_r_nm", "thrust_left_n", "thrust_right_n")}
    cols["cmd_left"] = np.asarray(thrusters.force_to_command(cols["thrust_left_n"], unit), float)
    cols["cmd_right"] = np.asarray(thrusters.force_to_command(cols["thrust_right_n"], unit), float)
    cols["saturated"] = rows[:, COL["saturated"]] != 0.0
    return frame_from_columns(cols, t_ns, codec_for_topic(topic))


def command_unit(thrusters) -> str:
    return "newton" if thrusters.map == "identity" else "normalized"


def make_controller(scen: Scenario, path: Path, vessel: Vessel | None = None, gains: Gains | None = None,
                    controller: str | None = None) -> Controller:
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
        from .estimate import OnlineEKF
        from .estimate.settings import EstimateSettings

        sn = st.sensors
        self.ekf = OnlineEKF(st.vessel, EstimateSettings(model="dynamic", current=True),
                             x0=np.array([*st.eta0, *st.nu0, 0.0, 0.0], float))
        self.dt = dt_ctrl
        gi, keep = noise["gps_index"], noise["gps_keep"]
        off = noise["gps_noise"] + noise["gps_bias"]
        for k, dn, de in noise["gps_jumps"]:
            off[k] = off[k] + (dn, de)
        self.gps = {int(k): (float(o[0]), float(o[1])) for k, o, ok in zip(gi, off, keep) if ok}
        self.gps_var = max(sn.gps_noise_m, 0.05) ** 2
        cb = math.radians(sn.compass_bias_deg)
        self.compass = {int(k): cb + float(w) for k, w in zip(noise["compass_index"], noise["compass_noise"])}
        self.compass_var = max(math.radians(sn.compass_noise_deg), math.radians(0.1)) ** 2
        self.last = -1
        self.X: list[np.ndarray] = []
        self.S: list[np.ndarray] = []

    def __call__(self, k: int, x, tau) -> np.ndarray:
        ekf = self.ekf
        if self.last >= 0:
            ekf.predict(self.dt, tau[0], tau[1])
        for j in range(self.last + 1, k + 1):  # samples since the previous tick, at this tick's state
            if j in self.gps:
                dn, de = self.gps[j]
                ekf.update_gnss(x[0] + dn, x[1] + de, self.gps_var)
            if j in self.compass:
                ekf.update_heading(float(np.round(ssa(x[2] + self.compass[j]), 4)), self.compass_var)
        self.last = k
        xh = ekf.x
        self.X.append(xh)
        self.S.append(np.sqrt(np.clip(np.diag(ekf.P), 0.0, None)))
        return np.ascontiguousarray(xh[:6])

    def frame(self, t_ns: np.ndarray):
        X, S = np.array(self.X), np.array(self.S)
        names = ["n_m", "e_m", "psi_rad", "u_mps", "v_mps", "r_radps", "current_n_mps", "current_e_mps"]
        cols = {c: X[:, i] for i, c in enumerate(names)}
        cols["psi_rad"] = ssa(cols["psi_rad"])
        cols.update({f"{c}_std": S[:, i] for i, c in enumerate(names)})
        return frame_from_columns(cols, t_ns, codec_for_topic("/estimate/state"))


def simulate_scenario(scen: Scenario, *, controller: str | None = None, seed: int | None = None,
                      duration_s: float | None = None) -> FieldLog:
    """Run a closed-loop scenario into a field log (sensors, truth, /control/state, usvlog.path)."""
    st = scen.sim if duration_s is None else replace(scen.sim, duration_s=duration_s)
    seed = scen.seed if seed is None else seed
    ctl_name = controller or scen.controller
    path = scen.path(st.datum)
    ctl = make_controller(scen, path, controller=ctl_name)
    rng = np.random.default_rng(seed)
    t = np.arange(int(round(st.duration_s / st.dt_s))) * st.dt_s
    noise = draw_sensor_noise(st, t, rng)
    every = max(1, int(round(1.0 / (scen.guidance.rate_hz * st.dt_s))))
    est = None if scen.controller_input == "truth" else EKFInTheLoop(st, t, noise, every * st.dt_s)
    run = closed_loop(path, st.vessel, ctl, duration_s=st.duration_s, dt_s=st.dt_s, integrator=st.integrator,
                      current_ne=st.current_ne, eta0=st.eta0, nu0=st.nu0, schedule=scen.schedule,
                      rate_hz=scen.guidance.rate_hz, estimator=est)
    extra = {"controller": ctl_name, "controller_input": run.controller_input,
             "gains": scen.gains.to_dict(), "guidance": scen.guidance.to_dict(), "path": scen.path_spec,
             "speed_schedule": [list(s) for s in scen.speed], "eta0": list(st.eta0), "nu0": list(st.nu0),
             "scenario_file": scen.source}
    log = field_log_from_run(st, run.t, run.states, run.tau[:, 0], run.tau[:, 1], rng,
                             producer="usvlog simulate (closed loop)", scenario=scen.name, seed=seed,
                             extra_settings=extra, noise=noise)
    t0 = int(log["/truth/state"].index[0])
    t_ns = t0 + np.round(run.t[run.tick] * 1e9).astype(np.int64)
    if est is not None:  # the onboard estimate the controller ran on, as a boat's log has it
        log.set("/estimate/state", est.frame(t_ns))
    thr = st.vessel.thrusters
    log.set("/control/state", controller_frame(run.ctrl, t_ns, "/control/state", thr, command_unit(thr)))
    log.meta[META_PATH] = path.metadata()
    return log


# -----------------------------------------------------------------------------
# metrics
# -----------------------------------------------------------------------------

@dataclass(frozen=True)
class TrackingMetrics:
    """How well a run followed the path (over ticks from ``start_s`` on)."""

    n_ticks: int
    start_s: float            # metrics from this time on (the scenario's [metrics] start_s, or 0
    duration_s: float         # when the run is shorter than that)
    cross_track_rms_m: float
    cross_track_p95_m: float
    cross_track_max_m: float
    heading_error_rms_rad: float
    surge_error_rms_mps: float
    time_saturated_s: float

    def to_dict(self) -> dict:
        return {f.name: getattr(self, f.name) for f in fields(self)}


def tracking_metrics(rows: np.ndarray, t_s: np.ndarray, start_s: float = 0.0) -> TrackingMetrics:
    t_s = np.asarray(t_s, float)
    dt = np.diff(t_s, append=t_s[-1] + (t_s[-1] - t_s[-2] if len(t_s) > 1 else 0.0))
    sel = t_s - t_s[0] >= start_s
    if not sel.any():  # a run shorter than the transient: measure all of it
        start_s = 0.0
        sel = np.ones(len(t_s), bool)
    r = rows[sel]
    xt = np.abs(r[:, COL["cross_track_m"]])
    rms = lambda a: float(np.sqrt(np.mean(np.square(a))))  # noqa: E731
    return TrackingMetrics(n_ticks=int(sel.sum()), start_s=float(start_s), duration_s=float(dt[sel].sum()),
                           cross_track_rms_m=rms(xt), cross_track_p95_m=float(np.percentile(xt, 95)),
                           cross_track_max_m=float(xt.max()),
                           heading_error_rms_rad=rms(r[:, COL["psi_e_rad"]]),
                           surge_error_rms_mps=rms(r[:, COL["u_e_mps"]]),
                           time_saturated_s=float(dt[sel][r[:, COL["saturated"]] != 0].sum()))


@dataclass(frozen=True)
class ReplayMetrics:
    """Open-loop replay vs what was recorded, and the what-if run."""

    state_source: str                 # "/estimate/state" or "/truth/state"
    controller: str                   # full / baseline (open-loop replay)
    replay: TrackingMetrics
    command_unit: str | None
    n_commands_compared: int
    command_rms: float | None         # replayed vs recorded left/right commands, in command_unit
    command_max_abs: float | None
    force_rms_n: float | None         # the same in newtons (when the log has forces)
    decisions_compared: int           # ticks matched with a recorded /control/state (closed-loop runs)
    decisions_max_abs: float | None   # max |replayed - recorded| of forces and moments there (N, N m)
    whatif_controller: str | None
    whatif: TrackingMetrics | None

    def to_dict(self) -> dict:
        d = {f.name: getattr(self, f.name) for f in fields(self)}
        d["replay"] = self.replay.to_dict()
        d["whatif"] = None if self.whatif is None else self.whatif.to_dict()
        return d


# -----------------------------------------------------------------------------
# replay of a recorded run
# -----------------------------------------------------------------------------

@dataclass(frozen=True)
class ReplayResult:
    log: FieldLog
    metrics: ReplayMetrics


def _state_source(log: FieldLog) -> tuple[str, np.ndarray, np.ndarray]:
    for topic in ("/estimate/state", "/truth/state"):
        f = log.get(topic)
        if f is not None and len(f):
            cols = ["n_m", "e_m", "psi_rad", "u_mps", "v_mps", "r_radps"]
            missing = [c for c in cols if c not in f.columns]
            if missing:
                raise InputError(f"{log.source or 'log'}: channel {topic} lacks {', '.join(missing)}")
            X = f[cols].to_numpy(dtype=float, copy=True)
            ok = np.all(np.isfinite(X), axis=1)
            if not ok.any():
                raise InputError(f"{log.source or 'log'}: channel {topic} has no finite state row")
            return topic, np.asarray(f.index, dtype=np.int64)[ok], X[ok]
    raise InputError(f"{log.source or 'log'}: no /estimate/state or /truth/state to replay "
                     "(run usvlog estimate first)")


def _states_at(t_state: np.ndarray, X: np.ndarray, t_tick: np.ndarray) -> np.ndarray:
    """States at tick times: exact rows where times match, linear interpolation elsewhere."""
    idx = np.searchsorted(t_state, t_tick)
    idx_c = np.clip(idx, 0, len(t_state) - 1)
    exact = t_state[idx_c] == t_tick
    out = np.empty((len(t_tick), 6))
    out[exact] = X[idx_c[exact]]
    if not exact.all():
        ts = (t_state - t_state[0]) / 1e9
        tt = (t_tick[~exact] - t_state[0]) / 1e9
        for j in range(6):
            y = np.unwrap(X[:, j]) if j == 2 else X[:, j]
            out[~exact, j] = np.interp(tt, ts, y)
    return out


def _current_of(log: FieldLog, topic: str) -> tuple[float, float]:
    f = log[topic]
    if "current_n_mps" in f.columns and "current_e_mps" in f.columns:
        cn = f["current_n_mps"].to_numpy(dtype=float)
        ce = f["current_e_mps"].to_numpy(dtype=float)
        ok = np.isfinite(cn) & np.isfinite(ce)
        if ok.any():
            return float(np.mean(cn[ok])), float(np.mean(ce[ok]))
    return 0.0, 0.0


def replay_log(log: FieldLog, scen: Scenario, *, vessel: Vessel | None = None, gains: Gains | None = None,
               controller: str | None = None, whatif: bool = True,
               whatif_controller: str | None = None) -> ReplayResult:
    """Open-loop replay of a recorded run plus a what-if simulation; returns the log with the results.

    The controller's model (and the what-if plant) is ``vessel``, else the scenario's
    ``[vessel]``, else the log's ``usvlog.vessel``; the gains are ``gains`` else the scenario's.
    """
    src = log.source or "log"
    ves = vessel or (scen.sim.vessel if "vessel" in scen.doc else None) or log.vessel or default_vessel()
    gains = gains or scen.gains
    ctl_name = controller or scen.controller
    wif_name = whatif_controller or ctl_name
    datum = log.datum or scen.sim.datum
    path = scen.path(datum)
    topic, t_state, X = _state_source(log)
    cmd = log.get("/thrust/command")
    rate = scen.guidance.rate_hz
    if cmd is not None and len(cmd):
        t_cmd = np.asarray(cmd.index, dtype=np.int64)
        sel = (t_cmd >= t_state[0]) & (t_cmd <= t_state[-1])
        t_tick = t_cmd[sel]
    else:
        sel = None
        t_tick = np.arange(t_state[0], t_state[-1] + 1, int(round(1e9 / rate)), dtype=np.int64)
    if len(t_tick) < 2:
        raise InputError(f"{src}: fewer than 2 controller ticks inside {topic}")
    Xt = _states_at(t_state, X, t_tick)
    t_rel = (t_tick - t_tick[0]) / 1e9
    dt = np.diff(t_rel, append=t_rel[-1] + (t_rel[-1] - t_rel[-2]))
    ctl = Controller(path, ves, gains, scen.guidance, full=ctl_name == "full")
    ctl.reset(Xt[0])
    rows = ctl.run(Xt, speed_at(scen.schedule, t_rel), dt, speed_at(scen.schedule, t_rel, 2))
    thr = ves.thrusters
    unit = command_unit(thr)
    n_cmp, c_rms, c_max, f_rms = 0, None, None, None
    if sel is not None:
        rec = cmd[sel]
        units = rec["unit"].astype(str).unique().tolist() if "unit" in rec.columns else []
        if len(units) == 1 and (units[0] == "newton" or thr.map != "identity"):
            unit = units[0]
    out = log.copy()
    frame = controller_frame(rows, t_tick, "/replay/controller", thr, unit)
    out.set("/replay/controller", frame)
    if sel is not None:
        rec = cmd[sel]
        d = np.concatenate([frame["cmd_left"].to_numpy() - rec["left"].to_numpy(dtype=float),
                            frame["cmd_right"].to_numpy() - rec["right"].to_numpy(dtype=float)])
        ok = np.isfinite(d)
        n_cmp = int(ok.sum() // 2)
        if ok.any():
            c_rms = float(np.sqrt(np.mean(d[ok] ** 2)))
            c_max = float(np.max(np.abs(d[ok])))
        if {"thrust_left_n", "thrust_right_n"} <= set(rec.columns):
            df = np.concatenate([frame["thrust_left_n"].to_numpy() - rec["thrust_left_n"].to_numpy(dtype=float),
                                 frame["thrust_right_n"].to_numpy() - rec["thrust_right_n"].to_numpy(dtype=float)])
            okf = np.isfinite(df)
            if okf.any():
                f_rms = float(np.sqrt(np.mean(df[okf] ** 2)))
    n_dec, dec_max = 0, None
    rec_cs = log.get("/control/state")
    if rec_cs is not None and len(rec_cs):
        tr_ns = np.asarray(rec_cs.index, dtype=np.int64)
        j = np.clip(np.searchsorted(tr_ns, t_tick), 0, len(tr_ns) - 1)
        hit = tr_ns[j] == t_tick
        n_dec = int(hit.sum())
        if n_dec:
            cols = ["tau_u_n", "tau_r_nm", "thrust_left_n", "thrust_right_n"]
            a = frame[cols].to_numpy(dtype=float)[hit]
            b = rec_cs[cols].to_numpy(dtype=float)[j[hit]]
            dec_max = float(np.nanmax(np.abs(a - b)))
    m_replay = tracking_metrics(rows, t_rel, scen.metrics_start_s)
    m_whatif = None
    if whatif:
        cur = _current_of(log, topic)
        wctl = Controller(path, ves, gains, scen.guidance, full=wif_name == "full")
        dur = float(t_rel[-1] + dt[-1])
        dt_s = 1.0 / rate
        run = closed_loop(path, ves, wctl, duration_s=dur, dt_s=dt_s, integrator=scen.sim.integrator,
                          current_ne=cur, eta0=Xt[0, :3], nu0=Xt[0, 3:], schedule=scen.schedule, rate_hz=rate)
        tw = t_tick[0] + np.round(run.t * 1e9).astype(np.int64)
        s = run.states
        st_cols = {"n_m": s[:, 0], "e_m": s[:, 1], "psi_rad": ssa(s[:, 2]), "u_mps": s[:, 3], "v_mps": s[:, 4],
                   "r_radps": s[:, 5], "current_n_mps": np.full(len(s), cur[0]),
                   "current_e_mps": np.full(len(s), cur[1]), "tau_u_n": run.tau[:, 0], "tau_r_nm": run.tau[:, 1]}
        out.set("/replay/whatif/state", frame_from_columns(st_cols, tw, codec_for_topic("/replay/whatif/state")))
        out.set("/replay/whatif/controller",
                controller_frame(run.ctrl, tw[run.tick], "/replay/whatif/controller", thr, unit))
        m_whatif = tracking_metrics(run.ctrl, run.t[run.tick], scen.metrics_start_s)
    out.meta[META_PATH] = path.metadata()
    metrics = ReplayMetrics(state_source=topic, controller=ctl_name, replay=m_replay,
                            command_unit=unit if sel is not None else None, n_commands_compared=n_cmp,
                            command_rms=c_rms, command_max_abs=c_max, force_rms_n=f_rms,
                            decisions_compared=n_dec, decisions_max_abs=dec_max,
                            whatif_controller=wif_name if whatif else None, whatif=m_whatif)
    out.add_provenance(producer="usvlog replay", source=src,
                       settings={"scenario": scen.source or scen.name, "state_source": topic,
                                 "controller": ctl_name, "whatif_controller": wif_name if whatif else None,
                                 "gains": gains.to_dict(), "guidance": scen.guidance.to_dict(),
                                 "vessel": ves.to_dict(), "path": scen.path_spec},
                       metrics=metrics.to_dict())
    return ReplayResult(out, metrics)


__all__ = ["Scenario", "scenario_from_dict", "closed_loop", "ClosedLoopRun", "simulate_scenario",
           "replay_log", "ReplayResult", "ReplayMetrics", "TrackingMetrics", "tracking_metrics",
           "controller_frame", "META_PATH"]
