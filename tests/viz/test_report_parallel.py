"""The report's figures drawn on two CPUs (a forked copy draws its share, by expected cost) are
the bytes drawn one after another in this process, and a copy that fails leaves its figures to
this one; the share is near the best split.

Run in a fresh interpreter: the report forks only when no other thread runs, and a test
worker (pytest-xdist) has threads of its own.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

import usvlog

ROOT = Path(usvlog.__file__).resolve().parents[1]

SCRIPT = r'''
import hashlib, json, os, sys
import numpy as np
from usvlog.view import report as rp

fail_in_copy = sys.argv[1] == "fail"
parent = os.getpid()
forked = []
_init = rp._Forked.__init__
def init(self, fn):
    forked.append(True)
    _init(self, fn)
rp._Forked.__init__ = init

def figs(fail):
    """Four small figures (one the log 'lacks'); with ``fail`` the copy cannot draw."""
    plt = rp._plt()
    x = np.linspace(0.0, 10.0, 2000)
    def make(k):
        def draw():
            if fail and os.getpid() != parent:
                raise RuntimeError("the copy fails")
            if k == 2:
                return None
            fig, ax = plt.subplots(figsize=(3.0, 2.0))
            ax.plot(x, np.sin(x * (k + 1)), label=f"sine {k}")
            ax.set_title(f"figure {k}")
            ax.legend()
            return fig
        return draw
    return [(f"f{k}.png", f"Figure {k}", make(k), "nothing") for k in range(4)]

def digest(d):
    return None if d is None else [d[0], hashlib.sha256(d[1]).hexdigest(), d[1][:8].hex()]

two_cores = rp._two_cores()
import threading
from usvlog._cpu import spare_cpu
why = {"threads": [t.name for t in threading.enumerate()], "spare_cpu": spare_cpu(),
       "affinity": len(os.sched_getaffinity(0)), "USVLOG_THREADS": os.environ.get("USVLOG_THREADS")}
one = [rp._drawn(title, make) for _name, title, make, _needs in figs(False)]
two = rp.draw_all(figs(fail_in_copy))
print(json.dumps({"two_cores": two_cores, "why": why, "forked": bool(forked), "one": [digest(d) for d in one],
                  "two": [digest(d) for d in two]}))
'''


@pytest.mark.parametrize("fail_in_copy", [False, True])
def test_two_cpus_draw_the_same_bytes(fail_in_copy):
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), *filter(None, [env.get("PYTHONPATH")])])
    r = subprocess.run([sys.executable, "-c", SCRIPT, "fail" if fail_in_copy else "ok"], capture_output=True,
                       text=True, env=env, cwd=ROOT, timeout=300)
    assert r.returncode == 0, r.stderr
    got = json.loads(r.stdout.strip().splitlines()[-1])
    if not got["two_cores"]:
        pytest.skip(f"drawing on two CPUs needs Linux, a second CPU and no other thread: {got['why']}")
    assert got["forked"]                               # the copy really drew (or failed to)
    one, two = got["one"], got["two"]
    assert one[2] is None and two[2] is None           # the figure the log lacks, in both
    assert [d is None for d in one] == [d is None for d in two]
    for a, b in zip(one, two):
        if a is not None:
            assert a[0] == b[0]                        # caption
            assert a[1] == b[1]                        # the very same PNG bytes
            assert bytes.fromhex(a[2]) == b"\x89PNG\r\n\x1a\n"


def test_figures_shared_by_cost_near_the_best_split():
    """The copy's share (:func:`share`, costliest first to the process with less to do) against every
    split: its longer side within 7/6 of the best split's (that rule's bound for two processes, held
    here with this process's own work too); figures that cost nothing (not drawn) never forked off."""
    import itertools

    import numpy as np

    from usvlog.view.report import FIGURE_COST, figure_costs, share

    rng = np.random.default_rng(7)
    cases = [list(FIGURE_COST.values()), [0.33, 0.83, 0.0, 0.0, 0.0, 0.0, 0.0]]
    cases += [list(np.round(rng.uniform(0.0, 1.0, rng.integers(2, 8)), 2)) for _ in range(40)]
    for costs in cases:
        for own in (0.0, 0.08, 0.5):
            theirs = share(costs, own)
            assert all(costs[i] > 0 for i in theirs)
            longest = max(own + sum(c for i, c in enumerate(costs) if i not in theirs), sum(costs[i] for i in theirs))
            best = min(max(own + sum(c for i, c in enumerate(costs) if i not in s), sum(costs[i] for i in s))
                       for k in range(len(costs) + 1) for s in itertools.combinations(range(len(costs)), k))
            assert longest <= 7 / 6 * best + 1e-12, (costs, own, theirs)
    figs = [(name, "", None, "") for name in FIGURE_COST]
    assert figure_costs(figs) == list(FIGURE_COST.values())
