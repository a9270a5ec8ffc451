"""Run many independent tasks on Dask: a local cluster of processes or an existing scheduler.

The one place where usvlog talks to ``dask.distributed``. :func:`run_tasks` submits one
task per item, hands each result to a callback as it arrives (for the progress bar and
the table), and on Ctrl-C cancels what has not finished, closes the client and the local
cluster it started, and re-raises: work already finished stays finished (the tasks write
their outputs atomically themselves). ``dask`` is imported only when tasks run.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from .._cpu import THREADS_VAR
from ..errors import ConfigError


@dataclass(frozen=True, kw_only=True)
class ClusterInfo:
    """Where the tasks ran.

    Attributes
    ----------
    scheduler : str
        The scheduler's address (``tcp://...``; ``local`` for the sequential path).
    dashboard : str or None
        The dashboard's address (None when there is none; for a local cluster without
        bokeh, a note saying so instead of an address that serves nothing).
    workers : int
        Worker processes at the start.
    local : bool
        A local cluster started (and closed) here.
    """

    scheduler: str
    dashboard: str | None
    workers: int
    local: bool


def default_workers() -> int:
    """Worker processes of a local cluster: the cores this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover (not on Linux)
        return max(1, os.cpu_count() or 1)


def _dashboard_note(link: str | None, local: bool) -> str | None:
    """The dashboard's address, or why a local cluster's has none (never an address that serves nothing)."""
    if not link or not local:   # a running scheduler serves its own pages (with its own bokeh)
        return link or None
    try:
        import bokeh  # type: ignore[import-not-found]  # noqa: F401  (a dependency: the dashboard's pages)
    except ImportError:
        return "none (its pages need bokeh>=3.1: pip install bokeh)"
    return link


class Runner:
    """Dask tasks on a local cluster of processes or on an existing scheduler, started on first use.

    Use as a context manager; :meth:`map` may be called several times on one cluster. The
    cluster starts when the first task is submitted (a campaign with nothing left to do
    starts none) and is closed on leaving the ``with`` block, also on Ctrl-C.

    Parameters
    ----------
    workers : int, optional
        Worker processes of the local cluster (default :func:`default_workers`), one thread
        each.
    scheduler : str, optional
        Address of a running Dask scheduler (``tcp://host:8786``) instead of a local cluster.
    sequential : bool
        Run the tasks in this process one after the other, without Dask (for measuring what
        the cluster adds, and for debugging).
    on_start : callable, optional
        Called with the :class:`ClusterInfo` once the client is connected.

    Raises
    ------
    usvlog.errors.ConfigError
        ``workers`` < 1, both ``workers`` and ``scheduler``, or a scheduler that cannot be
        reached.
    """

    def __init__(self, *, workers: int | None = None, scheduler: str | None = None, sequential: bool = False,
                 on_start: Callable[[ClusterInfo], None] | None = None):
        if workers is not None and workers < 1:
            raise ConfigError(f"--workers {workers} must be >= 1")
        if workers is not None and scheduler:
            raise ConfigError("--workers and --scheduler do not go together (the scheduler has its workers)")
        self.workers, self.scheduler, self.sequential, self.on_start = workers, scheduler, sequential, on_start
        self.cluster: Any = None
        self.client: Any = None
        self.info: ClusterInfo | None = None
        self.submitted = 0

    def __enter__(self) -> Runner:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Close the client and the local cluster started here (if any)."""
        client, cluster = self.client, self.cluster
        self.client = self.cluster = None
        if client is not None:
            client.close()
        if cluster is not None:
            cluster.close()

    def _connect(self):
        import logging

        from dask.distributed import Client, LocalCluster  # heavy: dask, only when tasks run

        for name in ("distributed", "distributed.worker", "distributed.scheduler", "distributed.nanny"):
            logging.getLogger(name).setLevel(logging.ERROR)   # the bar is the user's view of progress
        if self.scheduler:
            try:
                self.client = Client(self.scheduler, timeout="10s")
            except (OSError, TimeoutError) as err:
                raise ConfigError(f"--scheduler {self.scheduler}: cannot connect ({err})") from err
        else:
            import dask  # heavy: only when tasks run

            n = self.workers or default_workers()
            # Dask starts its workers with MALLOC_TRIM_THRESHOLD_=65536: glibc then returns every
            # freed block over 64 KB to the system at once, and a run's arrays come back as fresh
            # pages. Measured on 8 ten-minute runs (2 workers): 10.6-11.4 s of kernel time in the
            # workers instead of 2.1, tasks 25 % slower. glibc's own adaptive threshold is kept
            # (read_log hands decoding's heap back itself); a value in the environment still wins.
            # The workers' statistical profiler (a thread taking the GIL every 10 ms to walk the
            # task's stack, for the dashboard's Profile page) is off: the tasks are the
            # pipeline's stages, profiled by its own benchmarks; the status pages stay. The event
            # loops' health tick (20 ms), the memory monitor (100 ms) and the system monitor
            # (500 ms) run every 1, 1 and 2 s: a run takes seconds, and on a small machine the
            # scheduler, nannies and client share the cores with the workers (40 ten-minute runs
            # on 2 cores: 3.5-3.9 s of CPU in this process instead of 5.8-6.1 s). Each worker is one
            # core: its verbs keep their second-core work (threads, the report's forked drawer) in
            # one, unless USVLOG_THREADS is set in the environment. (Given as the workers' own
            # environment: Dask's pre-spawn variables are also written into this process's.)
            with dask.config.set({"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,
                                  "distributed.worker.profile.enabled": False,
                                  "distributed.admin.tick.interval": "1s",
                                  "distributed.worker.memory.monitor-interval": "1s",
                                  "distributed.admin.system-monitor.interval": "2s"}):
                self.cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                            dashboard_address=":0", silence_logs=logging.ERROR,
                                            env={THREADS_VAR: os.environ.get(THREADS_VAR) or "1"})
            self.client = Client(self.cluster)
        c, local = self.client, self.cluster is not None
        self.info = ClusterInfo(scheduler=str(c.scheduler.address), dashboard=_dashboard_note(c.dashboard_link, local),
                                workers=len(c.scheduler_info(n_workers=-1).get("workers", {})), local=local)
        if self.on_start:
            self.on_start(self.info)

    def map(self, fn: Callable, items: Sequence, *args, keys: Sequence[str] | None = None,
            on_result: Callable[[int, Any], None] | None = None,
            on_error: Callable[[int, BaseException], Any] | None = None) -> list:
        """``[fn(item, *args) for item in items]``, one task per item, results in item order.

        Parameters
        ----------
        fn : callable
            A module-level function (pickled by reference to the workers).
        items : sequence
            One task per item.
        *args
            Passed to every call after the item.
        keys : sequence of str, optional
            Dask keys of the tasks (unique; default generated).
        on_result : callable, optional
            Called with (index, result) as each task finishes, in finishing order.
        on_error : callable, optional
            Called with (index, exception) of a task that raised (or whose worker died);
            its return value becomes that item's result. Without it the exception
            propagates.

        Returns
        -------
        list
            The results in the order of ``items``.

        Raises
        ------
        KeyboardInterrupt
            After cancelling the unfinished tasks (the caller's ``with`` closes the cluster).
        """
        if not items:
            return []
        self.submitted += len(items)
        if self.sequential:
            return run_sequential(fn, items, *args, on_result=on_result, on_error=on_error)
        if self.client is None:
            self._connect()
        from dask.distributed import as_completed  # heavy: dask (already loaded by _connect)

        client = self.client
        assert client is not None
        futures: list = []
        try:
            index = {}
            for i, item in enumerate(items):
                kw = {"key": keys[i]} if keys is not None else {}
                f = client.submit(fn, item, *args, pure=False, **kw)
                index[f.key] = i
                futures.append(f)
            results: list = [None] * len(items)
            for f in as_completed(futures):
                i = index[f.key]
                try:
                    r = f.result()
                except Exception as err:
                    if on_error is None:
                        raise
                    r = on_error(i, err)
                results[i] = r
                f.release()
                if on_result:
                    on_result(i, r)
            return results
        finally:
            pending = [f for f in futures if not f.done()]
            if pending and self.client is not None:
                self.client.cancel(pending)


def run_tasks(fn: Callable, items: Sequence, *args, workers: int | None = None, scheduler: str | None = None,
              keys: Sequence[str] | None = None, on_start: Callable[[ClusterInfo], None] | None = None,
              on_result: Callable[[int, Any], None] | None = None,
              on_error: Callable[[int, BaseException], Any] | None = None) -> list:
    """:meth:`Runner.map` on a cluster of its own, closed at the end (parameters as there).

    Returns
    -------
    list
        The results in the order of ``items``.
    """
    with Runner(workers=workers, scheduler=scheduler, on_start=on_start) as r:
        return r.map(fn, items, *args, keys=keys, on_result=on_result, on_error=on_error)


def run_sequential(fn: Callable, items: Sequence, *args, on_result: Callable[[int, Any], None] | None = None,
                   on_error: Callable[[int, BaseException], Any] | None = None) -> list:
    """The same as :func:`run_tasks` in this process, one item after the other (no Dask).

    For measuring what the cluster adds (``benchmarks/bench_campaign.py``) and for a
    single run. Parameters as :func:`run_tasks`.
    """
    out = []
    for i, item in enumerate(items):
        try:
            r = fn(item, *args)
        except Exception as err:
            if on_error is None:
                raise
            r = on_error(i, err)
        out.append(r)
        if on_result:
            on_result(i, r)
    return out


__all__ = ["ClusterInfo", "Runner", "default_workers", "run_sequential", "run_tasks"]
