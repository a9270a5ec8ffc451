"""What a run says: its state (``usvlog estimate``), its model (``usvlog identify`` and the
``/identify/fit`` channel of a fit) and its standard manoeuvres (``usvlog manoeuvres``).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from ..errors import ConfigError, InputError
from ._common import PathLike, Progress, _check_paths, _is_path, _read, _say, _vessel_file
from .data_in import save

if TYPE_CHECKING:  # annotations and docstring links only: importing these at run time pulls numpy and pandas
    import os  # noqa: F401  (named in the docstrings: the API reference links it)

    from ..estimate import EstimateResult
    from ..identify import Identifier
    from ..log.fieldlog import FieldLog
    from ..model.vessel import Vessel  # noqa: F401  (named in the docstrings: the API reference links it)
    from ..trials import Manoeuvres

FIT_TOPIC = "/identify/fit"


# -----------------------------------------------------------------------------
# estimate, identify
# -----------------------------------------------------------------------------

def estimate(log, out: PathLike | None = None, *, model: str = "kinematic", vessel=None,
             current: bool | None = None, tune: bool = False, sway_damping: bool | None = None,
             gate: float = 0.9999, smoother: bool = True, gnss_delay_s: float | str = 0.0,
             compass_delay_s: float | str = 0.0, force: bool = False,
             progress: Progress = None, gps_only: bool = False,
             heading_offset: float | str | None = None) -> EstimateResult:
    """Estimate the state of a run with an EKF and RTS smoother (``usvlog estimate``).

    Parameters
    ----------
    log : FieldLog or path
        The run, or its MCAP file.
    out : str or os.PathLike, optional
        Write the log plus ``/estimate/state`` and ``/estimate/innovations`` to this MCAP file
        (checked before the work).
    model : str
        ``"kinematic"`` (no vessel parameters) or ``"dynamic"`` (the paper's model driven by the
        recorded thrust).
    vessel : Vessel or path, optional
        Vessel (or vessel TOML) of the dynamic model; default the log's own, else the built-in.
    current : bool, optional
        Estimate the water current (m/s); default on for the dynamic model, off for the
        kinematic one.
    tune : bool
        Pick the process noise by maximising the innovation likelihood.
    sway_damping : bool, optional
        Kinematic model in the body frame with an estimated sway damping (default on for the
        kinematic model).
    gate : float
        Chi-square probability of the NIS gate on each measurement (1.0: no gate).
    smoother : bool
        Run the RTS smoother (False: the forward filter only).
    gnss_delay_s, compass_delay_s : float or "auto"
        Sensor latency in s (a record stamped t describes the boat at t - delay), or
        ``"auto"``: estimated from the data (reported in ``report.latency``; not applied
        when the data do not determine it). Stored in ``out`` for identification.
    force : bool
        Replace an existing ``out``.
    progress : callable, optional
        Receives a line before the estimation starts.
    gps_only : bool
        Fuse no heading even when the log has one (without a usable heading channel the
        estimate is GNSS-only anyway; ``report.mode`` says which).
    heading_offset : float or "auto", optional
        Heading mounting offset in degrees, measured minus true (the heading fused is the
        measured one minus it), or ``"auto"``: detected against the course over ground and
        applied when one is found (``report.heading_offset`` says which). None: the vessel
        file's ``[sensors] heading_offset_deg``, else none. An estimate with a detected
        offset not applied, or an implausible sideslip, has ``report.status`` ``failed``.

    Returns
    -------
    EstimateResult
        ``state`` (n_m, e_m, psi_rad, u_mps, v_mps, r_radps, ... and their std on a 0.01 s
        grid), ``forward`` (the forward filter, made on first access), ``innovations``, ``report``
        (consistency, ``format()``, ``to_dict()``); ``to_log(log)`` adds them to a copy of the log.
        From a file to a file the log is estimated and written a time window at a time (memory
        flat in its length, ``usvlog.api.estimate_file``; the same file):
        ``state`` and ``innovations`` are then decoded from ``out`` when first asked for.
    """
    _check_paths([log], out, force)   # before the heavy imports: a mistyped path fails at once
    from ..estimate import EstimateSettings  # heavy: numpy, numba kernels
    from ..estimate import estimate as run_estimate
    from ..estimate.core import INPUT_TOPICS  # heavy: with the estimator

    delays = {"gnss": gnss_delay_s, "compass": compass_delay_s}
    auto = tuple(k for k, v in delays.items() if v == "auto")
    for k, v in delays.items():
        if v != "auto" and not isinstance(v, (int, float)):
            raise ConfigError(f"{k}_delay_s = {v!r} must be a number of seconds or 'auto'")
    offset = {"heading_offset_auto": True} if heading_offset == "auto" else \
        {} if heading_offset is None else {"compass_offset_rad": math.radians(float(heading_offset))}
    settings = EstimateSettings(model=model, current=current, tune=tune, gate_probability=gate,
                                smoother=smoother, sway_damping=sway_damping, gps_only=gps_only, estimate_delays=auto,
                                **{f"{k}_delay_s": 0.0 if v == "auto" else float(v) for k, v in delays.items()},
                                **offset)
    read_here = _is_path(log)
    src = log if read_here else log.source
    ves = _vessel_file(vessel)
    said = []

    def start() -> None:   # once the log is read
        _say(progress, f"estimating {src} ({model} model{', tuning' if tune else ''}"
                       f"{''.join(f', estimating the {k} delay' for k in auto)})")
        said.append(True)

    if read_here and out is not None:   # file to file: a time window at a time (memory flat in the log's length)
        from .estimate_file import estimate_file  # heavy: the estimator and the MCAP reader and writer

        done = estimate_file(log, out, settings, ves, force=force, started=start)
        if done is not None:
            return done
    log = _read(log, progress, topics=list(INPUT_TOPICS), defer=True)   # (else the whole log, as before)
    if not said:
        start()
    result = run_estimate(log, settings, ves)
    if out is not None:
        out_log = result.to_log(log)
        if read_here:   # read here: its channels go back to the file, copied undecoded
            del log
            out_log.redefer(INPUT_TOPICS)
        save(out_log, out, force=force)
    return result


def identify(logs, out: PathLike | None = None, *, vessel=None, method: str = "output-error",
             validate=None, holdout: float | None = None, fix: dict[str, float] | None = None, current: bool = True,
             out_log: PathLike | None = None, force: bool = False, progress: Progress = None,
             max_current_mps: float = 0.5, gnss_delay_s: float | None = None, model: str = "paper",
             fit_lag: bool = False, lag_s: float = 0.0, quadratic_surge: bool = False) -> Identifier:
    """Identify m, Iz, d11, d22, d33, xg of the paper's model (3) from logs (``usvlog identify``).

    Parameters
    ----------
    logs : FieldLog, path, or a list of them
        The runs, fitted jointly.
    out : str or os.PathLike, optional
        Write the identified vessel TOML here.
    vessel : Vessel or path, optional
        Thruster map and geometry, and start values (default: the vessel stored in the first log).
    method : str
        ``"output-error"`` (accurate, default), ``"equation-error"`` (fast, biased) or
        ``"filter-error"`` (the dynamic EKF's likelihood; slower).
    validate : FieldLog or path, optional
        A run not fitted on: the identified model's free run is compared with it (fit %);
        the result is the Identifier's ``validation_``.
    holdout : float, optional
        Hold out this last fraction (0 to 0.9) of each run for validation; 0: no validation.
        Default: 0.3 of one run, several runs left out in turn (none with ``validate``).
    fix : dict, optional
        Known parameters by name in SI units, e.g. ``{"m": 33.0}`` (kg).
    current : bool
        Fit a constant water current per run (two nuisance parameters, m/s).
    out_log : str or os.PathLike, optional
        Write a copy of the first log with the ``/identify/fit`` channel (measured vs model).
    force : bool
        Replace existing outputs, and write them even when the verdict is unusable (the
        TOML then says ``usable = false``).
    progress : callable, optional
        Receives a line before the fit starts.
    max_current_mps : float
        Bound on each component of a fitted current, m/s.
    gnss_delay_s : float, optional
        GNSS latency in s of every log (a fix stamped t describes the boat at t - delay);
        default: the delay an estimate stored in each log (``usvlog estimate
        --gnss-delay-s``), else 0.
    model : {"paper", "extended", "both"}
        Model structure: the paper's (default), the extended one (the TOML then has an
        ``[extended]`` table), or both compared on the validation (the better one written).
    fit_lag : bool
        Identify a first-order thruster lag too (:mod:`usvlog.identify.lag`; written to the
        TOML's ``[thrusters] lag_s``).
    lag_s : float
        A known first-order thruster lag (s): the thrust goes through it before the fit
        (the vessel's ``[thrusters] lag_s`` is the simulated plant's and is not applied).
    quadratic_surge : bool
        Also fit the paper model with a quadratic surge damping d11q (``d11 u + d11q u|u|``),
        returned only when it validates better, written as an ``[extended]`` vessel with one
        mass (m22 = m11) and no quadratic sway or yaw damping (paper or both, output error).

    Returns
    -------
    Identifier
        Fitted: ``params_``, ``stderr_``, ``ci95_``, ``corr_``, ``current_``, ``verdict_``
        (usable / usable with caveats / unusable), ``reasons_``, ``validation_``;
        ``to_vessel()``, ``to_dict()``.

    Raises
    ------
    UnusableResultError
        The verdict is unusable and ``force`` is not set: nothing is written; the error's
        ``identifier`` is the fitted Identifier (None when nothing could be fitted) and
        ``reasons`` the reasons.
    """
    _check_paths([*(logs if isinstance(logs, (list, tuple)) else [logs]), validate], out, force, out_log)
    from ..identify import Identifier  # heavy: numpy, scipy, numba kernels
    from ..identify.data import INPUT_TOPICS  # heavy: with the Identifier
    from ..io.atomic import write_text_atomic

    if validate is not None and holdout:
        raise ConfigError("validate on a log or hold out a fraction, not both")
    if holdout is None and validate is not None:
        holdout = 0.0
    idf = Identifier(method, fix=dict(fix or {}), current=current, holdout=holdout,
                     max_current_mps=max_current_mps, model=model, fit_lag=fit_lag,
                     lag_s=lag_s, quadratic_surge=quadratic_surge)
    ves = _vessel_file(vessel)
    # the channels the fit reads; every channel only for the first log when a copy of it is written
    topics = list(INPUT_TOPICS)
    runs = [_read(x, progress, None if out_log is not None and i == 0 else topics)
            for i, x in enumerate(logs if isinstance(logs, (list, tuple)) else [logs])]
    val_log = _read(validate, progress, topics) if validate is not None else None
    if gnss_delay_s is not None:
        from ..estimate.latency import with_delays  # heavy: numpy

        if not (isinstance(gnss_delay_s, (int, float)) and -1.0 <= gnss_delay_s <= 5.0):
            raise ConfigError(f"gnss_delay_s = {gnss_delay_s!r} must be a latency in [-1, 5] s")
        runs = [with_delays(r, gnss=gnss_delay_s) for r in runs]
        val_log = with_delays(val_log, gnss=gnss_delay_s) if val_log is not None else None
    _say(progress, f"identifying ({method}) from {len(runs)} log(s)")
    # what the outputs need of the logs is taken now: the fit is handed the logs, not shared them,
    # and lets their channels go once it has made its arrays of them (the copy with the fit keeps the first)
    damage = [f"# {r.source}: {r.recovery.one_line()}\n" for r in runs if r.recovery is not None]
    first = runs[0] if out_log is not None else None
    idf.fit(_hand_over(runs), ves)
    if val_log is not None:
        idf.use_validation([idf.validate(val_log)])
    if not force:
        idf.raise_if_unusable()
    if out is not None:
        write_text_atomic(out, "".join(damage) + idf.to_vessel().to_toml() + idf.toml_record(), force=force)
    if first is not None:
        save(fit_log(idf, first), out_log, force=force)
    return idf


def _hand_over(items: list) -> list:
    """A new list of ``items``' elements, ``items`` emptied: the function it is passed to holds them alone."""
    out = list(items)
    items.clear()
    return out


def fit_log(idf: Identifier, log: FieldLog) -> FieldLog:
    """A copy of the first fitted log with the ``/identify/fit`` channel (measured vs model states).

    Parameters
    ----------
    idf : Identifier
        A fitted Identifier.
    log : FieldLog
        The first log it was fitted on.

    Returns
    -------
    FieldLog
        ``log``'s channels (shared, see :meth:`FieldLog.copy`) plus ``/identify/fit`` and a
        provenance record of the fit.
    """
    import numpy as np  # heavy: only when a fit is written

    from ..log.channels import channel_spec, frame_from_columns  # heavy: pandas

    t, cols = idf.fit_frame(0)
    t_ns = idf.runs_[0].t0_ns + np.round(t * 1e9).astype(np.int64)
    out = log.copy()
    out.set(FIT_TOPIC, frame_from_columns(cols, t_ns, channel_spec(FIT_TOPIC)))
    out.add_provenance(producer="usvlog identify", source=str(log.source or ""),
                       settings={"method": idf.method, "fix": idf.fix, "current": idf.current,
                                 "params": idf.params_.to_dict()},
                       result=idf.to_dict())   # params, intervals and verdict, for the report
    return out


# -----------------------------------------------------------------------------
# manoeuvres
# -----------------------------------------------------------------------------

def manoeuvres(log, *, progress: Progress = None) -> Manoeuvres:
    """Find the standard manoeuvres of a run and measure them (``usvlog manoeuvres``).

    Turning circles, zig-zags, speed steps, stops and pivot turns, found from the thrust
    commands and the state, with the definitions of ``docs/manoeuvres.md`` (the execute is the
    moment the differential command is applied); each metric with its one-sigma.

    Parameters
    ----------
    log : FieldLog or path
        The run, or its MCAP file. Its ``/estimate/state`` is used; a log without one is
        estimated first with the default settings (``usvlog estimate``'s kinematic model).
    progress : callable, optional
        Receives a line before the work (and before an estimate).

    Returns
    -------
    usvlog.trials.Manoeuvres
        In time order, times in s from the log's start; empty when the run has none
        (``to_dict()``, ``to_dataframe()``, ``format()``).

    Raises
    ------
    InputError
        The log has no ``/thrust/command`` (manoeuvres are found from the commands) or no
        usable state.
    UnusableResultError
        The stored estimate, or the one made here, has status ``failed``.
    """
    _check_paths([log], None, False)
    from ..errors import UnusableResultError  # light: the error tree, loaded already
    from ..trials import find_manoeuvres  # heavy: numpy, pandas

    src = log if _is_path(log) else log.source
    log = _read(log, progress)
    thrust = log.get("/thrust/command")
    if thrust is None or len(thrust) < 2:
        raise InputError(f"{src or 'log'}: no /thrust/command: manoeuvres are found from the thrust commands")
    state = log.get("/estimate/state")
    if state is None or len(state) < 10:
        from ..estimate import EstimateSettings  # heavy: the estimator
        from ..estimate.core import estimate as estimate_run
        from ..trials import MANOEUVRE_Q_R, MANOEUVRE_Q_UV

        _say(progress, f"estimating {src or 'the log'} for its manoeuvres")
        # a track that follows the manoeuvre: the general estimate's process noise rounds a
        # fast hull's 1 s yaw reversals (zig-zag overshoots 1-2 deg small, advance 6-12 % off
        # on the Otter runs); this one follows the compass and the fixes through them
        est = estimate_run(log, EstimateSettings(q_uv=MANOEUVRE_Q_UV, q_r=MANOEUVRE_Q_R))
        status, why = est.report.status, "; ".join(est.report.blocking)
        state = est.state
    else:
        from ..log.status import estimate_status  # light: the stored status (with the log)

        st = estimate_status(log)
        status, why = (st.status, st.headline()) if st is not None else ("ok", "")
    if status == "failed":   # nothing is measured on an estimate its maker disowned
        raise UnusableResultError(f"{src or 'log'}: the estimate failed ({why}); no manoeuvre measured - "
                                  "estimate it again")
    tr = log.time_range()
    _say(progress, f"finding manoeuvres in {src or 'the log'}")
    try:
        return find_manoeuvres(state, thrust, int(tr[0]) if tr else int(state.index[0]))
    except InputError as err:
        raise InputError(f"{src or 'log'}: {err}") from err
