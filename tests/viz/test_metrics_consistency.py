"""One run's path-following metrics are the same numbers on the console, in --json, in the HTML
report and in a regression baseline, each with its window; the report and the console give the
heading error in degrees, --json and the baseline in radians."""

from __future__ import annotations

import json
import math
import re
import tomllib
from html.parser import HTMLParser
from pathlib import Path

import pytest

from usvlog.cli import main

DATA = Path(__file__).resolve().parents[1] / "data"
FIELDS = ("cross_track_rms_m", "cross_track_p95_m", "cross_track_max_m", "heading_error_rms_rad",
          "surge_error_rms_mps", "time_saturated_s")


class Tables(HTMLParser):
    """Every <table> of a page as {class: [[cell text, ...], ...]}."""

    def __init__(self):
        super().__init__()
        self.tables: dict[str, list[list[str]]] = {}
        self._cls = None
        self._row: list[str] | None = None
        self._cell: list[str] | None = None

    def handle_starttag(self, tag, attrs):
        if tag == "table":
            self._cls = dict(attrs).get("class", "")
            self.tables[self._cls] = []
        elif tag == "tr" and self._cls is not None:
            self._row = []
        elif tag in ("td", "th") and self._row is not None:
            self._cell = []

    def handle_endtag(self, tag):
        if tag in ("td", "th") and self._cell is not None:
            self._row.append("".join(self._cell).strip())
            self._cell = None
        elif tag == "tr" and self._row is not None:
            self.tables[self._cls].append(self._row)
            self._row = None
        elif tag == "table":
            self._cls = None

    def handle_data(self, data):
        if self._cell is not None:
            self._cell.append(data)


def tables(html: str) -> dict[str, list[list[str]]]:
    p = Tables()
    p.feed(html)
    return p.tables


def _human(name: str, value: float) -> tuple[str, float]:
    """(the name people see, its value): the heading error in degrees."""
    if name == "heading_error_rms_rad":
        return "heading_error_rms_deg", math.degrees(value)
    return name, value


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("consistency")
    log = DATA / "paper-sine.mcap"
    out = {}
    import contextlib
    import io

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        assert main(["replay", str(log), "--scenario", "paper-sine", "--out", str(tmp / "r.mcap"),
                     "--no-whatif"]) == 0
    out["console"] = buf.getvalue()
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        assert main(["replay", str(log), "--scenario", "paper-sine", "--out", str(tmp / "r.mcap"),
                     "--no-whatif", "--json", "--force"]) == 0
    out["json"] = json.loads(buf.getvalue())
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["report", str(tmp / "r.mcap"), "--out", str(tmp / "rep")]) == 0
    out["html"] = (tmp / "rep" / "report.html").read_text()
    scen = tmp / "sine-recorded.toml"
    scen.write_text(f'[scenario]\nname = "sine-recorded"\n[dataset]\nlog = "{log}"\n[stages]\nrun = ["replay"]\n'
                    '[replay]\nscenario = "paper-sine"\nstate = "recorded"\n'
                    '[baseline]\nfile = "sine-recorded-baseline.toml"\n')
    with contextlib.redirect_stdout(io.StringIO()):
        main(["regress", str(scen), "--update"])
    out["baseline"] = tomllib.loads((tmp / "sine-recorded-baseline.toml").read_text())["metrics"]
    return out


def test_console_json_html_and_baseline_agree(runs):
    js = runs["json"]["replay"]
    window = js["window"]
    assert window == "t>30s"   # paper-sine's [metrics] start_s
    console = dict(re.findall(r"^\s+(\S+\[[^\]]+\])\s+(\S+) ", runs["console"], re.M))
    html_rows = {r[1]: r[2] for r in tables(runs["html"])["pathmetrics"][1:] if r[0] == "replayed controller"}
    assert "over [t>30s]" in runs["console"] and "Path following, over [t&gt;30s]" in runs["html"]
    for f in FIELDS:
        name, value = _human(f, js[f])
        key = f"{name}[{window}]"
        shown_console, shown_html = float(console[key]), float(html_rows[key])
        digits = 10 ** -len(console[key].split(".")[1])
        assert shown_console == pytest.approx(value, abs=digits / 2 + 1e-12), key
        assert shown_html == shown_console, key          # the same text, not merely close
        assert runs["baseline"][f"replay.{f}"]["value"] == pytest.approx(js[f], rel=1e-12, abs=1e-15), f
    # the numbers are the replayed controller's over the window, not over the whole run
    assert js["start_s"] == 30.0 and js["duration_s"] == pytest.approx(js["n_ticks"] / 100.0, abs=0.02)


def test_heading_in_degrees_for_people_radians_when_stored(runs):
    js = runs["json"]["replay"]
    assert "heading_error_rms_deg[t>30s]" in runs["console"] and "heading_error_rms_rad" not in runs["console"]
    assert "heading_error_rms_rad" in js and "heading_error_rms_deg" not in json.dumps(runs["json"])
    units = {r[1]: r[3] for r in tables(runs["html"])["pathmetrics"][1:]}
    assert units["heading_error_rms_deg[t>30s]"] == "deg" and units["cross_track_rms_m[t>30s]"] == "m"
