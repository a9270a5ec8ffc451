"""Compiled kernels cannot go stale: an edit to a function a kernel calls from another file
is what the next run executes (the cache is keyed on the whole package source).

The closed-loop kernel (sim/closed_loop.py) compiles in control_tick/control_law
(control/law.py). numba's own cache checks only the kernel's file, so with it the edit below
would be ignored until the cache was cleared. Each run is a fresh process on a copy of the
package with its own NUMBA_CACHE_DIR.
"""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np

import usvlog

REPO = Path(usvlog.__file__).resolve().parent.parent

SCRIPT = """
import json
import sys
import numpy as np
import usvlog
from usvlog import _jit
from usvlog.control.gains import Gains, GuidanceSettings
from usvlog.control.law import Controller
from usvlog.control.paths import path_from_spec
from usvlog.model.vessel import default_vessel
from usvlog.sim.closed_loop import closed_loop

path = path_from_spec({"type": "circle", "center_ne": [0.0, 0.0], "radius_m": 20.0})
vessel = default_vessel()
ctl = Controller(path, vessel, Gains(), GuidanceSettings(rate_hz=20.0))
run = closed_loop(path, vessel, ctl, duration_s=8.0, dt_s=0.05, integrator="rk4", current_ne=(0.0, 0.0),
                  eta0=(-25.0, 3.0, 0.2), nu0=(0.5, 0.0, 0.0), schedule=np.array([[0.0, 1.0]]), rate_hz=20.0)
print(json.dumps({"file": usvlog.__file__, "cache_dir": _jit.cache_dir(),
                  "states": run.states.tolist(), "tau": run.tau.tolist(),
                  "compiler_set_up": "numba.np.linalg" in sys.modules,
                  "helpers_imported": "numba.np.arrayobj" in sys.modules}))
"""

EDIT_FROM = "    return tau_u, tau_r\n"            # end of control_law in control/law.py
EDIT_TO = "    return 0.5 * tau_u, tau_r\n"        # half the surge force demand


def _env(cache: Path, *paths: Path) -> dict:
    """This environment without numba's settings, with ``paths`` as PYTHONPATH and its own kernel cache."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_")}
    env.update(PYTHONPATH=os.pathsep.join(str(p) for p in paths), NUMBA_CACHE_DIR=str(cache))
    return env


def _run(pkg_root: Path, cache: Path, *, disable_jit: bool = False) -> dict:
    env = _env(cache, pkg_root)
    if disable_jit:
        env["NUMBA_DISABLE_JIT"] = "1"
    out = subprocess.run([sys.executable, "-c", SCRIPT], env=env, cwd=pkg_root, capture_output=True, text=True,
                         check=True)
    res = json.loads(out.stdout.strip().splitlines()[-1])
    assert Path(res["file"]).resolve() == (pkg_root / "usvlog" / "__init__.py").resolve()
    return res


def _files(cache: Path) -> dict:
    return {str(p.relative_to(cache)): p.stat().st_mtime_ns for p in cache.rglob("*") if p.is_file()}


def test_edit_in_called_file_is_what_runs(tmp_path):
    pkg = tmp_path / "pkg"
    shutil.copytree(REPO / "usvlog", pkg / "usvlog", ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copytree(REPO / "schemas", pkg / "schemas")
    cache = tmp_path / "cache"

    first = _run(pkg, cache)
    hash_dir = Path(first["cache_dir"])
    assert hash_dir.parent == cache / "usvlog"
    index = [p.name for p in hash_dir.rglob("*.nbi")]
    assert any(n.startswith("closed_loop._closed_loop_kernel") for n in index), index

    # unchanged source: the kernels come from the cache (nothing compiled or written again)
    before = _files(cache)
    second = _run(pkg, cache)
    assert _files(cache) == before
    assert second["cache_dir"] == first["cache_dir"]
    np.testing.assert_array_equal(second["states"], first["states"])
    # ... without setting numba's compiler up (its registries, scipy.linalg): only compiling needs it
    assert first["compiler_set_up"] and not second["compiler_set_up"]
    # ... nor importing the modules of numba's helpers compiled in (their environments rebuilt without them)
    assert first["helpers_imported"] and not second["helpers_imported"]

    # edit the function the kernel calls, in the other file
    law = pkg / "usvlog" / "control" / "law.py"
    text = law.read_text()
    assert text.count(EDIT_FROM) == 1, "control_law no longer ends as this test expects: update EDIT_FROM"
    law.write_text(text.replace(EDIT_FROM, EDIT_TO))

    edited = _run(pkg, cache)
    assert edited["cache_dir"] != first["cache_dir"]
    truth = _run(pkg, tmp_path / "unused", disable_jit=True)   # the edited source, interpreted
    old, new, ref = (np.asarray(r["states"]) for r in (first, edited, truth))
    np.testing.assert_allclose(new, ref, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(edited["tau"], truth["tau"], rtol=1e-9, atol=1e-9)
    assert np.max(np.abs(new - old)) > 0.1   # the edit matters: the old kernel would be visibly off


def test_source_hash_sees_every_file(tmp_path):
    from usvlog._jit import source_hash

    pkg = tmp_path / "p"
    (pkg / "sub" / "__pycache__").mkdir(parents=True)
    (pkg / "a.py").write_text("x = 1\n")
    (pkg / "sub" / "b.py").write_text("y = 2\n")
    (pkg / "notes.txt").write_text("not source")
    h0 = source_hash(str(pkg))
    (pkg / "sub" / "__pycache__" / "b.cpython-311.pyc").write_bytes(b"\0")   # not source
    (pkg / "notes.txt").write_text("still not source")
    assert source_hash(str(pkg)) == h0
    seen = {h0}
    (pkg / "sub" / "b.py").write_text("y = 3\n")                           # content
    seen.add(source_hash(str(pkg)))
    (pkg / "sub" / "b.py").rename(pkg / "sub" / "c.py")                    # name
    seen.add(source_hash(str(pkg)))
    (pkg / "d.py").write_text("")                                          # a new (empty) file
    seen.add(source_hash(str(pkg)))
    assert len(seen) == 4


def test_source_hash_leaves_out_only_what_kernels_cannot_reach(tmp_path):
    from usvlog._jit import UNREACHABLE, source_hash

    pkg = tmp_path / "p"
    for d in ("cli", "view", "control", "sim", "api"):
        (pkg / d).mkdir(parents=True)
        (pkg / d / "m.py").write_text("x = 1\n")
    h0 = source_hash(str(pkg))
    (pkg / "cli" / "m.py").write_text("x = 2\n")          # above the kernels: same hash
    (pkg / "view" / "m.py").write_text("x = 2\n")
    (pkg / "api" / "m.py").write_text("y = 1\n")
    assert source_hash(str(pkg)) == h0
    (pkg / "control" / "m.py").write_text("x = 2\n")      # reachable: a new hash
    assert source_hash(str(pkg)) != h0
    # every name left out is a layer above sim in the architecture test's table
    from tests.test_architecture import LAYERS, UNITS

    above = set().union(*(UNITS[u] for layer in LAYERS[:LAYERS.index(("sim",))] for u in layer))
    for name in UNREACHABLE:
        mod = "usvlog." + name.removesuffix(".py") if name not in ("__init__.py",) else "usvlog"
        assert mod in above or mod == "usvlog.__main__", mod
    # and every unit above sim is left out: an edit there must not recompile every kernel
    left_out = {"usvlog." + name.removesuffix(".py") if name != "__init__.py" else "usvlog" for name in UNREACHABLE}
    assert above <= left_out, sorted(above - left_out)


def _hash_dirs(parent, ages_h):
    import time

    now = time.time()
    for i, age in enumerate(ages_h):
        d = parent / f"h{i:02d}"
        (d / "sub").mkdir(parents=True)
        (d / "sub" / "f.nbi").write_bytes(b"x")
        os.utime(d, (now - age * 3600, now - age * 3600))
    (parent / "current").mkdir()
    return str(parent / "current")


AGES_H = [0.1, 0.5, 2, 3, 5, 8, 13, 21, 34, 55, 89]   # hours since each directory was last used


def test_prune_keeps_the_most_recently_used(tmp_path):
    from usvlog import _jit

    _jit._prune(str(tmp_path), _hash_dirs(tmp_path, AGES_H))
    # the current one plus the KEEP_DIRS - 1 most recently used others
    assert _jit.KEEP_DIRS == 8
    assert sorted(p.name for p in tmp_path.iterdir()) == ["current"] + [f"h{i:02d}" for i in range(7)]


def test_prune_never_deletes_a_directory_used_within_the_hour(tmp_path, monkeypatch):
    from usvlog import _jit

    monkeypatch.setattr(_jit, "KEEP_DIRS", 1)
    _jit._prune(str(tmp_path), _hash_dirs(tmp_path, AGES_H))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["current", "h00", "h01"]


KERNELS = '''
import numpy as np
from usvlog._jit import njit


@njit
def sized(n):
    return np.empty(n).size + np.zeros((n, 2)).size   # numba's array helpers, and their ValueError for n < 0


@njit
def checked(x):
    if x < 0:
        raise ValueError("negative x", x)
    return x
'''

ERRORS = """
import json, sys
import probe_kernels as k
out = [k.sized(3)]
for f, a in ((k.sized, -1), (k.checked, -2.0)):
    try:
        f(a)
    except Exception as e:
        out.append([type(e).__name__, str(e)])
print(json.dumps({"out": out, "helpers_imported": "numba.np.arrayobj" in sys.modules}))
"""


def test_errors_raised_in_cached_kernels_are_the_compiled_ones(tmp_path):
    """A kernel loaded from the cache, its helpers' modules not imported, raises what it raised compiled."""
    (tmp_path / "probe_kernels.py").write_text(KERNELS)
    env = _env(tmp_path / "cache", REPO, tmp_path)
    compiled, cached = (json.loads(subprocess.run([sys.executable, "-c", ERRORS], env=env, capture_output=True,
                                                  text=True, check=True).stdout.strip().splitlines()[-1])
                        for _ in range(2))
    sized, negative_size, negative_x = compiled["out"]
    assert sized == 3 + 3 * 2 and negative_size[0] == "ValueError"
    assert negative_x == ["ValueError", str(ValueError("negative x", -2.0))]   # as Python raises it
    assert cached["out"] == compiled["out"]
    assert compiled["helpers_imported"] and not cached["helpers_imported"]


ANNOUNCE = "compiling the numerical kernels for this machine"


def test_a_first_run_says_it_compiles_and_a_cached_run_does_not(tmp_path):
    """The command line says once why a first run waits (kernels compiled into the cache named), and
    nothing when every kernel comes from the cache."""
    env = _env(tmp_path / "cache", REPO)
    log = REPO / "tests" / "data" / "paper-sine.mcap"
    runs = [subprocess.run([sys.executable, "-m", "usvlog", "inspect", str(log)], env=env, capture_output=True,
                           text=True, check=True) for _ in range(2)]
    said = [ln for ln in runs[0].stderr.splitlines() if ANNOUNCE in ln]
    assert len(said) == 1, runs[0].stderr
    kept = list((tmp_path / "cache" / "usvlog").iterdir())
    assert len(kept) == 1 and f"kept in {kept[0]} for later runs" in said[0]
    assert any(kept[0].rglob("*.nbi"))
    assert ANNOUNCE not in runs[1].stderr and runs[1].stdout == runs[0].stdout


def test_the_first_compile_callback_fires_once_and_only_for_usvlog_kernels(tmp_path, monkeypatch):
    """on_first_compile: a kernel of another package compiled first does not fire it; the first usvlog
    kernel compiled does, once (a run whose kernels come from the cache: the test above)."""
    from usvlog import _jit

    monkeypatch.setattr(_jit, "_cache_dir", str(tmp_path))   # a fresh, empty cache directory for this test

    def outside(x):
        return x + 1.0

    def inside(x):
        return x * 2.0

    def also_inside(x):
        return x * 3.0

    inside.__module__ = also_inside.__module__ = "usvlog.probe"
    heard = []
    _jit.on_first_compile(lambda kernel, cache: heard.append((kernel, cache)))
    try:
        assert _jit.njit(outside)(1.0) == 2.0 and heard == []
        assert _jit.njit(inside)(1.0) == 2.0
        assert heard == [("usvlog.probe.test_the_first_compile_callback_fires_once_and_only_for_usvlog_kernels."
                          "<locals>.inside", str(tmp_path))]
        assert _jit.njit(also_inside)(1.0) == 3.0 and len(heard) == 1
    finally:
        _jit.on_first_compile(None)
