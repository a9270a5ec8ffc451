"""Kernels first called from several threads at once (identify's second shooting thread, a
log read on a thread): each dispatcher is made once, with the cache in usvlog's directory, and
numba's global CACHE_DIR, which :func:`usvlog._jit._compile` points there for a moment, is
left as it was."""

import threading

import numpy as np
from numba.core import config as numba_config

from usvlog import _jit


def _kernels(n):
    made = []
    for i in range(n):
        def k(x):
            return x + 1.0
        k.__name__ = k.__qualname__ = f"threads_probe_{i}"
        made.append(_jit.njit(k))
    return made


def test_dispatchers_made_by_many_threads_at_once():
    before = getattr(numba_config, "CACHE_DIR", "")
    kernels = _kernels(8)
    start = threading.Barrier(16)
    got: list = []
    errors: list = []

    def worker(k):
        try:
            start.wait()
            got.append((k, k.dispatcher))
        except BaseException as e:  # pragma: no cover - reported below
            errors.append(e)

    threads = [threading.Thread(target=worker, args=(k,)) for k in kernels for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors
    assert getattr(numba_config, "CACHE_DIR", "") == before
    for k in kernels:   # one dispatcher per kernel, whichever thread made it
        assert len({id(d) for kk, d in got if kk is k}) == 1
        assert k.dispatcher._cache._cache_path.startswith(_jit.cache_dir())
    assert kernels[0](np.float64(1.0)) == 2.0
