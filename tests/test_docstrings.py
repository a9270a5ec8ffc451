"""Every public function, class and method of the usvlog package has a docstring.

Walks the whole package (except the ``usvlog.cli`` package, whose verbs are documented by
their ``--help``, and private modules such as ``usvlog._jit``), imports each module and
checks the objects it defines itself: functions (numba-compiled ones included), classes and
the methods and properties those classes define. Names starting with ``_`` are skipped, and
so are objects that a module only re-exports from elsewhere.

The signature-like docstrings that ``dataclasses`` and ``typing.NamedTuple`` generate
(``Name(a: float, b: int)``) do not count as documentation.
"""

from __future__ import annotations

import importlib
import inspect
import pkgutil
import re

import usvlog

SKIP_PACKAGES = ("usvlog.cli",)


def _public_modules():
    """Names of the usvlog modules to check, sorted."""
    names = ["usvlog"]
    for info in pkgutil.walk_packages(usvlog.__path__, prefix="usvlog."):
        name = info.name
        if any(name == p or name.startswith(p + ".") for p in SKIP_PACKAGES):
            continue
        if any(part.startswith("_") for part in name.split(".")[1:]):
            continue
        names.append(name)
    return sorted(names)


def _is_routine(obj) -> bool:
    """True for plain functions and for numba dispatchers (which wrap one in ``py_func``)."""
    return inspect.isfunction(obj) or inspect.isfunction(getattr(obj, "py_func", None))


def _has_doc(doc: str | None) -> bool:
    return bool(doc and doc.strip())


def _class_has_doc(cls) -> bool:
    """Own docstring of a class, ignoring the ones dataclass/NamedTuple generate."""
    doc = cls.__dict__.get("__doc__")
    if not _has_doc(doc):
        return False
    generated = re.fullmatch(rf"{re.escape(cls.__name__)}\(.*\)", doc.strip(), flags=re.DOTALL)
    return generated is None


def _method_offenders(cls, qualname: str):
    """Public methods and properties defined in ``cls`` itself that have no docstring.

    A method that overrides a documented one of a base class inherits that docstring
    (``inspect.getdoc``), as numpydoc and Sphinx do."""
    out = []
    for name, raw in vars(cls).items():
        if name.startswith("_"):
            continue
        if isinstance(raw, (staticmethod, classmethod)):
            func = raw.__func__
        elif isinstance(raw, property):
            func = raw.fget
        elif _is_routine(raw):
            func = raw
        else:
            continue
        if func is None:
            continue
        doc = inspect.getdoc(getattr(cls, name, func))
        if not _has_doc(doc):
            out.append(f"{qualname}.{name}")
    return out


def find_undocumented():
    """Qualified names of every public usvlog object without a docstring."""
    missing = []
    for modname in _public_modules():
        module = importlib.import_module(modname)
        for name, obj in vars(module).items():
            if name.startswith("_"):
                continue
            if getattr(obj, "__module__", None) != modname:
                continue  # re-exported from another module, checked there
            if inspect.isclass(obj):
                if not _class_has_doc(obj):
                    missing.append(f"{modname}.{name}")
                missing.extend(_method_offenders(obj, f"{modname}.{name}"))
            elif _is_routine(obj) and not _has_doc(obj.__doc__):
                missing.append(f"{modname}.{name}")
    return missing


def test_every_public_object_has_a_docstring():
    missing = find_undocumented()
    assert not missing, f"{len(missing)} public objects without a docstring:\n" + "\n".join(missing)


def test_checker_sees_a_missing_docstring():
    """The walker itself: it must flag undocumented objects and accept documented ones."""
    import dataclasses
    import types

    mod = types.ModuleType("usvlog_fake_mod")

    def undocumented():
        return 1

    def documented():
        """Documented."""
        return 1

    @dataclasses.dataclass
    class Auto:
        a: float = 1.0

        def method(self):
            return self.a

        @property
        def prop(self):
            """Documented property."""
            return self.a

    for obj in (undocumented, documented, Auto):
        obj.__module__ = mod.__name__
        setattr(mod, obj.__name__, obj)
    found = []
    for name, obj in vars(mod).items():
        if inspect.isclass(obj):
            if not _class_has_doc(obj):
                found.append(name)
            found.extend(_method_offenders(obj, name))
        elif _is_routine(obj) and not _has_doc(obj.__doc__):
            found.append(name)
    assert sorted(found) == ["Auto", "Auto.method", "undocumented"]
