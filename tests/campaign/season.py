"""A generated field season: simulated runs of two vessels over three months (known truth).

``alpha``'s d11 steps by +20 % between 2026-05-31 and 2026-06-14 (the hull fouled, say);
``bravo``'s parameters stay put. Besides the excitation runs there is one straight-line run
(nothing to identify the yaw dynamics from) and one corrupt file. Used by the campaign
tests and by ``benchmarks/bench_campaign.py``.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from usvlog.io.config import load_vessel
from usvlog.io.mcap import write_log
from usvlog.sim.simulate import SensorSettings, SimSettings, simulate

D11_STEP = 0.20
STEP_BETWEEN = ("2026-05-31", "2026-06-14")
ALPHA_DATES = ("2026-05-03", "2026-05-17", "2026-05-31", "2026-06-14", "2026-06-28")   # 3 splits tried
BRAVO_DATES = ("2026-05-10", "2026-05-24", "2026-06-21", "2026-07-05")
STRAIGHT_DATE = "2026-06-07"
M_KG = 33.0   # both boats weighed: the campaign fixes m


def vessels():
    """{name: Vessel} of the two boats (truth before any step)."""
    base = load_vessel(None)
    return {"alpha": dataclasses.replace(base, name="alpha"),
            "bravo": dataclasses.replace(base, name="bravo", params=dataclasses.replace(base.params, d11=4.5, d33=6.0))}


def _with_d11(v, factor):
    return dataclasses.replace(v, params=dataclasses.replace(v.params, d11=v.params.d11 * factor))


def write_season(root, *, duration_s: float = 90.0, alpha_dates=ALPHA_DATES, bravo_dates=BRAVO_DATES,
                 straight: bool = True, corrupt: bool = True) -> dict:
    """Write the season's runs and the vessel map into ``root``.

    Returns
    -------
    dict
        ``runs`` (directory of the logs), ``map`` (the vessel map TOML), ``truth``
        ({file name: d11 true}), ``straight`` and ``corrupt`` (their file names or None).
    """
    root = Path(root)
    runs = root / "runs"
    runs.mkdir(parents=True, exist_ok=True)
    ves = vessels()
    for name, v in ves.items():
        (root / f"{name}.toml").write_text(v.to_toml())
    (root / "vessels.toml").write_text("".join(
        f'[vessel.{n}]\nfile = "{n}.toml"\nmatch = ["{n}_*"]\n\n' for n in ves))
    sens = SensorSettings(gps_noise_m=0.5, compass_noise_deg=1.0)
    truth = {}
    seed = 10
    step_day = STEP_BETWEEN[1]
    for name, dates in (("alpha", alpha_dates), ("bravo", bravo_dates)):
        for day in dates:
            factor = 1.0 + D11_STEP if name == "alpha" and day >= step_day else 1.0
            v = _with_d11(ves[name], factor)
            seed += 1
            log = simulate("excitation", SimSettings(vessel=v, duration_s=duration_s, sensors=sens,
                                                     start_utc=f"{day}T09:30:00+00:00"), seed=seed)
            f = runs / f"{name}_{day}.mcap"
            write_log(log, f)
            truth[f.name] = v.params.d11
    out = {"runs": runs, "map": root / "vessels.toml", "truth": truth, "straight": None, "corrupt": None}
    if straight:
        log = simulate("straight", SimSettings(vessel=ves["bravo"], duration_s=duration_s, sensors=sens,
                                               start_utc=f"{STRAIGHT_DATE}T14:00:00+00:00"), seed=99)
        f = runs / f"bravo_{STRAIGHT_DATE}_straight.mcap"
        write_log(log, f)
        out["straight"] = f.name
    if corrupt:
        f = runs / "alpha_2026-06-20_corrupt.bin"
        f.write_bytes(bytes(range(256)) * 40)   # what a card reader left: no log format at all
        out["corrupt"] = f.name
    return out
