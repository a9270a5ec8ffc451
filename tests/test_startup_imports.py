"""Start-up stays light: ``import usvlog``, the CLI parser and every ``--help`` import no heavy library.

Checked on ``sys.modules`` in a fresh interpreter (never on timings; those are measured by
benchmarks/bench_startup.py).
"""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

import usvlog
from usvlog.cli import VERBS

HEAVY = ("numpy", "pandas", "scipy", "numba", "rerun", "mcap", "matplotlib")
ROOT = Path(usvlog.__file__).resolve().parents[1]

_PROBE = """
import json, sys
{code}
print("\\nHEAVY=" + json.dumps(sorted({{m.split(".")[0] for m in sys.modules}} & set({heavy!r}))))
"""


def probe(code: str, cwd: Path = ROOT) -> tuple[list[str], subprocess.CompletedProcess]:
    """Heavy top-level packages in sys.modules after running ``code`` in a fresh interpreter, and
    the finished process (its output and stderr)."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), *filter(None, [env.get("PYTHONPATH")])])
    r = subprocess.run([sys.executable, "-c", _PROBE.format(code=code, heavy=HEAVY)], capture_output=True,
                       text=True, env=env, cwd=cwd)
    assert r.returncode == 0, r.stderr
    line = [x for x in r.stdout.splitlines() if x.startswith("HEAVY=")][-1]
    return json.loads(line[len("HEAVY="):]), r


def heavy_after(code: str) -> list[str]:
    """Heavy top-level packages in sys.modules after running ``code`` in a fresh interpreter."""
    return probe(code)[0]


def _cli(*argv: str) -> str:
    return f"""
from usvlog.cli import main
try:
    main({list(argv)!r})
except SystemExit:
    pass
"""


def test_import_usvlog_is_light():
    assert heavy_after("import usvlog; usvlog.__version__; dir(usvlog)") == []


def test_api_and_choices_modules_are_light():
    assert heavy_after("import usvlog.api, usvlog.choices; from usvlog import load, simulate, estimate") == []


def test_building_the_parser_is_light():
    assert heavy_after("from usvlog.cli import build_parser; build_parser()") == []


@pytest.mark.parametrize("argv", [["--help"], ["--version"], *[[v.rstrip("_"), "--help"] for v in VERBS],
                                  ["identify", "a.mcap", "--out", "p.toml", "--method", "foo"]],
                         ids=lambda a: " ".join(a))
def test_help_and_usage_errors_are_light(argv):
    assert heavy_after(_cli(*argv)) == []


def test_the_probe_sees_heavy_imports():
    # the check can fail: making a channel's frame loads pandas (and numpy), running a verb loads the library
    assert {"numpy", "pandas"} <= set(heavy_after("from usvlog.log.channels import empty_frame; "
                                                  "empty_frame('/gnss/fix')"))
    assert "numpy" in heavy_after(_cli("gains", "--json"))


def test_inspect_of_an_mcap_log_needs_no_pandas(tmp_path):
    # inspect streams the file's times through the reader: no channel frame is made, so no pandas
    path = tmp_path / "run.mcap"
    usvlog.simulate("turns", path, duration_s=20)
    heavy = heavy_after(f"import usvlog; s = usvlog.inspect({str(path)!r}); assert s.channels, s")
    assert "pandas" not in heavy and "numpy" in heavy


_MISSING, _EXISTS, _NODIR = "missing.mcap: no such file", "existing.mcap: output exists", "no does not exist"
_BAD_PATHS = {   # case: (argv, what the error says)
    "estimate a missing log": (["estimate", "{missing}", "--out", "{new}"], _MISSING),
    "estimate onto an existing output": (["estimate", "{log}", "--out", "{existing}"], _EXISTS),
    "estimate into a missing directory": (["estimate", "{log}", "--out", "{nodir}"], _NODIR),
    "identify a missing log": (["identify", "{log}", "{missing}", "--out", "{new}"], _MISSING),
    "identify onto an existing --out-log": (["identify", "{log}", "--out", "{new}", "--out-log", "{existing}"],
                                            _EXISTS),
    "replay a missing log": (["replay", "{missing}", "--scenario", "paper-sine", "--out", "{new}"], _MISSING),
    "replay onto an existing output": (["replay", "{log}", "--scenario", "paper-sine", "--out", "{existing}"],
                                       _EXISTS),
    "import a missing file": (["import", "{missing}", "--out", "{new}"], _MISSING),
    "import onto an existing output": (["import", "{log}", "--out", "{existing}"], _EXISTS),
    "simulate onto an existing output": (["simulate", "excitation", "--out", "{existing}"], _EXISTS),
}


@pytest.mark.parametrize("case", sorted(_BAD_PATHS))
def test_a_bad_path_is_refused_before_the_heavy_imports(case, tmp_path):
    """A missing input or an output in the way fails at once (exit 2, the one-line error the reader or
    writer gives), before the verb imports numpy, pandas or numba."""
    (tmp_path / "log.mcap").write_bytes(b"not read")
    (tmp_path / "existing.mcap").write_bytes(b"in the way")
    names = {"missing": tmp_path / "missing.mcap", "new": tmp_path / "new.mcap", "log": tmp_path / "log.mcap",
             "existing": tmp_path / "existing.mcap", "nodir": tmp_path / "no" / "new.mcap"}
    argv, expect = _BAD_PATHS[case]
    argv = [a.format(**names) for a in argv]
    code = f"""
from usvlog.cli import main
rc = main({argv!r})
print("RC=%d" % rc)
"""
    heavy, r = probe(code, cwd=tmp_path)
    assert "RC=2" in r.stdout, r.stdout + r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "error:" in lines[0] and expect in lines[0], r.stderr
    assert heavy == [], heavy
