"""Which stages a campaign runs, and how it knows its sources again (their hashes)."""

from __future__ import annotations

import pytest

from usvlog.campaign.tasks import RunSettings, run_key
from usvlog.errors import ConfigError


def test_an_open_loop_season_is_imported_estimated_and_identified_not_replayed():
    s = RunSettings()
    assert s.stages == ("import", "estimate", "identify") and s.scenario is None


def test_a_scenario_adds_the_replay_stage_and_a_listed_replay_gets_the_paper_circle():
    assert RunSettings(scenario="paper-sine").stages == ("import", "estimate", "identify", "replay")
    assert RunSettings(stages=("import", "estimate"), scenario="paper-sine").stages == ("import", "estimate", "replay")
    listed = RunSettings(stages=("replay", "import", "estimate", "identify"))
    assert listed.stages == ("import", "estimate", "identify", "replay") and listed.scenario == "paper-circle"


def test_the_replay_stage_and_its_scenario_are_part_of_the_key():
    keys = {run_key("0" * 64, s, None) for s in (RunSettings(), RunSettings(scenario="paper-circle"),
                                                  RunSettings(scenario="paper-sine"))}
    assert len(keys) == 3


def test_a_stage_that_does_not_exist_is_named():
    with pytest.raises(ConfigError, match="unknown stage replya"):
        RunSettings(stages=("import", "replya"))


def test_source_hashes_are_the_contents_and_read_again_only_when_changed(tmp_path):
    """The campaign's hash record: true sha256 of each file (and of a bag directory's files);
    a second campaign takes an unchanged source's hash from the record (shown by tampering
    with the record: the tampered value comes back), a changed source is read again."""
    import hashlib
    import json
    import os

    from usvlog.campaign.tasks import HASH_CACHE, content_sha256, source_hashes

    src = tmp_path / "src"
    src.mkdir()
    files = []
    for i in range(3):
        f = src / f"run{i}.csv"
        f.write_bytes(bytes([i]) * (1000 + i))
        files.append(f)
    bag = src / "bag"
    bag.mkdir()
    (bag / "metadata.yaml").write_text("x: 1\n")
    (bag / "b_0.db3").write_bytes(b"\x01" * 10)
    files.append(bag)
    out = tmp_path / "camp"
    out.mkdir()
    first = source_hashes(files, out)
    assert first[:3] == [hashlib.sha256(f.read_bytes()).hexdigest() for f in files[:3]]
    assert first[3] == content_sha256(bag)
    rec = json.loads((out / HASH_CACHE).read_text())
    for k in rec:
        rec[k]["sha256"] = "recorded"
    (out / HASH_CACHE).write_text(json.dumps(rec))
    files[1].write_bytes(b"changed")
    st = files[1].stat()
    os.utime(files[1], ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
    again = source_hashes(files, out)
    assert again == ["recorded", hashlib.sha256(b"changed").hexdigest(), "recorded", "recorded"]
