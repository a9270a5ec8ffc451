"""Whether a verb may use a second CPU core.

Some verbs run GIL-free work on a second thread (identify's shooting segments) or a forked copy
(the view's read of one channel, the report's drawing of some figures); the results are
bit-identical to one thread. That pays only when a core is free: a process pinned to one CPU,
or a campaign whose workers already fill every core, runs them in one.
"""

from __future__ import annotations

import os

THREADS_VAR = "USVLOG_THREADS"
"""Environment variable: ``1`` keeps every verb on one core (the campaign's workers set it),
a larger number allows a second one; unset, the CPUs this process may run on decide."""


def spare_cpu() -> bool:
    """True when this process may use a second CPU core.

    Returns
    -------
    bool
        ``USVLOG_THREADS`` > 1 if it is set to a whole number; else more than one CPU in the
        process's affinity mask (``os.cpu_count()`` where there is no mask).
    """
    v = os.environ.get(THREADS_VAR, "").strip()
    if v.isdigit():
        return int(v) > 1
    try:
        n = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):   # no affinity mask on this system
        n = os.cpu_count() or 1
    return n > 1
