"""CSV logs: one header row, columns mapped to roles, read in chunks.

Rows from merged loggers often fill only some columns: an empty cell means "no
sample of that stream at this time", never zero. A GNSS fix needs both latitude and
longitude in the row, a thrust sample both commands. Malformed rows (wrong field
count), unparseable cells and bad times are skipped and counted. This module finds the
header, the mapping and the guesses and reads the file in chunks;
:mod:`usvlog.io.importers.csvrows` turns each chunk of rows into role streams.

Time: ``time_ns`` (ns since the epoch), ``time_s``, ``time_ms``, ``time_us`` (seconds,
milliseconds, microseconds; since the epoch when the values are > 1e8 s, else relative
-- since boot or the start: ``--start-utc`` is then the time of the first row's sample,
else they count from the Unix epoch) or ``time_iso`` (ISO 8601 text). Roles are guessed
from obvious headers when not given.

Decided from the first :data:`SAMPLE_ROWS` rows (each decision, with why, in the
report's guesses; :mod:`usvlog.io.importers.infer`): the time column, when none is
given, among the headers that name a time -- it must be monotonic (a garbled one is
rejected with the reason) and its magnitude and step give its unit and base; degrees
or radians of a heading whose name does not say (``yaw``, ``heading``); rad/s or deg/s
of a yaw rate from its scale against d(heading)/dt; GNSS positions held between
updates on a resampled grid (:mod:`usvlog.io.importers.held`: one row kept per real
update, the repeats counted as ``gnss_held_repeat``). A gzip-compressed file is read
as it is.
"""

from __future__ import annotations

import gzip
import math
import re
import warnings
from collections.abc import Iterator

import numpy as np
import pandas as pd

from ...errors import InputError
from .catalog import Catalog, FieldInfo, TopicInfo
from .core import ImportReport, listing
from .csvrows import ROLE_NS, TIME_ROLES, VALUE_ROLES, Chunker, datetimes_ns, times_ns
from .held import Held, detect_held
from .infer import TimeVerdict, angle_unit, judge_time, rate_scale
from .probe import Series, course_agreement
from .sniff import check_gzip

# role -> normalized header names that mean it
GUESSES: dict[str, tuple[str, ...]] = {
    "time_ns": ("t_ns", "time_ns", "timestamp_ns", "stamp_ns", "log_time_ns"),
    "time_ms": ("time_ms", "t_ms", "timestamp_ms", "timems", "time_boot_ms", "epoch_ms"),
    "time_us": ("time_us", "t_us", "timestamp_us", "timeus", "time_boot_us", "epoch_us"),
    "time_s": ("time_s", "t_s", "time", "t", "timestamp", "seconds", "sec", "elapsed_s", "time_sec",
               "timestamp_s", "unix_time", "epoch_s"),
    "time_iso": ("utc", "datetime", "date_time", "time_utc", "iso_time"),
    "lat_deg": ("lat_deg", "lat", "latitude", "latitude_deg", "gps_lat", "gnss_lat"),
    "lon_deg": ("lon_deg", "lon", "lng", "long", "longitude", "longitude_deg", "gps_lon", "gnss_lon"),
    "alt_m": ("alt_m", "alt", "altitude", "altitude_m", "gps_alt"),
    "heading_deg": ("heading_deg", "heading", "hdg", "compass", "compass_deg", "yaw_deg", "heading_true_deg",
                    "yaw"),
    "heading_rad": ("heading_rad", "yaw_rad", "psi_rad", "psi"),
    "thrust_left": ("thrust_left", "left", "left_thrust", "thrust_left_n", "port", "motor_left", "thr_left",
                    "cmd_left", "left_cmd", "pwm_left", "left_pwm", "thruster_left", "left_n"),
    "thrust_right": ("thrust_right", "right", "right_thrust", "thrust_right_n", "starboard", "stbd",
                     "motor_right", "thr_right", "cmd_right", "right_cmd", "pwm_right", "right_pwm",
                     "thruster_right", "right_n"),
    "thrust_left_dir": ("thrust_left_dir", "left_dir", "dir_left", "left_direction", "direction_left"),
    "thrust_right_dir": ("thrust_right_dir", "right_dir", "dir_right", "right_direction", "direction_right"),
    "yaw_rate_degps": ("yaw_rate_degps", "yaw_rate", "gyro_z", "r_degps", "yaw_rate_deg_s", "rot_degps"),
    "yaw_rate_radps": ("yaw_rate_radps", "r_radps", "gyro_z_radps"),
    "local_n": ("local_n", "north_m", "n_m", "pos_n", "north", "position_north", "x_north"),
    "local_e": ("local_e", "east_m", "e_m", "pos_e", "east", "position_east", "y_east"),
    "local_x": ("x", "x_m", "pos_x", "position_x", "local_x"),
    "local_y": ("y", "y_m", "pos_y", "position_y", "local_y"),
    "speed_mps": ("speed_mps", "speed", "sog", "sog_mps", "ground_speed"),
    "course_deg": ("course_deg", "course", "cog", "cog_deg"),
}
def normalize_header(h: str) -> str:
    """A header as the role guesses compare it: lower case, runs of other characters -> ``_``.

    ``" Heading (deg)"`` -> ``"heading_deg"``; leading and trailing ``_`` are dropped.
    """
    s = re.sub(r"[^0-9a-z]+", "_", str(h).strip().lower())
    return s.strip("_")


def looks_like_csv(text: str) -> bool:
    """Whether the start of a file reads as CSV with a header row.

    Looks at the first 20 non-blank lines: the first has a separator (``,``, ``;`` or
    tab, see :func:`sniff_sep`) and a letter, and at most one later line in ten (at least
    one, when there are three or more rows) has more separators than it (of three or more
    lines the last is not checked: it may be cut mid-way).

    Parameters
    ----------
    text : str
        The file's first bytes, decoded.
    """
    lines = [ln for ln in text.splitlines()[:20] if ln.strip()]
    if len(lines) < 1:
        return False
    sep = sniff_sep(lines[0])
    if sep is None:
        return False
    n = lines[0].count(sep)
    if n < 1:
        return False
    body = lines[1:-1] if len(lines) > 2 else lines[1:]  # the last line may be cut mid-way
    over = sum(1 for ln in body if ln.count(sep) > n)   # one malformed row does not make it "not CSV"
    return over <= max(1, len(body) // 10) and (over == 0 or len(body) >= 3) and any(c.isalpha() for c in lines[0])


def sniff_sep(header_line: str) -> str | None:
    """The field separator of a header line: the most frequent of ``,``, ``;`` and tab.

    Returns None when the line has none of them (ties go to ``,``, then ``;``).
    """
    counts = {s: header_line.count(s) for s in (",", ";", "\t")}
    sep, n = max(counts.items(), key=lambda kv: kv[1])
    return sep if n > 0 else None


def guess_mapping(headers: list[str], given: dict) -> tuple[dict, dict]:
    """(mapping role -> header, guesses role -> header) from the given roles and the headers."""
    norm = {normalize_header(h): h for h in headers}
    mapping = dict(given)
    guessed = {}
    used = set(given.values())
    for role, names in GUESSES.items():
        if role in mapping:
            continue
        if role.startswith("time") and any(r.startswith("time") for r in mapping):
            continue
        for nm in names:
            h = norm.get(nm)
            if h is not None and h not in used:
                mapping[role] = guessed[role] = h
                used.add(h)
                break
    if "heading_rad" in mapping and "heading_deg" in mapping and "heading_deg" in guessed:
        del mapping["heading_deg"], guessed["heading_deg"]
    if "yaw_rate_radps" in mapping and "yaw_rate_degps" in guessed:
        del mapping["yaw_rate_degps"], guessed["yaw_rate_degps"]
    return mapping, guessed


def _parser_message(err: BaseException) -> str:
    """The first line of a pandas parser error (its messages can span lines)."""
    lines = str(err).strip().splitlines()
    return lines[0] if lines else type(err).__name__


def _header(p, opts) -> tuple[str, str, list[str]]:
    """(header line, separator, column names) of a CSV file; every ``--column`` must name one.

    Raises
    ------
    InputError
        The file cannot be read, has no header row, pandas cannot parse the header, or a
        ``--column`` names a column that is not in it.
    """
    try:
        with _open_text(p) as fh:
            header_line = fh.readline()
    except OSError as err:
        raise InputError(f"{p}: cannot read ({err})") from err
    if not header_line.strip():
        raise InputError(f"{p}: empty file (no header row)")
    sep = sniff_sep(header_line) or ","
    try:
        headers = list(pd.read_csv(p, nrows=0, sep=sep, encoding_errors="replace",
                                   compression=compression(p)).columns)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, ValueError) as err:
        raise InputError(f"{p} line 1: not a CSV header ({_parser_message(err)})") from err
    missing = {r: h for r, h in opts.columns.items() if h not in headers}
    if missing:
        r, h = next(iter(missing.items()))
        raise InputError(f"{p}: column {h!r} for role {r} is not in the header (columns: {listing(headers)})")
    return header_line, sep, headers


# -- decisions from the first rows -------------------------------------------------------------
SAMPLE_ROWS = 20_000
"""Rows read first to decide the time column, angle and rate units and held GNSS values."""
_TIME_TOKENS = frozenset(("time", "times", "timestamp", "stamp", "date", "datetime", "utc", "epoch",
                          "elapsed", "boot", "clock", "tow", "millis", "micros", "nanos", "sec", "secs",
                          "seconds", "timeus", "timems", "timens"))
_TIME_NAMES = tuple(n for r in ("time_ns", "time_ms", "time_us", "time_s", "time_iso") for n in GUESSES[r])
_UNITLESS_HEADING = {"yaw": "deg", "heading": "deg", "hdg": "deg", "compass": "deg", "psi": "rad",
                     "theta": "rad"}
_UNIT_ROLE = {"s": "time_s", "ms": "time_ms", "us": "time_us", "ns": "time_ns"}


def time_like(header: str) -> bool:
    """Whether a header names a time (``Unix Timestamp``, ``original_timestamp``, ``TimeUS``, ``Date``;
    ``t`` alone or with a unit, not ``t_water``)."""
    n = normalize_header(header)
    return n in _TIME_NAMES or any(tok in _TIME_TOKENS for tok in n.split("_"))


def _sample(p, sep: str, headers: list[str]) -> pd.DataFrame:
    """The first :data:`SAMPLE_ROWS` rows of the columns ``headers`` (bad rows left out)."""
    if not headers:
        return pd.DataFrame()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", pd.errors.ParserWarning)
            return pd.read_csv(p, sep=sep, nrows=SAMPLE_ROWS, usecols=headers, keep_default_na=False,
                               na_values=[""], on_bad_lines="skip", encoding_errors="replace",
                               compression=compression(p))
    except (pd.errors.ParserError, pd.errors.EmptyDataError, ValueError) as err:
        raise InputError(f"{p}: {_parser_message(err)}") from err


def _time_values(col: pd.Series) -> tuple[np.ndarray | None, bool]:
    """(values, ISO text?) of a candidate time column: numbers, or ISO 8601 text as ns since 1970;
    (None, False) when fewer than 90 % of its non-empty cells are either."""
    filled = max(1, int(col.notna().sum()))
    num = col if pd.api.types.is_numeric_dtype(col.dtype) else pd.to_numeric(col, errors="coerce")
    if num.notna().sum() >= 0.9 * filled:
        return num.to_numpy(dtype=float, na_value=np.nan), False
    ts = pd.to_datetime(col.astype("str"), format="ISO8601", utc=True, errors="coerce")
    if ts.notna().sum() >= 0.9 * filled:
        ns = datetimes_ns(ts.dt.tz_localize(None).to_numpy()).astype(float)
        return np.where(ns >= 0, ns, np.nan), True
    return None, False


def _choose_time(sample: pd.DataFrame, mapping: dict, guessed: dict, report, state: dict) -> None:
    """Pick the time column from the data (monotonic; unit from magnitude and step): updates
    ``mapping``/``guessed``, the report's reasons, and ``state`` (relative or not)."""
    cands = [h for h in sample.columns if time_like(h)]
    old = next(((r, mapping[r]) for r in TIME_ROLES if r in mapping), None)
    verdicts: dict[str, TimeVerdict] = {}
    for h in cands:
        v, text = _time_values(sample[h])
        verdicts[h] = (judge_time(v, normalize_header(h), text=text) if v is not None else
                       TimeVerdict(False, None, False, None, "neither numbers nor ISO 8601 times"))
    rejected = [f"{h!r}: {vd.why}" for h, vd in verdicts.items() if not vd.ok]
    if rejected:
        report.guesses["time_rejected"] = "; ".join(rejected)
    ok = [h for h, vd in verdicts.items() if vd.ok]
    if not ok:
        if old is not None:
            report.note(f"no time column is monotonic: {old[1]!r} taken because of its name "
                        f"({verdicts.get(old[1], TimeVerdict(False, None, False, None, '')).why or 'not judged'})")
        return
    for r in TIME_ROLES:
        mapping.pop(r, None)
        guessed.pop(r, None)
    names = [normalize_header(h) for h in ok]

    def rank(i: int) -> tuple:
        n = names[i]
        return (not verdicts[ok[i]].epoch, _TIME_NAMES.index(n) if n in _TIME_NAMES else len(_TIME_NAMES), i)

    h = ok[min(range(len(ok)), key=rank)]
    vd = verdicts[h]
    role = "time_iso" if vd.unit == "ns" and _time_values(sample[h])[1] else _UNIT_ROLE[vd.unit]
    mapping[role] = guessed[role] = h
    if role != "time_iso":
        state["relative"] = not vd.epoch
    report.guesses[f"reason {role}"] = vd.why
    report.guesses["time_column"] = f"{h!r}: {vd.why}"


def _sample_seconds(col: pd.Series, role: str) -> np.ndarray:
    """Times of the sample rows in s (on the column's own base; NaN where unusable)."""
    if role == "time_iso":
        v, _ = _time_values(col)
        return np.full(len(col), np.nan) if v is None else v / 1e9
    v = pd.to_numeric(col, errors="coerce").to_numpy(dtype=float, na_value=np.nan)
    return v * (ROLE_NS[role] / 1e9)


def _num(sample: pd.DataFrame, header: str) -> np.ndarray:
    return pd.to_numeric(sample[header], errors="coerce").to_numpy(dtype=float, na_value=np.nan)


def _heading_unit(sample: pd.DataFrame, mapping: dict, guessed: dict, report) -> None:
    """Degrees or radians of a guessed heading column whose name does not say (``yaw``, ``heading``)."""
    role = next((r for r in ("heading_deg", "heading_rad") if r in guessed), None)
    if role is None or normalize_header(mapping[role]) not in _UNITLESS_HEADING:
        return
    h = mapping[role]
    unit, why = angle_unit(_num(sample, h), _UNITLESS_HEADING[normalize_header(h)])
    new = f"heading_{unit}"
    if new != role:
        del mapping[role], guessed[role]
        mapping[new] = guessed[new] = h
    report.guesses["heading_unit"] = f"{h!r} in {unit}: {why}"
    report.guesses[f"reason {new}"] = f"{unit}: {why}"


def _yaw_rate_unit(sample: pd.DataFrame, t_s: np.ndarray, mapping: dict, guessed: dict, report) -> None:
    """rad/s or deg/s of a guessed yaw-rate column, from its scale against d(heading)/dt."""
    role = next((r for r in ("yaw_rate_degps", "yaw_rate_radps") if r in guessed), None)
    if role is None:
        return
    h = mapping[role]
    hr = next((r for r in ("heading_rad", "heading_deg") if r in mapping), None)
    fit = None
    if hr is not None:
        psi = _num(sample, mapping[hr]) * (1.0 if hr == "heading_rad" else np.pi / 180.0)
        r = _num(sample, h)
        mh, mr = np.isfinite(psi) & np.isfinite(t_s), np.isfinite(r) & np.isfinite(t_s)
        fit = rate_scale(t_s[mh], psi[mh], t_s[mr], r[mr])
    if fit is None:
        unit = "deg/s" if role == "yaw_rate_degps" else "rad/s"
        why = ("no heading to compare against" if hr is None else
               "the heading does not turn enough to compare against") + ": the name's unit"
        report.guesses["yaw_rate_unit"] = f"{h!r} in {unit} ({why})"
        return
    k, corr = fit
    new = "yaw_rate_radps" if abs(math.log(abs(k))) < abs(math.log(abs(k) / (180.0 / math.pi))) else "yaw_rate_degps"
    if new != role:
        del mapping[role], guessed[role]
        mapping[new] = guessed[new] = h
    unit = "rad/s" if new == "yaw_rate_radps" else "deg/s"
    why = (f"scale {k:.3g} against d(heading)/dt (correlation {corr:.2f}; 1 is rad/s, 57.3 deg/s)"
           + ("; its sign is opposite to the heading's" if k < 0 else ""))
    report.guesses["yaw_rate_unit"] = f"{h!r} in {unit}: {why}"
    report.guesses[f"reason {new}"] = f"{unit}: {why}"


def _held(sample: pd.DataFrame, t_s: np.ndarray, mapping: dict, report) -> Held | None:
    """Sample-and-hold GNSS positions in the first rows (:func:`usvlog.io.importers.held.detect_held`)."""
    if "lat_deg" not in mapping or "lon_deg" not in mapping:
        return None
    lat, lon = _num(sample, mapping["lat_deg"]), _num(sample, mapping["lon_deg"])
    m = np.isfinite(lat) & np.isfinite(lon) & np.isfinite(t_s) & (np.abs(t_s) < 9e9)   # a time in int64 ns
    held = detect_held(np.round(t_s[m] * 1e9).astype(np.int64), lat[m], lon[m])
    if held is not None:
        report.guesses["gnss_held"] = held.describe()
        report.guesses["gnss_rate_hz"] = round(held.rate_hz, 3)
    return held


def _decide(p, sep: str, headers: list[str], mapping: dict, guessed: dict, opts, report
            ) -> tuple[dict, Held | None]:
    """What the first rows decide: the time column and its unit (unless given), the units of
    guessed heading and yaw-rate columns, and held GNSS values. Updates ``mapping`` and
    ``guessed``; returns (the time state for :class:`Chunker`, the held GNSS stream or None)."""
    state: dict = {}
    given_time = any(r in opts.columns for r in TIME_ROLES)
    want = {h for h in headers if not given_time and time_like(h)}
    want |= {mapping[r] for r in ("lat_deg", "lon_deg", "heading_deg", "heading_rad", "yaw_rate_degps",
                                  "yaw_rate_radps", "local_x", "local_y") + TIME_ROLES if r in mapping}
    sample = _sample(p, sep, [h for h in headers if h in want])
    if not given_time:
        _choose_time(sample, mapping, guessed, report, state)
    _heading_unit(sample, mapping, guessed, report)
    time_role = next((r for r in TIME_ROLES if r in mapping), None)
    t_s = _sample_seconds(sample[mapping[time_role]], time_role) if time_role is not None and len(sample) else None
    _local_axes(sample, t_s, mapping, guessed, report)
    if t_s is None:
        return state, None
    _yaw_rate_unit(sample, t_s, mapping, guessed, report)
    return state, _held(sample, t_s, mapping, report)


def _local_axes(sample: pd.DataFrame, t_s, mapping: dict, guessed: dict, report) -> None:
    """Columns named only x/y (positions in metres, no latitude/longitude, no north/east columns):
    which is north. With a heading, the convention whose course over ground agrees with it
    (x north or x east); without one, x east and y north (the plotting and ROS convention), said so."""
    xy = [r for r in ("local_x", "local_y") if r in mapping]
    for r in xy:
        h = mapping.pop(r)
        guessed.pop(r, None)
        if len(xy) < 2 or "lat_deg" in mapping or "local_n" in mapping or "local_e" in mapping:
            continue
        mapping.setdefault("_" + r, h)
    if "_local_x" not in mapping:
        return
    x, y = mapping.pop("_local_x"), mapping.pop("_local_y")
    agree = {}
    hd = next((r for r in ("heading_deg", "heading_rad") if r in mapping), None)
    if hd is not None and t_s is not None and len(sample):
        t = np.round(np.nan_to_num(np.asarray(t_s, float)) * 1e9).astype(np.int64)
        hv = pd.to_numeric(sample[mapping[hd]], errors="coerce").to_numpy(float)
        xs = pd.to_numeric(sample[x], errors="coerce").to_numpy(float)
        ys = pd.to_numeric(sample[y], errors="coerce").to_numpy(float)
        unit = "deg" if hd == "heading_deg" else "rad"
        for name, (n, e) in (("x north, y east", (xs, ys)), ("x east, y north", (ys, xs))):
            agree[name] = course_agreement(Series(t, hv), unit, t, n, e)
    known = {k: v for k, v in agree.items() if v is not None}
    best = max(known, key=lambda k: known[k]) if known else None
    other = min(known, key=lambda k: known[k]) if known else None
    if best is not None and known[best] >= 0.5 and known[best] - known[other] >= 0.2:
        why = (f"{best}: the heading agrees with the course over ground {100 * known[best]:.0f} % of the time "
               f"({100 * known[other]:.0f} % the other way)")
    else:
        best, why = "x east, y north", ("x east, y north assumed (no heading decides it; give --column "
                                        "local_n=... --column local_e=... to say)")
    mapping["local_n"], mapping["local_e"] = (x, y) if best == "x north, y east" else (y, x)
    guessed["local_n"], guessed["local_e"] = mapping["local_n"], mapping["local_e"]
    report.guesses["local_frame"] = why


def compression(p) -> str | None:
    """``"gzip"`` for a gzip-compressed file (from its magic bytes, not its name), else None."""
    return "gzip" if check_gzip(p) else None


def _open_text(p):
    """The file as text (undecodable bytes replaced), gunzipped when it is gzip-compressed."""
    if compression(p) == "gzip":
        return gzip.open(p, "rt", encoding="utf-8", errors="replace", newline="")
    return open(p, encoding="utf-8", errors="replace", newline="")


def read(path, opts, report, *, fmt="csv", on_mapping=None) -> Iterator[dict]:
    """Batches of role streams from a CSV file (see :mod:`usvlog.io.importers.core`).

    Parameters
    ----------
    path : pathlib.Path
        The CSV file.
    opts : usvlog.io.importers.ImportOptions
        Column roles, thrust unit, start time (ns) for relative times, rows per chunk.
    report : usvlog.io.importers.core.ImportReport
        Filled with records read, skipped rows by reason, the mapping and the guesses.
    fmt : str
        Unused (one signature for every reader).
    on_mapping : callable, optional
        Called with ``report`` once the column mapping is known.

    Raises
    ------
    InputError
        No header, no time column, no usable column, a role mapped to a missing
        column, or a file pandas' parser cannot read (``from`` its error).
    """
    p = path
    header_line, sep, headers = _header(p, opts)
    mapping, guessed = guess_mapping(headers, opts.columns)
    state, held = _decide(p, sep, headers, mapping, guessed, opts, report)
    report.mapping.update(mapping)
    report.guesses.update({f"column {k}": v for k, v in guessed.items()})
    time_role = next((r for r in TIME_ROLES if r in mapping), None)
    if time_role is None:
        raise InputError(f"{p}: no time column found (give --column time_s=HEADER, or time_ms, time_us, "
                         f"time_ns, time_iso; columns: "
                         f"{listing(headers)})")
    for a, b in (("lat_deg", "lon_deg"), ("thrust_left", "thrust_right"), ("local_n", "local_e")):
        if (a in mapping) != (b in mapping):
            have, miss = (a, b) if a in mapping else (b, a)
            raise InputError(f"{p}: column {mapping[have]!r} ({have}) has no {miss} column to pair with "
                             f"(give --column {miss}=HEADER; columns: {listing(headers)})")
    if not any(r in mapping for r in VALUE_ROLES):
        raise InputError(f"{p}: no column maps to a role (give --column ROLE=HEADER; columns: "
                         f"{listing(headers)})")
    if on_mapping is not None:
        on_mapping(report)
    chunker = Chunker(mapping, time_role, opts, report, state=state, held=held)
    short, n_lines = short_rows(p, sep, header_line.count(sep))
    cut = [k for k in short if k == n_lines - 1]   # the last row of a file cut mid-way
    if cut:
        report.skip("csv_truncated_row", 1, where=f"line {cut[0] + 1}: the file ends inside this row")
    body = [k for k in short if k != n_lines - 1]
    if body:
        report.skip("csv_malformed_row", len(body), where=f"line {body[0] + 1}: fewer fields than the header")
    line0 = 2
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", pd.errors.ParserWarning)
        for chunk in _chunks(p, sep, opts.chunk_rows, skip=short):
            report.records += len(chunk)
            _count_malformed(caught, report)
            batch = chunker.batch(chunk, line0)
            line0 += len(chunk)
            yield batch
        _count_malformed(caught, report)


def short_rows(path, sep: str, n_sep: int, block: int = 1 << 22) -> tuple[list[int], int]:
    """(0-based line numbers of the non-blank rows with fewer separators than the header, lines in the file).

    pandas fills a row that lacks cells with empty ones, so a row missing its first cell
    would shift every value into the wrong column; such rows are skipped and counted
    instead (rows with too many cells pandas drops itself). Read in blocks with numpy
    (memory stays flat). A file with quotes is not checked (a quoted separator would
    count).

    Parameters
    ----------
    path : path-like
        The CSV file.
    sep : str
        The one-character separator.
    n_sep : int
        Separators in the header row.
    block : int
        Bytes read at a time.
    """
    out: list[int] = []
    sepb, line, carry = ord(sep), 0, b""
    with (gzip.open(path, "rb") if compression(path) else open(path, "rb")) as fh:
        while True:
            buf = fh.read(block)
            data = carry + buf if carry else buf
            if not buf:
                if not carry:
                    break
                data = carry + b"\n"
            if b'"' in data:
                return [], 0
            a = np.frombuffer(data, np.uint8)
            nl = np.flatnonzero(a == 10)
            if len(nl) == 0:
                carry = data
                continue
            seps = np.searchsorted(np.flatnonzero(a == sepb), nl)   # separators before each line end
            per = np.diff(seps, prepend=0)
            length = np.diff(nl, prepend=-1) - 1
            blank = (length == 0) | ((length == 1) & (a[np.maximum(nl - 1, 0)] == 13))
            bad = np.flatnonzero((per < n_sep) & ~blank)
            out.extend(int(line + k) for k in bad if line + k > 0)
            line += len(nl)
            carry = data[int(nl[-1]) + 1:]
            if not buf:
                break
    return out, line


def _chunks(p, sep: str, chunk_rows: int, skip=()) -> Iterator[pd.DataFrame]:
    """pandas' chunked reader; its parser errors become one-line InputErrors naming the file."""
    try:
        reader = pd.read_csv(p, sep=sep, chunksize=chunk_rows, keep_default_na=False, na_values=[""],
                             skiprows=list(skip) or None, compression=compression(p),
                             on_bad_lines="warn", encoding_errors="replace", skip_blank_lines=False,
                             low_memory=True)
        yield from reader   # usvlog's work on each chunk runs in the caller, outside this try
    except pd.errors.EmptyDataError as err:
        raise InputError(f"{p}: empty file (no rows)") from err
    except pd.errors.ParserError as err:
        raise InputError(f"{p}: {_parser_message(err)}") from err


def _count_malformed(caught: list, report) -> None:
    """Rows pandas skipped for a wrong field count (its ParserWarnings), counted once each."""
    for w in caught:
        msg = str(w.message)
        k = msg.count("Skipping line")
        if k:
            m = re.search(r"Skipping line (\d+)", msg)
            report.skip("csv_malformed_row", k, where=f"line {m.group(1)}: wrong number of fields")
    caught.clear()


# role -> canonical stream it feeds (for the catalog's mapping)
_ROLE_STREAM = {"lat_deg": "gnss", "lon_deg": "gnss", "alt_m": "gnss", "heading_deg": "heading",
                "heading_rad": "heading", "thrust_left": "thrust", "thrust_right": "thrust",
                "yaw_rate_degps": "yaw_rate", "yaw_rate_radps": "yaw_rate", "speed_mps": "velocity",
                "course_deg": "velocity", "local_n": "local", "local_e": "local"}


def catalog(path, opts) -> Catalog:
    """What a CSV log holds: one topic (the file) whose fields are its columns.

    Parameters
    ----------
    path : path-like
        The CSV file.
    opts : usvlog.io.importers.ImportOptions
        ``columns`` (role -> header) given by the user; the rest is guessed as :func:`read`
        does.

    Returns
    -------
    Catalog
        One topic named after the file (type ``csv``), its row count and time span (ns on
        the time column's base: since the Unix epoch, or since the first row for relative
        seconds), one field per column with its type (``float``, ``int``, ``text``,
        ``empty``) and first non-empty value; ``mapping`` role -> column (each role the
        importer uses, with why: given, or the header's common name); ``time_base`` ``utc``
        or ``relative``.

    Raises
    ------
    InputError
        No header row, or a column given in ``opts.columns`` that is not in the header.
    """
    from pathlib import Path  # only the catalog needs it

    p = Path(path)
    _, sep, headers = _header(p, opts)
    mapping, guessed = guess_mapping(headers, opts.columns)
    decided = ImportReport()
    state, _ = _decide(p, sep, headers, mapping, guessed, opts, decided)
    time_role = next((r for r in TIME_ROLES if r in mapping), None)
    n = 0
    first: dict = {}
    kinds: dict = {h: set() for h in headers}
    t_lo = t_hi = None
    rel = False
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", pd.errors.ParserWarning)
        for chunk in _chunks(p, sep, opts.chunk_rows):
            n += len(chunk)
            for h in headers:
                col = chunk[h]
                nz = col.dropna()
                if len(nz) and h not in first:
                    v = nz.iloc[0]
                    first[h] = v.item() if hasattr(v, "item") else str(v)
                dt = col.dtype
                kinds[h].add("int" if pd.api.types.is_integer_dtype(dt) else
                             "float" if pd.api.types.is_numeric_dtype(dt) else
                             ("text" if len(nz) else "empty"))
            if time_role is not None:
                t = times_ns(chunk[mapping[time_role]], time_role, None, _Quiet(), mapping[time_role], 2,
                           dict(state))
                t = t[t >= 0]
                if len(t):
                    t_lo = int(t.min()) if t_lo is None else min(t_lo, int(t.min()))
                    t_hi = int(t.max()) if t_hi is None else max(t_hi, int(t.max()))
                    rel = rel or bool(np.median(t) < 1e17)
    fields = []
    for h in headers:
        k = kinds[h] - {"empty"} or {"empty"}
        ftype = "float" if k == {"int", "float"} else "text" if len(k) > 1 else next(iter(k))
        fields.append(FieldInfo(path=str(h), type=ftype, sample=first.get(h)))
    cat = Catalog(source=str(p), format="csv",
                  topics=[TopicInfo(name=p.name, type="csv", count=n, first_ns=t_lo, last_ns=t_hi,
                                    fields=tuple(fields))],
                  time_base="relative" if (rel or time_role is None) else "utc")
    for role, h in mapping.items():
        cat.mapping[role] = f"{p.name}.{h}"
        stream = _ROLE_STREAM.get(role, "time")
        why = decided.guesses.get(f"reason {role}")
        cat.reasons[role] = (f"given (--column {role}={h})" if role not in guessed else
                             f"header {h!r}: {why}" if why else
                             f"header {h!r} is a common name for {role}") + f"; feeds {stream}"
    cat.notes.extend(f"{k}: {v}" for k, v in decided.guesses.items() if not k.startswith(("reason ", "column ")))
    if time_role is None:
        cat.notes.append(f"no time column found: give --column time_s=HEADER (columns: {listing(headers)})")
    for a, b in (("lat_deg", "lon_deg"), ("thrust_left", "thrust_right")):
        if (a in mapping) != (b in mapping):
            cat.notes.append(f"{a if a in mapping else b} has no {b if a in mapping else a} column to pair with")
    return cat


class _Quiet:
    """A report stand-in that drops what it is told (the catalog only looks)."""

    guesses: dict = {}

    def skip(self, *a, **k) -> None:
        pass

    def note(self, *a, **k) -> None:
        pass
