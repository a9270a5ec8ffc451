"""The Python API: the examples of the documentation's Python API page (docs/api.md, "## Examples") run as
written, in order, in an empty directory; the API names stay the functions; the API and the CLI verb give the
same result."""

import re
from pathlib import Path

import usvlog
from usvlog.cli import main

API_PAGE = Path(__file__).resolve().parents[1] / "docs" / "api.md"


def api_section() -> str:
    text = API_PAGE.read_text()
    m = re.search(r"^## Examples\n(.*?)(?=^## |\Z)", text, flags=re.S | re.M)
    assert m, "docs/api.md has no '## Examples' section"
    return m.group(1)


def python_blocks(section: str) -> list[str]:
    return re.findall(r"^```python\n(.*?)^```", section, flags=re.S | re.M)


def test_every_verb_has_an_example():
    code = "\n".join(python_blocks(api_section()))
    called = set(re.findall(r"\busvlog\.(\w+)\(", code))
    assert set(usvlog._API) <= called, f"no example for {sorted(set(usvlog._API) - called)}"


def test_docs_api_examples_run(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    blocks = python_blocks(api_section())
    assert len(blocks) >= 5
    ns: dict = {"__name__": "__docs_api__"}
    for i, block in enumerate(blocks):
        exec(compile(block, f"docs/api.md example {i + 1}", "exec"), ns)
    # what the examples say they wrote is there
    for name in ("run.mcap", "circle.mcap", "copy.mcap", "field.mcap", "est.mcap", "identified.toml",
                 "replay.mcap", "replay.rrd", "report/report.html", "baselines/est-check.toml"):
        assert (tmp_path / name).is_file(), name
    assert usvlog.load("copy.mcap").equals(usvlog.load("run.mcap"))
    assert any(t.startswith("/replay/") for t in usvlog.load("replay.mcap").topics)


def test_api_functions_are_not_replaced_by_subpackages_of_the_same_name():
    import usvlog.estimate.core  # noqa: F401  (the import system binds submodules on their parent)
    import usvlog.identify.identifier  # noqa: F401
    import usvlog.regress.stages  # noqa: F401
    import usvlog.replay  # noqa: F401
    from usvlog import api

    for name in usvlog._API:
        assert getattr(usvlog, name) is getattr(api, name), name
    from usvlog.estimate import EstimateSettings  # the subpackage itself is still imported by its full name

    assert EstimateSettings().model == "kinematic"


def test_api_and_cli_write_the_same_log(tmp_path):
    log = usvlog.simulate("turns", tmp_path / "api.mcap", seed=4, duration_s=20, gps_jumps=[(5, 10.0)])
    assert main(["simulate", "turns", "--out", str(tmp_path / "cli.mcap"), "--seed", "4", "--duration-s", "20",
                 "--gps-jump", "5:10"]) == 0
    assert usvlog.load(tmp_path / "cli.mcap").equals(usvlog.load(tmp_path / "api.mcap"))
    assert usvlog.load(tmp_path / "api.mcap").equals(log)
