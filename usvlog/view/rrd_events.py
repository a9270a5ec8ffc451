"""The text entries of one log: its events, the findings of ``usvlog check``, the manoeuvres.

Each is a TextLog at its time (``/runs/<name>/events``, ``/runs/<name>/check``,
``/runs/<name>/manoeuvres``) shown in the events view; the manoeuvres also draw their stretch of
the track in the local view. What they say comes from :mod:`usvlog.view.data`,
:mod:`usvlog.view.findings` and :mod:`usvlog.view.manoeuvres`. Methods of the writer (``self``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import rerun as rr

from . import data as vd
from . import findings as vfind
from . import manoeuvres as vman
from .windowed import findings_of, manoeuvres_of

if TYPE_CHECKING:
    from .rrd_writer import _Writer


def draw_events(self: _Writer) -> None:
    """The log's events, once each, with their level."""
    ev = vd.events_once(self.log)
    if not ev:
        return
    path = f"{self.prefix}/events"
    t = np.array([e.t_ns for e in ev], dtype=np.int64)
    text = [self.label(e.text) for e in ev]
    self.rec.send_columns(path, indexes=self.index_cols(t),
                          columns=rr.TextLog.columns(text=text, level=[e.level for e in ev]))
    self.views["events"].append(path)


def draw_manoeuvres(self: _Writer) -> None:
    """The standard manoeuvres (measured on the stored estimate): a text entry at each one's start
    (its metrics) and end in the events view, and its stretch of the track in the local view."""
    found, parts = manoeuvres_of(self.log)
    part = vman.rerun_parts(self.log, found, parts) if found else None
    if part is None:
        return
    t, text, level, strips, labels = part
    path = f"{self.prefix}/{vman.ENTITY}"
    self.rec.send_columns(path, indexes=self.index_cols(t),
                          columns=rr.TextLog.columns(text=[self.label(x) for x in text], level=level))
    self.views["events"].append(path)
    if strips:
        self.static("local", vman.TRACK_ENTITY, rr.LineStrips2D(
            strips, radii=rr.Radius.ui_points(3.0), labels=[self.label(x) for x in labels], show_labels=False))


def draw_findings(self: _Writer) -> None:
    """The findings of ``usvlog check``: one text entry per finding at its start, with its level."""
    res = findings_of(self.log)
    part = vfind.rerun_parts(self.log, res) if res is not None else None
    if part is None:
        return
    t, text, level = part
    path = f"{self.prefix}/{vfind.ENTITY}"
    self.rec.send_columns(path, indexes=self.index_cols(t),
                          columns=rr.TextLog.columns(text=[self.label(x) for x in text], level=level))
    self.views["events"].append(path)
