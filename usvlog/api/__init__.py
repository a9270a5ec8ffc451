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

This package imports only the standard library at the top: each function imports the part of
the library it needs when it is called, so that ``import usvlog`` and ``usvlog --help`` stay fast.

The functions live in modules of one job each, read top to bottom:

* :mod:`usvlog.api._common`: what every verb shares (reading a log, a vessel file, early path checks);
* :mod:`usvlog.api.data_in`: ``load``, ``save``, ``import_log``, ``inspect``, ``export``, ``check``;
* :mod:`usvlog.api.simulation`: ``simulate``;
* :mod:`usvlog.api.analysis`: ``estimate``, ``identify``, ``fit_log``, ``manoeuvres``;
* :mod:`usvlog.api.controller`: ``gains``, ``gains_and_vessel``, ``replay``;
* :mod:`usvlog.api.pictures`: ``to_rrd`` (``usvlog view``), ``report``;
* :mod:`usvlog.api.many_runs`: ``regress``, ``campaign``.
"""

from __future__ import annotations

# what the verbs share, and two constants, as they were reached when the API was one module
# (benchmarks/bench_write.py reads with _read and _REPLAY_READS)
from ._common import PathLike as PathLike
from ._common import Progress as Progress
from ._common import _check_paths as _check_paths
from ._common import _is_path as _is_path
from ._common import _read as _read
from ._common import _say as _say
from ._common import _vessel_file as _vessel_file
from .analysis import FIT_TOPIC as FIT_TOPIC
from .controller import _REPLAY_READS as _REPLAY_READS

# the verbs, in the order the API reference lists them (mkdocstrings orders them by line)
# isort: off
from .data_in import load
from .data_in import save
from .data_in import import_log
from .data_in import inspect
from .data_in import export
from .simulation import simulate
from .analysis import estimate
from .analysis import identify
from .analysis import fit_log
from .controller import gains_and_vessel
from .controller import gains
from .controller import replay
from .analysis import manoeuvres
from .data_in import check
from .pictures import to_rrd
from .pictures import report
from .many_runs import regress
from .many_runs import campaign
# isort: on

__all__ = ["campaign", "check", "estimate", "export", "fit_log", "gains", "gains_and_vessel", "identify",
           "import_log", "inspect", "load", "manoeuvres", "regress", "replay", "report", "save", "simulate",
           "to_rrd"]
