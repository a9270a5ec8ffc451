"""The recorder's background flush: the open chunk to the OS, then to disk, at a fixed rate."""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable


class FlushThread:
    """Calls the recorder's flush steps every ``0.8 * flush_s`` on a daemon thread.

    ``flush_s`` bounds how long a message waits in memory: flushing at a fixed rate of
    0.8 ``flush_s`` leaves a fifth of it for a late wake-up on a busy machine. Each
    round, under ``lock``: ``to_os()`` writes status rows and hands the open chunk to the
    OS and returns the file descriptor to fsync (None: the recording is over, stop);
    then, without the lock so the sources are not held up, ``os.fsync``; then, under
    ``lock``, ``after_sync()`` (rotation; returns False to stop). An ``OSError`` (a
    :class:`~usvlog.errors.StorageError` too) goes to ``fail`` (under ``lock``) and
    stops the thread.

    Parameters
    ----------
    flush_s : float
        The longest a message may wait in memory, s.
    lock : threading.RLock
        The recorder's lock.
    to_os, after_sync, fail : callable
        The recorder's steps, as above.
    """

    def __init__(self, flush_s: float, lock, *, to_os: Callable[[], int | None],
                 after_sync: Callable[[], bool], fail: Callable[[OSError], None]):
        self.period_s = 0.8 * flush_s
        self._lock = lock
        self._to_os, self._after_sync, self._fail = to_os, after_sync, fail
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="usvlog-record-flush", daemon=True)

    def start(self) -> None:
        """Start the background thread (flush every ``0.8 * flush_s`` s until :meth:`stop`)."""
        self._thread.start()

    def stop(self) -> None:
        """Stop and wait for the thread (unless called from it)."""
        self._stop.set()
        if self._thread.is_alive() and threading.current_thread() is not self._thread:
            self._thread.join()

    def _loop(self) -> None:
        period = self.period_s
        nxt = time.monotonic() + period
        while not self._stop.wait(max(0.0, nxt - time.monotonic())):
            nxt = max(nxt + period, time.monotonic() + 0.1 * period)
            try:
                with self._lock:
                    fd = self._to_os()             # in the page cache now: a killed process loses nothing more
                if fd is None:
                    return
                os.fsync(fd)                       # to disk, without holding up the sources
                with self._lock:
                    if not self._after_sync():
                        return
            except OSError as err:   # StorageError too (a part that cannot be created on rotation)
                with self._lock:
                    self._fail(err)
                return
