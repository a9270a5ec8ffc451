"""``usvlog record``: live GNSS/compass (NMEA) and thrust (JSON lines) into a power-loss-safe log."""

from __future__ import annotations

import signal
import sys
import threading

from .common import print_json, stage


def register(sub) -> None:
    p = sub.add_parser("record",
                       help="record live GNSS/compass (NMEA) and thrust (JSON lines) to a power-loss-safe log",
                       description="Sources: serial:///dev/ttyUSB0?baud=4800, udp://0.0.0.0:10110 (listen), "
                                   "tcp://host:port (connect). GNSS and compass may share one URL. "
                                   "SIGINT/SIGTERM finish the file cleanly; a SIGKILL or power cut loses at most "
                                   "the last second.")
    p.add_argument("--out", required=True, help="output MCAP file (with rotation: OUT_000.mcap, OUT_001.mcap, ...)")
    p.add_argument("--gnss", metavar="SRC", help="NMEA 0183 GNSS source (GGA/RMC/GLL/ZDA)")
    p.add_argument("--compass", metavar="SRC", help="NMEA 0183 compass source (HDT/HDG/HDM)")
    p.add_argument("--thrust", metavar="SRC", help="JSON-lines source of thrust commands / controller state")
    p.add_argument("--vessel", default=None, help="vessel TOML stored in the log")
    rot = p.add_mutually_exclusive_group()
    rot.add_argument("--rotate-mb", type=float, default=None, metavar="N", help="start a new file every N MB")
    rot.add_argument("--rotate-min", type=float, default=None, metavar="N", help="start a new file every N minutes")
    p.add_argument("--duration-s", type=float, default=None, metavar="S", help="stop after S seconds")
    p.add_argument("--flush-s", type=float, default=1.0, help="flush+fsync interval (default 1 s)")
    p.add_argument("--force", action="store_true", help="overwrite existing outputs")
    p.add_argument("--json", action="store_true", help="print a JSON summary on stdout at the end")
    p.set_defaults(func=run)


def run(args) -> int:
    """Open the sources and start reading them, then import the recorder and record.

    The sockets (and serial port) are opened and their reader threads started with
    only the standard library loaded, so what arrives while numpy, pandas and the
    MCAP writer import (about a second) waits in each source's backlog with the time
    it was read (see :mod:`usvlog.io.record.sources`), instead of being lost.
    """
    # light: standard library only, so the sockets are bound before the heavy imports below
    from ..io.record.sources import open_sources, shutdown

    stop = threading.Event()

    def _stop(signum, frame):
        stop.set()

    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, _stop)
    sources = open_sources(args.gnss, args.compass, args.thrust)
    for s in sources:
        s.start()
    try:
        # heavy: numpy, pandas and the MCAP writer, imported while the sources read
        from ..io.config import load_vessel
        from ..io.record import record

        vessel = load_vessel(args.vessel) if args.vessel else None
    except BaseException:
        shutdown(sources)
        raise
    tty = sys.stderr.isatty()
    state = {"n": 0}

    def on_status(st):
        state["n"] += 1
        if tty:
            print("\r" + st.line()[:200].ljust(120), end="", file=sys.stderr, flush=True)
        elif state["n"] % 10 == 1:
            print(st.line(), file=sys.stderr, flush=True)

    try:
        summary = record(args.out, gnss=args.gnss, compass=args.compass, thrust=args.thrust, vessel=vessel,
                         rotate_mb=args.rotate_mb, rotate_min=args.rotate_min, duration_s=args.duration_s,
                         force=args.force, flush_s=args.flush_s, stop=stop, on_status=on_status, sources=sources)
    finally:
        if tty:
            print(file=sys.stderr)
    stage(summary.status.line())
    stage(f"wrote {', '.join(summary.files)} ({summary.stopped_by})")
    for name, err in summary.source_errors.items():
        stage(f"source {name}: {err}")
    if args.json:
        print_json(summary.to_dict())
    return 0
