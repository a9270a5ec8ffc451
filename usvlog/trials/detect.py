"""Find the standard manoeuvres of a run from its thrust commands and its state.

Pure: arrays in (:class:`Track`, :class:`Commands`), a :class:`~usvlog.trials.result.Manoeuvres`
out. The definitions, adapted to differential thrust, are in ``docs/manoeuvres.md``:

1. the commands are cut into *holds*: stretches over which both thrusters keep their
   command (within :attr:`Settings.tol_frac` of the run's full scale);
2. a hold's *differential* is ``left - right``, its *common* thrust ``left + right``; the
   differential is *applied* when it is at least :attr:`Settings.diff_frac` of the full scale;
3. the kinds, each from holds and the state (heading, speed):

   * pivot turn: thrusters of opposite signs, held at least ``min_pivot_s``;
   * turning circle: one differential (thrusters of one sign) held through a heading change of
     at least ``min_turn_deg``;
   * zig-zag: a differential applied, then reversed at least twice, each reversal when the
     heading is off the execute heading by one angle (within ``zigzag_angle_tol_deg``), alternately
     to either side;
   * speed steps: at least two consecutive steps of the common thrust without differential,
     each held at least ``min_step_s``;
   * stop / coast-down: both thrusters to zero while moving, held at least ``min_stop_s``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pandas as pd

from ..errors import InputError
from . import metrics as M
from .result import Manoeuvre, Manoeuvres


@dataclass(frozen=True, kw_only=True)
class Settings:
    """Thresholds of the detection (defaults as documented in docs/manoeuvres.md).

    Parameters
    ----------
    tol_frac : float
        Two commands are the same when within this fraction of the full scale (the largest
        thruster command of the run).
    diff_frac : float
        A differential is applied when ``|left - right|`` is at least this fraction of the
        full scale.
    step_frac : float
        A speed step changes the common thrust by at least this fraction of the full scale.
    min_turn_deg : float
        A turning circle turns the heading at least this much within one held differential.
    min_step_s, min_stop_s, min_pivot_s : float
        Shortest hold of a speed step, a stop and a pivot turn, s.
    min_stop_speed_mps : float
        A stop starts from at least this speed over ground.
    zigzag_angle_tol_deg : float
        The heading deviations at a zig-zag's reversals agree within this.
    """

    tol_frac: float = 0.03
    diff_frac: float = 0.1
    step_frac: float = 0.1
    min_turn_deg: float = 360.0
    min_step_s: float = 15.0
    min_stop_s: float = 5.0
    min_pivot_s: float = 5.0
    min_stop_speed_mps: float = 0.2
    zigzag_angle_tol_deg: float = 4.0

    def __post_init__(self):
        for name in ("tol_frac", "diff_frac", "step_frac", "min_turn_deg", "min_step_s", "min_stop_s",
                     "min_pivot_s", "min_stop_speed_mps", "zigzag_angle_tol_deg"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise InputError(f"manoeuvre setting {name} = {v!r} must be a positive number")


@dataclass(frozen=True)
class Track:
    """The state of a run: times (s from the log's start), pose, body velocities and one-sigmas.

    ``psi`` is unwrapped (continuous); the ``*_std`` arrays are zeros for a truth trajectory.
    """

    t: np.ndarray
    n: np.ndarray
    e: np.ndarray
    psi: np.ndarray
    u: np.ndarray
    v: np.ndarray
    r: np.ndarray
    n_std: np.ndarray
    e_std: np.ndarray
    psi_std: np.ndarray
    u_std: np.ndarray
    r_std: np.ndarray

    @property
    def speed(self) -> np.ndarray:
        """Speed over ground sqrt(u^2 + v^2), m/s."""
        return np.hypot(self.u, self.v)

    def at(self, t: float) -> int:
        """Index of the first sample at or after ``t`` (clipped to the track)."""
        return min(int(np.searchsorted(self.t, t)), len(self.t) - 1)


@dataclass(frozen=True)
class Commands:
    """Thrust commands: times (s from the log's start), left and right (forces in N when known)."""

    t: np.ndarray
    left: np.ndarray
    right: np.ndarray
    unit: str = "N"


@dataclass(frozen=True)
class Hold:
    """A stretch of constant commands: [start, end) in s, mean left and right."""

    start: float
    end: float
    left: float
    right: float

    @property
    def diff(self) -> float:
        """left - right."""
        return self.left - self.right

    @property
    def common(self) -> float:
        """left + right."""
        return self.left + self.right

    @property
    def duration(self) -> float:
        """end - start, s."""
        return self.end - self.start


_POSE = ("n_m", "e_m", "psi_rad", "u_mps", "v_mps", "r_radps")
_SIGMAS = ("n_m", "e_m", "psi_rad", "u_mps", "r_radps")
_TRACK_FIELDS = ("t", "n", "e", "psi", "u", "v", "r", "n_std", "e_std", "psi_std", "u_std", "r_std")
_FORCES = ("thrust_left_n", "thrust_right_n")


class TrackBuilder:
    """A :class:`Track` made from a state channel's frame a block of rows at a time (the blocks in
    time order, joined the whole frame): the track :func:`track_from_frame` makes of the whole frame,
    its arrays allocated once and no frame of the whole run held.

    Parameters
    ----------
    rows : int
        The channel's rows (at least those of every block added).
    t0_ns : int
        The log's start (ns since the Unix epoch).
    """

    def __init__(self, rows: int, t0_ns: int):
        self.t0_ns = int(t0_ns)
        self.arrays = {k: np.empty(rows) for k in _TRACK_FIELDS}
        self.n = 0
        self._psi: float | None = None     # the last raw heading kept and the unwrapping's correction
        self._carry: float | None = None   # summed so far: np.unwrap of the whole run, carried over

    def add(self, frame: pd.DataFrame) -> TrackBuilder:
        """Add the next block of rows (rows with a non-finite pose are dropped); returns self."""
        t = (np.asarray(frame.index.to_numpy(), np.int64) - self.t0_ns) * 1e-9

        def col(name: str) -> np.ndarray:
            return frame[name].to_numpy(float) if name in frame.columns else np.zeros(len(frame))

        n, e, psi, u, v, r = (col(c) for c in _POSE)
        ok = np.isfinite(n) & np.isfinite(e) & np.isfinite(psi) & np.isfinite(u) & np.isfinite(v) & np.isfinite(r)
        a, b = self.n, self.n + int(ok.sum())
        put = self.arrays
        for k, x in zip(("t", "n", "e", "u", "v", "r"), (t, n, e, u, v, r)):
            put[k][a:b] = x[ok]
        for k, c in zip(_TRACK_FIELDS[7:], _SIGMAS):
            put[k][a:b] = np.nan_to_num(col(c + "_std")[ok], nan=0.0)
        self._unwrap(psi[ok], put["psi"][a:b])
        self.n = b
        return self

    def _unwrap(self, p: np.ndarray, out: np.ndarray) -> None:
        """``out`` = the block ``p`` of headings unwrapped as ``np.unwrap`` unwraps the whole run (its
        steps and their corrections the same; the corrections summed on from the blocks before)."""
        if not len(p):
            return
        q = p if self._psi is None else np.r_[self._psi, p]
        dd = np.diff(q)
        lo, period = -np.pi, 2 * np.pi   # as np.unwrap (period 2 pi, discont pi)
        ddmod = np.mod(dd - lo, period) + lo
        np.copyto(ddmod, -lo, where=(ddmod == lo) & (dd > 0))
        fix = ddmod - dd
        np.copyto(fix, 0, where=np.abs(dd) < -lo)
        summed = np.cumsum(fix) if self._carry is None else np.cumsum(np.r_[self._carry, fix])[1:]
        if self._psi is None:
            out[0] = p[0]
        out[len(out) - len(summed):] = q[1:] + summed
        self._psi = float(p[-1])
        self._carry = float(summed[-1]) if len(summed) else self._carry

    def track(self) -> Track:
        """The :class:`Track` of the rows added.

        Raises
        ------
        usvlog.errors.InputError
            With fewer than 10 finite rows.
        """
        if self.n < 10:
            raise InputError(f"the state has {self.n} finite rows: too few to find manoeuvres")
        return Track(*(self.arrays[k][:self.n] for k in _TRACK_FIELDS))


def track_from_frame(frame: pd.DataFrame, t0_ns: int) -> Track:
    """A :class:`Track` from an ``/estimate/state`` or ``/truth/state`` frame (indexed by t_ns).

    Missing ``*_std`` columns (a truth) are zeros; rows with a non-finite pose are dropped.

    Raises
    ------
    usvlog.errors.InputError
        With fewer than 10 finite rows.
    """
    return TrackBuilder(len(frame), t0_ns).add(frame).track()


def uses_forces(columns, finite_left: int, rows: int) -> bool:
    """Whether a ``/thrust/command`` channel's commands are taken as its forces: it has the force
    columns and ``thrust_left_n`` is finite on more than 90 % of its ``rows`` (``finite_left`` of them)."""
    return set(_FORCES) <= set(columns) and rows > 0 and finite_left / rows > 0.9


class CommandsBuilder:
    """:class:`Commands` made from a ``/thrust/command`` frame a block of rows at a time (the blocks
    in time order, joined the whole frame): the commands :func:`commands_from_frame` makes of the
    whole frame, its arrays allocated once.

    Parameters
    ----------
    rows : int
        The channel's rows (at least those of every block added).
    t0_ns : int
        The log's start (ns since the Unix epoch).
    forces : bool
        Take the forces ``thrust_left_n``/``thrust_right_n`` (:func:`uses_forces`), else the
        commands ``left``/``right``.
    unit : str or None
        The unit of the channel's first row (None: it has no unit column): the commands' unit
        (``N`` for forces; ``command`` without one).
    """

    def __init__(self, rows: int, t0_ns: int, forces: bool, unit: str | None):
        self.t0_ns = int(t0_ns)
        self.unit = "N" if forces else "command" if unit is None else unit
        self.names = _FORCES if forces else ("left", "right")
        self.t, self.left, self.right = np.empty(rows), np.empty(rows), np.empty(rows)
        self.n = 0

    def add(self, frame: pd.DataFrame) -> CommandsBuilder:
        """Add the next block of rows (rows without both commands finite are dropped); returns self."""
        t = (np.asarray(frame.index.to_numpy(), np.int64) - self.t0_ns) * 1e-9
        left, right = (frame[c].to_numpy(float) for c in self.names)
        ok = np.isfinite(left) & np.isfinite(right)
        a, b = self.n, self.n + int(ok.sum())
        self.t[a:b], self.left[a:b], self.right[a:b] = t[ok], left[ok], right[ok]
        self.n = b
        return self

    def commands(self) -> Commands:
        """The :class:`Commands` of the rows added, in time order.

        Raises
        ------
        usvlog.errors.InputError
            With fewer than 2 finite commands.
        """
        if self.n < 2:
            raise InputError("/thrust/command has fewer than 2 finite commands: no manoeuvre can be found")
        t, left, right = self.t[:self.n], self.left[:self.n], self.right[:self.n]
        if np.any(np.diff(t) < 0):   # else the stable sort's order is the rows' own
            order = np.argsort(t, kind="stable")
            t, left, right = t[order], left[order], right[order]
        return Commands(t, left, right, self.unit)


def commands_from_frame(frame: pd.DataFrame, t0_ns: int) -> Commands:
    """:class:`Commands` from a ``/thrust/command`` frame: the forces ``thrust_left_n`` and
    ``thrust_right_n`` when they are finite (:func:`uses_forces`), else the commands ``left`` and
    ``right``.

    Raises
    ------
    usvlog.errors.InputError
        With fewer than 2 finite commands.
    """
    finite = int(np.isfinite(frame["thrust_left_n"].to_numpy(float)).sum()) if "thrust_left_n" in frame.columns else 0
    forces = uses_forces(frame.columns, finite, len(frame))
    unit = str(frame["unit"].iloc[0]) if "unit" in frame.columns and len(frame) else None
    return CommandsBuilder(len(frame), t0_ns, forces, unit).add(frame).commands()


def full_scale(cmd: Commands) -> float:
    """The run's full scale: the 99.9th percentile of |left| and |right| (0 for an idle run)."""
    both = np.r_[cmd.left, cmd.right]
    return float(np.percentile(np.abs(both, out=both), 99.9, overwrite_input=True))   # one copy of the commands


def holds(cmd: Commands, tol: float) -> list[Hold]:
    """Cut the commands into holds: a new hold starts where either thruster leaves the first
    value of the current hold by more than ``tol``.

    The last hold ends at the last command's time.
    """
    t, left, right = cmd.t, cmd.left, cmd.right
    out: list[Hold] = []
    i = 0
    n = len(t)
    while i < n:
        j, step = i + 1, 64   # look ahead in growing chunks: linear in the run's length however many holds
        while j < n:
            k = min(j + step, n)
            away = np.flatnonzero((np.abs(left[j:k] - left[i]) > tol) | (np.abs(right[j:k] - right[i]) > tol))
            if len(away):
                j += int(away[0])
                break
            j, step = k, 2 * step
        end = t[j] if j < n else t[-1]
        out.append(Hold(float(t[i]), float(end), float(np.mean(left[i:j])), float(np.mean(right[i:j]))))
        i = j
    return out


@dataclass(frozen=True)
class Plan:
    """The commands as the detection reads them (:func:`plan`): its settings, the run's full scale,
    the holds (none for an idle run) and the commands' unit. Small: the commands can go once it is made."""

    settings: Settings
    full_scale: float
    holds: tuple[Hold, ...]
    unit: str


def plan(cmd: Commands, settings: Settings | None = None) -> Plan:
    """The :class:`Plan` of the commands ``cmd`` (``settings``: the detection's, default :class:`Settings`)."""
    st = settings or Settings()
    fs = full_scale(cmd)
    return Plan(st, fs, tuple(holds(cmd, st.tol_frac * fs)) if fs > 0 else (), cmd.unit)


def find(track: Track, cmd: Commands, settings: Settings | None = None, *, t0_ns: int = 0,
         source: str = "") -> Manoeuvres:
    """Find the standard manoeuvres of a run and measure them.

    Parameters
    ----------
    track : Track
        The state (estimate or truth), times in s from the log's start.
    cmd : Commands
        The thrust commands, same time base.
    settings : Settings, optional
    t0_ns : int
        The log's start (recorded in the result).
    source : str
        Where the state came from (recorded in the result).

    Returns
    -------
    Manoeuvres
        In time order; empty when the run has none.
    """
    return find_planned(track, plan(cmd, settings), t0_ns=t0_ns, source=source)


def find_planned(track: Track, p: Plan, *, t0_ns: int = 0, source: str = "") -> Manoeuvres:
    """:func:`find` on the commands' :class:`Plan` ``p`` (made before the track: the commands and the
    track need not be held together)."""
    st, fs = p.settings, p.full_scale
    if not fs > 0:
        return Manoeuvres((), int(t0_ns), source)
    hs = [h for h in p.holds if h.end > track.t[0] and h.start < track.t[-1]]
    d_on = st.diff_frac * fs
    zero = st.tol_frac * fs
    used = [False] * len(hs)
    found: list[Manoeuvre] = []

    # zig-zags first: their holds are not turning circles or steps
    for i in range(len(hs)):
        if used[i]:
            continue
        z = _zigzag_at(track, hs, i, d_on, st, p.unit)
        if z is not None:
            m, k = z
            found.append(m)
            for j in range(i, k):
                used[j] = True
    for i, h in enumerate(hs):
        if used[i] or h.duration <= 0:
            continue
        opposite = h.left * h.right < 0 and min(abs(h.left), abs(h.right)) > zero
        if opposite and abs(h.diff) >= d_on and h.duration >= st.min_pivot_s:
            found.append(M.pivot(track, h.start, h.end))
            used[i] = True
        elif not opposite and abs(h.diff) >= d_on:
            i0, i1 = track.at(h.start), track.at(h.end)
            turned = abs(track.psi[i1] - track.psi[i0])
            if math.degrees(turned) >= st.min_turn_deg:
                tc = M.turning_circle(track, h.start, h.end)
                if tc is not None:
                    found.append(tc)
                    used[i] = True
        elif abs(h.left) <= zero and abs(h.right) <= zero and h.duration >= st.min_stop_s and i > 0 \
                and h.start - track.t[0] >= M.EXECUTE_HEADING_S:
            w = (track.t >= h.start - M.EXECUTE_HEADING_S) & (track.t < h.start)
            if track.u[w].mean() >= st.min_stop_speed_mps:
                sm = M.stop(track, h.start, h.end)
                if sm is not None:
                    found.append(sm)
                    used[i] = True
    found.extend(_speed_steps(track, hs, used, d_on, zero, fs, st, p.unit))
    found.sort(key=lambda m: m.start_s)
    return Manoeuvres(tuple(found), int(t0_ns), source)


def _zigzag_at(track: Track, hs: list[Hold], i: int, d_on: float, st: Settings,
               unit: str) -> tuple[Manoeuvre, int] | None:
    """A zig-zag whose execute is hold ``i``: (the manoeuvre, the index after its last hold), or None."""
    h0 = hs[i]
    if abs(h0.diff) < d_on or h0.left * h0.right < 0:
        return None
    seq = [h0]
    k = i + 1
    while k < len(hs):
        h = hs[k]
        same_size = abs(abs(h.diff) - abs(h0.diff)) <= 0.25 * abs(h0.diff)
        if not (same_size and np.sign(h.diff) == -np.sign(seq[-1].diff)
                and abs(h.common - h0.common) <= 0.25 * max(abs(h0.diff), 1e-12)):
            break
        seq.append(h)
        k += 1
    if len(seq) < 3:   # execute + at least two reversals
        return None
    psi0 = M.execute_heading(track, h0.start)
    devs = np.array([track.psi[track.at(h.start)] - psi0 for h in seq[1:]])
    # every reversal with the heading off to alternate sides, by one angle
    signs = np.sign(devs)
    if np.any(signs == 0) or np.any(signs[1:] == signs[:-1]):
        return None
    if np.ptp(np.abs(devs)) > 2 * st.zigzag_angle_tol_deg * math.pi / 180 or \
            math.degrees(np.mean(np.abs(devs))) < 2.0:
        return None
    m = M.zigzag(track, [h.start for h in seq], seq[-1].end)
    if m is None:
        return None
    return m, k


def _speed_steps(track: Track, hs: list[Hold], used: list[bool], d_on: float, zero: float, fs: float,
                 st: Settings, unit: str) -> list[Manoeuvre]:
    """Runs of at least two consecutive speed steps (straight holds, the common thrust changed)."""
    steps = []
    for i in range(1, len(hs)):
        h, p = hs[i], hs[i - 1]
        ok = (not used[i] and abs(h.diff) < d_on and abs(p.diff) < d_on and h.common > zero
              and abs(h.common - p.common) >= st.step_frac * fs and h.duration >= st.min_step_s)
        steps.append(i if ok else None)
    out = []
    group: list[int] = []
    ends: list[int | None] = [*steps, None]
    for k in ends:
        if k is not None and (not group or k == group[-1] + 1):
            group.append(k)
            continue
        if len(group) >= 2:
            m = M.speed_steps(track, [(hs[j].start, hs[j].end, hs[j].common) for j in group], unit)
            if m is not None:
                out.append(m)
                for j in group:
                    used[j] = True
        group = [k] if k is not None else []
    return out


__all__ = ["Commands", "CommandsBuilder", "Hold", "Plan", "Settings", "Track", "TrackBuilder", "commands_from_frame",
           "find", "find_planned", "full_scale", "holds", "plan", "track_from_frame", "uses_forces"]
