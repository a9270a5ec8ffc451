"""The documentation's tutorial runs as written: the `usvlog` commands of docs/tutorial.md, in order, on the
real VantTec bag (MIT, tests/data/real/LICENSE.vanttec_usv.txt) in an empty directory, each with the exit code
the page shows (0 unless the page follows it with `$ echo $?` and another number)."""

import re
import shlex
import shutil
from pathlib import Path

import pytest

from usvlog.cli import main

ROOT = Path(__file__).resolve().parents[1]
TUTORIAL = ROOT / "docs" / "tutorial.md"
README = ROOT / "README.md"
BAG = ROOT / "tests" / "data" / "real" / "vanttec" / "vn_2021-06-11-13-29-34.bag"


def tutorial_commands(text: str) -> list[tuple[list[str], int]]:
    """(argv after `usvlog`, expected exit code) of each `usvlog ...` line of the ```console/```bash blocks."""
    commands: list[tuple[list[str], int]] = []
    for block in re.findall(r"^```(?:console|bash)\n(.*?)^```", text, flags=re.S | re.M):
        lines = block.splitlines()
        prompted = any(x.startswith("$ ") for x in lines)   # with prompts, the other lines are output
        for i, line in enumerate(lines):
            if prompted and not line.startswith("$ "):
                continue
            cmd = line[2:] if prompted else line
            if not cmd.startswith("usvlog "):
                continue
            expected = 0
            rest = [x for x in lines[i + 1:] if x.startswith("$ ")]
            if rest and rest[0].strip() == "$ echo $?":
                after = lines[lines.index(rest[0], i + 1) + 1].strip()
                expected = int(after)
            commands.append((shlex.split(cmd, comments=True)[1:], expected))
    return commands


def test_the_tutorial_parses_into_the_pipeline():
    cmds = tutorial_commands(TUTORIAL.read_text())
    verbs = [argv[0] for argv, _ in cmds]
    assert verbs == ["inspect", "import", "check", "estimate", "identify", "view", "report"], verbs
    assert dict((argv[0], code) for argv, code in cmds)["identify"] == 1   # the page shows the unusable verdict
    assert all(BAG.name in argv for argv, _ in cmds[:2])


@pytest.mark.skipif(not BAG.is_file(), reason="the VantTec bag is in the source checkout only")
def test_tutorial_commands_run_with_the_exit_codes_shown(tmp_path, monkeypatch):
    pytest.importorskip("rosbags")
    pytest.importorskip("matplotlib")
    shutil.copy(BAG, tmp_path / BAG.name)
    monkeypatch.chdir(tmp_path)
    for argv, expected in tutorial_commands(TUTORIAL.read_text()):
        assert main(argv) == expected, f"usvlog {shlex.join(argv)}"
    for name in ("run.mcap", "est.mcap", "run.rrd", "report/report.html"):
        assert (tmp_path / name).is_file(), name
    assert not (tmp_path / "boat.toml").exists()   # unusable: nothing written
    for img in re.findall(r"!\[[^]]*\]\((img/[^)]+)\)", TUTORIAL.read_text()):
        assert (TUTORIAL.parent / img).is_file(), img


def test_the_readme_tour_is_the_tutorial():
    """The README's five-minute tour shows the tutorial's commands (which the test above runs), in its order."""
    tour = [argv for argv, _ in tutorial_commands(README.read_text())]
    tutorial = [argv for argv, _ in tutorial_commands(TUTORIAL.read_text())]
    assert [a[0] for a in tour] == ["inspect", "import", "check", "estimate", "identify", "view", "report"]
    assert tour == [a for a in tutorial if a in tour] and all(a in tutorial for a in tour)


def test_readme_is_short_and_keeps_its_setup_commands():
    text = README.read_text()
    assert text.count("\n") <= 300
    setup = re.search(r"^## Set up\n(.*?)(?=^## )", text, flags=re.S | re.M).group(1)
    commands = re.findall(r"^```sh\n(.*?)\n```", setup, flags=re.S | re.M)
    assert commands[1].endswith('pip install -e ".[test]" && pytest -q -m "not slow" -n auto')
    assert 'pytest -q -m "not slow" -n auto' in (ROOT / ".ci" / "run").read_text()   # CI runs the README's command
