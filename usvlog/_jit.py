"""numba's ``njit`` when available, otherwise a no-op decorator (same results, slower)."""

from __future__ import annotations

try:  # pragma: no cover - exercised implicitly
    from numba import njit as _njit

    def njit(fn=None, **kw):
        kw.setdefault("cache", True)
        if fn is None:
            return lambda f: _njit(**kw)(f)
        return _njit(**kw)(fn)

    HAVE_NUMBA = True
except ImportError:  # pragma: no cover
    def njit(fn=None, **kw):
        if fn is None:
            return lambda f: f
        return fn

    HAVE_NUMBA = False
