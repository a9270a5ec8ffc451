"""Simulated NMEA runs of a boat on straight legs (GGA + RMC + VTG + HDT) for the heading
mounting offset and GNSS noise tests: the truth is kept next to the file written."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from usvlog.io.nmea import format_deg_min, with_checksum
from usvlog.io.record.loopback import hdt, rmc
from usvlog.model.frames import Datum, ned_to_geodetic

T0_NS = 1_780_308_000_000_000_000   # 2026-06-01 10:00:00 UTC
DATUM = Datum(lat_deg=59.9, lon_deg=10.7)
KNOT = 1852.0 / 3600.0


@dataclass(frozen=True)
class Run:
    """Truth of a simulated run, on a 0.1 s grid from T0_NS."""

    t_s: np.ndarray
    n_m: np.ndarray
    e_m: np.ndarray
    psi_rad: np.ndarray      # true hull heading
    u_mps: np.ndarray        # over-ground body velocity
    v_mps: np.ndarray


def truth(courses_deg=(20, 110, 200, 290, 20, 110), leg_s=50.0, turn_s=10.0, speed=1.2,
          current_ne=(0.0, 0.0)) -> Run:
    """Heading held on each course for ``leg_s``, turned at a constant rate over ``turn_s``
    to the next; speed through the water ``speed`` along the heading, plus the current."""
    dt = 0.1
    psi = []
    for i, c in enumerate(courses_deg):
        psi += [math.radians(c)] * int(round(leg_s / dt))
        if i + 1 < len(courses_deg):
            d = math.radians(((courses_deg[i + 1] - c + 180) % 360) - 180)
            k = int(round(turn_s / dt))
            psi += list(math.radians(c) + d * (np.arange(1, k + 1) / k))
    psi = np.asarray(psi)
    t = dt * np.arange(len(psi))
    vn = speed * np.cos(psi) + current_ne[0]
    ve = speed * np.sin(psi) + current_ne[1]
    n = np.concatenate([[0.0], np.cumsum(vn[:-1] * dt)])
    e = np.concatenate([[0.0], np.cumsum(ve[:-1] * dt)])
    u = vn * np.cos(psi) + ve * np.sin(psi)
    v = -vn * np.sin(psi) + ve * np.cos(psi)
    return Run(t, n, e, psi, u, v)


def _hms(t_ns: int) -> str:
    s = (t_ns // 1_000_000) / 1000.0
    tod = s % 86400.0
    return f"{int(tod // 3600):02d}{int(tod % 3600 // 60):02d}{tod % 60:06.3f}"


def gga(t_ns: int, lat: float, lon: float, quality: int, hdop: float) -> str:
    """A GGA sentence with a given fix quality and HDOP."""
    la, ns = format_deg_min(lat, True)
    lo, ew = format_deg_min(lon, False)
    return with_checksum(f"GPGGA,{_hms(t_ns)},{la},{ns},{lo},{ew},{quality},14,{hdop:.1f},12.00,M,0.0,M,,")


def vtg(cog_deg: float, sog_mps: float) -> str:
    """A VTG sentence (true course, speed in knots and km/h)."""
    return with_checksum(f"GPVTG,{cog_deg % 360:.2f},T,,M,{sog_mps / KNOT:.3f},N,{sog_mps * 3.6:.3f},K,A")


def write_nmea(path, run: Run, *, offset_deg=0.0, quality=4, hdop=0.7, sigma_m=0.02, heading_sd_deg=0.3,
               seed=0) -> None:
    """GGA + RMC + VTG at 5 Hz and HDT (true heading + ``offset_deg`` + noise) at 10 Hz."""
    rng = np.random.default_rng(seed)
    k = len(run.t_s)
    n = run.n_m + sigma_m * rng.standard_normal(k)
    e = run.e_m + sigma_m * rng.standard_normal(k)
    lat, lon, _ = ned_to_geodetic(n, e, 0.0, datum=DATUM)
    vn, ve = np.gradient(run.n_m, run.t_s), np.gradient(run.e_m, run.t_s)
    sog, cog = np.hypot(vn, ve), np.degrees(np.arctan2(ve, vn))
    hd = np.degrees(run.psi_rad) + offset_deg + heading_sd_deg * rng.standard_normal(k)
    lines = []
    for i in range(k):
        t_ns = T0_NS + int(round(run.t_s[i] * 1e9))
        if i % 2 == 0:
            lines += [gga(t_ns, lat[i], lon[i], quality, hdop), rmc(t_ns, lat[i], lon[i], sog[i] / KNOT, cog[i]),
                      vtg(cog[i], sog[i])]
        lines.append(hdt(hd[i]))
    with open(path, "w") as f:
        f.write("\r\n".join(lines) + "\r\n")
