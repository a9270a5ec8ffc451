"""Rerun visualisation of runs and replays: FieldLog(s) -> .rrd with a blueprint inside.

The rrd modules are the only ones that import rerun. Everything is sent with ``send_columns``
(whole arrays at once); per-row logging is some 50x slower (see benchmarks/bench_view.py).

Entity tree, one subtree per log (``name`` defaults to the log file's stem)::

    /runs/<name>/map/{gps, gps_rejected, estimate, truth, whatif, path, boat}   GeoPoints / GeoLineStrings
    /runs/<name>/local/{...same..., ctl_<ctl>/closest, ctl_<ctl>/carrot, ctl_<ctl>/arrows} 2D, x = east, y = -north
    /runs/<name>/ts/<quantity>/<series>                                       Scalars (fit/: identification)
    /runs/<name>/events                                                       TextLog
    /runs/<name>/check                                   TextLog: the findings of usvlog check, at their start
    /runs/<name>/manoeuvres (start and end of each), /runs/<name>/local/manoeuvres (its stretch)

``<ctl>`` is ``control`` (closed-loop simulation), ``replay`` (controller replayed on a
recorded run) or ``whatif``. The local 2D view draws x = east and y = -north, so with
the viewer's y axis pointing down north is up and east is right. Timeline ``time`` (UTC); with
several logs also ``elapsed`` (since each log's start, so runs recorded on different days overlay).
Tracks and per-tick overlays are thinned to at most 10 Hz; time series keep every sample. A long log
read a time window at a time (:mod:`usvlog.view.windowed`) is drawn a block of rows at a time
(:mod:`usvlog.view.rrd_windows`): the same recording, its memory flat in the log's length.

This module writes the .rrd (:func:`to_rrd`) and opens it in a viewer (:func:`spawn_viewer`,
:func:`serve`); what goes into it is drawn by a writer per log (:mod:`usvlog.view.rrd_writer`,
with its parts in :mod:`usvlog.view.rrd_tracks`, :mod:`usvlog.view.rrd_series` and
:mod:`usvlog.view.rrd_events`; shared names and colours in :mod:`usvlog.view.rrd_style`) and laid
out by :mod:`usvlog.view.rrd_blueprint`.
"""

from __future__ import annotations

import contextlib
import math
import os
import signal
import subprocess
import sys
import uuid
from pathlib import Path

import rerun as rr

from ..errors import ConfigError, InputError
from ..io.atomic import atomic_path, check_output
from ..io.atomic import deferred_signals as _deferred
from ..log.fieldlog import FieldLog
from .rrd_blueprint import build_blueprint
from .rrd_style import _safe, default_names
from .rrd_writer import _Writer
from .windowed import NotWindowed, whole

# isort: split
# names other modules import from here (the tests), their code now in the rrd_* modules
from .rrd_blueprint import map_zoom, y_range  # noqa: F401
from .rrd_style import SERIES_PALETTE, scalar_column  # noqa: F401
from .rrd_tracks import OVERLAY_HZ

APP_ID = "usvlog"
DEFAULT_HOST = "127.0.0.1"


# -----------------------------------------------------------------------------
# public API
# -----------------------------------------------------------------------------

def _recording(logs: list[FieldLog], names: list[str]) -> rr.RecordingStream:
    key = "|".join(f"{n}:{lg.time_range()}" for n, lg in zip(names, logs))
    rid = uuid.uuid5(uuid.NAMESPACE_URL, "usvlog:" + key)
    return rr.RecordingStream(APP_ID, recording_id=rid, send_properties=False)   # properties: see _name


def recording_name(names: list[str]) -> str:
    """The name the viewer lists the recording under: the runs' names (``paper_circle``, ``a + b``)."""
    return " + ".join(names)


def _name(rec: rr.RecordingStream, logs: list[FieldLog], names: list[str]) -> None:
    """Name the recording after its runs and start it at the first log's start (not the wall clock:
    the same logs give the same file)."""
    rec.send_recording_name(recording_name(names))
    tr = logs[0].time_range()
    if tr:
        rec.send_recording_start_time_nanos(int(tr[0]))


def _prepare(logs, names):
    if isinstance(logs, FieldLog):
        logs = [logs]
    logs = list(logs)
    if not logs:
        raise InputError("nothing to view: no logs given")
    if names is None:
        names = default_names(logs)
    else:
        names = [_safe(n) for n in names]
        if len(names) != len(logs) or len(set(names)) != len(names):
            raise InputError(f"need {len(logs)} distinct names, got {names}")
    for log, name in zip(logs, names):
        if log.time_range() is None:
            raise InputError(f"{log.source or name}: log has no data to view")
    return logs, names


def _draw(rec, logs, names) -> list[_Writer]:
    writers = []
    multi = len(logs) > 1
    for i, (log, name) in enumerate(zip(logs, names)):
        w = _Writer(rec, log, name, i, multi)
        w.draw()
        writers.append(w)
    return writers


def to_rrd(logs: list[FieldLog] | FieldLog, out_path, *, names: list[str] | None = None,
           force: bool = False) -> Path:
    """Write one or several logs to an .rrd file with the blueprint stored inside.

    Several logs are overlaid under ``/runs/<name>/`` (names default to the files' stems)
    and also shown side by side; the time panel then starts on the ``elapsed`` timeline.

    Parameters
    ----------
    logs : FieldLog or list of FieldLog
        Raw, estimated, replayed or simulated logs; whatever channels they hold are drawn
        (GPS and estimated/true tracks on a map and in local NED metres, controller
        overlays, time series, events).
    out_path : str or os.PathLike
        The .rrd file to write (atomically).
    names : list of str, optional
        One distinct name per log (made safe for entity paths); default
        :func:`default_names`.
    force : bool, default False
        Overwrite an existing file.

    Returns
    -------
    pathlib.Path
        The written file; open it with :func:`spawn_viewer` or :func:`serve`.

    Raises
    ------
    usvlog.errors.InputError
        If no logs are given, a log has no data, or ``names`` are not distinct or do
        not match the logs.
    usvlog.errors.OutputExistsError
        If ``out_path`` exists and ``force`` is False.
    usvlog.errors.StorageError
        If the file cannot be written.
    """
    logs, names = _prepare(logs, names)
    out = check_output(out_path, force)
    try:
        return _write(logs, names, out, force)
    except NotWindowed:   # a log's file could not be read in windows after all: drawn from the whole log
        return _write([whole(lg) for lg in logs], names, out, force)


def _write(logs: list[FieldLog], names: list[str], out: Path, force: bool) -> Path:
    rec = _recording(logs, names)
    with atomic_path(out, force=force) as tmp:
        rec.save(tmp)
        try:
            _name(rec, logs, names)
            writers = _draw(rec, logs, names)
            # the blueprint depends on what the logs hold, so it goes in last (stored as the default)
            rec.send_blueprint(build_blueprint(writers), make_active=True, make_default=True)
            rec.flush()
        finally:
            rec.disconnect()
    return out


def viewer_command(rrd_path, *, serve: bool = False, host: str = DEFAULT_HOST, port: int | None = None,
                   grpc_port: int | None = None) -> list[str]:
    """The ``rerun`` command that opens (or serves to a browser) an .rrd file.

    Both the native viewer and the server bind ``host`` (127.0.0.1 unless given; rerun's own
    default is every interface, 0.0.0.0). ``port`` is the web viewer's HTTP port (``serve``
    only) and ``grpc_port`` the data server's port (the native viewer's is 9876).

    Parameters
    ----------
    rrd_path : str or os.PathLike
        The recording.
    serve : bool, default False
        Serve a web viewer and the data instead of opening the native viewer.
    host : str, default "127.0.0.1"
        Address every listening socket binds.
    port, grpc_port : int, optional
        TCP ports (default: rerun's, 9090 and 9876).

    Returns
    -------
    list of str
        The command (see :func:`rerun_executable`).
    """
    cmd = [*rerun_executable(), "--bind", host]
    if serve:
        cmd.append("--serve-web")
        if port is not None:
            cmd += ["--web-viewer-port", str(int(port))]
    if grpc_port is not None:
        cmd += ["--port", str(int(grpc_port))]
    cmd.append(str(rrd_path))
    return cmd


def rerun_executable() -> list[str]:
    """The rerun viewer binary shipped with rerun-sdk, found as its ``rerun`` launcher finds it.

    Run directly (not through the Python launcher, which would start it as a grandchild), so the
    process started is the viewer or server itself. Falls back to ``python -m rerun_cli``.
    """
    import importlib.util  # only to locate the binary

    if os.environ.get("RERUN_CLI_PATH"):
        return [os.environ["RERUN_CLI_PATH"]]
    spec = importlib.util.find_spec("rerun_cli")
    if spec is not None and spec.submodule_search_locations:
        pkg = Path(list(spec.submodule_search_locations)[0])
        exe = ".exe" if sys.platform.startswith("win") else ""
        for cand in (pkg / "Rerun.app" / "Contents" / "MacOS" / "Rerun", pkg / f"rerun{exe}"):
            if cand.is_file() and os.access(cand, os.X_OK):
                return [str(cand)]
    return [sys.executable, "-m", "rerun_cli"]


def display_missing(environ=None, platform: str | None = None) -> bool:
    """True on a Linux/BSD machine without a graphical session (neither DISPLAY nor WAYLAND_DISPLAY set).

    macOS and Windows always have a display for the native viewer.
    """
    env = os.environ if environ is None else environ
    plat = sys.platform if platform is None else platform
    if plat.startswith(("win", "darwin", "cygwin")):
        return False
    return not (env.get("DISPLAY") or env.get("WAYLAND_DISPLAY"))


def open_elsewhere(rrd_path) -> str:
    """The command that opens ``rrd_path`` on a machine with a display (``rerun FILE.rrd``)."""
    import shlex  # only for this message

    return f"rerun {shlex.quote(str(rrd_path))}"


def no_display_message(rrd_path) -> str:
    """The one-line error of ``--spawn`` without a display: where the recording is and how to open it."""
    return (f"--spawn: no display here (DISPLAY and WAYLAND_DISPLAY are unset), no viewer started; the recording "
            f"is {rrd_path}: open it on a machine with a display with `{open_elsewhere(rrd_path)}`, or serve it "
            f"to a browser with --serve")


def spawn_viewer(rrd_path, *, host: str = DEFAULT_HOST, grpc_port: int | None = None,
                 check_s: float = 2.0) -> subprocess.Popen:
    """Open the native viewer on an .rrd file, bound to ``host`` (127.0.0.1); it outlives this process.

    Parameters
    ----------
    rrd_path : str or os.PathLike
        The recording.
    host : str, default "127.0.0.1"
        Address the viewer's data server binds.
    grpc_port : int, optional
        Its port (default 9876).
    check_s : float, default 2.0
        Seconds to watch for a viewer that fails at once (its own messages then come before
        this error, not after the shell's prompt).

    Returns
    -------
    subprocess.Popen
        The viewer (in its own session).

    Raises
    ------
    usvlog.errors.ConfigError
        If there is no display (nothing is started: the message names the file and the command
        that opens it elsewhere), or the viewer exits with an error within ``check_s``.
    """
    if display_missing():
        raise ConfigError(no_display_message(rrd_path))
    proc = subprocess.Popen(viewer_command(rrd_path, host=host, grpc_port=grpc_port), start_new_session=True)
    try:
        rc = proc.wait(timeout=check_s)
    except subprocess.TimeoutExpired:
        return proc
    if rc != 0:
        raise ConfigError(f"--spawn: the Rerun viewer stopped at once (exit code {rc}, its messages are above); "
                          f"the recording is {rrd_path}: open it with `{open_elsewhere(rrd_path)}`")
    return proc  # it handed the file to a viewer already running, or the window was closed


def serve(rrd_path, *, host: str = DEFAULT_HOST, port: int | None = None, grpc_port: int | None = None) -> int:
    """Serve an .rrd file to a browser viewer until interrupted; returns the exit code.

    The server runs in its own process group, and however this call ends (the server exits,
    Ctrl-C, SIGTERM or SIGHUP turned into an exception by the CLI, an error) the whole group is
    stopped: SIGTERM, then SIGKILL after 10 s. Ctrl-C is the normal way to stop and returns 0;
    an interruption carrying a ``signum`` attribute (the CLI's ``Terminated``) propagates after
    the clean-up.

    Parameters
    ----------
    rrd_path : str or os.PathLike
        The recording.
    host : str, default "127.0.0.1"
        Address the web viewer and the data server bind.
    port, grpc_port : int, optional
        HTTP port of the web viewer (default 9090) and port of the data server (default 9876).

    Returns
    -------
    int
        The server's exit code, or 0 when stopped with Ctrl-C.
    """
    proc = None
    try:  # not under deferred signals: the child would inherit the blocked mask
        proc = subprocess.Popen(viewer_command(rrd_path, serve=True, host=host, port=port, grpc_port=grpc_port),
                                start_new_session=True)
        return proc.wait()
    except KeyboardInterrupt as err:
        if getattr(err, "signum", None) is not None:
            raise
        return 0
    finally:
        if proc is not None:
            _stop_group(proc)


def _stop_group(proc: subprocess.Popen, grace_s: float = 10.0) -> None:
    """Stop every process of ``proc``'s group (SIGTERM, then SIGKILL) and wait, bounded, until it is gone."""
    import time  # only on the way out

    with _deferred():  # a second Ctrl-C or SIGTERM does not cut the clean-up short
        for sig, wait_s in ((signal.SIGTERM, grace_s), (signal.SIGKILL, 5.0)):
            try:
                os.killpg(proc.pid, sig)
            except ProcessLookupError:
                break
            except PermissionError:  # pragma: no cover - a pid reused by another user's process
                break
            deadline = time.monotonic() + wait_s
            while time.monotonic() < deadline:
                with contextlib.suppress(subprocess.TimeoutExpired):
                    proc.wait(timeout=0.05)  # reaps the server (or the launcher of the fallback command)
                try:
                    os.killpg(proc.pid, 0)
                except ProcessLookupError:
                    return
                time.sleep(0.05)
        with contextlib.suppress(subprocess.TimeoutExpired):
            proc.wait(timeout=1.0)


__all__ = ["to_rrd", "build_blueprint", "viewer_command", "display_missing", "no_display_message",
           "open_elsewhere", "spawn_viewer",
           "serve", "default_names",
           "OVERLAY_HZ", "math"]
