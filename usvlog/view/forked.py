"""Work done by a forked copy of the process while this one does something else.

The view and the report use it where this process is held by the GIL (importing rerun or
matplotlib, drawing figures with matplotlib) and the other work needs no state but what the
copy inherits: a channel read from the log's file, figures drawn from the log. The value comes
back pickled through a temporary file; when the copy fails, the caller does the work itself, so
the result never depends on whether the copy ran.
"""

from __future__ import annotations

import contextlib
import os
import pickle
import sys
import tempfile

from .._cpu import spare_cpu


class Forked:
    """``fn()`` run in a forked copy of this process; :meth:`result` waits for its (picklable) value.

    Parameters
    ----------
    fn : callable
        Called without arguments in the copy; its value must pickle.
    """

    def __init__(self, fn):
        self._file = tempfile.TemporaryFile()   # noqa: SIM115 - closed by result() or stop()
        self.pid = os.fork()
        if self.pid == 0:   # the copy: the value into the file, then out without the parent's exit handlers
            code = 1
            try:
                pickle.dump(fn(), self._file, protocol=pickle.HIGHEST_PROTOCOL)
                self._file.flush()
                code = 0
            finally:
                os._exit(code)

    def result(self):
        """``fn()``'s value, or None when the copy failed (the caller then does the work itself)."""
        try:
            _pid, status = os.waitpid(self.pid, 0)
            if os.waitstatus_to_exitcode(status) != 0:
                return None
            self._file.seek(0)
            return pickle.load(self._file)   # noqa: S301 - written by this process's own copy
        finally:
            self._file.close()

    def stop(self) -> None:
        """End the copy (the caller failed) and reap it."""
        import signal  # stdlib: only when the caller fails

        with contextlib.suppress(ProcessLookupError):
            os.kill(self.pid, signal.SIGKILL)
        with contextlib.suppress(ChildProcessError):
            os.waitpid(self.pid, 0)
        self._file.close()


def two_cores() -> bool:
    """True when a forked copy may work beside this process: Linux, a spare CPU
    (:func:`usvlog._cpu.spare_cpu`, ``USVLOG_THREADS``) and no other thread running (one could
    hold a lock, e.g. an import's, the copy would wait on forever).

    Returns
    -------
    bool
        Whether to fork.
    """
    import threading  # stdlib: only when a copy could be used

    return (sys.platform.startswith("linux") and hasattr(os, "fork") and spare_cpu()
            and threading.active_count() == 1)
