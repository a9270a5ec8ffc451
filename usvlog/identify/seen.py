"""A model's free run as the sensors would have recorded it: the measurements it would have made.

Validation compares a free run with the smoothed measurements. A smoother trades noise for
lag: the smoothed surge speed of a boat that accelerates hard (an 80 kg catamaran that
reaches 1.5 m/s in three seconds) trails the true one, and its fit % against the true speed
is well under 100 even where GPS and compass are perfect. A free run compared with those
states directly is charged for the smoother's lag as if it were the model's error.

So the free run is compared like with like (the prefiltered comparison of output-error
identification): its positions and heading are sampled at the log's own GNSS and compass
stamps (with the same latencies), its ground velocity and yaw rate at the stamps of those
channels when the log has them, and the result is smoothed exactly as the data were (the same
estimator with the same process noise, :func:`usvlog.identify.smooth.kinematic_states`). What
is left between the two is the model's error plus the smoothed measurement noise, not the
smoother's lag. The free run's own states are kept for plots (:class:`~usvlog.identify.validation.Validation`).

:func:`free_run_log` builds that log: pure data in, a :class:`~usvlog.log.fieldlog.FieldLog`
out, no I/O. :class:`SeenLog` holds what it is built from, the whole log's or a part's (a
window of the run keeps only its own records, and the whole log can go).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..estimate.layout import COMPASS_TOPIC, GNSS_TOPIC, THRUST_TOPIC, VELOCITY_TOPIC, YAW_RATE_TOPIC
from ..estimate.problem import ThrustFrames
from ..log.fieldlog import FieldLog
from ..log.positions import LOCAL_TOPIC
from ..model.frames import Datum, ned_to_geodetic, ssa
from .data import RunData, run_thrust

COPIED_TOPICS = (THRUST_TOPIC, GNSS_TOPIC, COMPASS_TOPIC, VELOCITY_TOPIC, YAW_RATE_TOPIC, LOCAL_TOPIC)
"""The channels the kinematic smoother reads; the others are left out of a free run's log."""


def _log_datum(log: FieldLog) -> Datum | None:
    """The datum :func:`usvlog.identify.data.run_data` put the fixes about: the log's, else its first valid fix."""
    if log.datum is not None:
        return log.datum
    g = log.get(GNSS_TOPIC)
    if g is None:
        return None
    lat, lon = g["lat_deg"].to_numpy(float), g["lon_deg"].to_numpy(float)
    ok = np.isfinite(lat) & np.isfinite(lon)
    return Datum(lat_deg=float(lat[ok][0]), lon_deg=float(lon[ok][0])) if ok.any() else None


def ground_velocity(psi, u, v, current=(0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """Velocity over ground, north and east (m/s), of body velocities ``u``, ``v`` relative to the
    water (m/s) at heading ``psi`` (rad) in a constant ``current`` (north, east, m/s)."""
    c, s = np.cos(psi), np.sin(psi)
    return c * u - s * v + float(current[0]), s * u + c * v + float(current[1])


@dataclass(frozen=True)
class SeenLog:
    """What a free run's log is made of (:meth:`free_run_log`): the recorded log's channels the
    smoother reads (:data:`COPIED_TOPICS`), its metadata, the datum its fixes were put about, and
    the run's time origin and sensor latencies. Made from a log with :meth:`of`; :meth:`window`
    keeps a copy of a part only, so that the whole log can go."""

    channels: dict          # topic -> frame (the log's own, or a window's copy)
    meta: dict
    schemas: dict
    source: str | None
    datum: Datum | None     # the whole log's (its first valid fix may lie outside a window)
    t0_ns: int              # the run's time origin (RunData.t0_ns)
    delay: dict             # topic -> latency (s) of the stamps of that channel
    thrust: RunData | None = None   # the run, when the log had no thrust channel: its thrust is the free runs'

    @classmethod
    def of(cls, log: FieldLog, run: RunData) -> SeenLog:
        """The parts of ``log`` a free run of ``run`` is recorded with (the frames shared, not copied);
        the thrust the run's (its arrays shared) when ``log`` has no thrust channel."""
        channels = {topic: frame for topic in COPIED_TOPICS if (frame := log.get(topic)) is not None}
        delay = {GNSS_TOPIC: run.gnss_delay_s, LOCAL_TOPIC: run.gnss_delay_s, VELOCITY_TOPIC: run.gnss_delay_s,
                 COMPASS_TOPIC: run.compass_delay_s}
        return cls(channels=channels, meta=dict(log.meta), schemas=dict(log.schemas), source=log.source,
                   datum=_log_datum(log), t0_ns=run.t0_ns, delay=delay,
                   thrust=None if THRUST_TOPIC in channels else run)

    def window(self, t_lo: float, t_hi: float) -> SeenLog:
        """A copy of the records stamped within 1 s of ``[t_lo, t_hi]`` (s from ``t0_ns``; +-inf:
        open): every record a free run inside that span is recorded with (:meth:`free_run_log`
        keeps those stamped within the free run's span)."""
        lo = -np.inf if t_lo == -np.inf else self.t0_ns + (t_lo - 1.0) * 1e9
        hi = np.inf if t_hi == np.inf else self.t0_ns + (t_hi + 1.0) * 1e9
        channels = {}
        for topic, frame in self.channels.items():
            idx = np.asarray(frame.index, dtype=np.int64)
            channels[topic] = frame[(idx >= lo) & (idx <= hi)].copy()
        thrust = None if self.thrust is None else self.thrust.window(t_lo - 1.0, t_hi + 1.0)   # (views)
        return replace(self, channels=channels, thrust=thrust)

    def _span_ns(self, t) -> tuple[int, int]:
        """The stamps (ns) of a free run's first and last times ``t`` (s from ``t0_ns``)."""
        return self.t0_ns + int(round(t[0] * 1e9)), self.t0_ns + int(round(t[-1] * 1e9))

    def thrust_over(self, t) -> ThrustFrames | None:
        """The thrust a free run over times ``t`` (s) is smoothed with when its log has none: the
        run's records stamped within the free run's span (:func:`~usvlog.identify.data.run_thrust`),
        as its log would keep them; None when the log has its thrust channel."""
        return None if self.thrust is None else run_thrust(self.thrust, *self._span_ns(np.asarray(t, float)))

    def free_run_log(self, t, sim, current=(0.0, 0.0)) -> FieldLog:
        """The recorded log over ``[t[0], t[-1]]`` had the boat moved as ``sim``: :func:`free_run_log`."""
        t = np.asarray(t, float)
        sim = np.asarray(sim, float)
        lo, hi = self._span_ns(t)
        psi = sim[:, 2]
        vn, ve = ground_velocity(psi, sim[:, 3], sim[:, 4], current)
        channels = {}
        for topic, frame in self.channels.items():
            idx = np.asarray(frame.index, dtype=np.int64)
            keep = (idx >= lo) & (idx <= hi)
            frame = frame[keep].copy()
            ts = (idx[keep] - self.t0_ns) / 1e9 - self.delay.get(topic, 0.0)

            def at(y, ts=ts):
                return np.interp(ts, t, y)

            if topic == GNSS_TOPIC and self.datum is not None:
                lat, lon, _ = ned_to_geodetic(at(sim[:, 0]), at(sim[:, 1]), 0.0, datum=self.datum)
                frame["lat_deg"], frame["lon_deg"] = lat, lon
            elif topic == LOCAL_TOPIC:
                frame["n_m"], frame["e_m"] = at(sim[:, 0]), at(sim[:, 1])
            elif topic == COMPASS_TOPIC:
                frame["heading_rad"] = ssa(at(psi))
            elif topic == YAW_RATE_TOPIC:
                frame["r_radps"] = at(sim[:, 5])
            elif topic == VELOCITY_TOPIC:
                n_, e_ = at(vn), at(ve)
                frame["sog_mps"], frame["cog_rad"] = np.hypot(n_, e_), np.arctan2(e_, n_)
            channels[topic] = frame
        return FieldLog(channels=channels, meta=dict(self.meta), schemas=dict(self.schemas), source=self.source)


def free_run_log(log: FieldLog, run: RunData, t, sim, current=(0.0, 0.0)) -> FieldLog:
    """The log ``log`` would have been over ``[t[0], t[-1]]`` had the boat moved as ``sim``.

    Parameters
    ----------
    log : FieldLog
        The recorded run (its stamps, noise columns, thrust and metadata are kept).
    run : RunData
        The run's arrays (time origin ``t0_ns`` and the sensor latencies).
    t : numpy.ndarray, shape (N,)
        Times of the free run in s from ``run.t0_ns`` (increasing).
    sim : numpy.ndarray, shape (N, 6)
        The free run: n (m), e (m), psi (rad), u, v (m/s, relative to the water), r (rad/s).
    current : (float, float), default (0.0, 0.0)
        Current north, east (m/s) the free run was made with (its ground velocity is the
        water-relative one plus this).

    Returns
    -------
    FieldLog
        A copy of the smoother's channels restricted to the free run's span, with positions,
        heading, ground velocity and yaw rate replaced by the free run's at each record's
        stamp minus that sensor's latency.
    """
    return SeenLog.of(log, run).free_run_log(t, sim, current)


__all__ = ["COPIED_TOPICS", "SeenLog", "free_run_log", "ground_velocity"]
