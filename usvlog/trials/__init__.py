"""Standard manoeuvres found in a run (turning circle, zig-zag, speed steps, stop, pivot turn).

Pure: a state frame (``/estimate/state`` or ``/truth/state``) and the ``/thrust/command``
frame in, :class:`Manoeuvres` out. Definitions: ``docs/manoeuvres.md``.
"""

from __future__ import annotations

import pandas as pd

from .detect import (
    Commands,
    CommandsBuilder,
    Plan,
    Settings,
    Track,
    TrackBuilder,
    commands_from_frame,
    find,
    find_planned,
    plan,
    track_from_frame,
    uses_forces,
)
from .result import KINDS, TITLES, Manoeuvre, Manoeuvres, Metric

MANOEUVRE_Q_UV = 0.03
"""Process noise of u and v (m^2/s^3) of the estimate ``usvlog manoeuvres`` makes for a log that has
none: larger than the general estimate's, so the track follows a fast hull's turns (measured on the
Otter runs: advance within 4.4 %, tactical diameter within 1 %, zig-zag overshoots within 0.85 deg of
the truth, against 6-12 %, 5 % and 2.3 deg with the general default)."""
MANOEUVRE_Q_R = 0.05
"""Process noise of r (rad^2/s^3) of that estimate (see :data:`MANOEUVRE_Q_UV`)."""


def find_manoeuvres(state: pd.DataFrame, thrust: pd.DataFrame, t0_ns: int, *, settings: Settings | None = None,
                    source: str = "/estimate/state") -> Manoeuvres:
    """Find and measure the standard manoeuvres of a run.

    Parameters
    ----------
    state : pandas.DataFrame
        The state indexed by ``t_ns``: ``n_m, e_m, psi_rad, u_mps, v_mps, r_radps`` and, for
        an estimate, their ``_std`` columns (a truth without them has zero sigmas).
    thrust : pandas.DataFrame
        ``/thrust/command`` indexed by ``t_ns`` (forces ``thrust_left_n``/``thrust_right_n``
        when finite, else ``left``/``right``).
    t0_ns : int
        The log's start (ns since the Unix epoch): times are reported in s from it.
    settings : Settings, optional
        Detection thresholds.
    source : str
        Name of the state's channel, recorded in the result.

    Returns
    -------
    Manoeuvres
        Empty when the run has no standard manoeuvre.

    Raises
    ------
    usvlog.errors.InputError
        A state or command channel without enough finite rows.
    """
    return find(track_from_frame(state, t0_ns), commands_from_frame(thrust, t0_ns), settings,
                t0_ns=t0_ns, source=source)


__all__ = ["KINDS", "MANOEUVRE_Q_R", "MANOEUVRE_Q_UV", "TITLES", "Commands", "CommandsBuilder", "Manoeuvre",
           "Manoeuvres", "Metric", "Plan", "Settings", "Track", "TrackBuilder", "commands_from_frame", "find",
           "find_manoeuvres", "find_planned", "plan", "track_from_frame", "uses_forces"]
