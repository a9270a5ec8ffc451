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


def heavy_after(code: str) -> list[str]:
    """Heavy top-level packages in sys.modules after running ``code`` in a fresh interpreter."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), *filter(None, [env.get("PYTHONPATH")])])
    r = subprocess.run([sys.executable, "-c", _PROBE.format(code=code, heavy=HEAVY)], capture_output=True,
                       text=True, env=env, cwd=ROOT)
    assert r.returncode == 0, r.stderr
    line = [x for x in r.stdout.splitlines() if x.startswith("HEAVY=")][-1]
    return json.loads(line[len("HEAVY="):])


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
