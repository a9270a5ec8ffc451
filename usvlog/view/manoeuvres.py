"""The standard manoeuvres of a run as the report and the Rerun recording show them.

:func:`of_log` measures them on the log's stored estimate (the report and the view make no
estimate of their own); :func:`html_section` is the report's table, :func:`draw_on_track` marks
each manoeuvre on a track figure and :func:`rerun_parts` is what the recording shows of each
(a text entry on the timeline at its start and end, and its stretch of the track).
"""

from __future__ import annotations

import html
import math

import numpy as np

from ..errors import UsvlogError
from ..log.fieldlog import FieldLog
from ..trials import Manoeuvres, commands_from_frame, find_planned, plan, track_from_frame

ENTITY = "manoeuvres"
"""Rerun entity of the manoeuvres' text log under a run (``/runs/<name>/manoeuvres``)."""

TRACK_ENTITY = "local/manoeuvres"
"""Rerun entity of the manoeuvres' stretches of the track under a run (local 2D view)."""


STATE, THRUST = "/estimate/state", "/thrust/command"


def of_log(log: FieldLog) -> Manoeuvres | None:
    """The manoeuvres measured on ``/estimate/state`` with ``/thrust/command``, or None when the
    log lacks either (or they hold too little to measure)."""
    tr = log.time_range()
    return measure({STATE: log.get(STATE), THRUST: log.get(THRUST)}, None if tr is None else int(tr[0]))


def measure(frames: dict, t0_ns: int | None) -> Manoeuvres | None:
    """The manoeuvres measured on ``frames[STATE]`` with ``frames[THRUST]`` (:func:`usvlog.trials.find_manoeuvres`),
    or None when either is missing (or they hold too little to measure).

    Each frame is taken out of ``frames`` once made into what the measurement uses (the commands,
    then the track): a caller holding them only there has their memory back before the next.
    ``t0_ns`` is the log's start (None for an empty log).
    """
    state, thrust = frames.get(STATE), frames.get(THRUST)
    if state is None or thrust is None or len(state) < 10 or len(thrust) < 2 or t0_ns is None:
        return None
    if "n_m" not in state.columns or not np.isfinite(state["n_m"].to_numpy(float)).any():
        return None
    del state, thrust
    return find_on(lambda: commands_from_frame(frames.pop(THRUST), t0_ns),
                 lambda: track_from_frame(frames.pop(STATE), t0_ns), t0_ns)


def find_on(commands, track, t0_ns: int) -> Manoeuvres | None:
    """The manoeuvres of the commands ``commands()`` on the track ``track()`` of ``/estimate/state``
    (:func:`usvlog.trials.find`; the commands made and read first, let go before the track is made),
    or None when either holds too little to measure."""
    try:
        planned = plan(commands())
        return find_planned(track(), planned, t0_ns=t0_ns, source=STATE)
    except UsvlogError:
        return None


def _fmt(v: float, s: float) -> str:
    digits = 2 if abs(v) < 100 else 1
    return f"{v:.{digits}f} ± {s:.{digits}f}" if math.isfinite(s) else f"{v:.{digits}f}"


def html_section(found: Manoeuvres | None) -> list[str]:
    """The report's section: one table row per metric (manoeuvre, start and end s, value ± one-sigma),
    and each speed-step manoeuvre's speed-thrust curve; nothing when the log has no estimate."""
    if found is None:
        return []
    e = html.escape
    parts = [f"<h2 id='manoeuvres'>Manoeuvres ({len(found)})</h2>"]
    if not len(found):
        return parts + ["<p>no standard manoeuvre found</p>"]
    parts.append("<p>Found from the thrust commands and measured on the estimate; times in s from the log's "
                 "start, each value ± one-sigma (definitions: docs/manoeuvres.md). Each is drawn on the track "
                 "figure by its number.</p>")
    rows = []
    for i, m in enumerate(found):
        name = f"{i + 1}. {m.title}" + (f" to {m.direction}" if m.direction else "")
        for k, x in enumerate(m.metrics):
            rows.append((name if k == 0 else "", f"{m.start_s:.1f}" if k == 0 else "",
                         f"{m.end_s:.1f}" if k == 0 else "", x.name, _fmt(x.value, x.std)))
    parts.append("<table class='manoeuvres'><tr>" + "".join(
        f"<th>{h}</th>" for h in ("manoeuvre", "start s", "end s", "metric", "value ± 1σ")) + "</tr>")
    parts += ["<tr>" + "".join(f"<td>{e(str(c))}</td>" for c in r) + "</tr>" for r in rows]
    parts.append("</table>")
    for i, m in enumerate(found):
        if m.steps:
            parts.append(f"<h3>{i + 1}. speed-thrust curve</h3><table class='speedthrust'><tr><th>start s</th>"
                         f"<th>thrust ({e(m.thrust_unit)})</th><th>steady speed m/s</th><th>time constant s</th></tr>")
            for s in m.steps:
                parts.append(f"<tr><td>{s['start_s']:.1f}</td><td>{s['thrust']:.2f}</td>"
                             f"<td>{e(_fmt(s['speed_mps'], s['speed_mps_std']))}</td>"
                             f"<td>{e(_fmt(s['time_constant_s'], s['time_constant_s_std']))}</td></tr>")
            parts.append("</table>")
    return parts


def _stretch(log: FieldLog, t0_ns: int, a_s: float, b_s: float) -> tuple[np.ndarray, np.ndarray]:
    est = log[STATE]
    t = (est.index.to_numpy().astype(np.int64) - t0_ns) * 1e-9
    k = (t >= a_s) & (t <= b_s)
    return est["n_m"].to_numpy(float)[k], est["e_m"].to_numpy(float)[k]


def stretches(log: FieldLog, found: Manoeuvres | None) -> list[tuple[np.ndarray, np.ndarray]]:
    """Each manoeuvre's stretch of the estimated track: (north m, east m), in the order of ``found``
    (empty without manoeuvres)."""
    if not found:
        return []
    return [_stretch(log, found.t0_ns, m.start_s, m.end_s) for m in found]


def draw_on_track(ax, xy, found: Manoeuvres | None, parts: list[tuple[np.ndarray, np.ndarray]]) -> None:
    """Mark each manoeuvre on a track figure: its stretch of the estimated track (``parts``, from
    :func:`stretches`), thick, numbered as in the report's table. ``xy(n, e)`` maps north/east to the
    figure's axes."""
    if not found:
        return
    for i, (m, (n, e)) in enumerate(zip(found, parts)):
        if not len(n):
            continue
        ax.plot(*xy(n, e), "-", color=f"C{(i % 8) + 2}", lw=3.0, alpha=0.55, zorder=5,
                label=f"{i + 1}. {m.title}")
        ax.annotate(str(i + 1), xy(n[0], e[0]), fontsize=9, fontweight="bold", zorder=7)


def rerun_parts(log: FieldLog, found: Manoeuvres | None = None, parts: list | None = None):
    """What the Rerun recording shows of the manoeuvres (the recording's writer sends it): those
    ``found`` (default: :func:`of_log`), their stretches ``parts`` (default: :func:`stretches`).

    Returns
    -------
    tuple or None
        ``(t_ns, texts, levels, strips, labels)``: a text entry at each manoeuvre's start (its
        metrics, level INFO) and end (DEBUG), times in ns since the Unix epoch; its stretch of the
        estimated track as a strip in the local view's axes (x = east, y = -north) with a label.
        None when the log has no estimate or no manoeuvre.
    """
    found = of_log(log) if found is None else found
    if not found:
        return None
    parts = stretches(log, found) if parts is None else parts
    t_ns, texts, levels, strips, labels = [], [], [], [], []
    for i, (m, (n, e)) in enumerate(zip(found, parts)):
        head = f"{i + 1}. {m.title}" + (f" to {m.direction}" if m.direction else "")
        t_ns += [found.t0_ns + round(m.start_s * 1e9), found.t0_ns + round(m.end_s * 1e9)]
        texts += [head + f": {m.start_s:.1f} s to {m.end_s:.1f} s; "
                  + "; ".join(f"{x.name} {_fmt(x.value, x.std)}" for x in m.metrics), f"{head}: end"]
        levels += ["INFO", "DEBUG"]
        if len(n) > 1:
            strips.append(np.column_stack([e, -n])[::max(1, len(n) // 2000)])
            labels.append(f"{i + 1}. {m.title}")
    return np.asarray(t_ns, np.int64), texts, levels, strips, labels


__all__ = ["ENTITY", "STATE", "THRUST", "TRACK_ENTITY", "draw_on_track", "find_on", "html_section", "measure",
           "of_log", "rerun_parts", "stretches"]
