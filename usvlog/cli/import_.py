"""``usvlog import``: a field log (CSV, NMEA, ROS bag, .bin, .ulg) -> canonical MCAP log."""

from __future__ import annotations

from ..choices import IMPORT_FORMATS, THRUST_UNITS
from .common import parse_pairs, print_json, stage


def register(sub) -> None:
    p = sub.add_parser("import", help="import a field log (CSV, NMEA, ROS 1/2 bag, ArduPilot .bin, PX4 .ulg)")
    p.add_argument("src", help="field log file (or ROS 2 bag directory)")
    p.add_argument("--out", required=True, help="output MCAP file")
    p.add_argument("--format", default="auto", choices=("auto",) + IMPORT_FORMATS,
                   help="input format (default: detected from the content)")
    p.add_argument("--vessel", default=None, help="vessel TOML (thruster map for non-newton commands)")
    p.add_argument("--column", action="append", default=[], metavar="ROLE=HEADER",
                   help="CSV: map a role (time_s, time_ms, time_us, time_ns: seconds, milliseconds, "
                        "microseconds, nanoseconds, since 1970 or, with --start-utc, since boot; time_iso, "
                        "lat_deg, lon_deg, alt_m, local_n, local_e: metres north and east, heading_deg, "
                        "heading_rad, thrust_left, thrust_right, yaw_rate_degps, yaw_rate_radps, speed_mps, "
                        "course_deg, thrust_left_dir, thrust_right_dir: direction flags, 0 forward and non-zero "
                        "reverse, or -1/+1) to a column; repeatable")
    p.add_argument("--topic", action="append", default=[], metavar="ROLE=SOURCE[.field.path[i]]",
                   help="map a role (gnss, heading, yaw_rate, thrust, thrust_left, thrust_right, velocity, "
                        "speed_mps, course; local: a pose whose x/y are metres; local_n, local_e: metres north "
                        "and east) to a topic/message and field path, as `usvlog inspect SOURCE` lists "
                        "them: /fix, /motors.left, /cmd.data[1], actuator_outputs.1.output[0], RCOU.C1, "
                        "/mocap.pose[0]; a scalar message needs no field; repeatable")
    p.add_argument("--msg-dir", action="append", default=[], metavar="DIR",
                   help="ROS bags without stored message definitions: every .msg file under DIR "
                        "(<pkg>/msg/<Name>.msg) defines the type <pkg>/msg/<Name>; repeatable")
    p.add_argument("--thrust-unit", choices=THRUST_UNITS, default=None,
                   help="unit of recorded thruster commands (default: guessed from the values)")
    p.add_argument("--thrust-range", default=None, metavar="LO:HI",
                   help="range of integer thrust commands (unit counts), e.g. --thrust-range=-255:255 or "
                        "0:200 (full scale: the larger magnitude; commands outside it are skipped and counted)")
    p.add_argument("--keep-dead", action="store_true",
                   help="write channels the health audit judges dead (a compass that never moves while the "
                        "track turns) as data; by default they go to /raw/... and are flagged")
    p.add_argument("--start-utc", default=None, metavar="ISO",
                   help="time of the first sample of a log with relative times (time columns, line stamps), "
                        "e.g. 2024-05-01T10:00:00Z")
    p.add_argument("--prefix-time", default=None, metavar="auto|FORMAT",
                   help="NMEA/text: use the time stamp a logger wrote before each sentence (auto: ISO 8601 or "
                        "seconds; or a strptime format such as '%%Y-%%m-%%d %%H:%%M:%%S.%%f'; none: never). "
                        "Default: only stamps that give their zone; sentence UTC (RMC/ZDA) otherwise")
    p.add_argument("--force", action="store_true",
                   help="overwrite an existing output; also write a log that keeps less than half of a sensor's "
                        "samples (exit 1 without it), flagged as unusable in its provenance")
    p.add_argument("--datum", default=None, metavar="LAT,LON",
                   help="origin of the local frame in degrees: positions in metres (an INS pose, odometry, "
                        "motion capture) are geo-referenced to it (default: they stay local, the view has no map)")
    p.add_argument("--json", action="store_true", help="print the import report as JSON")
    p.set_defaults(func=run)


def _print_mapping(report) -> None:
    stage(f"importing {report.source} as {report.format}")
    guessed = {k.split(" ", 1)[-1] for k in report.guesses if k.startswith(("column ", "topic "))}
    for role, src in report.mapping.items():
        why = report.guesses.get(f"reason {role}")
        stage(f"  {role:<16} <- {src}" + (f"   (guessed: {why})" if why else "   (guessed)" if role in guessed else ""))


def run(args) -> int:
    from .. import api  # light: the library's calls import what they use

    res = api.import_log(args.src, args.out, fmt=args.format, vessel=args.vessel or None,
                         columns=parse_pairs(args.column, "--column"), topics=parse_pairs(args.topic, "--topic"),
                         thrust_unit=args.thrust_unit, start_utc=args.start_utc, force=args.force,
                         on_mapping=_print_mapping, prefix_time=getattr(args, "prefix_time", None),
                         thrust_range=args.thrust_range, keep_dead=args.keep_dead,
                         msg_dirs=getattr(args, "msg_dir", None) or (), datum=args.datum)
    r = res.report
    if args.json:
        print_json(res.to_dict())
        return 0
    for k, v in r.guesses.items():
        if not k.startswith(("column ", "topic ", "reason ")):
            print(f"guessed   {k} = {v}")
    for note in r.notes:
        print(f"note      {note}")
    for topic, n in sorted(r.counts.items()):
        print(f"wrote     {topic:<20} {n:>9} samples")
    if r.skipped:
        print("skipped   " + ", ".join(f"{k} {v}" for k, v in sorted(r.skipped.items())))
        for k, w in r.first_bad.items():
            print(f"  first {k}: {w}")
    print(f"output    {res.out}")
    return 0
