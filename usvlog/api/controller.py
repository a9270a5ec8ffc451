"""The controller: its gains checked against Theorem 3.1 (``usvlog gains``) and replayed over a
recorded run, with a what-if run of the closed loop (``usvlog replay``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from typing import TYPE_CHECKING

from ._common import PathLike, Progress, _check_paths, _is_path, _read, _say
from .data_in import save

if TYPE_CHECKING:  # annotations and docstring links only: importing these at run time pulls numpy and pandas
    import os  # noqa: F401  (named in the docstrings: the API reference links it)

    from ..control.gains import GainCheck, Gains
    from ..log.fieldlog import FieldLog  # noqa: F401  (named in the docstrings: the API reference links it)
    from ..model.vessel import Vessel
    from ..replay import ReplayResult

# the channels replay decodes when it reads a file (estimate: usvlog.estimate.core.INPUT_TOPICS);
# the others stay in it (decoded if the verb touches one after all, e.g. /truth/state when there is
# no estimate; copied undecoded to --out)
_REPLAY_READS = ["/estimate/state", "/thrust/command", "/control/state"]


# -----------------------------------------------------------------------------
# control: gains, replay
# -----------------------------------------------------------------------------

def gains_and_vessel(gains="paper-circle", vessel=None) -> tuple[Gains, Vessel]:
    """The gains and the vessel :func:`gains` checks, resolved as ``usvlog gains`` does.

    Parameters
    ----------
    gains : Gains, str or os.PathLike
        A Gains object, a gains TOML (``[gains]``, ``[guidance]``), a scenario file, or the name
        of a shipped scenario.
    vessel : Vessel or path, optional
        A Vessel, a vessel TOML or a scenario file with ``[vessel]``. Default: the scenario's
        ``[vessel]`` when ``gains`` is a file that has one, else the paper's Section IV vessel.

    Returns
    -------
    (Gains, Vessel)
    """
    from ..io.config import load_vessel, load_vessel_or_scenario_vessel, read_toml  # heavy: numpy
    from ..sim.scenario import load_gains, scenario_path

    g = gains
    path = None
    if _is_path(gains):
        path = scenario_path(gains)
        g, _ = load_gains(path)
    if _is_path(vessel):
        vessel = load_vessel_or_scenario_vessel(vessel)
    elif vessel is None:
        vessel = load_vessel_or_scenario_vessel(path) if path is not None and "vessel" in read_toml(path) \
            else load_vessel(None)
    return g, vessel


def gains(gains="paper-circle", *, vessel=None, q: Sequence[float] | None = None, delta: float | None = None,
          theta: float = 0.5) -> GainCheck:
    """Check controller gains against Theorem 3.1 and compute the bound (18) (``usvlog gains``).

    Parameters
    ----------
    gains : Gains, str or os.PathLike
        The gains: a Gains object, a gains TOML, a scenario file or a shipped scenario's name
        (default ``"paper-circle"``, the paper's Section IV gains).
    vessel : Vessel or path, optional
        See :func:`gains_and_vessel` (default the scenario's, else the paper's vessel).
    q : sequence of 6 floats or 6x6 array, optional
        Q of the Lyapunov equation P A_e + A_e^T P = -Q (diagonal or full; default identity).
    delta : float, optional
        Bound on the perturbation g(t, x_e) of (13), in the units of the error state.
    theta : float
        theta of (18), 0 < theta < 1.

    Returns
    -------
    GainCheck
        ``conditions``, ``eigenvalues`` of A_e, ``hurwitz``, ``P``, c1..c4, ``bound_per_delta``,
        ``bound``; ``ok`` is True when every condition holds, ``verdict`` says which fails.
    """
    from ..control.gains import check_gains  # heavy: numpy, scipy

    g, ves = gains_and_vessel(gains, vessel)
    return check_gains(ves.params, g, Q=q, delta=delta, theta=theta)


def replay(log, scenario: PathLike, out: PathLike | None = None, *, gains=None, vessel=None,
           controller: str | None = None, whatif: bool = True, whatif_controller: str | None = None,
           force: bool = False, progress: Progress = None) -> ReplayResult:
    """Replay a recorded run through guidance and controller, plus a what-if run (``usvlog replay``).

    Parameters
    ----------
    log : FieldLog or path
        The recorded run (with ``/estimate/state`` or ``/truth/state``), or its MCAP file.
    scenario : str or os.PathLike
        Closed-loop scenario: a TOML file (path, gains, guidance, speed) or a shipped name
        (``"paper-circle"``, ``"paper-sine"``).
    out : str or os.PathLike, optional
        Write the log plus the ``/replay/*`` channels to this MCAP file.
    gains : Gains or path, optional
        Gains overriding the scenario's ``[gains]``; a gains TOML with a ``[guidance]`` table
        also overrides the scenario's guidance.
    vessel : Vessel or path, optional
        The controller's model and the what-if plant (a vessel TOML or a scenario with
        ``[vessel]``); default the scenario's ``[vessel]``, else the log's.
    controller : str, optional
        ``"full"`` or ``"baseline"``, replayed open loop (default: the scenario's).
    whatif : bool
        Also simulate the closed loop from the recorded initial state (the what-if run).
    whatif_controller : str, optional
        Controller of the what-if run (default: as ``controller``).
    force : bool
        Replace an existing ``out``.
    progress : callable, optional
        Receives a line as reading and replaying start.

    Returns
    -------
    ReplayResult
        ``log`` (input plus ``/replay/*``) and ``metrics`` (cross-track error in m, heading
        error in rad, surge error in m/s, time saturated in s, command differences).
    """
    _check_paths([log], out, force)
    from ..io.config import load_vessel_or_scenario_vessel, read_toml  # heavy: numpy, numba kernels
    from ..replay import replay_file, replay_log
    from ..sim.scenario import load_gains, load_scenario

    scen = load_scenario(scenario)
    if _is_path(gains):
        path = gains
        gains, guidance = load_gains(path)
        if "guidance" in read_toml(path):  # a [guidance] table there overrides the scenario's
            scen = replace(scen, guidance=guidance)
    if _is_path(vessel):
        vessel = load_vessel_or_scenario_vessel(vessel)
    read_here = _is_path(log)
    if read_here:
        _say(progress, f"reading {log}")
    said = False
    if read_here and out is not None:   # file to file: a time window at a time (memory flat in the run)
        _say(progress, f"replaying with scenario {scen.name}")
        said = True
        res = replay_file(log, scen, out, vessel=vessel, gains=gains, controller=controller, whatif=whatif,
                          whatif_controller=whatif_controller, force=force)
        if res is not None:
            _say(progress, f"wrote {out}")
            return res
    log = _read(log, progress, topics=_REPLAY_READS, defer=True)   # (else the whole log, as before)
    if not said:
        _say(progress, f"replaying with scenario {scen.name}")
    # memory: a log read here gives its channels back to the file once replay has used them
    res = replay_log(log, scen, vessel=vessel, gains=gains, controller=controller, whatif=whatif,
                     whatif_controller=whatif_controller, release_inputs=read_here)
    if out is not None:
        save(res.log, out, force=force)
        _say(progress, f"wrote {out}")
    return res
