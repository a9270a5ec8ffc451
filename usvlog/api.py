"""The Python API: one function per command line verb, with the verb's options and defaults.

Every function here is reached as ``usvlog.<name>`` (``usvlog.simulate``, ``usvlog.estimate``,
...). Each one is thin glue over the library (the same calls the verb of ``usvlog.cli`` makes,
which in turn calls these functions), takes logs either as :class:`~usvlog.FieldLog` objects or as
paths of canonical MCAP files, writes an output only when given one (atomically; an existing file
is replaced only with ``force=True``), and returns a result object. Nothing here prints: the
functions that take long accept ``progress``, a callable that receives a one-line description of
each stage as it starts (the command line prints these on stderr).

Errors a caller causes (a bad file, a wrong option) raise :class:`~usvlog.UsvlogError`
subclasses with a one-line message.

This module imports only the standard library at the top: each function imports the part of
the library it needs when it is called, so that ``import usvlog`` and ``usvlog --help`` stay fast.
"""

from __future__ import annotations

import difflib
import math
import os
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from .errors import ConfigError, InputError, StorageError

if TYPE_CHECKING:  # for annotations only: importing these at run time pulls numpy and pandas
    from .check import CheckResult
    from .control.gains import GainCheck, Gains
    from .estimate import EstimateResult
    from .identify import Identifier
    from .io.importers import ImportResult
    from .io.importers.catalog import Catalog
    from .log.fieldlog import FieldLog
    from .log.summary import LogSummary
    from .model.vessel import Vessel
    from .regress.stages import ScenarioOutcome
    from .replay import ReplayResult
    from .trials import Manoeuvres

PathLike = str | os.PathLike
Progress = Callable[[str], None] | None

FIT_TOPIC = "/identify/fit"

# the channels replay decodes when it reads a file (estimate: usvlog.estimate.core.INPUT_TOPICS);
# the others stay in it (decoded if the verb touches one after all, e.g. /truth/state when there is
# no estimate; copied undecoded to --out)
_REPLAY_READS = ["/estimate/state", "/thrust/command", "/control/state"]


def _is_path(x: Any) -> bool:
    return isinstance(x, (str, os.PathLike))


def _say(progress: Progress, msg: str) -> None:
    if progress is not None:
        progress(msg)


def _read(log, progress: Progress = None, topics=None, drawn=None, defer: bool = False):
    """``log`` itself when it is a FieldLog, else the canonical MCAP file at that path, loaded
    (only the channels ``topics`` when given; with ``defer`` the others stay in the file,
    decoded when touched and copied undecoded when the log is saved; ``drawn``: the channels a
    view or report draws, with the others only when they widen its time range,
    :func:`usvlog.view.source.read_drawn`).

    A damaged file loads with what could be recovered; then its one-line damage report
    ("input damaged: ...") goes to ``progress`` and into the log's provenance, so every
    output made from it carries the note.
    """
    if _is_path(log):
        from .io.mcap import read_log  # heavy: imported only when a log is read

        if drawn is not None:
            from .view.source import read_drawn  # heavy: numpy (view and report import it anyway)

            log = read_drawn(log, drawn, read_log)
        else:
            log = read_log(log, topics=topics, defer=defer)
        if log.recovery is not None:
            note = log.recovery.one_line()
            _say(progress, f"{log.source}: {note}")
            log.add_provenance(producer="usvlog load", source=str(log.source or ""), input_damage=note)
    return log


def _vessel_file(vessel):
    """None, a Vessel as given, or a vessel TOML file loaded."""
    if _is_path(vessel):
        from .io.config import load_vessel  # heavy: imports numpy (the vessel model)

        return load_vessel(vessel)
    return vessel


def _check_paths(inputs, out, force: bool, *more_out, parent: bool = True) -> None:
    """Refuse missing input logs and outputs that exist without ``force``, before a verb's heavy
    imports, with the same one-line errors the readers and writers would give later.

    ``inputs``: the paths among them are checked (logs given as objects are skipped; vessels are
    not passed: a bare name is a shipped vessel). ``out`` and ``more_out``: those not None.
    ``parent``: also require an output's directory to exist."""
    from .io.atomic import check_input, check_output  # light: os and pathlib

    for p in inputs:
        if _is_path(p):
            check_input(p)
    for o in (out, *more_out):
        if o is not None:
            check_output(o, force, parent=parent)


# -----------------------------------------------------------------------------
# logs: load, save, import, inspect, export
# -----------------------------------------------------------------------------

def load(path, **kwargs) -> FieldLog:
    """Load a canonical MCAP log, recovering what it can from a damaged file.

    Parameters
    ----------
    path : str, os.PathLike or list of them
        The MCAP file. A list of paths loads consecutive files of one run (a rotated
        recording, ``run_000.mcap``, ``run_001.mcap``, ...) as one log.
    **kwargs
        ``topics`` (list of str): load only these channels. ``strict`` (bool, single file
        only): raise instead of recovering a file cut short. ``defer`` (bool, single file
        only, with ``topics``): keep the other channels in the file, decoded when touched
        and copied undecoded by :func:`save` (see :func:`usvlog.io.mcap.read_log`).

    Returns
    -------
    FieldLog
        One DataFrame per channel indexed by ``t_ns`` (int64 ns since the Unix epoch);
        ``log.recovery`` says what was lost from a damaged file (None when nothing was).
    """
    from .io.mcap import read_log, read_logs  # heavy: the compiled MCAP reader (numpy, numba)

    if isinstance(path, (list, tuple)):
        return read_logs(path, **kwargs)
    return read_log(path, **kwargs)


def save(log: FieldLog, path: PathLike, force: bool = False, **kw) -> Path:
    """Write ``log`` as a canonical MCAP file, atomically.

    Parameters
    ----------
    log : FieldLog
        The run to write.
    path : str or os.PathLike
        Output file; its directory must exist.
    force : bool
        Replace an existing file (else :class:`~usvlog.errors.OutputExistsError`).
    **kw
        ``chunk_size`` (bytes of messages per zstd chunk, default 1 MiB) and ``compression``
        (``"zstd"``, default, or ``""`` for none).

    Returns
    -------
    pathlib.Path
        The path written.
    """
    from .io.mcap import write_log  # heavy: the compiled MCAP writer

    write_log(log, path, force=force, **kw)
    return Path(path)


def import_log(src: PathLike, out: PathLike | None = None, *, fmt: str = "auto", vessel=None,
               columns: dict[str, str] | None = None, topics: dict[str, str] | None = None,
               thrust_unit: str | None = None, start_utc: str | int | None = None, force: bool = False,
               on_mapping: Callable | None = None, prefix_time: str | None = None,
               thrust_range: str | tuple | None = None, keep_dead: bool = False,
               msg_dirs: Sequence[PathLike] = (), datum: str | tuple | None = None) -> ImportResult:
    """Import a field log (CSV, NMEA 0183, ROS 1/2 bag, ArduPilot .bin, PX4 .ulg): ``usvlog import``.

    Parameters
    ----------
    src : str or os.PathLike
        The field log file (or ROS 2 bag directory).
    out : str or os.PathLike, optional
        Stream the canonical log into this MCAP file (then ``result.log`` is None); without it
        the log is returned in memory.
    fmt : str
        ``"auto"`` (detected from the content, not the name) or one of
        :data:`usvlog.choices.IMPORT_FORMATS` (``--format``).
    vessel : Vessel or path, optional
        Vessel (or vessel TOML) whose thruster map turns non-newton commands into forces.
    columns : dict, optional
        CSV: role -> column header (roles: ``time_s``, ``lat_deg``, ``heading_deg``,
        ``thrust_left``, ...); what is not given is guessed.
    topics : dict, optional
        role -> ``SOURCE[.field.path[i]]`` as ``usvlog inspect SOURCE`` lists them (roles:
        ``gnss``, ``heading``, ``yaw_rate``, ``thrust``, ``thrust_left``, ``thrust_right``,
        ``velocity``, ``speed_mps``, ``course``); what is not given is chosen by structure.
    thrust_unit : str, optional
        Unit of the recorded thruster commands (:data:`usvlog.choices.THRUST_UNITS`);
        None guesses it from the values.
    start_utc : str or int, optional
        Time of the first sample of a log with relative times: ISO 8601 text or ns since the
        Unix epoch.
    force : bool
        Replace an existing ``out``.
    on_mapping : callable, optional
        Called with the import report once the column/topic mapping is known, before the bulk
        of the work.
    prefix_time : str, optional
        NMEA/text logs: ``"auto"`` or a ``strptime`` format to use the time stamps a logger
        wrote before each sentence, ``"none"`` never; None uses only stamps that say their
        zone (``--prefix-time``).
    thrust_range : str or tuple, optional
        ``"LO:HI"`` or ``(lo, hi)``: range of integer ``counts`` commands (``--thrust-range``);
        guessed from the values when None.
    keep_dead : bool
        Write channels the sensor health audit judges dead as data (``--keep-dead``); by
        default they go to ``/raw/...`` and are flagged.
    msg_dirs : sequence of str or os.PathLike
        ROS bags: directories whose ``.msg`` files (``<pkg>/msg/<Name>.msg``) define the
        message types the bag does not store (``--msg-dir``, repeatable).
    datum : str or tuple, optional
        ``"LAT,LON"`` or ``(lat, lon)`` in degrees (``--datum``): the origin of the local
        frame; positions in metres (``/local/position``) are then geo-referenced. None: the
        first fix (and local positions stay local).

    Returns
    -------
    ImportResult
        ``log`` (None when streamed to ``out``), ``report`` (mapping, guesses, counts, skipped
        records) and ``out``.
    """
    _check_paths([src], out, force, parent=False)   # the importer's own checks, before its imports
    from .io.importers import import_file  # heavy: the importers (numpy, pandas)

    return import_file(src, fmt, vessel=_vessel_file(vessel), columns=columns, topics=topics,
                       thrust_unit=thrust_unit, start_utc=start_utc, out=out, force=force,
                       on_mapping=on_mapping, prefix_time=prefix_time, thrust_range=thrust_range,
                       keep_dead=keep_dead, msg_dirs=msg_dirs, datum=datum)


def inspect(log, *, fmt: str = "auto", topics: dict[str, str] | None = None,
            msg_dirs: Sequence[PathLike] = ()) -> LogSummary | Catalog:
    """What is in a log or a foreign source (``usvlog inspect``).

    A canonical MCAP log gives its summary: the file is read a chunk at a time
    (:func:`usvlog.io.mcap.reader.iter_chunks`: every chunk's CRC checked, recovery past damage
    as :func:`load` does) and only its time stamps are looked at, so memory stays bounded
    (about 200 MB) whatever the file's size; payloads are not decoded (a message that does not
    fit its schema is reported by :func:`load`). Any other source (ROS 1/2 bag, ULog,
    DataFlash, NMEA, CSV) gives its catalog: every topic/message with type, count, time span
    and field paths, the role mapping ``usvlog import`` would use and why.

    Parameters
    ----------
    log : FieldLog or path
        The log, its MCAP file, or a foreign source file (a directory for a ROS 2 bag).
    fmt : str
        Format of a foreign source: ``"auto"`` (from the content) or one of
        :data:`usvlog.choices.IMPORT_FORMATS`.
    topics : dict, optional
        role -> ``SOURCE.field.path[i]`` for a foreign source, checked and honoured as
        ``usvlog import --topic`` would.
    msg_dirs : sequence of str or os.PathLike
        ROS bags: directories of ``.msg`` files for the types the bag does not store
        (``--msg-dir``).

    Returns
    -------
    LogSummary or Catalog
        LogSummary (canonical log): per channel count, nominal rate (Hz), first/last time (ns),
        duration (s), gaps longer than 3 periods, backwards and repeated time stamps; plus
        metadata, recovery and skipped-record counts. ``format_summary`` of
        :mod:`usvlog.log.summary` prints it, ``to_dict()`` gives the JSON form;
        ``recovery["nothing_recovered"]`` marks a damaged file with nothing in it
        (``usvlog inspect`` exits 1). Catalog (foreign source):
        :class:`usvlog.io.importers.catalog.Catalog`, printed by ``format_catalog``.
    """
    if _is_path(log):
        path = Path(log)
        if _is_canonical_candidate(path):
            return _inspect_file(path)
        from .io.importers import catalog_file  # heavy: the importers (numpy, pandas)

        return catalog_file(path, fmt, topics=topics, msg_dirs=msg_dirs)
    from .log.summary import summarize  # heavy: numpy, pandas

    return summarize(log)


def _is_canonical_candidate(path: Path) -> bool:
    """An MCAP file that is not a ROS 2 bag, a missing path, or a non-MCAP file named ``*.mcap``."""
    if not path.exists():
        return True
    if path.is_dir():
        return False
    try:
        with open(path, "rb") as fh:
            head = fh.read(64)
    except OSError as err:
        raise StorageError(f"{path}: cannot be read ({err.strerror or err})") from err
    if head.startswith(b"\x89MCAP0\r\n"):
        return b"ros2" not in head[8:64]  # the header record's profile names a ROS 2 bag
    return path.suffix.lower() == ".mcap"


def _inspect_file(path: Path) -> LogSummary:
    """:func:`inspect` of an MCAP file, streamed: the same summary as ``summarize(load(path))``."""
    # heavy: numpy, the MCAP reader
    from .io.mcap.reader import by_channel as split_channels
    from .io.mcap.reader import codec_of_channel, iter_chunks
    from .log.channels import schema_for_topic
    from .log.fieldlog import META_PROVENANCE
    from .log.summary import LogSummary, TimeStats, skipped_from_provenance

    def by_channel(chunk):
        """(channel id, its times, its sequence numbers) in the chunk, in file order."""
        groups = split_channels(chunk.channel_id)
        if len(groups) == 1:
            yield groups[0][0], chunk.log_time_ns, chunk.sequence
            return
        for c, ix in groups:
            yield c, chunk.log_time_ns[ix], chunk.sequence[ix]

    stats: dict[int, TimeStats] = {}
    with iter_chunks(path) as stream:
        for chunk in stream:
            for c, t, seq in by_channel(chunk):
                stats.setdefault(c, TimeStats()).add(t, seq)
        channels, meta, recovery = stream.channels, stream.metadata, stream.recovery()
    again = {c for c, st in stats.items() if st.needs_pass()}
    if again:   # a median from a histogram, or stamps out of order: read the stamps once more
        for c in again:
            stats[c].start_pass()
        with iter_chunks(path) as stream:
            for chunk in stream:
                for c, t, seq in by_channel(chunk):
                    if c in again:
                        stats[c].refine(t, seq)
    by_topic = {}
    for cid in sorted(channels):
        ch = channels[cid]
        if not ch.canonical:
            continue  # not a canonical channel: load leaves it alone too
        schema, _codec = codec_of_channel(path, ch)
        title = schema.get("title", "") or (schema_for_topic(ch.topic) or {}).get("title", "")
        by_topic[ch.topic] = stats.get(cid, TimeStats()).summary(ch.topic, title)
    chans = tuple(by_topic[t] for t in sorted(by_topic))
    firsts = [c.first_ns for c in chans if c.first_ns is not None]
    lasts = [c.last_ns for c in chans if c.last_ns is not None]
    first = min(firsts) if firsts else None
    last = max(lasts) if lasts else None
    prov_keys = sorted((k for k in meta if k.startswith(META_PROVENANCE + "/")), key=lambda k: int(k.rsplit("/", 1)[1]))
    return LogSummary(str(path), chans, first, last, (last - first) / 1e9 if first is not None else 0.0,
                      {k: dict(v) for k, v in meta.items()}, recovery.to_dict() if recovery else None,
                      skipped_from_provenance([meta[k] for k in prov_keys]))


def export(log, out: PathLike, *, fmt: str = "csv", force: bool = False,
           progress: Progress = None) -> list[Path]:
    """Write each channel of a log to ``out/<topic>.csv`` or ``.parquet`` (``usvlog export``).

    Parameters
    ----------
    log : FieldLog or path
        The log, or its MCAP file.
    out : str or os.PathLike
        Output directory (created when missing).
    fmt : str
        ``"csv"`` (default) or ``"parquet"`` (``--format``).
    force : bool
        Replace existing files (every output is checked before the first is written).
    progress : callable, optional
        Receives the one-line damage report of a damaged input file.

    Returns
    -------
    list of pathlib.Path
        The files written, one per channel; the index ``t_ns`` (ns since the Unix epoch) is
        the first column.
    """
    from .io.export import export_log  # heavy: pandas

    return export_log(_read(log, progress), out, fmt=fmt, force=force)


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
        path), with the vessel, datum and provenance.
    """
    _check_paths([], out, force)   # fail before the work (and the imports), not after
    from .resources import replay_dir  # heavy: the sim/io stack pulls numpy, pandas, numba
    from .sim.scenario import closed_loop_scenarios
    from .sim.simulate import SCENARIOS
    from .sim.simulate import simulate as simulate_open_loop

    name = str(scenario)
    if name not in SCENARIOS:
        p = Path(scenario)
        if not (p.suffix == ".toml" or p.exists() or "/" in name or (replay_dir() / f"{name}.toml").exists()):
            raise ConfigError(f"no scenario {name!r} (open loop: {', '.join(SCENARIOS)}; closed loop: "
                              f"{', '.join(closed_loop_scenarios())}; or a scenario TOML file)")
        log = _simulate_closed_loop(scenario, seed=seed, controller=controller, duration_s=duration_s,
                                    vessel=vessel, truth_rate_hz=truth_rate_hz, progress=progress)
    else:
        settings = _sim_settings(duration_s=duration_s, current_mps=current_mps, current_dir_deg=current_dir_deg,
                                 vessel=vessel, gps_noise_m=gps_noise_m, compass_noise_deg=compass_noise_deg,
                                 gps_bias_m=gps_bias_m, gps_jumps=gps_jumps, gps_dropouts=gps_dropouts,
                                 compass_bias_deg=compass_bias_deg, truth_rate_hz=truth_rate_hz)
        seed = 0 if seed is None else seed
        _say(progress, f"simulating {name} ({settings.duration_s:.0f} s, seed {seed})")
        log = simulate_open_loop(name, settings, seed=seed)
    if out is not None:
        save(log, out, force=force)
        _say(progress, f"wrote {out}")
    return log


def _sim_settings(*, duration_s, current_mps, current_dir_deg, vessel, gps_noise_m, compass_noise_deg,
                  gps_bias_m, gps_jumps, gps_dropouts, compass_bias_deg, truth_rate_hz):
    """SimSettings of an open-loop run (sensor defaults where an option is None)."""
    from .io.config import load_vessel  # heavy: numpy
    from .sim.simulate import SensorSettings, SimSettings

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


def _simulate_closed_loop(scenario, *, seed, controller, duration_s, vessel, truth_rate_hz, progress):
    """A closed-loop scenario (replay/<name>.toml or a file); the scenario holds the settings."""
    from .sim.closed_loop import simulate_scenario  # heavy: the compiled closed loop
    from .sim.scenario import load_scenario

    scen = load_scenario(scenario, vessel=_vessel_file(vessel))
    duration_s = None if duration_s is None else float(duration_s)
    if truth_rate_hz is not None:
        sens = replace(scen.sim.sensors, truth_rate_hz=float(truth_rate_hz))
        scen = replace(scen, sim=replace(scen.sim, sensors=sens))
    ctl = controller or scen.controller
    dur = duration_s or scen.sim.duration_s
    _say(progress, f"simulating {scen.name} closed loop ({dur:.0f} s, controller {ctl}, "
                   f"input {scen.controller_input})")
    return simulate_scenario(scen, controller=ctl, seed=seed, duration_s=duration_s)


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
    """
    _check_paths([log], out, force)   # before the heavy imports: a mistyped path fails at once
    from .estimate import EstimateSettings  # heavy: numpy, numba kernels
    from .estimate import estimate as run_estimate
    from .estimate.core import INPUT_TOPICS  # heavy: with the estimator

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
    log = _read(log, progress, topics=list(INPUT_TOPICS), defer=True)
    ves = _vessel_file(vessel)
    _say(progress, f"estimating {src} ({model} model{', tuning' if tune else ''}"
                   f"{''.join(f', estimating the {k} delay' for k in auto)})")
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
             max_current_mps: float = 0.5, gnss_delay_s: float | None = None, model: str = "paper") -> Identifier:
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
    from .identify import Identifier  # heavy: numpy, scipy, numba kernels
    from .identify.data import INPUT_TOPICS  # heavy: with the Identifier
    from .io.atomic import write_text_atomic

    if validate is not None and holdout:
        raise ConfigError("validate on a log or hold out a fraction, not both")
    if holdout is None and validate is not None:
        holdout = 0.0
    idf = Identifier(method, fix=dict(fix or {}), current=current, holdout=holdout,
                     max_current_mps=max_current_mps, model=model)
    ves = _vessel_file(vessel)
    # the channels the fit reads; every channel only for the first log when a copy of it is written
    topics = list(INPUT_TOPICS)
    runs = [_read(x, progress, None if out_log is not None and i == 0 else topics)
            for i, x in enumerate(logs if isinstance(logs, (list, tuple)) else [logs])]
    val_log = _read(validate, progress, topics) if validate is not None else None
    if gnss_delay_s is not None:
        from .estimate.latency import with_delays  # heavy: numpy

        if not (isinstance(gnss_delay_s, (int, float)) and -1.0 <= gnss_delay_s <= 5.0):
            raise ConfigError(f"gnss_delay_s = {gnss_delay_s!r} must be a latency in [-1, 5] s")
        runs = [with_delays(r, gnss=gnss_delay_s) for r in runs]
        val_log = with_delays(val_log, gnss=gnss_delay_s) if val_log is not None else None
    _say(progress, f"identifying ({method}) from {len(runs)} log(s)")
    idf.fit(runs, ves)
    if val_log is not None:
        idf.use_validation([idf.validate(val_log)])
    if not force:
        idf.raise_if_unusable()
    if out is not None:
        damage = [f"# {r.source}: {r.recovery.one_line()}\n" for r in runs if r.recovery is not None]
        write_text_atomic(out, "".join(damage) + idf.to_vessel().to_toml() + idf.toml_record(), force=force)
    if out_log is not None:
        save(fit_log(idf, runs[0]), out_log, force=force)
    return idf


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

    from .log.channels import channel_spec, frame_from_columns  # heavy: pandas

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
    from .io.config import load_vessel, load_vessel_or_scenario_vessel, read_toml  # heavy: numpy
    from .sim.scenario import load_gains, scenario_path

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
    from .control.gains import check_gains  # heavy: numpy, scipy

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
    from .io.config import load_vessel_or_scenario_vessel, read_toml  # heavy: numpy, numba kernels
    from .replay import replay_log
    from .sim.scenario import load_gains, load_scenario

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
    log = _read(log, progress, topics=_REPLAY_READS, defer=True)
    _say(progress, f"replaying with scenario {scen.name}")
    # memory: a log read here gives its channels back to the file once replay has used them
    res = replay_log(log, scen, vessel=vessel, gains=gains, controller=controller, whatif=whatif,
                     whatif_controller=whatif_controller, release_inputs=read_here)
    if out is not None:
        save(res.log, out, force=force)
        _say(progress, f"wrote {out}")
    return res


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
    from .errors import UnusableResultError  # light: the error tree, loaded already
    from .trials import find_manoeuvres  # heavy: numpy, pandas

    src = log if _is_path(log) else log.source
    log = _read(log, progress)
    thrust = log.get("/thrust/command")
    if thrust is None or len(thrust) < 2:
        raise InputError(f"{src or 'log'}: no /thrust/command: manoeuvres are found from the thrust commands")
    state = log.get("/estimate/state")
    if state is None or len(state) < 10:
        est = estimate(log, progress=progress)
        status, why = est.report.status, "; ".join(est.report.blocking)
        state = est.state
    else:
        from .log.status import estimate_status  # light: the stored status (with the log)

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


# -----------------------------------------------------------------------------
# check
# -----------------------------------------------------------------------------

def check(log, *, vessel=None, fmt: str = "auto", msg_dirs: Sequence[PathLike] = (),
          progress: Progress = None) -> CheckResult:
    """Is this log sound, and what is wrong with the boat's sensors (``usvlog check``)?

    Parameters
    ----------
    log : FieldLog or path
        A log, its canonical MCAP file, or any field log ``usvlog import`` reads: that one is
        imported in memory first with the import's own guesses (an import that keeps too
        little is checked all the same, its reason an error finding).
    vessel : Vessel or path, optional
        The boat (thruster map and limits, heading offset); default the log's own.
    fmt : str
        Format of a field log (``"auto"``: from the content).
    msg_dirs : sequence of str or os.PathLike
        ROS bags: directories of ``.msg`` files for types the bag does not store.
    progress : callable, optional
        Receives a line per stage.

    Returns
    -------
    usvlog.check.CheckResult
        The findings (severity, channel, time range from the log's start, evidence, action)
        and the checks that ran; ``exit_code`` is 1 when any finding is an error.
    """
    from .log.findings import Finding, findings_from_health  # light: standard library only

    extra: list = []
    if _is_path(log) and not _is_canonical_candidate(Path(log)):
        _say(progress, f"importing {log} in memory")
        res = import_log(log, fmt=fmt, vessel=vessel, force=True, msg_dirs=msg_dirs)
        rep = res.report
        if rep.unusable:
            extra.append(Finding(severity="error", code="import.unusable", evidence=str(rep.unusable),
                                 action="fix the mapping or the time column at import"))
        topic = {"gnss": "/gnss/fix", "heading": "/compass/heading", "yaw_rate": "/imu/yaw_rate",
                 "velocity": "/gnss/velocity", "local": "/local/position"}
        held = {topic.get(k[:-len("_held_repeat")], k): int(n) for k, n in rep.skipped.items()
                if k.endswith("_held_repeat")}
        extra += findings_from_health(None, held)
        log = res.log
    else:
        if _is_path(log):
            _check_paths([log], None, False)
        log = _read(log, progress)
    from .check import check_log  # heavy: numpy, scipy and the identification's smoother

    _say(progress, "checking")
    return check_log(log, _vessel_file(vessel), extra=extra)


# -----------------------------------------------------------------------------
# view, report, regress
# -----------------------------------------------------------------------------

def to_rrd(logs, out: PathLike | None = None, *, names: Sequence[str] | None = None, force: bool = False,
           progress: Progress = None) -> Path:
    """Write logs to a Rerun ``.rrd`` recording with its blueprint inside (``usvlog view``).

    Parameters
    ----------
    logs : FieldLog, path, or a list of them
        The runs; several are overlaid.
    out : str or os.PathLike, optional
        Output ``.rrd`` (default: the first log's file with the suffix ``.rrd``).
    names : sequence of str, optional
        Name of each log in the viewer (default: the file names).
    force : bool
        Replace an existing ``out``.
    progress : callable, optional
        Receives a line as each log is read and as writing starts.

    Returns
    -------
    pathlib.Path
        The recording written (open it with ``rerun FILE``).
    """
    from .io.atomic import check_output  # heavy: numpy
    from .view.source import VIEW_READ  # heavy: numpy (with the recording's imports below)

    items = list(logs) if isinstance(logs, (list, tuple)) else [logs]
    if not items:
        raise InputError("nothing to view: no logs given")
    if out is None:
        first = items[0]
        src = first if _is_path(first) else first.source
        if not src:
            raise ConfigError("out is needed for a log that was not loaded from a file")
        out = Path(src).with_suffix(".rrd")
    out = Path(out)
    check_output(out, force, parent=True)  # fail before the work, not after
    if names is not None and len(names) != len(items):
        raise InputError(f"{len(names)} names for {len(items)} logs (one name per log)")
    read = []
    for x in items:
        if _is_path(x):
            _say(progress, f"reading {x}")
        read.append(_read(x, progress, drawn=VIEW_READ))
    from .view.data import refuse_failed_estimate, warnings  # heavy: numpy
    from .view.rrd import to_rrd as write_rrd  # heavy: rerun is imported only when a recording is made

    for lg in read:
        refuse_failed_estimate(lg)
    for lg in read:
        for w in warnings(lg):
            if not w.startswith("input damaged"):   # _read said those already
                _say(progress, f"warning: {lg.source or 'log'}: {w}")
    _say(progress, f"writing {out}")
    return write_rrd(read, out, names=None if names is None else list(names), force=force)


def report(log, out: PathLike, baseline=None, *, axes: str = "paper", force: bool = False,
           progress: Progress = None) -> Path:
    """Write an HTML report with PNG figures in the style of the paper (``usvlog report``).

    Parameters
    ----------
    log : FieldLog or path
        The run, or its MCAP file.
    out : str or os.PathLike
        Output directory (``report.html`` and the figures; created when missing).
    baseline : FieldLog or path, optional
        A second run (e.g. the PI/PID baseline) compared in Fig. 2.
    axes : str
        ``"paper"`` (X = north to the right, Y = east up, as in the paper) or ``"map"``
        (north up).
    force : bool
        Replace existing files.
    progress : callable, optional
        Receives a line as writing starts.

    Returns
    -------
    pathlib.Path
        The page ``out/report.html``.
    """
    from .view.report import check_report_outputs, write_report  # heavy: matplotlib, numpy
    from .view.source import REPORT_READ  # heavy: numpy (with the report's imports above)

    check_report_outputs(out, force)  # fail before the work, not after
    log = _read(log, progress, drawn=REPORT_READ)
    base = _read(baseline, progress, drawn=REPORT_READ) if baseline is not None else None
    from .view.data import refuse_failed_estimate, warnings  # heavy: numpy (with the report's imports above)

    for lg in (log, base):
        if lg is not None:
            refuse_failed_estimate(lg)
    for w in warnings(log):
        if not w.startswith("input damaged"):   # _read said those already
            _say(progress, f"warning: {w}")
    _say(progress, f"writing report to {out}")
    return write_report(log, out, baseline=base, force=force, axes=axes)


def regress(paths: Sequence[PathLike] | None = None, *, update: bool = False, junit: PathLike | None = None,
            force: bool = False, jobs: int | None = None, progress: Progress = None,
            on_start: Callable[[list[Path]], None] | None = None,
            on_outcome: Callable[[ScenarioOutcome], None] | None = None, workers: int | None = None,
            scheduler: str | None = None) -> list[ScenarioOutcome]:
    """Re-run recorded datasets through estimate/identify/replay and gate on baselines (``usvlog regress``).

    Parameters
    ----------
    paths : sequence of str or os.PathLike, optional
        Regression scenario files (TOML with ``[dataset]``) or directories of them
        (default: the shipped ``replay/``).
    update : bool
        Accept the current metrics as the new baselines (rewrites the baseline files; the
        differences go to ``progress``).
    junit : str or os.PathLike, optional
        Also write JUnit XML for a CI system (its place is checked before any scenario runs).
    force : bool
        Replace an existing ``junit`` file.
    jobs : int, optional
        Deprecated alias of ``workers`` (it ran a process pool of its own before the campaign
        engine did the parallel runs).
    progress : callable, optional
        Receives the unified diff of each baseline that ``update`` changes.
    on_start : callable, optional
        Called with the list of scenario files once they are found and their datasets checked,
        before the first runs.
    on_outcome : callable, optional
        Called with each scenario's outcome as it finishes.
    workers : int, optional
        Run the scenarios as Dask tasks on a local cluster of this many processes (the
        campaign engine, :class:`usvlog.campaign.engine.Runner`); without it and without
        ``scheduler`` they run one after the other in this process.
    scheduler : str, optional
        Run them on a running Dask scheduler (``tcp://host:8786``) instead.

    Returns
    -------
    list of ScenarioOutcome
        One per scenario: metrics, the checks against the baseline, seconds, error; an outcome
        ``failed`` when a metric regressed or the run failed.
    """
    from .campaign.engine import Runner  # the campaign engine runs the scenarios (dask only once tasks run)
    from .io.atomic import check_output, write_text_atomic  # heavy: the regression stages pull the library
    from .regress.baselines import (
        find_regress_scenarios,
        format_baseline,
        load_regress_scenario,
        read_baseline,
        write_baseline,
    )
    from .regress.gate import junit_xml
    from .regress.stages import accept
    from .resources import replay_dir

    if jobs is not None:   # the deprecated name of workers
        import warnings  # only for the deprecated option

        warnings.warn("regress(jobs=N) is deprecated: use workers=N (the campaign engine's local Dask cluster)",
                      DeprecationWarning, stacklevel=2)
        if workers is not None and workers != jobs:
            raise ConfigError(f"--jobs {jobs} and --workers {workers} differ (--jobs is the old name of --workers)")
        workers = jobs
    parallel = workers is not None or bool(scheduler)
    runner = Runner(workers=workers, scheduler=scheduler, sequential=not parallel,   # options checked here
                    on_start=lambda info: _say(progress, f"dask: {info.scheduler}; dashboard "
                                                         f"{info.dashboard or '(none)'}"))
    if junit:  # the report's place is checked before the scenarios run, not after
        check_output(junit, force, parent=True)
    found = find_regress_scenarios(list(paths) if paths else [replay_dir()])
    if not found:
        raise ConfigError("no regression scenarios found (a scenario has a [dataset] section)")
    _check_datasets(found, shipped=not paths)
    if on_start:
        on_start(found)
    with runner:   # no cluster starts for the sequential path
        outcomes: list[ScenarioOutcome] = runner.map(_regress_one, [str(p) for p in found],
                                                     on_result=(lambda i, o: on_outcome(o)) if on_outcome else None)
    if update:
        for p, o in zip(found, outcomes):
            if o.error:
                continue
            scn = load_regress_scenario(p)
            old = read_baseline(scn.baseline)
            new = accept(o, old)
            before = format_baseline(old).splitlines()
            after = format_baseline(new).splitlines()
            if before != after:
                _say(progress, "".join(difflib.unified_diff([x + "\n" for x in before], [x + "\n" for x in after],
                                                            str(scn.baseline), str(scn.baseline) + " (new)")))
                scn.baseline.parent.mkdir(parents=True, exist_ok=True)
                write_baseline(scn.baseline, new, header=f"Accepted metrics of regression scenario {scn.name}.\n"
                               f"Dataset: {scn.dataset.name}. Rewrite with: usvlog regress {p.name} --update")
    if junit:
        checks = [c for o in outcomes for c in o.checks]
        write_text_atomic(junit, junit_xml(checks, {o.name: o.seconds for o in outcomes},
                                           {o.name: o.error for o in outcomes if o.error}), force=force)
    return outcomes


def _regress_one(path: str) -> ScenarioOutcome:
    """Load a scenario and its baseline, run it (top level: runs in worker processes)."""
    from .regress.baselines import load_regress_scenario, read_baseline  # heavy: the regression stages
    from .regress.stages import run_scenario

    scn = load_regress_scenario(path)
    return run_scenario(scn, read_baseline(scn.baseline))


def _check_datasets(paths, *, shipped: bool) -> None:
    """Every scenario's recorded run must exist: a missing one is the user's error, before any work."""
    from .regress.baselines import load_regress_scenario  # heavy: the regression stages

    scns = [load_regress_scenario(p) for p in paths]
    missing = [s for s in scns if not s.dataset.exists()]
    if not missing:
        return
    hint = ""
    if shipped and len(missing) == len(scns):
        hint = ("; the shipped scenarios' datasets are in tests/data/ of a source checkout, not in the installed "
                "package: run usvlog regress in a checkout, or give your own scenarios")
    raise StorageError(f"{missing[0].dataset}: dataset of scenario {missing[0].name} not found "
                       f"({len(missing)} of {len(scns)} scenarios miss theirs){hint}")


# -----------------------------------------------------------------------------
# campaign
# -----------------------------------------------------------------------------

def campaign(sources, out: PathLike, *, vessel=None, vessel_map=None, stages: Sequence[str] | None = None,
             scheduler: str | None = None, workers: int | None = None, joint: bool = False,
             estimate_model: str = "kinematic", method: str = "output-error", holdout: float = 0.25,
             fix: dict[str, float] | None = None, current: bool = True, scenario: str | None = None,
             sequential: bool = False, report: bool = True, progress: Progress = None,
             on_plan: Callable[[int, int], None] | None = None, on_row: Callable[[dict], None] | None = None):
    """Take many runs through the stages on Dask, find parameter drift, write one report (``usvlog campaign``).

    Each run is one Dask task that calls this module's :func:`import_log` (or :func:`load`),
    :func:`estimate`, :func:`identify` and :func:`replay`; a run is keyed by its content and
    the settings, so a second campaign into the same ``out`` skips the finished runs.

    Parameters
    ----------
    sources : sequence of str or os.PathLike
        Field logs of any importable format or canonical MCAP logs: files, directories
        (their files) and globs.
    out : str or os.PathLike
        Campaign directory: ``runs.parquet``, ``runs/<run_id>/`` (``log.mcap``,
        ``estimate.mcap``, ``vessel.toml``, ``row.json``), ``campaign.html``, the drift PNGs,
        ``campaign.rrd``, ``campaign.json``.
    vessel : Vessel TOML path, optional
        The vessel of every run (thruster map, start values).
    vessel_map : path, optional
        A TOML of ``[vessel.NAME]`` tables with ``file`` and ``match`` (source patterns).
    stages : sequence of str, optional
        From ``import``, ``estimate``, ``identify``, ``replay`` (default ``import``,
        ``estimate``, ``identify``; ``replay`` also when ``scenario`` is given).
    scheduler : str, optional
        Address of a running Dask scheduler (``tcp://host:8786``); the workers must see
        the sources and ``out`` at the same paths.
    workers : int, optional
        Processes of the local Dask cluster (default: the core count), one thread each.
    joint : bool
        Also fit one model per vessel from all its usable runs, validated leave-one-run-out.
    estimate_model, method, holdout, fix, current, scenario
        The stages' options: :func:`estimate` ``model``; :func:`identify` ``method``,
        ``holdout`` (validation fit % on the last fraction of each run), ``fix`` (SI),
        ``current``; :func:`replay` ``scenario`` (giving one adds the replay stage; a
        listed ``replay`` without it replays ``paper-circle``).
    sequential : bool
        Run in this process without Dask.
    report : bool
        Write the HTML report, its PNGs and the Rerun recording.
    progress : callable, optional
        Receives one-line notes (the cluster and its dashboard address, files written).
    on_plan : callable, optional
        Called with (runs to do, runs finished before) before the first task.
    on_row : callable, optional
        Called with each run's row (a dict of the table's columns) as it finishes.

    Returns
    -------
    usvlog.campaign.core.CampaignResult
        ``table`` (``runs.parquet``), ``drift`` ({vessel: {parameter: ParameterDrift}}),
        ``joint``, ``executed`` and ``reused`` run counts, ``files``.
    """
    from .campaign.core import run_campaign  # heavy: numpy, pandas; dask only once tasks run
    from .campaign.tasks import RunSettings, Stages

    settings = RunSettings(stages=tuple(stages) if stages else RunSettings().stages, estimate_model=estimate_model,
                           method=method, holdout=holdout, fix=dict(fix or {}), current=current, scenario=scenario)
    fns = Stages(load=load, import_log=import_log, save=save, estimate=estimate, identify=identify, replay=replay)
    return run_campaign(list(sources) if isinstance(sources, (list, tuple)) else [sources], out, stages=fns,
                        settings=settings, vessel=vessel, vessel_map=vessel_map, workers=workers,
                        scheduler=scheduler, joint=joint, sequential=sequential, report=report,
                        progress=progress, on_plan=on_plan, on_row=on_row)


__all__ = ["campaign", "estimate", "export", "fit_log", "gains", "gains_and_vessel", "identify", "import_log",
           "inspect", "load", "regress", "replay", "report", "save", "simulate", "to_rrd"]
