"""One child process timed as a user would see it: the benchmarks that run usvlog's verbs in fresh processes."""

from __future__ import annotations

import os
import subprocess
import tempfile
import time
from dataclasses import dataclass


@dataclass(frozen=True)
class Timed:
    """What one child process took and said."""

    wall_s: float        # from spawning it to its exit
    cpu_s: float         # its user + system CPU (its threads included)
    user_s: float
    sys_s: float
    peak_rss_mb: float   # its ru_maxrss
    returncode: int
    stdout: bytes
    stderr: bytes


def timed_run(cmd: list[str], env: dict | None = None, cwd=None) -> Timed:
    """Run ``cmd`` to its end and measure it (``os.wait4``: the child's own CPU and peak RSS).

    Its output goes to temporary files (not pipes, which a large output would fill and stall)
    and is read back after it exits.
    """
    with tempfile.TemporaryFile() as so, tempfile.TemporaryFile() as se:
        t = time.perf_counter()
        p = subprocess.Popen(cmd, env=env, cwd=cwd, stdout=so, stderr=se)
        _, status, ru = os.wait4(p.pid, 0)
        wall = time.perf_counter() - t
        p.returncode = os.waitstatus_to_exitcode(status)
        so.seek(0)
        se.seek(0)
        return Timed(wall, ru.ru_utime + ru.ru_stime, ru.ru_utime, ru.ru_stime, ru.ru_maxrss / 1024, p.returncode,
                     so.read(), se.read())
