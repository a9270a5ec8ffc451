"""The report's identification section shows the k-step-ahead fit % the verdict reads (5, 10, 30 s)."""

from __future__ import annotations

import re


def test_identification_section_shows_the_predictions_ahead():
    from usvlog.api import fit_log
    from usvlog.identify.identifier import Identifier
    from usvlog.sim.simulate import SimSettings, simulate
    from usvlog.view.report_page import _identification_section

    log = simulate("excitation", SimSettings(duration_s=200.0), seed=4)
    idf = Identifier("output-error", holdout=0.3).fit([log])
    html = "\n".join(_identification_section(fit_log(idf, log)))
    m = re.search(r"<p>Predicted ahead: (.*?)\.</p>", html)
    assert m, html
    shown = dict(re.findall(r"(\d+) s: ([^;]+)", m.group(1)))
    assert list(shown) == ["5", "10", "30"]
    for h, text in shown.items():
        values = dict(re.findall(r"([uvr]) (-?[\d.]+) %", text))
        for c in "uvr":
            assert abs(float(values[c]) - idf.fit_percent_ahead_[h][c]) < 0.051
