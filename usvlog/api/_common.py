"""What every verb of the API shares: the types of its arguments, reading a log given as a path
or an object, loading a vessel file, refusing bad paths early and passing progress lines on.

Standard library only at the top (as in the whole :mod:`usvlog.api` package): the heavy parts are
imported inside the functions, when a log is read.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import Any

PathLike = str | os.PathLike
Progress = Callable[[str], None] | None


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
        from ..io.mcap import read_log  # heavy: imported only when a log is read

        if drawn is not None:
            from ..view.source import read_drawn  # heavy: numpy (view and report import it anyway)

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
        from ..io.config import load_vessel  # heavy: imports numpy (the vessel model)

        return load_vessel(vessel)
    return vessel


def _check_paths(inputs, out, force: bool, *more_out, parent: bool = True) -> None:
    """Refuse missing input logs and outputs that exist without ``force``, before a verb's heavy
    imports, with the same one-line errors the readers and writers would give later.

    ``inputs``: the paths among them are checked (logs given as objects are skipped; vessels are
    not passed: a bare name is a shipped vessel). ``out`` and ``more_out``: those not None.
    ``parent``: also require an output's directory to exist."""
    from ..io.atomic import check_input, check_output  # light: os and pathlib

    for p in inputs:
        if _is_path(p):
            check_input(p)
    for o in (out, *more_out):
        if o is not None:
            check_output(o, force, parent=parent)
