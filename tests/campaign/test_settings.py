"""Which stages a campaign runs: replay only when asked for or when a scenario is given."""

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
