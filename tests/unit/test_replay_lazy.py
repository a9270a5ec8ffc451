"""The estimate and replay verbs read only the channels they use: their files are those of the
verbs run on the whole log decoded."""

import usvlog
from usvlog.io.mcap import read_log, write_log


def test_estimate_from_a_file_writes_what_the_whole_log_gives(tmp_path, excitation_file):
    usvlog.estimate(str(excitation_file), tmp_path / "e.mcap")
    whole = read_log(excitation_file)
    write_log(usvlog.estimate(whole).to_log(whole), tmp_path / "e_whole.mcap")
    assert (tmp_path / "e.mcap").read_bytes() == (tmp_path / "e_whole.mcap").read_bytes()


def test_replay_from_a_file_writes_what_the_whole_log_gives(tmp_path, excitation_file):
    # no /estimate/state here: replay touches the deferred /truth/state, decoded then
    res = usvlog.replay(str(excitation_file), "paper-sine", tmp_path / "r.mcap")
    assert res.metrics.state_source == "/truth/state" and res.log.deferred is not None
    ref = usvlog.replay(read_log(excitation_file), "paper-sine")
    assert res.log.topics == ref.log.topics and res.metrics == ref.metrics
    write_log(ref.log, tmp_path / "r_whole.mcap")
    assert (tmp_path / "r.mcap").read_bytes() == (tmp_path / "r_whole.mcap").read_bytes()
    assert res.log.equals(ref.log)                          # the deferred channels decode when touched
