"""Damage is loud downstream: a verb reading a damaged log says so in one line and keeps the
note in its output's provenance; regress fails on a damaged dataset."""

import json

import pytest
from mcap.reader import make_reader

from usvlog.cli import main
from usvlog.io.mcap import read_log, write_log
from usvlog.io.mcap.format import OP_CHUNK
from usvlog.sim.simulate import SimSettings, simulate


@pytest.fixture(scope="module")
def damaged(tmp_path_factory):
    """A 60 s run written in small chunks, with the CRC of one chunk in the middle broken."""
    d = tmp_path_factory.mktemp("dmg")
    good = d / "good.mcap"
    write_log(simulate("excitation", SimSettings(duration_s=60.0), seed=5), good, chunk_size=32 * 1024)
    data = bytearray(good.read_bytes())
    with open(good, "rb") as fh:   # the chunks holding /gnss/fix (a channel's messages have chunks of their own)
        summary = make_reader(fh).get_summary()
    fix = next(c.id for c in summary.channels.values() if c.topic == "/gnss/fix")
    offs = sorted(c.chunk_start_offset for c in summary.chunk_indexes if fix in c.message_index_offsets)
    assert len(offs) > 2 and all(data[o] == OP_CHUNK for o in offs)
    mid = offs[len(offs) // 2]
    data[mid + 9 + 24] ^= 0xFF            # the chunk's uncompressed CRC field
    bad = d / "bad.mcap"
    bad.write_bytes(bytes(data))
    return good, bad


def test_estimate_of_a_damaged_log_says_so_and_keeps_the_note(damaged, tmp_path, capsys):
    good, bad = damaged
    ref = read_log(good)
    log = read_log(bad)
    assert log.recovery is not None and len(log["/gnss/fix"]) < len(ref["/gnss/fix"])
    out = tmp_path / "est.mcap"
    assert main(["estimate", str(bad), "--out", str(out), "--json"]) == 0
    captured = capsys.readouterr()
    lines = [x for x in captured.err.splitlines() if "input damaged" in x]
    assert len(lines) == 1 and "1 chunk(s) lost" in lines[0] and str(bad) in lines[0]
    json.loads(captured.out)
    prov = read_log(out).provenance
    assert any(p.get("input_damage", "").startswith("input damaged: ") for p in prov)
    # an intact input: no such line, no such note
    assert main(["estimate", str(good), "--out", str(tmp_path / "ok.mcap"), "--json"]) == 0
    assert "input damaged" not in capsys.readouterr().err
    assert not any("input_damage" in p for p in read_log(tmp_path / "ok.mcap").provenance)


def test_regress_fails_on_a_damaged_dataset(damaged, tmp_path, capsys):
    _good, bad = damaged
    scen = tmp_path / "dmg.toml"
    scen.write_text(f'[scenario]\nname = "dmg"\n\n[dataset]\nlog = "{bad}"\n\n[stages]\nrun = ["estimate"]\n'
                    '\n[estimate]\nmodel = "kinematic"\n')
    rc = main(["regress", str(scen)])
    captured = capsys.readouterr()
    assert rc == 1, captured
    assert "input damaged" in captured.out + captured.err


@pytest.mark.parametrize("verb", ["export", "view", "report"])
def test_other_verbs_say_the_input_is_damaged(damaged, tmp_path, capsys, verb):
    _good, bad = damaged
    out = tmp_path / ("o.rrd" if verb == "view" else "o")
    assert main([verb, str(bad), "--out", str(out)]) == 0
    lines = [x for x in capsys.readouterr().err.splitlines() if "input damaged" in x]
    assert len(lines) == 1 and "1 chunk(s) lost" in lines[0]


def test_identify_keeps_the_damage_note_in_its_vessel_file(damaged, tmp_path, capsys):
    import tomllib

    _good, bad = damaged
    out = tmp_path / "v.toml"
    # a 60 s run is too short to validate on (the verdict would refuse it): the damage note is the point here
    assert main(["identify", str(bad), "--out", str(out), "--method", "equation-error", "--no-validate",
                 "--json"]) == 0
    text = out.read_text()
    assert text.startswith(f"# {bad}: input damaged: ") and "1 chunk(s) lost" in text.splitlines()[0]
    assert tomllib.loads(text)["model"]["m"] > 0          # still a vessel file
    assert sum("input damaged" in x for x in capsys.readouterr().err.splitlines()) == 1
