"""The one way usvlog compiles: numba's ``njit`` with an on-disk cache that cannot go stale.

numba's own cache (``cache=True``) reloads a compiled function as long as the function's
*own* source file is unchanged, even when a function it calls from another file has been
edited (the closed loop calls :func:`usvlog.control.law.control_tick` and
:func:`usvlog.sim.plant.plant_step`; the EKF kernels call the vessel model). So every
kernel of the package is compiled through :func:`njit` here, which keys the cache on the
whole package: its directory is

    <parent>/<sha256 of the usvlog/**/*.py files kernels can reach, sorted by path, first 16 hex digits>/

with ``<parent>`` = ``$NUMBA_CACHE_DIR/usvlog`` when that is set, else the user cache
directory (``~/.cache/usvlog/numba`` on Linux, honouring ``XDG_CACHE_HOME``). Any edit
in the part of the package a kernel can reach (all of it but the layers above sim:
:data:`UNREACHABLE`) gives a fresh directory, so a kernel never runs code compiled from
an older source. The hash is computed once per process, at the first kernel decorated
(a few ms: read and hash ~0.6 MB).

Old directories: each process touches the one it uses; when a new directory is made,
the others beyond the 8 most recently used are deleted, except any used in the last
hour (a parallel checkout or a running process may still need it). A full set of
kernels takes ~4 MB.

If the directory cannot be written, kernels compile without a cache (never into numba's
default ``__pycache__`` location, which is the stale-prone one). ``NUMBA_DISABLE_JIT=1``
runs everything as plain Python, as numba documents.

Functions meant to be called both from Python and from kernels are marked with
:func:`jitable` (numba's ``register_jitable``): they are compiled into each calling
kernel, so their callers' cache entries are covered by the same hash.

Nothing here imports numba until a kernel is first called: :func:`njit` returns a lazy
kernel (the numba dispatcher is made, and its machine code loaded from the cache, on the
first call) and :func:`jitable` only notes the function, registering it with numba when
numba is loaded. A verb that never calls a kernel does not pay numba's import (~0.3 s).

Loading a kernel from the cache does not set numba's CPU target up for compiling: numba's
own cache load first installs every typing and lowering registry of the target (~180
modules, among them numba's linear algebra, which imports all of ``scipy.linalg`` for its
BLAS check: 0.25-0.45 CPU s per process in ``benchmarks/bench_numba_load.py``, the larger
part of a verb's numba cost), which only compiling needs. Cached machine code needs the
runtime (NRT) and the symbols numba registers with LLVM, so a cache load of a usvlog kernel
sets up just those (:func:`_cache_load_overload`); a kernel that is compiled (a cache miss)
goes through numba's compiler, which installs the registries itself. The machine code run
is the same either way.
"""

from __future__ import annotations

import functools
import os
import sys
import time
import types
from collections.abc import MutableMapping

_PACKAGE_DIR = os.path.dirname(os.path.abspath(__file__))
KEEP_DIRS = 8             # hash directories kept (most recently used first)
KEEP_RECENT_S = 3600.0    # never delete a directory used this recently (s)

_cache_dir: str | None = None   # resolved on first use; "" when caching is off

# Parts of the package no kernel can reach: they sit above sim/estimate/identify/control in
# the import layers (tests/test_architecture.py fails on any import from below into them),
# so a compiled function can neither call nor read a constant from them. Left out of the
# hash, an edit there (the CLI, the views, the campaign engine) does not recompile every kernel.
UNREACHABLE = frozenset({"__init__.py", "__main__.py", "api", "replay.py", "cli", "campaign", "view", "regress",
                         "check"})


def source_hash(package_dir: str = _PACKAGE_DIR, skip: frozenset[str] = UNREACHABLE) -> str:
    """SHA-256 (hex) of every ``*.py`` file under ``package_dir`` with its relative path,
    except the top-level files and directories named in ``skip`` (:data:`UNREACHABLE`).

    Parameters
    ----------
    package_dir : str
        Root of the package (default: the installed ``usvlog`` directory).

    Returns
    -------
    str
        64 hex digits; any change to any source file (content, name, added, removed)
        changes it.
    """
    files = []
    for root, dirs, names in os.walk(package_dir):
        rel = os.path.relpath(root, package_dir)
        dirs[:] = [d for d in dirs if d != "__pycache__" and not (rel == "." and d in skip)]
        for n in names:
            if n.endswith(".py") and not (rel == "." and n in skip):
                files.append((n if rel == "." else f"{rel}/{n}".replace(os.sep, "/"), os.path.join(root, n)))
    files.sort()
    import hashlib  # only when the first kernel is made (the command line imports this module at start)

    h = hashlib.sha256()
    for rel, full in files:
        with open(full, "rb") as f:
            data = f.read()
        h.update(f"{rel}\0{len(data)}\0".encode())
        h.update(data)
    return h.hexdigest()


def cache_parent() -> str:
    """Directory holding the per-source-hash cache directories.

    Returns
    -------
    str
        ``$NUMBA_CACHE_DIR/usvlog`` when ``NUMBA_CACHE_DIR`` is set (as numba read it at
        import), else ``<user cache dir>/usvlog/numba``.
    """
    from numba.core import config as numba_config  # heavy: numba, only once a kernel is needed

    cache_dir = getattr(numba_config, "CACHE_DIR", "")   # set at numba's import from the environment
    if cache_dir:
        return os.path.join(cache_dir, "usvlog")
    from numba.misc.appdirs import AppDirs

    return os.path.join(AppDirs("usvlog", appauthor=False).user_cache_dir, "numba")


def _prune(parent: str, current: str) -> None:
    """Delete hash directories beyond the KEEP_DIRS most recently used (see module doc)."""
    now = time.time()
    entries = []
    with os.scandir(parent) as it:
        for e in it:
            if e.is_dir(follow_symlinks=False) and e.path != current:
                try:
                    entries.append((e.stat(follow_symlinks=False).st_mtime, e.path))
                except OSError:
                    pass
    entries.sort(reverse=True)
    for mtime, path in entries[KEEP_DIRS - 1:]:
        if now - mtime > KEEP_RECENT_S:
            import shutil  # only when pruning

            shutil.rmtree(path, ignore_errors=True)


def cache_dir() -> str:
    """The cache directory for this source tree ("" if it cannot be written: no cache).

    Returns
    -------
    str
        ``<cache_parent()>/<first 16 hex digits of source_hash()>``, created on first use.
    """
    global _cache_dir
    if _cache_dir is None:
        parent = cache_parent()
        path = os.path.join(parent, source_hash()[:16])
        try:
            new = not os.path.isdir(path)
            os.makedirs(path, exist_ok=True)
            import tempfile  # only when the first kernel is made

            tempfile.TemporaryFile(dir=path).close()   # writable (numba checks the same)
            os.utime(path)                              # "used now", for pruning
        except OSError:
            path = ""
            new = False
        if new:
            try:
                _prune(parent, path)
            except OSError:  # pruning is housekeeping only
                pass
        _cache_dir = path
    return _cache_dir


def _cache_load_overload(self, sig, target_context):
    """numba's ``Cache.load_overload`` without the full target refresh (see the module doc).

    The runtime and the hash-secret symbols are what cached machine code links against
    beyond the symbols numba registers when its target context is made. The environments of
    numba's own helpers compiled into a kernel are rebuilt without importing their modules
    (:func:`_rebuild_env`).
    """
    from numba.core import environment  # heavy: numba internals, loaded with numba already
    from numba.core.runtime import nrt

    nrt.rtsys.initialize(target_context)
    import numba.cpython.hashing  # noqa: F401  (registers the _numba_hashsecret_* symbols)

    rebuild = getattr(environment, "_rebuild_env", None)
    if rebuild is None or not hasattr(environment, "lookup_environment") or \
            not isinstance(getattr(environment.Environment, "_memo", None), MutableMapping):
        # a numba whose environments work otherwise: its own load
        with self._guard_against_spurious_io_errors():
            return self._load_overload(sig, target_context)
    # the cached entry's pickle names numba.core.environment._rebuild_env: ours while it loads
    # (numba's compiler lock is held here, so no other load sees it)
    environment._rebuild_env = functools.partial(_rebuild_env, rebuild)
    try:
        with self._guard_against_spurious_io_errors():
            return self._load_overload(sig, target_context)
    finally:
        environment._rebuild_env = rebuild


def _rebuild_env(numba_rebuild, modname, consts, env_name):
    """numba's ``environment._rebuild_env`` (``numba_rebuild``), but a numba module not imported
    yet is not imported.

    An environment holds the globals of the function's module, which only object-mode code
    reads (``pylowering``); usvlog's kernels and the numba helpers compiled into them are
    nopython code, which reads only the environment's constants. Importing the helpers' modules
    (``numba.np.arrayobj`` registers ~360 overloads: ~0.1 s) is what a cached kernel's first
    load spent most on; such an environment gets its module's name alone as globals.
    """
    from numba.core import environment  # heavy: numba internals, loaded with numba already

    if modname in sys.modules or not (modname or "").startswith("numba."):
        return numba_rebuild(modname, consts, env_name)
    env = environment.lookup_environment(env_name)
    if env is None:
        env = environment.Environment({"__name__": modname})
        env.consts[:] = consts
        env.env_name = env_name
        environment.Environment._memo[env_name] = env
    return env


def _light_loads(dispatcher):
    """``dispatcher`` with its cache loading through :func:`_cache_load_overload`
    (this dispatcher only: numba's other users in the process are left as they are)."""
    cache = getattr(dispatcher, "_cache", None)
    if all(hasattr(cache, a) for a in ("_load_overload", "_guard_against_spurious_io_errors")):
        cache.load_overload = types.MethodType(_cache_load_overload, cache)
    return dispatcher


_PACKAGE = __name__.split(".")[0]
_on_compile: list = []       # the callback of on_first_compile, while it has not fired


def on_first_compile(callback) -> None:
    """Call ``callback(kernel, cache)`` once, when this process first compiles a usvlog kernel
    (a cache miss: the first run after an install or an upgrade, or a new argument type).

    Loading a kernel from the cache does not call it. The library itself says nothing; the
    command line uses this to say why a first run waits (compiling takes up to a minute).

    Parameters
    ----------
    callback : callable
        Receives the kernel's qualified name (``module.function``) and the cache directory it
        is compiled into ("" when the cache cannot be written: every run compiles again).
        None: no callback.
    """
    _on_compile[:] = [callback] if callback is not None else []


def _compile_listener():
    """A numba event listener that calls the :func:`on_first_compile` callback at the first
    compile of a usvlog kernel (numba fires ``numba:compile`` only on a cache miss)."""
    from numba.core import event  # heavy: numba, loaded with the first kernel

    class FirstCompile(event.Listener):
        def on_start(self, ev):
            if not _on_compile:
                return
            fn = getattr(ev.data.get("dispatcher"), "py_func", None)
            module = getattr(fn, "__module__", "") or ""
            if module.split(".")[0] == _PACKAGE:
                callback = _on_compile.pop()
                callback(f"{module}.{getattr(fn, '__qualname__', '?')}", cache_dir())

        def on_end(self, ev):
            pass

    return FirstCompile()


def _compile(fn, kw: dict):
    """The numba dispatcher of ``fn`` with the cache keyed on the package source."""
    from numba import njit as numba_njit  # heavy: numba, only when a kernel is first called
    from numba.core import config as numba_config

    _register_pending()
    kw = dict(kw)
    kw.setdefault("cache", True)
    if not kw["cache"] or getattr(numba_config, "DISABLE_JIT", False):
        return numba_njit(**kw)(fn)
    path = cache_dir()
    if not path:
        kw["cache"] = False
        return numba_njit(**kw)(fn)
    # numba's user-provided locator reads config.CACHE_DIR when the dispatcher's cache is
    # made (inside the decorator): point it at our directory for just that moment
    saved = getattr(numba_config, "CACHE_DIR", "")
    numba_config.CACHE_DIR = path  # type: ignore[attr-defined,unused-ignore]
    try:
        return _light_loads(numba_njit(**kw)(fn))
    finally:
        numba_config.CACHE_DIR = saved  # type: ignore[attr-defined,unused-ignore]


class _LazyKernel:
    """A kernel whose numba dispatcher is made on its first call (see :func:`njit`).

    Calls, attributes and numba's typing (a kernel calling this one) go to the dispatcher;
    ``py_func``, the name and the docstring are the Python function's, without numba."""

    def __init__(self, fn, kw: dict):
        functools.update_wrapper(self, fn)
        self.py_func = fn
        self._kw = kw
        self._dispatcher = None

    @property
    def dispatcher(self):
        """The numba dispatcher (made, and numba imported, on first use)."""
        d = self._dispatcher
        if d is None:
            # One thread at a time (_compile points numba's global CACHE_DIR for a moment), under numba's own
            # re-entrant compiler lock, so no other lock is taken in the opposite order by a thread that is
            # compiling a kernel calling this one
            from numba.core.compiler_lock import global_compiler_lock  # heavy: numba, for the dispatcher

            with global_compiler_lock:
                d = self._dispatcher
                if d is None:
                    d = self._dispatcher = _compile(self.py_func, self._kw)
                    # later calls through the defining module's name skip this wrapper
                    mod = sys.modules.get(self.py_func.__module__)
                    if mod is not None and getattr(mod, self.py_func.__name__, None) is self:
                        setattr(mod, self.py_func.__name__, d)
        return d

    @property
    def _numba_type_(self):
        # numba's typeof() asks for this when a kernel refers to this one
        return self.dispatcher._numba_type_

    def __call__(self, *args, **kwargs):
        return self.dispatcher(*args, **kwargs)

    def __getattr__(self, name):
        if name.startswith("__") or name in ("_dispatcher", "_kw", "py_func"):
            raise AttributeError(name)
        return getattr(self.dispatcher, name)

    def __repr__(self) -> str:
        return f"<lazy kernel {self.py_func.__module__}.{self.py_func.__qualname__}>"


def njit(fn=None, **kw):
    """numba's ``njit`` with the cache keyed on the package source (see the module doc).

    Use as ``@njit``, ``@njit(**options)`` or ``njit(fn)``; the options are numba's.
    ``cache`` defaults to True. numba is imported and the dispatcher made on the first
    call, not here.

    Parameters
    ----------
    fn : callable, optional
        The function to compile.
    **kw
        numba ``njit`` options.

    Returns
    -------
    A lazy kernel calling the numba dispatcher (or ``fn`` itself with
    ``NUMBA_DISABLE_JIT=1``), or a decorator when ``fn`` is None.
    """
    if fn is None:
        return lambda f: njit(f, **kw)
    return _LazyKernel(fn, kw)


def readonly(a):
    """``a`` as a read-only view (no copy), for a kernel argument the kernel only reads.

    numba compiles, caches and loads a kernel once per argument signature, and a writable and
    a read-only array are different types to it. A buffer of bytes decoded by a kernel is
    read-only when it comes from ``np.frombuffer`` of ``bytes`` (one decompressed chunk) and
    writable when it was assembled (an arena, a concatenation), which depends on the file's size
    and layout; passed through here, the kernel has one signature whatever the caller holds, so a
    first short log does not compile the kernel again (the JSON decoder: 3.4 s).

    Parameters
    ----------
    a : numpy.ndarray
        Any array.

    Returns
    -------
    numpy.ndarray
        ``a`` itself when it is read-only, else a read-only view of it.
    """
    if not a.flags.writeable:
        return a
    v = a.view()
    v.flags.writeable = False
    return v


_pending: list = []          # jitable functions not registered with numba yet
_registered = [False]        # numba loaded and the pending functions registered


def _register_pending() -> None:
    from numba.core.compiler_lock import global_compiler_lock  # heavy: numba, only when a kernel is first called
    from numba.extending import register_jitable

    # one thread at a time: a log read on a second thread calls its first kernel while the main thread
    # imports modules that mark functions jitable
    with global_compiler_lock:
        if not _registered[0]:
            from numba.core import event

            event.register("numba:compile", _compile_listener())
        _registered[0] = True
        while _pending:
            register_jitable(_pending.pop(0))


def jitable(fn):
    """Mark ``fn`` as callable from kernels too (numba's ``register_jitable``).

    Registered with numba when numba is loaded (at the first kernel call), so defining
    one does not import numba.

    Parameters
    ----------
    fn : callable
        Plain-arithmetic Python function.

    Returns
    -------
    callable
        ``fn`` itself (unchanged in Python); kernels that call it compile it in.
    """
    _pending.append(fn)
    if _registered[0]:
        _register_pending()
    return fn


__all__ = ["cache_dir", "cache_parent", "jitable", "njit", "on_first_compile", "readonly", "source_hash"]
