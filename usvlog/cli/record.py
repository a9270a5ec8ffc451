"""``usvlog record``: live GNSS/compass (NMEA) and thrust (JSON lines) into a power-loss-safe log."""

from __future__ import annotations

import os
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
    p.add_argument("--view", nargs="?", const="spawn", default=None, metavar="spawn|ADDRESS",
                   help="stream to a Rerun viewer while recording: 'spawn' (default) starts one, or the address of "
                        "a running one (rerun+http://HOST:PORT/proxy, HOST:PORT); the recording is unaffected if "
                        "the viewer goes away")
    p.add_argument("--view-bind", default="127.0.0.1", metavar="HOST",
                   help="address the spawned viewer listens on (default 127.0.0.1)")
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
    live = None
    if args.view:
        try:
            live = _live_view(args, vessel, tty)
        except BaseException:   # a bad --view address: exit 2 before recording
            shutdown(sources)
            raise

    def on_status(st):
        state["n"] += 1
        if tty:
            print("\r" + st.line()[:200].ljust(120), end="", file=sys.stderr, flush=True)
        elif state["n"] % 10 == 1:
            print(st.line(), file=sys.stderr, flush=True)

    try:
        summary = record(args.out, gnss=args.gnss, compass=args.compass, thrust=args.thrust, vessel=vessel,
                         rotate_mb=args.rotate_mb, rotate_min=args.rotate_min, duration_s=args.duration_s,
                         force=args.force, flush_s=args.flush_s, stop=stop, on_status=on_status, sources=sources,
                         subscribers=[] if live is None else [(live, live.topics)])
    finally:
        if live is not None:
            live.close()
        if tty:
            print(file=sys.stderr)
    stage(summary.status.line())
    stage(f"wrote {', '.join(summary.files)} ({summary.stopped_by})")
    for name, err in summary.source_errors.items():
        stage(f"source {name}: {err}")
    out = summary.to_dict()
    if live is not None:
        v = out["view"] = live.summary()
        stage(f"live view {v['url']}: {v['received']} messages received, {v['dropped']} dropped"
              + ("; stopped early (see above)" if v["error"] else ""))
    if args.json:
        print_json(out)
    return 0


def _live_view(args, vessel, tty: bool):
    """The live view (``--view``), started; a viewer that fails is reported once, the recording goes on."""
    from pathlib import Path  # only for the recording's name

    # the SDK's own log lines about a lost connection would repeat what the view reports once
    os.environ.setdefault("RUST_LOG", "warn,re_grpc_client=off,re_sdk=off")
    # heavy: rerun and the online filter, only with --view
    from ..view.live import LiveView

    def on_error(msg):
        stage(("\n" if tty else "") + msg)

    return LiveView(args.view, bind=args.view_bind, name=Path(args.out).name, vessel=vessel,
                    on_error=on_error).start()
