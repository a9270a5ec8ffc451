"""The README's "Python API" examples run as written, in order, in an empty directory."""

import re
from pathlib import Path

import usvlog

README = Path(__file__).resolve().parents[1] / "README.md"


def api_section() -> str:
    text = README.read_text()
    m = re.search(r"^## Python API\n(.*?)(?=^## )", text, flags=re.S | re.M)
    assert m, "README.md has no '## Python API' section"
    return m.group(1)


def python_blocks(section: str) -> list[str]:
    return re.findall(r"^```python\n(.*?)^```", section, flags=re.S | re.M)


def test_every_verb_has_an_example():
    code = "\n".join(python_blocks(api_section()))
    called = set(re.findall(r"\busvlog\.(\w+)\(", code))
    assert set(usvlog._API) <= called, f"no example for {sorted(set(usvlog._API) - called)}"


def test_readme_api_examples_run(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    blocks = python_blocks(api_section())
    assert len(blocks) >= 5
    ns: dict = {"__name__": "__readme__"}
    for i, block in enumerate(blocks):
        exec(compile(block, f"README.md Python API block {i + 1}", "exec"), ns)
    # what the examples say they wrote is there
    for name in ("run.mcap", "circle.mcap", "copy.mcap", "field.mcap", "est.mcap", "identified.toml",
                 "replay.mcap", "replay.rrd", "report/report.html", "baselines/est-check.toml"):
        assert (tmp_path / name).is_file(), name
    assert usvlog.load("copy.mcap").equals(usvlog.load("run.mcap"))
    assert any(t.startswith("/replay/") for t in usvlog.load("replay.mcap").topics)
