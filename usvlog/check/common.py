"""What every check reads from a log, prepared once: times in s from the log's start, the
track in metres, the compass heading, the thrust, and (lazily) the smoothed states.

Times are seconds from the log's first time stamp over all channels (what a finding's time
range counts from). Each array is None when the log lacks the channel.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from ..errors import UsvlogError
from ..estimate.core import COMPASS_TOPIC, GNSS_TOPIC, THRUST_TOPIC, YAW_RATE_TOPIC
from ..identify.data import run_data
from ..identify.smooth import KinStates, savgol_states, thrust_on_grid
from ..log.fieldlog import FieldLog
from ..log.positions import LOCAL_TOPIC, local_positions, uses_local
from ..log.summary import health_from_provenance
from ..model.frames import Datum, geodetic_to_ned
from ..model.vessel import Vessel, default_vessel

QUALITY_TOPIC = "/gnss/quality"
SENSOR_TOPICS = (GNSS_TOPIC, LOCAL_TOPIC, COMPASS_TOPIC, YAW_RATE_TOPIC, "/gnss/velocity", QUALITY_TOPIC,
                 THRUST_TOPIC)
"""The channels whose rate, gaps and time order are checked (those a log has)."""


def _sorted_unique(t: np.ndarray, *cols: np.ndarray):
    """Sort by time and drop repeated time stamps (the first kept): the arrays themselves when they
    are so already (no copy)."""
    if not len(t) or bool((np.diff(t) > 0).all()):
        return (t, *cols)
    o = np.argsort(t, kind="stable")
    t = t[o]
    keep = np.concatenate([[True], np.diff(t) > 0])
    return (t[keep], *(c[o][keep] for c in cols))


@dataclass(frozen=True)
class Smoothed:
    """What the checks take of the run as an identification sees it (:func:`smooth`): its smoothed
    over-ground states (local cubic fits, 10 Hz; times from the run's first thrust sample), the
    thrust (tau_u N, tau_r N m) on their grid, and that first sample (ns); the states and the
    thrust None when the run cannot be made (a channel missing, too few samples, commands without
    forces) or smoothed."""

    states: KinStates | None = None
    tau: tuple[np.ndarray, np.ndarray] | None = None
    t0_ns: int = 0


def smooth(log: FieldLog, vessel: Vessel | None = None) -> Smoothed:
    """The :class:`Smoothed` run of ``log`` (:func:`usvlog.identify.data.run_data`, then
    :func:`usvlog.identify.smooth.savgol_states`) for the boat ``vessel`` (default the log's own,
    else the built-in one); the run's arrays (the thrust at its own rate) are let go once made.
    It reads the log's thrust, GNSS (or local positions) and compass only."""
    try:
        run = run_data(log, vessel or log.vessel or default_vessel())
        states = savgol_states(run)
    except UsvlogError:
        return Smoothed()
    return Smoothed(states, thrust_on_grid(run, states.t), run.t0_ns)


@dataclass
class CheckContext:
    """One log prepared for the checks (see the module docstring).

    Attributes
    ----------
    log : FieldLog
    vessel : Vessel
        The one given, else the log's, else the built-in one.
    vessel_given : bool
        A vessel was given or stored (its thruster limits and offset are the boat's own).
    t0_ns : int
        The log's start (ns since the Unix epoch); every ``*_s`` time counts from it.
    health : dict
        The import's sensor health record (``{}`` when none).
    """

    log: FieldLog
    vessel: Vessel
    vessel_given: bool
    t0_ns: int
    health: dict = field(default_factory=dict)
    given: Smoothed | None = None

    @classmethod
    def of(cls, log: FieldLog, vessel: Vessel | None = None, smoothed: Smoothed | None = None) -> CheckContext:
        """The context of ``log`` (``vessel``: the boat, default the log's own; ``smoothed``: its
        :func:`smooth`, when made before)."""
        tr = log.time_range()
        v = vessel or log.vessel
        return cls(log=log, vessel=v or default_vessel(), vessel_given=v is not None,
                   t0_ns=int(tr[0]) if tr else 0, health=health_from_provenance(log.provenance) or {},
                   given=smoothed)

    def seconds(self, t_ns) -> np.ndarray:
        """ns since the Unix epoch -> s from the log's start."""
        return (np.asarray(t_ns, np.int64) - self.t0_ns) / 1e9

    def times(self, topic: str) -> np.ndarray | None:
        """A channel's record times (s from the start, in the order stored), None when missing or empty."""
        f = self.log.get(topic)
        return None if f is None or not len(f) else self.seconds(f.index)

    @cached_property
    def track(self) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """(t s, n m, e m) of the valid positions in time order (GNSS fixes about the log's
        datum or the first fix; local positions when the log has no fix); None without."""
        if uses_local(self.log):
            lp = local_positions(self.log)
            return None if lp is None else _sorted_unique(self.seconds(lp.t_ns), lp.n_m, lp.e_m)
        g = self.log.get(GNSS_TOPIC)
        if g is None or not len(g):
            return None
        lat, lon = g["lat_deg"].to_numpy(float), g["lon_deg"].to_numpy(float)
        ok = np.isfinite(lat) & np.isfinite(lon) & (np.abs(lat) <= 90) & (np.abs(lon) <= 180)
        if ok.sum() < 2:
            return None
        datum = self.log.datum or Datum(lat_deg=float(lat[ok][0]), lon_deg=float(lon[ok][0]))
        n, e, _ = geodetic_to_ned(lat[ok], lon[ok], 0.0, datum=datum)
        return _sorted_unique(self.seconds(np.asarray(g.index, np.int64)[ok]), np.asarray(n, float),
                              np.asarray(e, float))

    @cached_property
    def heading(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(t s, heading rad as measured) of the valid compass records in time order; None without."""
        c = self.log.get(COMPASS_TOPIC)
        if c is None or not len(c):
            return None
        h = c["heading_rad"].to_numpy(float)
        ok = np.isfinite(h)
        if ok.sum() < 2:
            return None
        return _sorted_unique(self.seconds(np.asarray(c.index, np.int64)[ok]), h[ok])

    @cached_property
    def thrust(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, str] | None:
        """(t s, left, right, unit) of the recorded commands as logged, in time order; None without."""
        f = self.log.get(THRUST_TOPIC)
        if f is None or not len(f) or "left" not in f or "right" not in f:
            return None
        unit = str(f["unit"].iloc[0]) if "unit" in f else "newton"
        t, left, right = _sorted_unique(self.seconds(f.index), f["left"].to_numpy(float), f["right"].to_numpy(float))
        return t, left, right, unit

    @cached_property
    def track_turn_deg(self) -> float | None:
        """Total turning of the track (deg, summed over legs of 5 m), None without a track."""
        tr = self.track
        if tr is None:
            return None
        _, n, e = tr
        pts, last = [], None
        for i in range(len(n)):   # legs of 5 m (GNSS noise makes shorter moves turn at random)
            if last is None or math.hypot(n[i] - n[last], e[i] - e[last]) >= 5.0:
                pts.append(i)
                last = i
        if len(pts) < 3:
            return 0.0
        p = np.asarray(pts)
        course = np.arctan2(np.diff(e[p]), np.diff(n[p]))
        return float(np.degrees(np.abs(np.angle(np.exp(1j * np.diff(course)))).sum()))

    @cached_property
    def _smoothed(self) -> Smoothed:
        """:func:`smooth` of the log (the one given, when made before)."""
        return self.given or smooth(self.log, self.vessel)

    def smooth_first(self) -> None:
        """Make :attr:`states` now, while the context holds nothing else: the smoothing's peak is
        the checks' largest. A failure is left to the checks that use the states (they meet it again)."""
        try:
            _ = self._smoothed
        except Exception:   # noqa: S110 -- reported by each check that uses the states
            pass

    @property
    def states(self) -> KinStates | None:
        """Smoothed over-ground states of the run as an identification sees it (local cubic fits,
        10 Hz; times from the run's first thrust sample), None without."""
        return self._smoothed.states

    @property
    def tau_on_states(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(tau_u N, tau_r N m) on the grid of :attr:`states`."""
        return self._smoothed.tau

    def run_seconds(self, t_run_s) -> np.ndarray:
        """Times of :attr:`states` (s from the run's first thrust sample) -> s from the log's start."""
        return np.asarray(t_run_s, float) + (self._smoothed.t0_ns - self.t0_ns) / 1e9
