"""The import graph of ``usvlog`` follows the pipeline: no cycles, no upward imports.

A small AST walk over ``usvlog/**/*.py`` (no extra dependency) collects every
import of a usvlog module, at module level and inside functions, with relative
imports resolved (and ``importlib.import_module`` with a literal name; a name built
at run time is not seen). The checks, each failing with the list of offenders:

* every module belongs to a unit of the layer table (:data:`UNITS`);
* no import cycle between modules (the imports that run at import time);
* no cycle between packages or layer units, counting function-level imports too;
* every import follows :data:`LAYERS` (and the rules for ``io``, the edge);
* every function-level import of a usvlog module says why, in a comment on the
  same line or the line above (``# start-up: ...``, ``# optional dependency ...``).
  This holds for ``usvlog/cli`` and ``usvlog/__init__.py`` too: their lazy imports
  carry a reason like any other. (Function-level imports of third-party modules are
  not checked; give them a reason too.)

The last tests run the same checker on small packages written to a temporary
directory, to show that it catches cycles, upward imports and unexplained
function-level imports.
"""

from __future__ import annotations

import ast
import io
import re
import tokenize
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = "usvlog"

# -----------------------------------------------------------------------------
# the layers
# -----------------------------------------------------------------------------

# Units: each usvlog module belongs to exactly one (longest prefix wins; the bare
# package name matches only usvlog/__init__.py).
UNITS: dict[str, tuple[str, ...]] = {
    "cli":      ("usvlog.cli", "usvlog.__main__"),
    "api":      ("usvlog", "usvlog.api"),         # usvlog/__init__.py (+ the usvlog/api/ package)
    "campaign": ("usvlog.campaign",),
    "view":     ("usvlog.view",),
    "regress":  ("usvlog.regress",),
    "replay":   ("usvlog.replay",),
    "check":    ("usvlog.check",),
    "sim":      ("usvlog.sim",),
    "estimate": ("usvlog.estimate",),
    "identify": ("usvlog.identify",),
    "control":  ("usvlog.control",),
    "trials":   ("usvlog.trials",),
    "log":      ("usvlog.log",),
    "model":    ("usvlog.model",),
    "base":     ("usvlog.errors", "usvlog._version", "usvlog._jit", "usvlog._cpu", "usvlog.resources",
                 "usvlog.choices"),
    "io":       ("usvlog.io",),
}

# Layers, top to bottom. A unit may import the units of every layer below its own;
# units side by side in one layer are independent, except for SIDEWAYS.
LAYERS: tuple[tuple[str, ...], ...] = (
    ("cli",),
    ("api",),
    ("campaign",),      # many runs of the pipeline: runs the API's stages (handed in), draws with view
    ("view", "regress"),
    ("replay", "check"),   # check: judges a log with the numerics below (view and campaign show it)
    ("sim",),
    ("estimate", "identify", "control", "trials"),
    ("log",),
    ("model",),
    ("base",),
)
SIDEWAYS: frozenset[tuple[str, str]] = frozenset({
    ("identify", "estimate"),   # identification smooths with the estimator
})
# control is pure: only the model and the log (and base) under it
NARROWED: dict[str, frozenset[str]] = {
    "control": frozenset({"log", "model", "base"}),
    "trials": frozenset({"log", "model", "base"}),   # manoeuvres: pure, from the state frame handed in
}
# io is the edge: it reads and writes model/log objects and is used from the top only.
IO = "io"
IO_MAY_IMPORT = frozenset({"model", "log", "base"})
IO_IMPORTED_BY = frozenset({"cli", "api", "campaign", "view", "regress", "replay", "sim"})


def allowed_imports(layers=LAYERS, sideways=SIDEWAYS, narrowed=NARROWED,
                    io_may_import=IO_MAY_IMPORT, io_imported_by=IO_IMPORTED_BY) -> dict[str, frozenset[str]]:
    """{unit: the other units it may import}, from the tables above."""
    out: dict[str, set[str]] = {}
    for i, layer in enumerate(layers):
        below = {u for lower in layers[i + 1:] for u in lower}
        for u in layer:
            out[u] = set(below) | {v for (a, v) in sideways if a == u}
            if u in narrowed:
                out[u] &= set(narrowed[u])
            if u in io_imported_by:
                out[u].add(IO)
    out[IO] = set(io_may_import)
    return {u: frozenset(v) for u, v in out.items()}


def unit_of(module: str, units: dict[str, tuple[str, ...]] = UNITS) -> str | None:
    """The unit holding ``module``: the longest matching prefix; a prefix without a dot
    (the root package) matches only itself, i.e. the package's ``__init__.py``."""
    best, best_len = None, -1
    for unit, prefixes in units.items():
        for p in prefixes:
            hit = module == p or ("." in p and module.startswith(p + "."))
            if hit and len(p) > best_len:
                best, best_len = unit, len(p)
    return best


# -----------------------------------------------------------------------------
# the walk
# -----------------------------------------------------------------------------

@dataclass(frozen=True)
class Import:
    importer: str          # module doing the import
    imported: str          # usvlog module (or package) imported
    path: Path
    line: int
    function_level: bool   # inside a def or lambda: runs when called
    type_checking: bool    # under ``if TYPE_CHECKING:``: never runs
    reason: str            # comment on the statement's lines or the line above ("" if none)

    def where(self) -> str:
        try:
            rel = self.path.relative_to(ROOT)
        except ValueError:
            rel = self.path
        return f"{rel}:{self.line}"


def find_modules(root: Path, package: str) -> dict[str, Path]:
    """{dotted module name: file} for every .py file of ``root/package``."""
    out = {}
    for path in sorted((root / package).rglob("*.py")):
        parts = list(path.relative_to(root).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        out[".".join(parts)] = path
    return out


_NOT_A_REASON = re.compile(r"noqa(:\s*[A-Z0-9, ]+)?|type:\s*ignore(\[[^\]]*\])?|pragma:[^#]*|isort:\s*skip")


def _comments(source: str) -> dict[int, tuple[str, bool]]:
    """{line: (comment text, the line holds only a comment)}."""
    out = {}
    lines = source.splitlines()
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type == tokenize.COMMENT:
            row = tok.start[0]
            alone = lines[row - 1].strip().startswith("#")
            out[row] = (tok.string.lstrip("#").strip(), alone)
    return out


def _reason(comments: dict[int, tuple[str, bool]], first: int, last: int,
            import_lines: frozenset[int] = frozenset()) -> str:
    """The reason comment of a statement on lines first..last: a comment on those lines
    or a comment-only line just above it. One reason covers a block of imports: a
    comment-only line above the run of import statements the statement belongs to, or a
    comment on the run's first line, counts for every import of the run. Tool pragmas
    (noqa, type: ignore) do not count."""
    found = [comments[r][0] for r in range(first, last + 1) if r in comments]
    above = first - 1
    while above in import_lines:
        above -= 1
    if above in comments and comments[above][1]:
        found.append(comments[above][0])
    if above + 1 < first and above + 1 in comments:
        found.append(comments[above + 1][0])
    for text in found:
        words = re.findall(r"[A-Za-z]{2,}", _NOT_A_REASON.sub("", text))
        if len(words) >= 2:
            return text
    return ""


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _literal_import_module(node: ast.Call) -> bool:
    """``import_module("name", ...)`` or ``importlib.import_module(...)`` with a literal name."""
    f = node.func
    named = (isinstance(f, ast.Name) and f.id == "import_module") or (
        isinstance(f, ast.Attribute) and f.attr == "import_module")
    return named and bool(node.args) and isinstance(node.args[0], ast.Constant) and isinstance(node.args[0].value, str)


def imports_of(module: str, path: Path, known: set[str], package: str) -> list[Import]:
    """Every import of a ``package`` module in one file, resolved to a known module."""
    source = path.read_text()
    tree = ast.parse(source, str(path))
    comments = _comments(source)
    import_lines = frozenset(r for n in ast.walk(tree) if isinstance(n, (ast.Import, ast.ImportFrom))
                             for r in range(n.lineno, (n.end_lineno or n.lineno) + 1))
    is_pkg = path.name == "__init__.py"
    here = module.split(".") if is_pkg else module.split(".")[:-1]
    out: list[Import] = []

    def resolve(name: str) -> str | None:
        """The longest known module that ``name`` names or lies in."""
        parts = name.split(".")
        while parts:
            cand = ".".join(parts)
            if cand in known:
                return cand
            parts.pop()
        return None

    seen: set[tuple[str, int]] = set()

    def add(target: str | None, node: ast.stmt | ast.expr, in_func: bool, tc: bool) -> None:
        if target is None or (target, node.lineno) in seen:   # from x import a, b: one edge
            return
        seen.add((target, node.lineno))
        out.append(Import(module, target, path, node.lineno, in_func, tc,
                          _reason(comments, node.lineno, node.end_lineno or node.lineno, import_lines)))

    def visit(node: ast.AST, in_func: bool, tc: bool) -> None:
        if isinstance(node, ast.Import):
            for a in node.names:
                if a.name == package or a.name.startswith(package + "."):
                    add(resolve(a.name), node, in_func, tc)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = ".".join(here[:len(here) - (node.level - 1)] + ([node.module] if node.module else []))
            else:
                base = node.module or ""
            if base == package or base.startswith(package + "."):
                for a in node.names:
                    sub = f"{base}.{a.name}"
                    add(sub if sub in known else resolve(base), node, in_func, tc)
        elif isinstance(node, ast.Call) and _literal_import_module(node):
            name = node.args[0].value
            if name.startswith("."):
                anchor = ".".join(here)
                if len(node.args) > 1 and isinstance(node.args[1], ast.Constant):
                    anchor = str(node.args[1].value)
                level = len(name) - len(name.lstrip("."))
                parts = anchor.split(".")
                name = ".".join(parts[:len(parts) - (level - 1)] + [name.lstrip(".")]).rstrip(".")
            if name == package or name.startswith(package + "."):
                add(resolve(name), node, in_func, tc)
        for child in ast.iter_child_nodes(node):
            if isinstance(node, ast.If) and _is_type_checking(node.test) and child in node.body:
                visit(child, in_func, True)
            else:
                visit(child, in_func or isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)), tc)

    visit(tree, False, False)
    return out


def import_graph(root: Path = ROOT, package: str = PACKAGE) -> tuple[dict[str, Path], list[Import]]:
    mods = find_modules(root, package)
    known = set(mods)
    edges = [imp for m, p in mods.items() for imp in imports_of(m, p, known, package) if imp.imported != m]
    return mods, edges


# -----------------------------------------------------------------------------
# the checks (each returns a list of offences, one line each)
# -----------------------------------------------------------------------------

def _cycles(nodes, edges: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one node (Tarjan), each as a
    sorted list of names."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    comps: list[list[str]] = []
    counter = [0]

    def strong(v: str) -> None:  # recursion depth is bounded by the package size
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(edges.get(v, ())):
            if w not in index:
                strong(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                comps.append(sorted(comp))

    for v in sorted(nodes):
        if v not in index:
            strong(v)
    return sorted(comps)


def _describe_cycle(comp: list[str], edge_lines: dict[tuple[str, str], list[Import]]) -> str:
    inside = set(comp)
    lines = [f"  cycle between {', '.join(comp)}:"]
    for (a, b), imps in sorted(edge_lines.items()):
        if a in inside and b in inside:
            lines.append(f"    {a} -> {b}  ({', '.join(i.where() for i in imps)})")
    return "\n".join(lines)


def module_cycles(edges: list[Import]) -> list[str]:
    """Cycles between modules through the imports that run at import time."""
    runtime = [e for e in edges if not e.function_level and not e.type_checking]
    graph: dict[str, set[str]] = {}
    lines: dict[tuple[str, str], list[Import]] = {}
    for e in runtime:
        graph.setdefault(e.importer, set()).add(e.imported)
        lines.setdefault((e.importer, e.imported), []).append(e)
    nodes = set(graph) | {e.imported for e in runtime}
    return [_describe_cycle(c, lines) for c in _cycles(nodes, graph)]


def package_of(module: str, mods: dict[str, Path]) -> str:
    """The package a module lies in (a package's ``__init__`` is the package itself);
    modules directly under the root package stand for themselves."""
    if mods[module].name == "__init__.py" or "." not in module:
        return module
    parent = module.rsplit(".", 1)[0]
    return module if "." not in parent else parent


def package_cycles(mods: dict[str, Path], edges: list[Import]) -> list[str]:
    """Cycles between packages (``usvlog.io``, ``usvlog.io.mcap``, ...), counting
    function-level imports too."""
    graph: dict[str, set[str]] = {}
    lines: dict[tuple[str, str], list[Import]] = {}
    for e in edges:
        a, b = package_of(e.importer, mods), package_of(e.imported, mods)
        if a != b:
            graph.setdefault(a, set()).add(b)
            lines.setdefault((a, b), []).append(e)
    return [_describe_cycle(c, lines) for c in _cycles({package_of(m, mods) for m in mods}, graph)]


def unit_cycles(edges: list[Import], units=UNITS) -> list[str]:
    """Cycles between units (layers, io), counting function-level imports too."""
    graph: dict[str, set[str]] = {}
    lines: dict[tuple[str, str], list[Import]] = {}
    for e in edges:
        a, b = unit_of(e.importer, units), unit_of(e.imported, units)
        if a and b and a != b:
            graph.setdefault(a, set()).add(b)
            lines.setdefault((a, b), []).append(e)
    return [_describe_cycle(c, lines) for c in _cycles(set(units), graph)]


def unknown_modules(mods: dict[str, Path], units=UNITS) -> list[str]:
    return [f"  {m} ({p}) is in no unit of the layer table" for m, p in sorted(mods.items())
            if unit_of(m, units) is None]


def layer_violations(edges: list[Import], units=UNITS, allowed=None) -> list[str]:
    """Imports that go up, sideways between independent units, or across the io edge."""
    allowed = allowed_imports() if allowed is None else allowed
    out = []
    for e in sorted(edges, key=lambda e: (str(e.path), e.line)):
        a, b = unit_of(e.importer, units), unit_of(e.imported, units)
        if a is None or b is None or a == b or b in allowed.get(a, ()):
            continue
        kind = "function-level " if e.function_level else ""
        out.append(f"  {e.where()}: {e.importer} [{a}] {kind}imports {e.imported} [{b}]"
                   f" ({a} may import: {', '.join(sorted(allowed.get(a, ()))) or 'nothing'})")
    return out


def unexplained_function_imports(edges: list[Import]) -> list[str]:
    """Function-level imports of package modules without a one-line reason comment."""
    return [f"  {e.where()}: {e.importer} imports {e.imported} inside a function, with no reason comment"
            for e in sorted(edges, key=lambda e: (str(e.path), e.line))
            if e.function_level and not e.reason]


def _report(title: str, offences: list[str]) -> str:
    return f"{title} ({len(offences)}):\n" + "\n".join(offences)


# -----------------------------------------------------------------------------
# tests on usvlog
# -----------------------------------------------------------------------------

@lru_cache(maxsize=1)
def _graph():
    mods, edges = import_graph()
    assert len(mods) > 50 and len(edges) > 100, "the walk found too little: is ROOT right?"
    return mods, edges


def test_every_module_has_a_layer():
    mods, _ = _graph()
    offences = unknown_modules(mods)
    assert not offences, _report("modules missing from UNITS in tests/test_architecture.py", offences)


def test_no_import_cycle_between_modules():
    _, edges = _graph()
    offences = module_cycles(edges)
    assert not offences, _report("import cycles between modules (module-level imports)", offences)


def test_no_import_cycle_between_packages_or_units():
    mods, edges = _graph()
    offences = package_cycles(mods, edges) + unit_cycles(edges)
    assert not offences, _report("import cycles between packages or layer units (function-level imports "
                                 "included)", offences)


def test_imports_follow_the_layers():
    _, edges = _graph()
    offences = layer_violations(edges)
    assert not offences, _report("imports against the layers (cli > api > view, regress > replay > sim > "
                                 "estimate, identify, control > log > model > base; io at the edge)", offences)


def test_function_level_imports_say_why():
    _, edges = _graph()
    offences = unexplained_function_imports(edges)
    assert not offences, _report("function-level imports without a reason comment (same line or the line "
                                 "above, e.g. '# start-up: numba is loaded on first use')", offences)


def test_the_layer_table_is_itself_acyclic():
    allowed = allowed_imports()
    graph = {u: set(v) for u, v in allowed.items()}
    assert set(allowed) == set(UNITS)
    assert not _cycles(set(allowed), graph)
    assert "io" not in allowed["log"] and "io" not in allowed["model"] and "io" in allowed["sim"]
    assert allowed["control"] == {"log", "model", "base"}
    assert "estimate" in allowed["identify"] and "identify" not in allowed["estimate"]


# -----------------------------------------------------------------------------
# the checker catches what it should
# -----------------------------------------------------------------------------

def _write(root: Path, files: dict[str, str]) -> None:
    for rel, text in files.items():
        p = root / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(text)


def test_checker_catches_cycles_upward_imports_and_unexplained_lazy_imports(tmp_path):
    _write(tmp_path, {
        "usvlog/__init__.py": "from .log.fieldlog import FieldLog\n",
        "usvlog/errors.py": "",
        "usvlog/model/__init__.py": "",
        "usvlog/model/vessel.py": "from ..errors import UsvlogError\n",
        "usvlog/log/__init__.py": "",
        "usvlog/log/fieldlog.py": "from ..model import vessel\n",
        # log -> io: the wrong way, hidden in a function, and without a reason
        "usvlog/log/channels.py": "def f():\n    from ..io.mcap import kernels\n    return kernels\n",
        "usvlog/io/__init__.py": "",
        "usvlog/io/mcap/__init__.py": "",
        "usvlog/io/mcap/kernels.py": "import usvlog.log.fieldlog\n",
        # regress modules importing each other at module level
        "usvlog/regress/__init__.py": "",
        "usvlog/regress/stages.py": "from . import baselines\n",
        "usvlog/regress/baselines.py": "from .stages import run\n",
        # control may import only log/model/base; estimate is next to it
        "usvlog/control/__init__.py": "",
        "usvlog/control/law.py": (
            "import numpy as np\n"
            "def g():\n"
            "    # start-up: the estimator is heavy\n"
            "    from usvlog.estimate import core\n"
            "    x = 1\n"
            "    from ..model import vessel  # noqa: F401\n"
            "    from ..model import vessel as v2  # start-up: numba kernels\n"
            "    return core\n"),
        "usvlog/estimate/__init__.py": "",
        "usvlog/estimate/core.py": "from ..log.fieldlog import FieldLog\n",
        "usvlog/mystery.py": "",
    })
    mods, edges = import_graph(tmp_path, "usvlog")
    assert "usvlog.regress.stages" in mods and "usvlog" in mods

    assert unknown_modules(mods) == [f"  usvlog.mystery ({tmp_path / 'usvlog/mystery.py'}) is in no unit "
                                     "of the layer table"]

    cycles = module_cycles(edges)
    assert len(cycles) == 1
    assert "usvlog.regress.baselines, usvlog.regress.stages" in cycles[0]
    assert "usvlog.regress.stages -> usvlog.regress.baselines" in cycles[0]
    assert "usvlog.regress.baselines -> usvlog.regress.stages" in cycles[0]

    # log -> io (function level) and io -> log close a cycle between units
    ucycles = unit_cycles(edges)
    assert len(ucycles) == 1 and "cycle between io, log" in ucycles[0]
    pcycles = package_cycles(mods, edges)
    assert len(pcycles) == 1 and "cycle between usvlog.io.mcap, usvlog.log" in pcycles[0]

    bad = layer_violations(edges)
    assert len(bad) == 2, bad
    assert "control/law.py:4: usvlog.control.law [control] function-level imports usvlog.estimate.core " \
           "[estimate] (control may import: base, log, model)" in bad[0]
    assert "log/channels.py:2: usvlog.log.channels [log] function-level imports usvlog.io.mcap.kernels [io] " \
           "(log may import: base, model)" in bad[1]

    lazy = unexplained_function_imports(edges)
    # channels.py:2 has no comment; law.py:4 has one on the line above, law.py:7 on its own line;
    # law.py:6 has only a linter pragma (and a statement parts it from the explained block above)
    assert [s.split(": ")[0].rsplit("/", 2)[-2:] for s in lazy] == [["control", "law.py:6"], ["log", "channels.py:2"]]


def test_imports_resolve_to_modules_and_packages(tmp_path):
    _write(tmp_path, {
        "usvlog/__init__.py": "",
        "usvlog/io/__init__.py": "",
        "usvlog/io/mcap/__init__.py": "from .reader import read_log\n",
        "usvlog/io/mcap/reader.py": ("from .. import atomic\n"
                                     "from ..atomic import write, read\n"
                                     "from . import kernels as K\n"),
        "usvlog/io/mcap/kernels.py": "",
        "usvlog/io/atomic.py": (
            "import usvlog.io.mcap\n"
            "from typing import TYPE_CHECKING\n"
            "if TYPE_CHECKING:\n"
            "    from usvlog.io.mcap.reader import X\n"
            "def f():\n"
            "    import importlib\n"
            "    return importlib.import_module('.mcap.kernels', __package__)  # start-up: numba\n"),
    })
    _, edges = import_graph(tmp_path, "usvlog")
    got = sorted((e.importer, e.imported, e.line, e.function_level, e.type_checking, e.reason) for e in edges)
    assert got == [
        ("usvlog.io.atomic", "usvlog.io.mcap", 1, False, False, ""),
        ("usvlog.io.atomic", "usvlog.io.mcap.kernels", 7, True, False, "start-up: numba"),
        ("usvlog.io.atomic", "usvlog.io.mcap.reader", 4, False, True, ""),
        ("usvlog.io.mcap", "usvlog.io.mcap.reader", 1, False, False, ""),
        ("usvlog.io.mcap.reader", "usvlog.io.atomic", 1, False, False, ""),
        ("usvlog.io.mcap.reader", "usvlog.io.atomic", 2, False, False, ""),
        ("usvlog.io.mcap.reader", "usvlog.io.mcap.kernels", 3, False, False, ""),
    ]
    # reader -> atomic -> mcap (package) -> reader: a cycle at import time; the
    # TYPE_CHECKING edge alone would not be one
    cycles = module_cycles(edges)
    assert len(cycles) == 1 and "cycle between usvlog.io.atomic, usvlog.io.mcap, usvlog.io.mcap.reader" in cycles[0]
