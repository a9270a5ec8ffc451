"""A stand-in boat for trying the recorder without hardware (and for its tests).

Streams what a small USV's sensors send: NMEA GGA + RMC (GNSS, default 10 Hz),
HDT (compass, 20 Hz) and thrust commands as JSON lines (100 Hz), for a boat
driving a circle, to UDP addresses, a TCP connection or a serial line (any file
descriptor). It keeps every value it sent so a test can compare the recording
with the truth.

    python -m usvlog.io.record.loopback --gnss udp://127.0.0.1:10110 \\
        --compass udp://127.0.0.1:10110 --thrust udp://127.0.0.1:10111 --duration-s 30
"""

from __future__ import annotations

import argparse
import math
import socket
import threading
import time
from dataclasses import dataclass, field

import orjson

from ..nmea import format_deg_min, with_checksum
from .sources import parse_source

_M_PER_DEG = 111_320.0


def _hms(gps_ns: int) -> str:
    s = (gps_ns // 1_000_000) / 1000.0
    tod = s % 86400.0
    h = int(tod // 3600)
    mi = int(tod % 3600 // 60)
    return f"{h:02d}{mi:02d}{tod % 60:06.3f}"


def _dmy(gps_ns: int) -> str:
    t = time.gmtime(gps_ns // 1_000_000_000)
    return f"{t.tm_mday:02d}{t.tm_mon:02d}{t.tm_year % 100:02d}"


def gga(gps_ns: int, lat: float, lon: float, alt_m: float, sats: int = 9, hdop: float = 0.8) -> str:
    """A GGA sentence (geoid separation 0, so altitude is the ellipsoid height).

    Parameters
    ----------
    gps_ns : int
        GPS time, ns since the Unix epoch (the sentence keeps the time of day, ms).
    lat, lon : float
        Position, degrees.
    alt_m : float
        Altitude, m.
    sats : int
        Satellites in use.
    hdop : float
        Horizontal dilution of precision.

    Returns
    -------
    str
        The sentence with its checksum, without line ending.
    """
    la, ns = format_deg_min(lat, True)
    lo, ew = format_deg_min(lon, False)
    return with_checksum(f"GPGGA,{_hms(gps_ns)},{la},{ns},{lo},{ew},1,{sats:02d},{hdop:.1f},{alt_m:.2f},M,0.0,M,,")


def rmc(gps_ns: int, lat: float, lon: float, sog_kn: float = 0.0, cog_deg: float = 0.0) -> str:
    """An RMC sentence (status A).

    Parameters
    ----------
    gps_ns : int
        GPS time, ns since the Unix epoch (time of day to the ms, and the date).
    lat, lon : float
        Position, degrees.
    sog_kn : float
        Speed over ground, knots.
    cog_deg : float
        Course over ground, degrees from true north.

    Returns
    -------
    str
        The sentence with its checksum, without line ending.
    """
    la, ns = format_deg_min(lat, True)
    lo, ew = format_deg_min(lon, False)
    return with_checksum(f"GPRMC,{_hms(gps_ns)},A,{la},{ns},{lo},{ew},{sog_kn:.2f},{cog_deg % 360:.2f},"
                         f"{_dmy(gps_ns)},,")


def hdt(heading_deg: float) -> str:
    """An HDT sentence (true heading).

    Parameters
    ----------
    heading_deg : float
        Heading, degrees clockwise from true north (wrapped to [0, 360)).

    Returns
    -------
    str
        The sentence with its checksum, without line ending.
    """
    return with_checksum(f"HEHDT,{heading_deg % 360.0:.3f},T")


@dataclass
class Sent:
    """Everything the loopback boat sent: lists of tuples, in order."""

    fixes: list = field(default_factory=list)     # (send_ns, gps_ns, lat, lon, alt)
    headings: list = field(default_factory=list)  # (send_ns, heading_deg)
    thrust: list = field(default_factory=list)    # (send_ns, left, right)
    garbage: list = field(default_factory=list)   # lines sent that are malformed on purpose


def udp_target(url_or_addr):
    """A send(bytes) callable for a UDP address.

    Parameters
    ----------
    url_or_addr : str or tuple
        ``udp://host:port`` or a (host, port) pair.

    Returns
    -------
    callable
        ``send(data: bytes)``: one datagram.
    """
    if isinstance(url_or_addr, str):
        spec = parse_source(url_or_addr)
        addr = (spec.host, spec.port)
    else:
        addr = tuple(url_or_addr)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    return lambda data: sock.sendto(data, addr)


def free_udp_port(host: str = "127.0.0.1") -> int:
    """A UDP port that is free now (for tests and benchmarks on loopback).

    Parameters
    ----------
    host : str
        Address to find a port on.

    Returns
    -------
    int
    """
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind((host, 0))
    port = s.getsockname()[1]
    s.close()
    return port


class LoopbackBoat:
    """Sends the sensor streams of a boat on a circle until ``duration_s`` or ``stop``.

    ``gnss``, ``compass``, ``thrust``: callables taking bytes (one write per message)
    or None. ``gps_lag_s``: how late the GPS time is relative to the sender's
    clock (so the recorder's clock offset estimate has a known answer).
    ``garbage_every``: every n-th GNSS epoch also sends a malformed sentence.
    """

    def __init__(self, *, gnss=None, compass=None, thrust=None, gnss_hz: float = 10.0,
                 compass_hz: float = 20.0, thrust_hz: float = 100.0, lat0: float = 59.9,
                 lon0: float = 10.7, radius_m: float = 50.0, period_s: float = 60.0,
                 gps_lag_s: float = 0.0, garbage_every: int = 0, thrust_time: bool = True):
        self.gnss, self.compass, self.thrust = gnss, compass, thrust
        self.rates = (gnss_hz, compass_hz, thrust_hz)
        self.lat0, self.lon0, self.radius, self.period = lat0, lon0, radius_m, period_s
        self.gps_lag_ns = int(gps_lag_s * 1e9)
        self.garbage_every = garbage_every
        self.thrust_time = thrust_time
        self.sent = Sent()

    def pose(self, t_s: float) -> tuple[float, float, float]:
        """Where the boat is on its circle.

        Parameters
        ----------
        t_s : float
            Time since the start, s.

        Returns
        -------
        tuple of float
            Latitude and longitude (degrees) and heading (degrees clockwise from north, [0, 360)).
        """
        w = 2 * math.pi / self.period
        n = self.radius * math.sin(w * t_s)
        e = self.radius * (1 - math.cos(w * t_s))
        lat = self.lat0 + n / _M_PER_DEG
        lon = self.lon0 + e / (_M_PER_DEG * math.cos(math.radians(self.lat0)))
        return lat, lon, math.degrees(w * t_s) % 360.0

    def run(self, duration_s: float, stop: threading.Event | None = None) -> Sent:
        """Send every stream at its rate for ``duration_s`` (or until ``stop`` is set).

        Parameters
        ----------
        duration_s : float
            How long to send, s.
        stop : threading.Event, optional
            Stops early when set.

        Returns
        -------
        Sent
            Everything sent, in order (also ``self.sent``).
        """
        streams = [(hz, fn) for hz, fn in zip(self.rates, (self._gnss, self._compass, self._thrust))
                   if hz and hz > 0]
        streams = [(hz, fn) for hz, fn in streams if getattr(self, fn.__name__[1:]) is not None]
        t0 = time.monotonic()
        nxt = [t0] * len(streams)
        k = [0] * len(streams)
        end = t0 + duration_s
        while not (stop is not None and stop.is_set()):
            i = min(range(len(streams)), key=nxt.__getitem__) if streams else None
            if i is None or nxt[i] >= end:
                break
            delay = nxt[i] - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            streams[i][1](k[i], nxt[i] - t0)
            k[i] += 1
            nxt[i] = t0 + k[i] / streams[i][0]
        return self.sent

    def _gnss(self, k: int, t_s: float) -> None:
        now = time.time_ns()
        gps = now - self.gps_lag_ns
        lat, lon, _ = self.pose(t_s)
        alt = 1.5 + 0.01 * (k % 50)
        self.sent.fixes.append((now, (gps // 1_000_000) * 1_000_000, lat, lon, alt))
        self.gnss((gga(gps, lat, lon, alt) + "\r\n").encode())
        self.gnss((rmc(gps, lat, lon) + "\r\n").encode())
        if self.garbage_every and k % self.garbage_every == self.garbage_every - 1:
            bad = gga(gps, lat, lon, alt)[:-2] + "00"
            if bad == gga(gps, lat, lon, alt):
                bad = bad[:-2] + "01"
            self.sent.garbage.append(bad)
            self.gnss((bad + "\r\n").encode())

    def _compass(self, k: int, t_s: float) -> None:
        _, _, psi = self.pose(t_s)
        self.sent.headings.append((time.time_ns(), round(psi % 360.0, 3) % 360.0))
        self.compass((hdt(psi) + "\r\n").encode())

    def _thrust(self, k: int, t_s: float) -> None:
        left, right = round(20.0 + 10.0 * math.sin(0.5 * t_s), 4), float(k % 1000)
        now = time.time_ns()
        self.sent.thrust.append((now, left, right))
        msg = {"left": left, "right": right, "unit": "newton"}
        if self.thrust_time:
            msg["t"] = now / 1e9
        self.thrust(orjson.dumps(msg) + b"\n")


def main(argv=None) -> int:
    """``python -m usvlog.io.record.loopback``: stream the stand-in boat over UDP.

    Parameters
    ----------
    argv : list of str, optional
        Command line arguments (default: ``sys.argv[1:]``).

    Returns
    -------
    int
        Exit code (0).
    """
    ap = argparse.ArgumentParser(prog="python -m usvlog.io.record.loopback",
                                 description="stream a stand-in boat's NMEA and thrust messages over UDP")
    ap.add_argument("--gnss", help="udp://host:port for GGA+RMC")
    ap.add_argument("--compass", help="udp://host:port for HDT")
    ap.add_argument("--thrust", help="udp://host:port for JSON thrust lines")
    ap.add_argument("--duration-s", type=float, default=30.0)
    ap.add_argument("--gnss-hz", type=float, default=10.0)
    ap.add_argument("--compass-hz", type=float, default=20.0)
    ap.add_argument("--thrust-hz", type=float, default=100.0)
    a = ap.parse_args(argv)
    boat = LoopbackBoat(gnss=udp_target(a.gnss) if a.gnss else None,
                        compass=udp_target(a.compass) if a.compass else None,
                        thrust=udp_target(a.thrust) if a.thrust else None,
                        gnss_hz=a.gnss_hz, compass_hz=a.compass_hz, thrust_hz=a.thrust_hz)
    try:
        sent = boat.run(a.duration_s)
    except KeyboardInterrupt:
        sent = boat.sent
    print(f"sent {len(sent.fixes)} fixes (GGA+RMC), {len(sent.headings)} headings, {len(sent.thrust)} thrust")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
