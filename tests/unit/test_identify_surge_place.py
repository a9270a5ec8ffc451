"""Where the surge candidate goes in the list (a tie in validation goes to the first).

Its m is the surge equation's own fit; it is preferred in a tie only where that fit determines m
(standard error within 30 % of it). A thruster lag fitted with the mass can swap the two (in surge a
lag and the hull's time constant are interchangeable): on a Fossen Otter run with --fit-lag the surge
equation gave m 13 +- 7 kg for an 85 kg hull, and preferred in a tie it was returned with r 34 %
against 80 % for the candidate beside it.
"""

from __future__ import annotations

import numpy as np

from usvlog.identify.candidates import Candidate, Start, place_surge_candidate


def _cand(name: str, model: str = "paper", m: float = 30.0, se_m: float | None = None) -> Candidate:
    theta = np.array([m, 10.0, 5.0, 5.0, 5.0, 0.1])
    return Candidate(start=Start(name=name, kind="output-error", theta=theta, model=model), theta=theta,
                     currents=np.zeros((1, 2)), fitted=None, validations=[],
                     held_stderr={} if se_m is None else {"m": se_m})


def test_a_determined_surge_mass_is_preferred_and_an_undetermined_one_decides_no_tie():
    rest = [_cand("output error"), _cand("velocity output error"), _cand("equation error"),
            _cand("quadratic surge", model="extended")]
    names = lambda cs: [c.start.name for c in cs]   # noqa: E731
    precise = _cand("surge", m=85.0, se_m=0.3 * 85.0)        # at the limit: preferred
    assert names(place_surge_candidate(rest, precise)) == ["surge", "output error", "velocity output error",
                                                           "equation error", "quadratic surge"]
    loose = _cand("surge", m=13.0, se_m=6.9)                 # 53 %: after the paper model's own
    assert names(place_surge_candidate(rest, loose)) == ["output error", "velocity output error",
                                                         "equation error", "surge", "quadratic surge"]
    assert names(place_surge_candidate(rest[:3], loose))[-1] == "surge"
    assert names(place_surge_candidate(rest, None)) == names(rest)
