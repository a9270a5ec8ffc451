"""Whether a verb may use a second CPU core.

Some verbs run GIL-free work on a second thread (the smoother's block re-runs, identify's
shooting segments, replay's what-if closed loop) or draw the report's figures in a forked copy;
the results are bit-identical to one thread. That pays only when a core is free: a process
pinned to one CPU, or a campaign whose workers already fill every core, runs them in one.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable
from typing import TypeVar

_T = TypeVar("_T")

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


def run_ahead(fn: Callable[[], _T]) -> Callable[[], _T]:
    """Start ``fn()`` on a second thread, for its result to be taken later.

    A verb reads its log (zstd decompression and compiled ``nogil`` read kernels: most of it
    without the GIL) while its main thread imports the verb's modules and checks its options
    (~0.5-1 s of start-up that holds the GIL): on a second core the two overlap. The main
    thread keeps the order of everything the user sees: its own errors (a bad option) come
    first, then ``fn``'s, raised where the result is taken; ``fn`` must not print.

    Parameters
    ----------
    fn : callable
        Called without arguments, once. Start it only after importing what it imports at
        its top (its lazy imports, numba's and pandas', must not wait on a module the main
        thread is importing in turn).

    Returns
    -------
    callable
        ``result()`` waits for the thread and returns ``fn()``'s value, or raises its
        exception. Without a spare CPU (:func:`spare_cpu`) no thread is started and
        ``result()`` is ``fn`` itself: it runs when its result is asked for.
    """
    if not spare_cpu():
        return fn
    box: list = []

    def run() -> None:
        try:
            box.append((True, fn()))
        except BaseException as err:  # noqa: BLE001 - raised again where the result is taken
            box.append((False, err))

    th = threading.Thread(target=run, name="usvlog-read-ahead", daemon=True)
    th.start()

    def result() -> _T:
        th.join()
        ok, value = box.pop()
        if not ok:
            raise value
        return value

    return result
