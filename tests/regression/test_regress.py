"""The shipped regression set: it passes, it is deterministic, and the gate bites."""

from __future__ import annotations

import json
import shutil
import tomllib
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from usvlog.cli import main
from usvlog.regress.baselines import (
    find_regress_scenarios,
    load_regress_scenario,
    read_baseline,
)
from usvlog.regress.stages import run_scenario, run_stages
from usvlog.resources import replay_dir

pytestmark = pytest.mark.regression

REPLAY = replay_dir()
SCENARIOS = find_regress_scenarios([REPLAY])


def _toml_value(v) -> str:
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    return repr(v)


def _write_toml(doc: dict, path: Path) -> None:
    lines = []
    for sec, table in doc.items():
        subs = {k: v for k, v in table.items() if isinstance(v, dict)}
        lines.append(f"[{sec}]")
        lines += [f"{k} = {_toml_value(v)}" for k, v in table.items() if not isinstance(v, dict)]
        for k, v in subs.items():
            lines.append(f"[{sec}.{k}]")
            lines += [f"{kk} = {_toml_value(vv)}" for kk, vv in v.items()]
    path.write_text("\n".join(lines) + "\n")


def perturbed(tmp_path: Path, name: str, edit) -> Path:
    """A copy of a shipped scenario, changed by ``edit(doc)``, against the shipped baseline."""
    src = REPLAY / f"{name}.toml"
    doc = tomllib.loads(src.read_text())
    doc["dataset"]["log"] = str((src.parent / doc["dataset"]["log"]).resolve())
    doc["baseline"]["file"] = str((src.parent / doc["baseline"]["file"]).resolve())
    if "replay" in doc:
        doc["replay"]["scenario"] = str((src.parent / doc["replay"]["scenario"]).resolve())
    edit(doc)
    out = tmp_path / f"{name}-perturbed.toml"
    _write_toml(doc, out)
    return out


def test_shipped_set_is_complete():
    names = {load_regress_scenario(p).name for p in SCENARIOS}
    assert {"ident-current", "sine-ekf", "gps-faults", "imported-csv", "imported-nmea", "imported-ros2"} <= names
    for p in SCENARIOS:
        scn = load_regress_scenario(p)
        assert scn.dataset.exists() and scn.dataset.stat().st_size < 2.1e6
        assert read_baseline(scn.baseline), f"{scn.baseline} has no accepted metrics"


@pytest.mark.parametrize("path", SCENARIOS, ids=lambda p: p.stem)
def test_scenario_passes_its_baseline(path):
    scn = load_regress_scenario(path)
    out = run_scenario(scn, read_baseline(scn.baseline))
    assert out.error is None, out.error
    bad = [c.message for c in out.checks if c.failed]
    assert not bad, bad
    assert all(c.verdict != "new" for c in out.checks)  # every metric has an accepted baseline


def test_results_are_deterministic():
    from usvlog.io.mcap import read_log

    scn = load_regress_scenario(REPLAY / "sine-ekf.toml")
    a = run_stages(scn, read_log(scn.dataset))
    b = run_stages(scn, read_log(scn.dataset))
    assert a == b


def test_halving_kppsi_fails_exactly_the_controller_metrics(tmp_path, capsys):
    def edit(doc):
        doc["replay"]["gains"] = {"KPpsi": 2.5}
    path = perturbed(tmp_path, "sine-ekf", edit)
    junit = tmp_path / "junit.xml"
    rc = main(["regress", str(path), "--junit", str(junit), "--json"])
    assert rc == 1
    res = json.loads(capsys.readouterr().out)["scenarios"][0]
    failed = {c["metric"] for c in res["checks"] if c["verdict"] in ("REGRESSED", "missing")}
    assert failed, "halving KPpsi must fail something"
    assert all(m.startswith(("replay.", "whatif.")) for m in failed), failed
    assert "replay.command_rms" in failed and "whatif.heading_error_rms_rad" in failed
    assert not any(m.startswith("estimate.") for m in failed)
    root = ET.parse(junit).getroot()
    assert int(root.attrib["failures"]) == len(failed)


def test_compass_bias_in_the_smoother_fails_the_estimate_metrics(tmp_path, capsys):
    def edit(doc):
        doc["estimate"]["compass_offset_rad"] = 0.05  # the smoother now believes a 2.9 deg mounting offset
    path = perturbed(tmp_path, "gps-faults", edit)
    assert main(["regress", str(path)]) == 1
    out = capsys.readouterr().out
    assert "REGRESSION gps-faults-perturbed" not in out  # scenario keeps its [scenario] name
    assert "estimate.psi_rms_deg rose" in out
    assert "estimate.gnss_rejected" not in [ln.split()[1] for ln in out.splitlines()
                                            if ln.endswith("REGRESSED") and len(ln.split()) > 1]


def test_cli_table_and_junit(tmp_path, capsys):
    junit = tmp_path / "r.xml"
    rc = main(["regress", str(REPLAY / "gps-faults.toml"), str(REPLAY / "imported-nmea.toml"), "--junit", str(junit)])
    out = capsys.readouterr().out
    assert rc == 0, out
    assert "gps-faults" in out and "estimate.gnss_rejected" in out and "0 regressed, 0 errors" in out
    root = ET.parse(junit).getroot()
    assert root.tag == "testsuites" and root.attrib["failures"] == "0"
    assert {s.attrib["name"] for s in root} == {"gps-faults", "imported-nmea"}


def test_update_rewrites_only_on_request_and_shows_diff(tmp_path, capsys):
    scn_src = REPLAY / "imported-nmea.toml"
    base = tmp_path / "baselines" / "imported-nmea.toml"
    base.parent.mkdir()
    shutil.copy(REPLAY / "baselines" / "imported-nmea.toml", base)
    text = base.read_text().replace("value = ", "value = 1e3 + ", 1)  # corrupt one accepted value
    text = text.replace("value = 1e3 + ", "value = 1000.0 # ", 1)
    base.write_text(text)

    def edit(doc):
        doc["baseline"]["file"] = str(base)
    path = perturbed(tmp_path, "imported-nmea", edit)
    assert main(["regress", str(path)]) == 1          # the corrupted baseline fails
    assert base.read_text() == text                     # and is not rewritten without --update
    capsys.readouterr()
    assert main(["regress", str(path), "--update"]) == 0
    err = capsys.readouterr().err
    assert "-value = 1000.0" in err and "+value = " in err
    assert main(["regress", str(path)]) == 0
    assert scn_src.exists()
