"""The demo's outputs in a real headless browser (Debian's chromium, software rendering).

* The HTML report renders: every image loads, the identification section and its verdict are
  there, the screenshot is not blank.
* The demo's .rrd in Rerun's web viewer (``rerun --serve-web`` bound to 127.0.0.1, WebGL): the
  viewer shows the recording by name, and the map and the plots are drawn (pixel variance of
  their regions in a screenshot).

Skipped with a reason where no chromium is installed (CI installs it with apt where it can).
"""

from __future__ import annotations

import contextlib
import io
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

from usvlog.cli import main
from usvlog.view.rrd import viewer_command

from .browser import Browser, chromium_path, free_port

pytestmark = [pytest.mark.slow, pytest.mark.browser,
              pytest.mark.skipif(chromium_path() is None,
                                 reason="no chromium here (apt-get install chromium; CI installs it where apt works)")]


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo") / "d"
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["demo", "--out", str(out), "--duration-s", "120"]) == 0
    return out


def _image(path: Path) -> np.ndarray:
    import matplotlib.image as mpimg

    return mpimg.imread(path)[..., :3]


def test_demo_report_renders_with_every_image_and_the_identification(demo, tmp_path):
    page = demo / "report" / "report.html"
    with Browser(width=1200, height=2400) as b:
        b.open(page.as_uri())
        assert b.wait_for("document.readyState === 'complete'", 60)
        n_img = b.js("document.images.length")
        broken = b.js("Array.from(document.images).filter(i => !(i.complete && i.naturalWidth > 0))"
                      ".map(i => i.getAttribute('src'))")
        ident = b.js("(() => { const h = document.getElementById('identification');"
                     " return h ? h.textContent : null })()")
        verdict = b.js("document.querySelectorAll('ul.verdict li').length")
        params = b.js("Array.from(document.querySelectorAll('table.params tr td:first-child'))"
                      ".map(td => td.textContent)")
        status = b.js("document.getElementById('status').textContent")
        shot = b.screenshot(tmp_path / "report.png")
        b.open((demo / "report" / "paper-circle" / "report.html").as_uri())
        assert b.wait_for("document.readyState === 'complete'", 60)
        broken2 = b.js("Array.from(document.images).filter(i => !(i.complete && i.naturalWidth > 0)).length")
        n_img2 = b.js("document.images.length")
    assert n_img >= 4 and broken == []
    assert n_img2 >= 3 and broken2 == 0
    assert ident.startswith("Identification: ") and verdict >= 1
    assert params == ["m", "Iz", "d11", "d22", "d33", "xg"]
    assert status.startswith("Estimate: ") and "Identification: " in status
    img = _image(shot)
    assert img.std() > 0.05   # text, tables and figures, not a blank page


def test_demo_rrd_in_the_web_viewer_shows_the_map_and_the_plots(demo, tmp_path):
    web, grpc = free_port(), free_port()
    cmd = viewer_command(demo / "demo.rrd", serve=True, host="127.0.0.1", port=web, grpc_port=grpc)
    server = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        url = f"http://127.0.0.1:{web}/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A{grpc}%2Fproxy&renderer=webgl"
        with Browser(width=1600, height=1000) as b:
            deadline = time.monotonic() + 30
            while time.monotonic() < deadline:   # the server is up when it answers
                with contextlib.suppress(OSError):
                    import urllib.request

                    urllib.request.urlopen(f"http://127.0.0.1:{web}/", timeout=2).close()
                    break
                time.sleep(0.3)
            b.open(url)
            assert b.wait_for("document.querySelector('canvas') !== null", 90)
            # the wasm viewer streams the recording in and draws it (software rendering, a busy machine:
            # up to minutes); look every 10 s until the map and the plots show data
            deadline = time.monotonic() + 240
            while True:
                time.sleep(10)
                shot = b.screenshot(tmp_path / "viewer.png")
                problems = _blank_regions(_image(shot))
                if not problems or time.monotonic() > deadline:
                    break
    finally:
        with contextlib.suppress(ProcessLookupError):
            import os
            import signal

            os.killpg(server.pid, signal.SIGTERM)
        server.wait(timeout=20)
    assert not problems, f"{', '.join(problems)} blank after 4 minutes (screenshot: {shot})"


def _blank_regions(img: np.ndarray) -> list[str]:
    """Which of the viewer's regions look blank: the tracks (map) top-left, the surge speed and
    heading plots top-right (plots need coloured lines, not only the grey of axes and text)."""
    h, w = img.shape[:2]
    out = []
    regions = {"map": img[int(0.08 * h):int(0.55 * h), int(0.14 * w):int(0.45 * w)],
               "plots": img[int(0.08 * h):int(0.50 * h), int(0.48 * w):int(0.80 * w)]}
    for name, reg in regions.items():
        colours = {tuple(p) for p in (reg.reshape(-1, 3) * 255).astype(np.uint8)[::7]}
        sat = reg.max(axis=-1) - reg.min(axis=-1)
        if reg.std() < 0.02 or len(colours) < 50 or (name == "plots" and (sat > 0.3).mean() < 0.002):
            out.append(name)
    return out
