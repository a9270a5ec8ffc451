"""Live view of a recording: what the recorder writes, streamed to a Rerun viewer as it comes.

:class:`LiveView` is a subscriber of :class:`usvlog.io.record.Recorder` (``Recorder.subscribe``).
On the recorder's hot path it keeps at most ``max_hz`` messages per second of each topic
(the recorder's status: all) and appends those as ``(topic, row, t_ns)`` to a bounded queue,
counting what does not fit (never waits, takes no lock). Its own thread drains the queue
every ``batch_s``, runs the online EKF (:class:`usvlog.estimate.OnlineEKF`, kinematic model,
no thrust needed) on the fixes and headings, and sends each series as one column per batch::

    /map/fixes, /map/track, /map/boat        raw fixes, online EKF track, where the boat is now
                                             (static: redrawn every batch, thinned to MAP_POINTS)
    /heading/compass, /heading/ekf           deg, clockwise from north, [0, 360)
    /speed/ekf                               speed over ground, m/s
    /thrust/left, /thrust/right              the commands as sent, in their unit
    /status/<source>/{rate_hz,bad_lines,dropped}   the recorder's counters
    /status/view/dropped                     messages this view dropped (its queue was full)

A display needs no more than ``max_hz`` (default 20 Hz) per series: the MCAP keeps
everything, the view draws what the eye can follow, and the SDK encodes a few columns a
second (what the view costs the recorder: ``benchmarks/bench_record.py``). Every
``probe_s`` the thread checks that the viewer is still there (its TCP port accepts, the
spawned viewer runs); a viewer that went away, or could not be reached, is reported once
through ``on_error`` and the view stops: the recording goes on untouched.

``rerun`` and the online filter are imported by the view's thread (this module imports them
only there), so the recording starts without waiting for them.
"""

from __future__ import annotations

import collections
import contextlib
import math
import os
import re
import socket
import subprocess
import threading
import time
from typing import TYPE_CHECKING
from urllib.parse import urlsplit

import numpy as np

from ..errors import ConfigError
from ..io.record.topics import TOPIC_FIX, TOPIC_HEADING, TOPIC_STATUS, TOPIC_THRUST
from ..model.frames import Datum, geodetic_to_ned, ned_to_geodetic
from ..model.vessel import default_vessel

if TYPE_CHECKING:
    from ..estimate import OnlineEKF

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 9876          # the native viewer's gRPC port
MAP_POINTS = 2000            # most points per map layer (older ones thinned)
TOPICS = frozenset({TOPIC_FIX, TOPIC_HEADING, TOPIC_THRUST, TOPIC_STATUS})
_MAX_DT_S = 5.0              # a longer gap between samples restarts the filter


def viewer_url(target: str) -> tuple[str, str, int]:
    """The gRPC URL of a viewer given as ``rerun+http://HOST:PORT/proxy``, ``HOST:PORT`` or ``PORT``.

    Parameters
    ----------
    target : str
        The viewer's address.

    Returns
    -------
    url, host, port : str, str, int
        ``rerun+http://HOST:PORT/proxy`` and its parts.

    Raises
    ------
    usvlog.errors.ConfigError
        If the address cannot be read.
    """
    t = target.strip()
    if t.isdigit():
        t = f"{DEFAULT_HOST}:{t}"
    if "://" not in t:
        t = f"rerun+http://{t}/proxy"
    try:
        u = urlsplit(t)
        port = u.port
    except ValueError as err:
        raise ConfigError(f"--view {target}: {err}") from err
    if u.scheme not in ("rerun", "rerun+http", "rerun+https") or not u.hostname or port is None \
            or u.path not in ("", "/proxy"):
        raise ConfigError(f"--view {target}: not spawn, PORT, HOST:PORT or rerun+http://HOST:PORT/proxy")
    return f"{u.scheme}://{u.netloc}/proxy", u.hostname, port


def _free_tcp_port(host: str, preferred: int) -> int:
    for port in (preferred, 0):
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            try:
                s.bind((host, port))
            except OSError:
                continue
            return s.getsockname()[1]
    raise ConfigError(f"--view spawn: no free TCP port on {host}")  # pragma: no cover - bind(0) always works


def _accepts(host: str, port: int, timeout_s: float = 1.0) -> bool:
    try:
        with socket.create_connection((host, port), timeout=timeout_s):
            return True
    except OSError:
        return False


class _Thin:
    """Keeps a sample when at least ``1/max_hz`` s passed since the last one kept."""

    def __init__(self, max_hz: float):
        self.step = int(1e9 / max_hz) if max_hz > 0 else 0
        self.last = -(1 << 62)

    def keep(self, t_ns: int) -> bool:
        if t_ns - self.last >= self.step:
            self.last = t_ns
            return True
        return False


class _Series:
    """Rows of one batch, per entity: times (ns) and values, sent with ``send_columns``."""

    def __init__(self):
        self.rows: dict[str, tuple[list, list]] = {}

    def add(self, path: str, t_ns: int, value: float) -> None:
        if value is None or not math.isfinite(value):
            return
        t, v = self.rows.setdefault(path, ([], []))
        t.append(t_ns)
        v.append(value)


class LiveView:
    """Streams a recording to a Rerun viewer from its own thread (see the module's text).

    Parameters
    ----------
    target : str
        ``spawn`` (start a native viewer bound to ``bind``) or the address of a running
        viewer (``rerun+http://HOST:PORT/proxy``, ``HOST:PORT``, ``PORT``).
    bind : str, default "127.0.0.1"
        Address the spawned viewer listens on.
    name : str, default "usvlog record"
        Recording name shown in the viewer.
    vessel : Vessel, optional
        Vessel for the online filter (its kinematic model does not use the parameters).
    queue_size : int, default 20000
        Messages waiting for the view's thread; more are dropped and counted.
    batch_s : float, default 1.0
        How often the thread sends, s.
    max_hz : float, default 20.0
        Most messages per second of each topic taken from the recorder (fixes, headings,
        thrust; not the recorder's status), and most filter outputs per second sent.
    probe_s : float, default 1.0
        How often the viewer is checked, s.
    on_error : callable, optional
        ``on_error(message)``, called once when the viewer cannot be reached or went away.

    Attributes
    ----------
    error : str or None
        Why the view stopped, if it did.
    dropped : int
        Messages dropped because the queue was full (not those thinned on purpose).
    thread_cpu_s : float
        CPU time of the view's thread so far, s.
    start_cpu_s : float
        Of which its start (importing the SDK, loading the filter, connecting), s.
    """

    topics = TOPICS

    def __init__(self, target: str = "spawn", *, bind: str = DEFAULT_HOST, name: str = "usvlog record",
                 vessel=None, queue_size: int = 20000, batch_s: float = 1.0, max_hz: float = 20.0,
                 probe_s: float = 1.0, on_error=None):
        self.target = target
        self.bind = bind
        if target == "spawn":
            self.url, self.host, self.port = None, bind if bind not in ("0.0.0.0", "::") else DEFAULT_HOST, 0
        else:
            self.url, self.host, self.port = viewer_url(target)
        self.name = name
        self.batch_s, self.max_hz, self.probe_s = float(batch_s), float(max_hz), float(probe_s)
        self.on_error = on_error
        self.error: str | None = None
        self.dropped = 0
        self.received = 0
        self.thread_cpu_s = 0.0   # CPU time of the view's thread so far, s
        self.start_cpu_s = 0.0    # of which connecting (importing the SDK, loading the filter), s
        self.sent: dict[str, int] = {}
        self._q: collections.deque = collections.deque()   # append/popleft are atomic: no lock
        self._q_max = int(queue_size)
        self._stop = threading.Event()
        self._failed = False
        self._thread = threading.Thread(target=self._run, name="usvlog-live-view", daemon=True)
        self._proc: subprocess.Popen | None = None
        self._rec = None
        self._settings = None       # EstimateSettings of the online filter (set by the thread)
        self._vessel = vessel or default_vessel()
        self._ekf: OnlineEKF | None = None
        self._datum: Datum | None = None
        self._t_last: int | None = None
        self._first: tuple[int, float, float] | None = None   # a fix waiting for the next to start the filter
        self._psi: float | None = None                          # the last compass heading, rad
        self._fixes: list[tuple[float, float]] = []
        self._track: list[tuple[float, float]] = []
        self._track_ned: list[tuple[float, float]] = []        # filtered positions not yet in _track, m
        self._thin: dict[str, _Thin] = {}
        self._hot_step = int(1e9 / max_hz) if max_hz > 0 else 0
        self._hot_last = {TOPIC_FIX: -(1 << 62), TOPIC_THRUST: -(1 << 62), TOPIC_HEADING: -(1 << 62)}

    # -- the recorder's side (hot path) -------------------------------------------
    def __call__(self, topic: str, row: dict, t_ns: int) -> None:
        """Queue one message for the view (never blocks; counts it as dropped when the queue is full).

        Parameters
        ----------
        topic : str
            Canonical topic.
        row : dict
            The row written.
        t_ns : int
            Receive time, ns since the Unix epoch.
        """
        if self._failed:
            return
        last = self._hot_last.get(topic)
        if last is not None:   # fixes, headings, thrust: at most max_hz reach the queue
            if t_ns - last < self._hot_step:
                return
            self._hot_last[topic] = t_ns
        if len(self._q) >= self._q_max:
            self.dropped += 1
        else:
            self._q.append((topic, row, t_ns))

    # -- life ----------------------------------------------------------------------
    def start(self) -> LiveView:
        """Start the view's thread (it connects, or spawns the viewer, and sends)."""
        self._thread.start()
        return self

    def close(self, timeout_s: float = 5.0) -> None:
        """Send what is queued, flush and stop the thread (the viewer keeps running).

        Parameters
        ----------
        timeout_s : float
            Longest wait for the thread, s.
        """
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout_s)

    def summary(self) -> dict:
        """What the view did: target, URL, messages received, rows sent per entity, drops, error.

        Returns
        -------
        dict
            JSON-ready.
        """
        return {"target": self.target, "url": self.url, "received": self.received, "dropped": self.dropped,
                "sent": dict(self.sent), "error": self.error, "thread_cpu_s": round(self.thread_cpu_s, 3),
                "start_cpu_s": round(self.start_cpu_s, 3)}

    def _fail(self, message: str) -> None:
        if self._failed:
            return
        self._failed = True
        self.error = message
        if self.on_error is not None:
            with contextlib.suppress(Exception):
                self.on_error(message)
        self._q.clear()
        with contextlib.suppress(Exception):
            if self._rec is not None:   # drop what the SDK still holds for the lost viewer (may take seconds)
                self._rec.disconnect()

    def _alive(self) -> str | None:
        """Why the viewer is not there, or None when it is."""
        if self._proc is not None and self._proc.poll() is not None:
            return f"the viewer started here exited (code {self._proc.returncode})"
        if not _accepts(self.host, self.port):
            return f"the viewer at {self.url} does not answer (gone or unreachable)"
        return None

    def _open(self) -> None:
        import rerun as rr  # heavy: the SDK, only when a live view runs

        # heavy: the online filter (scipy, numba), on this thread: the recording does not wait for it
        from ..estimate import EstimateSettings, OnlineEKF

        if self.target == "spawn":
            from .rrd import display_missing, rerun_executable  # the same viewer binary as `usvlog view`

            if display_missing():
                raise ConfigError("no display here (DISPLAY and WAYLAND_DISPLAY are unset) for --view spawn; "
                                  "start `rerun --bind 127.0.0.1` where there is one and give --view HOST:PORT")
            self.port = _free_tcp_port(self.host, DEFAULT_PORT)
            self.url = f"rerun+http://{self.host}:{self.port}/proxy"
            self._proc = subprocess.Popen([*rerun_executable(), "--bind", self.host, "--port", str(self.port)],
                                          stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                          start_new_session=True)   # the viewer outlives the recording
            deadline = time.monotonic() + 15.0
            while not _accepts(self.host, self.port, 0.2):
                if self._proc.poll() is not None or time.monotonic() > deadline:
                    raise ConfigError(f"the Rerun viewer did not start on {self.url}")
                time.sleep(0.1)
        elif not _accepts(self.host, self.port):
            raise ConfigError(f"no Rerun viewer at {self.url} (start one with `rerun --bind 127.0.0.1 "
                              f"--port {self.port}` or `rerun --serve-grpc ...`)")
        self._settings = EstimateSettings(model="kinematic", sway_damping=False, smoother=False)
        warm = OnlineEKF(self._vessel, self._settings)   # load the compiled filter before the first fix
        warm.predict(0.01)
        warm.update_gnss(0.0, 0.0, 1.0)
        # the SDK's batcher would wake every 0.2 s (its own thread, ~0.5 % CPU): each batch is flushed
        # here instead (_run), its tick only catches what a flush missed
        rec = rr.RecordingStream("usvlog", recording_id=f"live-{os.getpid()}-{time.time_ns()}",
                                 send_properties=False,
                                 batcher_config=rr.ChunkBatcherConfig(flush_tick=max(10.0, 4 * self.batch_s)))
        rec.connect_grpc(self.url, default_blueprint=self._blueprint())
        rec.send_recording_name(self.name)
        self._rec = rec

    @staticmethod
    def _blueprint():
        import rerun.blueprint as rrb  # heavy: with the SDK

        window = rrb.VisibleTimeRange("time", start=rrb.TimeRangeBoundary.cursor_relative(seconds=-60.0),
                                      end=rrb.TimeRangeBoundary.cursor_relative())

        def plot(name, origin):
            return rrb.TimeSeriesView(name=name, origin=origin, time_ranges=window,
                                      plot_legend=rrb.PlotLegend(corner=rrb.Corner2D.LeftTop))

        return rrb.Blueprint(rrb.Horizontal(
            rrb.MapView(name="Map: fixes (grey), online EKF track (blue)", origin="/map", zoom=17.0),
            rrb.Vertical(plot("Heading, deg", "/heading"), plot("Speed over ground (EKF), m/s", "/speed"),
                         plot("Thrust commands", "/thrust"), plot("Recorder status", "/status"))),
            collapse_panels=True)

    def _run(self) -> None:
        try:
            self._open()
        except Exception as err:  # any failure of the viewer is reported, never raised into the recording
            self._fail(f"live view off: {err}")
            return
        self.start_cpu_s = time.thread_time()
        next_probe = time.monotonic() + self.probe_s
        while not self._failed:
            stopping = self._stop.wait(self.batch_s)
            try:
                if self._send(self._drain()) or stopping:
                    self._rec.flush(timeout_sec=2.0 if stopping else 0.0)   # 0: start it, do not wait
            except Exception as err:  # noqa: BLE001 - the SDK's errors are reported, not raised
                self._fail(f"live view stopped: {err}")
                return
            self.thread_cpu_s = time.thread_time()
            if stopping:
                return
            if time.monotonic() >= next_probe:
                next_probe = time.monotonic() + self.probe_s
                why = self._alive()
                if why is not None:
                    self._fail(f"live view stopped: {why}; the recording goes on")
                    return

    def _drain(self) -> list:
        q = self._q
        return [q.popleft() for _ in range(len(q))]   # only this thread takes from the queue

    # -- what is sent ----------------------------------------------------------------
    def _keep(self, path: str, t_ns: int) -> bool:
        th = self._thin.get(path)
        if th is None:
            th = self._thin[path] = _Thin(self.max_hz)
        return th.keep(t_ns)

    def _send(self, batch: list) -> bool:
        """Run the filter over a batch and send it; False when it was empty."""
        if not batch:
            return False
        self.received += len(batch)
        batch.sort(key=lambda m: m[2])
        ne = iter(self._fixes_ned(batch))
        s = _Series()
        for topic, row, t in batch:
            if topic == TOPIC_FIX:
                self._on_fix(s, row, t, next(ne))
            elif topic == TOPIC_HEADING:
                self._on_heading(s, row, t)
            elif topic == TOPIC_THRUST:
                s.add("/thrust/left", t, row["left"])
                s.add("/thrust/right", t, row["right"])
            elif topic == TOPIC_STATUS:
                src = re.sub(r"[^A-Za-z0-9_]", "_", str(row["source"])) or "source"
                s.add(f"/status/{src}/rate_hz", t, row["rate_hz"])
                s.add(f"/status/{src}/bad_lines", t, row["garbage"])
                if row["dropped"] is not None and row["dropped"] >= 0:
                    s.add(f"/status/{src}/dropped", t, row["dropped"])
                s.add("/status/view/dropped", t, self.dropped)
        self._send_series(s)
        self._send_map()
        return True

    def _fixes_ned(self, batch: list) -> list:
        """North, east (m) of each fix of the batch about the first fix of the run, or None."""
        ll = [(m[1]["lat_deg"], m[1]["lon_deg"]) for m in batch if m[0] == TOPIC_FIX]
        if not ll:
            return []
        lat, lon = np.array(ll, float).T
        ok = np.isfinite(lat) & np.isfinite(lon)
        if self._datum is None and ok.any():
            k = int(np.argmax(ok))
            self._datum = Datum(lat_deg=float(lat[k]), lon_deg=float(lon[k]), alt_m=0.0)
        if self._datum is None:
            return [None] * len(ll)
        n, e, _ = geodetic_to_ned(np.where(ok, lat, self._datum.lat_deg), np.where(ok, lon, self._datum.lon_deg),
                                  0.0, datum=self._datum)
        return [(float(a), float(b)) if good else None for a, b, good in zip(n, e, ok)]

    def _send_series(self, s: _Series) -> None:
        import rerun as rr  # heavy: with the SDK (imported already by _open)

        for path, (t, v) in s.rows.items():
            self._rec.send_columns(path, indexes=[rr.TimeColumn("time", timestamp=np.asarray(t, "datetime64[ns]"))],
                                   columns=rr.Scalars.columns(scalars=np.asarray(v, float)))
            self.sent[path] = self.sent.get(path, 0) + len(t)

    def _send_map(self) -> None:
        import rerun as rr  # heavy: with the SDK (imported already by _open)

        if self._track_ned:   # the new filtered positions, converted at once
            lat, lon, _ = ned_to_geodetic(*np.array(self._track_ned, float).T, 0.0, datum=self._datum)
            ok = np.isfinite(lat) & np.isfinite(lon)
            self._track.extend(zip(lat[ok].tolist(), lon[ok].tolist()))
            self._track_ned.clear()
        if not self._fixes:
            return
        rec = self._rec
        for path, pts, color, radius in (("/map/fixes", self._fixes, (150, 150, 150), 2.0),
                                         ("/map/track", self._track, (31, 119, 180), 3.0)):
            if len(pts) > MAP_POINTS:   # thin the older half, keep the newest points
                del pts[:MAP_POINTS // 2:2]
            if pts:
                rec.log(path, rr.GeoPoints(lat_lon=np.asarray(pts), radii=rr.Radius.ui_points(radius),
                                           colors=[color]), static=True)
                self.sent[path] = self.sent.get(path, 0) + 1
        last = self._track[-1] if self._track else self._fixes[-1]
        rec.log("/map/boat", rr.GeoPoints(lat_lon=[last], radii=rr.Radius.ui_points(7.0), colors=[(255, 90, 0)]),
                static=True)

    # -- the online filter -----------------------------------------------------------
    def _predict_to(self, t: int) -> bool:
        """Predict the filter to ``t``; False when there is none yet (or it restarted)."""
        if self._ekf is None:
            return False
        dt = (t - self._t_last) / 1e9
        if dt > _MAX_DT_S:
            self._ekf = None   # a long gap: start again from the next two fixes
            return False
        if dt > 0:
            self._ekf.predict(dt)
            self._t_last = t
        return True

    def _on_fix(self, s: _Series, row: dict, t: int, ne: tuple[float, float] | None) -> None:
        if ne is None:   # not a finite position
            return
        self._fixes.append((row["lat_deg"], row["lon_deg"]))
        n, e = ne
        st = self._settings
        var = st.gps_fallback_m ** 2
        if row.get("cov_type", 0) and row.get("cov_nn_m2", 0) > 0 and row.get("cov_ee_m2", 0) > 0:
            var = 0.5 * (row["cov_nn_m2"] + row["cov_ee_m2"])
        if self._predict_to(t):
            self._ekf.update_gnss(n, e, var)
            self._emit(s, t, track=True)
            return
        # (re)start from two fixes: position and velocity by their difference, heading from the compass
        first, self._first = self._first, (t, n, e)
        if first is None or not 0 < (t - first[0]) / 1e9 <= _MAX_DT_S:
            return
        # the filter's module: imported by _open already
        from ..estimate import OnlineEKF
        from ..estimate.core import state_size

        dt = (t - first[0]) / 1e9
        x0 = np.zeros(state_size(st))
        x0[0], x0[1], x0[3], x0[4] = n, e, (n - first[1]) / dt, (e - first[2]) / dt
        x0[2] = self._psi if self._psi is not None else math.atan2(x0[4], x0[3])
        self._ekf = OnlineEKF(self._vessel, st, x0=x0)
        self._t_last, self._first = t, None
        self._emit(s, t, track=True)

    def _on_heading(self, s: _Series, row: dict, t: int) -> None:
        psi = self._psi = row["heading_rad"]
        s.add("/heading/compass", t, math.degrees(psi) % 360.0)
        if self._predict_to(t):
            std = row.get("std_rad")
            std = std if std is not None and std > 0 else self._settings.compass_fallback_rad
            self._ekf.update_heading(float(psi), std * std)
            self._emit(s, t, track=False)

    def _emit(self, s: _Series, t: int, track: bool) -> None:
        x = self._ekf.x
        if track:   # the map's track: the filtered position at each fix (converted by _send_map)
            self._track_ned.append((float(x[0]), float(x[1])))
        if self._keep("/ekf", t):
            s.add("/heading/ekf", t, math.degrees(x[2]) % 360.0)
            s.add("/speed/ekf", t, math.hypot(x[3], x[4]))


__all__ = ["LiveView", "viewer_url", "TOPICS", "DEFAULT_HOST", "DEFAULT_PORT"]
