"""`usvlog inspect SOURCE` dispatches to the format's catalog (the real ULog and DataFlash logs)."""

from __future__ import annotations

import json
import shlex
from pathlib import Path

from usvlog.cli import main

REAL = Path(__file__).resolve().parents[1] / "data" / "real"
ULG = REAL / "px4_sample_log_small.ulg"
BIN = REAL / "ardusub_small.BIN"


def test_inspect_ulog_lists_topics_mapping_and_a_command_that_imports(tmp_path, capsys):
    assert main(["inspect", str(ULG), "--json"]) == 0
    cat = json.loads(capsys.readouterr().out)
    assert cat["format"] == "ulog"
    gps = next(t for t in cat["topics"] if t["name"] == "vehicle_gps_position")
    assert gps["count"] == 32                    # pyulog's count (tests/data/real README)
    assert {"lat", "lon", "eph"} <= {f["path"] for f in gps["fields"]}
    assert cat["mapping"]["gnss"] == "vehicle_gps_position"
    cmd = shlex.split(cat["import_command"].replace("px4_sample_log_small.mcap", str(tmp_path / "x.mcap")))
    assert main(cmd[1:]) == 0 and (tmp_path / "x.mcap").exists()
    capsys.readouterr()
    assert main(["inspect", str(ULG)]) == 0
    text = capsys.readouterr().out
    assert "  vehicle_gps_position  [vehicle_gps_position]  32 msgs" in text and "import with" in text


def test_inspect_topic_error_lists_fields_and_dataflash_says_no_gnss(capsys):
    assert main(["inspect", str(ULG), "--topic", "yaw_rate=vehicle_angular_velocity.xyz[5]"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "xyz[2]" in err[0]
    assert main(["inspect", str(BIN), "--json"]) == 0
    cat = json.loads(capsys.readouterr().out)
    assert "gnss" not in cat["mapping"] and "no GNSS" in cat["reasons"]["gnss"]
