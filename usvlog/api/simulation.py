"""Runs made up: the paper's plant and sensors simulated into a field log, open loop or a
closed-loop scenario (``usvlog simulate``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..errors import ConfigError, StorageError, UsvlogError
from ._common import PathLike, Progress, _check_paths, _say, _vessel_file
from .data_in import save

if TYPE_CHECKING:  # annotations and docstring links only: importing these at run time pulls numpy and pandas
    import os  # noqa: F401  (named in the docstrings: the API reference links it)

    from ..log.fieldlog import FieldLog
    from ..model.vessel import Vessel  # noqa: F401  (named in the docstrings: the API reference links it)


# -----------------------------------------------------------------------------
# simulate
# -----------------------------------------------------------------------------

def simulate(scenario: PathLike, out: PathLike | None = None, *, seed: int | None = None,
             controller: str | None = None, duration_s: float | None = None, current_mps: float = 0.0,
             current_dir_deg: float = 0.0, vessel=None, gps_noise_m: float | None = None,
             compass_noise_deg: float | None = None, gps_bias_m: float | None = None,
             gps_jumps: Sequence[tuple[float, float]] = (), gps_dropouts: Sequence[tuple[float, float]] = (),
             compass_bias_deg: float | None = None, truth_rate_hz: float | None = None, force: bool = False,
             progress: Progress = None) -> FieldLog:
    """Simulate the paper's plant and sensors into a field log (``usvlog simulate``).

    Parameters
    ----------
    scenario : str or os.PathLike
        A built-in open-loop scenario (``"excitation"``, ``"turns"``, ``"straight"``), the name
        of a closed-loop scenario shipped in ``replay/`` (``"paper-circle"``, ``"paper-sine"``)
        or a closed-loop scenario TOML file. A closed-loop scenario takes its settings from the
        file: only ``duration_s``, ``seed``, ``vessel``, ``controller`` and ``truth_rate_hz``
        override them (the sensor and current options below are for open-loop runs).
    out : str or os.PathLike, optional
        Also write the log to this MCAP file (checked before the simulation runs).
    seed : int, optional
        Random seed: same seed, same log. Default 0, or the closed-loop scenario's.
    controller : str, optional
        Closed loop: ``"full"`` (the paper's controller (9)-(10)) or ``"baseline"`` (PI/PID);
        default the scenario's.
    duration_s : float, optional
        Run length in s (default 600 s open loop, else the scenario's).
    current_mps : float
        Water current speed in m/s (open loop).
    current_dir_deg : float
        Direction the current flows towards, degrees clockwise from north.
    vessel : Vessel or path, optional
        Vessel (or vessel TOML); default the paper's Section IV vessel (closed loop: the
        scenario's).
    gps_noise_m, compass_noise_deg : float, optional
        One-sigma GPS noise per axis in m, compass noise in degrees (default 1.5 m, 2 deg).
    gps_bias_m : float, optional
        Standard deviation in m of a slowly wandering GPS bias (Gauss-Markov, 300 s).
    gps_jumps : sequence of (t_s, size_m)
        Single-fix GPS outliers of ``size_m`` m at ``t_s`` s.
    gps_dropouts : sequence of (start_s, duration_s)
        No GPS fixes for ``duration_s`` s from ``start_s`` s.
    compass_bias_deg : float, optional
        Constant compass bias in degrees.
    truth_rate_hz : float, optional
        Rate in Hz of ``/truth/state`` (default: every integration step).
    force : bool
        Replace an existing ``out``.
    progress : callable, optional
        Receives a line describing the run before it starts.

    Returns
    -------
    FieldLog
        GNSS, compass, thrust and truth channels (closed loop also ``/control/state`` and the
        path), with the vessel, datum and provenance. A run with ``out`` is simulated and
        written a time window at a time (memory flat in its length; the file is the one
        :func:`save` writes for the whole log) and the log returned is ``out`` read with its
        channels deferred (decoded when first touched).
    """
    _check_paths([], out, force)   # fail before the work (and the imports), not after
    from ..resources import replay_dir  # heavy: the sim/io stack pulls numpy, pandas, numba
    from ..sim.scenario import closed_loop_scenarios
    from ..sim.simulate import SCENARIOS
    from ..sim.simulate import simulate as simulate_open_loop

    name = str(scenario)
    if name not in SCENARIOS:
        p = Path(scenario)
        if not (p.suffix == ".toml" or p.exists() or "/" in name or (replay_dir() / f"{name}.toml").exists()):
            raise ConfigError(f"no scenario {name!r} (open loop: {', '.join(SCENARIOS)}; closed loop: "
                              f"{', '.join(closed_loop_scenarios())}; or a scenario TOML file)")
        log = _simulate_closed_loop(scenario, out, seed=seed, controller=controller, duration_s=duration_s,
                                    vessel=vessel, truth_rate_hz=truth_rate_hz, force=force, progress=progress)
    else:
        settings = _sim_settings(duration_s=duration_s, current_mps=current_mps, current_dir_deg=current_dir_deg,
                                 vessel=vessel, gps_noise_m=gps_noise_m, compass_noise_deg=compass_noise_deg,
                                 gps_bias_m=gps_bias_m, gps_jumps=gps_jumps, gps_dropouts=gps_dropouts,
                                 compass_bias_deg=compass_bias_deg, truth_rate_hz=truth_rate_hz)
        seed = 0 if seed is None else seed
        _say(progress, f"simulating {name} ({settings.duration_s:.0f} s, seed {seed})")
        if out is None:
            return simulate_open_loop(name, settings, seed=seed)
        from ..sim.simulate import simulate_windows  # heavy: numpy, pandas, numba

        topics = ["/truth/state", "/thrust/command", "/gnss/fix", "/compass/heading"]   # the run's channel order
        log = _write_windows(*simulate_windows(name, settings, seed=seed), topics, out, force,
                             lambda: simulate_open_loop(name, settings, seed=seed))
    if out is not None:
        _say(progress, f"wrote {out}")
    return log


def _write_windows(header: FieldLog, windows, topics: list[str], out: PathLike, force: bool, whole) -> FieldLog:
    """A run simulated and written to ``out`` a time window at a time (memory flat in its
    length); returns ``out`` read with its channels deferred.

    ``header`` is the run's log without channels and ``windows`` its frames window after
    window (``topics``: their channels in the log's order), as ``simulate_windows`` and
    ``scenario_windows`` make them. The windows' channels go to a spool beside ``out`` as
    they are made, then ``out`` is written from the log's metadata and the spool, undecoded:
    the file :func:`save` writes for the whole run's log, byte for byte
    (:func:`usvlog.io.mcap.writer.write_log_merged`). ``whole()`` makes that whole log, written
    instead where the spool cannot be copied as it is stored.
    """
    from ..io.mcap import read_log  # heavy: the compiled MCAP reader and writer
    from ..io.mcap.windows import NotWindowed  # heavy: with the reader
    from ..io.mcap.writer import SLICE_MESSAGES, Spool, merged_ids, time_slices, write_log_merged  # heavy

    out_p = Path(out)
    spool = out_p.parent / f".{out_p.name}.sim.spool"
    try:
        sp = Spool(spool, topics, merged_ids(header, topics))
        for frames in windows:   # encoded a time slice at a time, as write_log does (memory: a slice)
            for batch in time_slices({t: f for t, f in frames.items() if len(f)}, SLICE_MESSAGES):
                sp.add(batch)
        write_log_merged(header, out, [sp.close()], topics, force=force)
    except NotWindowed:   # the spool cannot be copied as it is stored (not expected): the whole run at once
        save(whole(), out, force=force)
    except UsvlogError:
        raise
    except OSError as err:   # a spool beside the output that cannot be written
        raise StorageError(f"{out_p}: cannot write beside it ({err.strerror or err})") from err
    finally:
        spool.unlink(missing_ok=True)
    return read_log(out, topics=[], defer=True)


def _sim_settings(*, duration_s, current_mps, current_dir_deg, vessel, gps_noise_m, compass_noise_deg,
                  gps_bias_m, gps_jumps, gps_dropouts, compass_bias_deg, truth_rate_hz):
    """SimSettings of an open-loop run (sensor defaults where an option is None)."""
    from ..io.config import load_vessel  # heavy: numpy
    from ..sim.simulate import SensorSettings, SimSettings

    sens: dict[str, Any] = {}  # numbers as floats, as the command line gives them (they go into the provenance)
    if gps_noise_m is not None:
        sens["gps_noise_m"] = float(gps_noise_m)
    if compass_noise_deg is not None:
        sens["compass_noise_deg"] = float(compass_noise_deg)
    if compass_bias_deg is not None:
        sens["compass_bias_deg"] = float(compass_bias_deg)
    if gps_bias_m is not None:
        sens["gps_bias_sigma_m"] = float(gps_bias_m)
    if truth_rate_hz is not None:
        sens["truth_rate_hz"] = float(truth_rate_hz)
    sens["gps_jumps"] = tuple((float(a), float(b)) for a, b in gps_jumps)
    sens["gps_dropouts"] = tuple((float(a), float(b)) for a, b in gps_dropouts)
    kw: dict[str, Any] = dict(vessel=_vessel_file(vessel) or load_vessel(None), current_mps=float(current_mps),
                              current_dir_deg=float(current_dir_deg), sensors=SensorSettings(**sens))
    if duration_s is not None:
        kw["duration_s"] = float(duration_s)
    return SimSettings(**kw)


def _simulate_closed_loop(scenario, out, *, seed, controller, duration_s, vessel, truth_rate_hz, force, progress):
    """A closed-loop scenario (replay/<name>.toml or a file); the scenario holds the settings.
    With ``out``, simulated and written a time window at a time (:func:`_write_windows`)."""
    from ..sim.closed_loop import scenario_topics, scenario_windows, simulate_scenario  # heavy: the compiled loop
    from ..sim.scenario import load_scenario

    scen = load_scenario(scenario, vessel=_vessel_file(vessel))
    duration_s = None if duration_s is None else float(duration_s)
    if truth_rate_hz is not None:
        sens = replace(scen.sim.sensors, truth_rate_hz=float(truth_rate_hz))
        scen = replace(scen, sim=replace(scen.sim, sensors=sens))
    ctl = controller or scen.controller
    dur = duration_s or scen.sim.duration_s
    _say(progress, f"simulating {scen.name} closed loop ({dur:.0f} s, controller {ctl}, "
                   f"input {scen.controller_input})")
    if out is None:
        return simulate_scenario(scen, controller=ctl, seed=seed, duration_s=duration_s)
    return _write_windows(*scenario_windows(scen, controller=ctl, seed=seed, duration_s=duration_s),
                          scenario_topics(scen), out, force,
                          lambda: simulate_scenario(scen, controller=ctl, seed=seed, duration_s=duration_s))
