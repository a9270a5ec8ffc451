"""The campaign's progress line: runs done of those to do, failed and unusable counts, time left."""

from __future__ import annotations

import io
import re

from usvlog.cli.campaign import Bar


def test_counts_and_eta():
    out = io.StringIO()
    bar = Bar(out)
    bar.plan(4, 3)
    bar.row({"run_id": "a", "status": "ok", "verdict": "usable"})
    bar.row({"run_id": "b", "status": "failed", "verdict": None})
    bar.row({"vessel": "alpha", "d11": 5.0})   # a joint fit's row: not a run
    bar.row({"run_id": "c", "status": "ok", "verdict": "unusable"})
    line = bar.line()
    assert re.match(r"campaign \[#{18}\.{6}\] 3/4 runs, 1 failed, 1 unusable, 3 reused, \d+ s left$", line), line
    bar.row({"run_id": "d", "status": "ok", "verdict": "caveats"})
    assert bar.line().endswith("4/4 runs, 1 failed, 1 unusable, 3 reused, done")
    assert out.getvalue().splitlines()[-1] == bar.line()   # not a terminal: whole lines, the last one final
