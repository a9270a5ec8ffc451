"""``usvlog view``: logs -> a Rerun .rrd (blueprint inside); optionally open or serve it."""

from __future__ import annotations

from ..errors import ConfigError, InputError
from .common import stage


def register(sub) -> None:
    p = sub.add_parser("view", help="visualise logs in Rerun: write an .rrd, optionally open or serve it")
    p.add_argument("logs", nargs="+", metavar="LOG", help="canonical MCAP log(s); several are overlaid")
    p.add_argument("--out", default=None, help="output .rrd (default: <first log>.rrd next to it)")
    p.add_argument("--name", action="append", default=None,
                   help="name of each log in the viewer (repeat; default: the file names)")
    p.add_argument("--spawn", action="store_true",
                   help="open the native Rerun viewer on the result (needs a display; binds --host)")
    p.add_argument("--serve", action="store_true",
                   help="serve the result to a browser viewer (blocks; Ctrl-C, SIGTERM or SIGHUP stop the server)")
    p.add_argument("--host", default="127.0.0.1",
                   help="address the viewer and the server bind (default 127.0.0.1)")
    p.add_argument("--port", type=int, default=None, help="web viewer HTTP port for --serve (default 9090)")
    p.add_argument("--grpc-port", type=int, default=None,
                   help="port of the data server (--serve) or of the native viewer (--spawn) (default 9876)")
    p.add_argument("--force", action="store_true", help="overwrite an existing output")
    p.set_defaults(func=run)


def run(args) -> int:
    from .. import api  # heavy: imported only when the verb runs (rerun only when a recording is made)

    if args.name is not None and len(args.name) != len(args.logs):
        raise InputError(f"--name given {len(args.name)} times for {len(args.logs)} logs")
    for opt, port in (("--port", args.port), ("--grpc-port", args.grpc_port)):
        if port is not None and not 1 <= port <= 65535:
            raise ConfigError(f"{opt} {port}: not a TCP port (1 to 65535)")
    out = api.to_rrd(args.logs, args.out or None, names=args.name, force=args.force, progress=stage)
    print(out)
    if args.spawn or args.serve:
        from ..view import rrd as viz  # heavy: rerun

        if args.spawn and viz.display_missing():  # one line: the file and how to open it elsewhere
            raise ConfigError(viz.no_display_message(out))
        if args.spawn:
            stage(f"opening the Rerun viewer (bound to {args.host})")
            viz.spawn_viewer(out, host=args.host, grpc_port=None if args.serve else args.grpc_port)
        if args.serve:
            stage(f"serving {out} on {args.host} (Ctrl-C to stop)")
            return viz.serve(out, host=args.host, port=args.port, grpc_port=args.grpc_port)
    return 0
