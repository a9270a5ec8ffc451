import xml.etree.ElementTree as ET

import pytest

from usvlog.errors import ConfigError
from usvlog.regress.gate import BaselineEntry, compare, junit_xml, updated_baseline

B = {
    "cross_track_rms_m": BaselineEntry(value=0.10, worse="larger", abs_tol=0.01),
    "fit_u_pct": BaselineEntry(value=90.0, worse="smaller", abs_tol=1.0),
    "m_kg": BaselineEntry(value=33.0, worse="either", rel_tol=0.02),
}


def test_within_tolerance_is_ok_and_direction_matters():
    checks = {c.metric: c for c in compare("s", {"cross_track_rms_m": 0.105, "fit_u_pct": 89.5, "m_kg": 33.5}, B)}
    assert all(c.verdict == "ok" for c in checks.values())
    checks = {c.metric: c for c in compare("s", {"cross_track_rms_m": 0.12, "fit_u_pct": 95.0, "m_kg": 34.0}, B)}
    xt = checks["cross_track_rms_m"]
    assert xt.verdict == "REGRESSED" and "rose from 0.1 to 0.12" in xt.message
    assert checks["fit_u_pct"].verdict == "improved" and not checks["fit_u_pct"].failed
    assert checks["m_kg"].verdict == "REGRESSED"  # 34 is 3% off 33 > 2%
    assert checks["cross_track_rms_m"].change == pytest.approx(0.02)


def test_missing_and_new_metrics():
    checks = {c.metric: c for c in compare("s", {"cross_track_rms_m": 0.1, "fit_u_pct": 90.0, "extra": 1.0}, B)}
    assert checks["m_kg"].verdict == "missing" and checks["m_kg"].failed
    assert checks["extra"].verdict == "new" and not checks["extra"].failed


def test_update_keeps_tolerances():
    new = updated_baseline({"cross_track_rms_m": 0.2, "other": 3.0}, B)
    assert new["cross_track_rms_m"].value == 0.2 and new["cross_track_rms_m"].abs_tol == 0.01
    assert new["other"].rel_tol == 0.05 and "m_kg" not in new


def test_junit_is_valid_xml_with_failures():
    checks = compare("paper-sine", {"cross_track_rms_m": 0.5, "fit_u_pct": 90.0, "m_kg": 33.0}, B)
    root = ET.fromstring(junit_xml(checks, {"paper-sine": 1.5}, {"broken": "boom <x>"}))
    assert root.tag == "testsuites" and root.attrib["failures"] == "1" and root.attrib["errors"] == "1"
    suites = {s.attrib["name"]: s for s in root}
    assert suites["paper-sine"].attrib["tests"] == "3"
    fails = [tc for tc in suites["paper-sine"] if tc.find("failure") is not None]
    assert [tc.attrib["name"] for tc in fails] == ["cross_track_rms_m"]
    assert suites["broken"].find("testcase/error").attrib["message"] == "boom <x>"


def test_bad_direction_rejected():
    with pytest.raises(ConfigError):
        BaselineEntry(value=1.0, worse="bigger")
