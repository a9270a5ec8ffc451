"""The listing of an NMEA/text log (``usvlog inspect``): one topic per sentence type, its fields by position.

:func:`catalog` reads the file once with the reader's own line scan, prefix-time policy and
sentence parser (:mod:`usvlog.io.importers.nmea`) and says what :func:`~.nmea.read` would
use: sentence types with their talkers, counts of readable sentences, time spans, a
sample of every field, and what was skipped and why.
"""

from __future__ import annotations

from collections import Counter, defaultdict

from ..nmea import NmeaChecksumError, NmeaError, NmeaFieldError, parse_sentence
from .catalog import Catalog, FieldInfo, TopicInfo
from .nmea import _SENTENCE, PrefixTimeError, _Clock, _lines, _prefix_policy, _scan, prefix_time

# sentence type -> its field names, by position (1 = the first field after the head)
FIELD_NAMES: dict[str, tuple[str, ...]] = {
    "GGA": ("time_utc", "lat_ddmm", "lat_hemi", "lon_dddmm", "lon_hemi", "fix_quality", "satellites", "hdop",
            "alt_msl_m", "alt_unit", "geoid_sep_m", "geoid_sep_unit", "dgps_age_s", "dgps_station"),
    "RMC": ("time_utc", "status", "lat_ddmm", "lat_hemi", "lon_dddmm", "lon_hemi", "sog_kn", "cog_deg", "date",
            "mag_var_deg", "mag_var_dir", "mode"),
    "GLL": ("lat_ddmm", "lat_hemi", "lon_dddmm", "lon_hemi", "time_utc", "status", "mode"),
    "VTG": ("cog_true_deg", "true_ref", "cog_mag_deg", "mag_ref", "sog_kn", "kn_unit", "sog_kmh", "kmh_unit",
            "mode"),
    "HDT": ("heading_deg", "true_ref"),
    "HDM": ("heading_deg", "mag_ref"),
    "HDG": ("heading_deg", "deviation_deg", "deviation_dir", "variation_deg", "variation_dir"),
    "ZDA": ("time_utc", "day", "month", "year", "zone_h", "zone_min"),
    "GSA": ("mode", "fix_type") + tuple(f"prn{i}" for i in range(1, 13)) + ("pdop", "hdop", "vdop"),
    "GSV": ("messages", "message", "satellites_in_view"),
    "ROT": ("rate_degpmin", "status"),
}
# role -> (sentence types that feed it, the field used)
_ROLE_SOURCES = {"gnss": (("GGA", "RMC", "GLL"), "lat_ddmm"), "heading": (("HDT", "HDG", "HDM"), "heading_deg"),
                 "velocity": (("VTG", "RMC"), "sog_kn")}


def _field_type(values: list[str]) -> str:
    """``float``, ``int`` or ``text`` from a field's non-empty values."""
    vals = [v for v in values if v != ""]
    if not vals:
        return "empty"
    try:
        for v in vals:
            int(v)
        return "int"
    except ValueError:
        pass
    try:
        for v in vals:
            float(v)
        return "float"
    except ValueError:
        return "text"


def catalog(path, opts) -> Catalog:
    """What an NMEA/text log holds: one topic per sentence type, its fields by position.

    Parameters
    ----------
    path : path-like
        The log file.
    opts : usvlog.io.importers.ImportOptions
        ``prefix_time`` decides which times the spans are on (as :func:`read` does).

    Returns
    -------
    Catalog
        Topics named by sentence type (``RMC``, ``GGA``, ``HDT``, ...; type ``NMEA GPRMC``
        with the talkers seen), counts of readable sentences (checksum holds), the time span
        (ns since the Unix epoch: the sentence UTC for RMC/GGA/GLL/ZDA, the line prefix
        time for the others when it is used), fields named by position (``RMC.sog_kn`` is
        field 7; unknown types ``f1``, ``f2``, ...) with their type (the position in the
        type text) and the first value; ``time_base`` ``utc`` when the file has RMC/ZDA
        dates or zoned prefix times; the roles the importer maps and why; notes for the
        lines skipped.

    Raises
    ------
    StorageError
        The file cannot be read.
    """
    mode = getattr(opts, "prefix_time", None)
    sc = _scan(path, mode)
    tmp_report = _NoteSink()
    use_prefix, offset = _prefix_policy(sc, mode, getattr(opts, "start_utc_ns", None), tmp_report)
    clock = _Clock(sc.day0)
    counts: Counter = Counter()
    talkers: dict = defaultdict(set)
    values: dict = defaultdict(lambda: defaultdict(list))
    first_vals: dict = {}
    span: dict = {}
    bad = Counter()
    for line in _lines(path):
        m = _SENTENCE.search(line)
        if m is None:
            if line.strip():
                bad["lines without a sentence"] += 1
            continue
        body = line[m.start():].strip()
        if sc.checksummed and "*" not in body:
            bad["sentences without their checksum"] += 1
            continue
        try:
            smp = parse_sentence(body, require_checksum=False)
        except NmeaChecksumError:
            bad["bad checksums"] += 1
            continue
        except NmeaFieldError:
            smp = None
        except NmeaError:
            bad["unreadable sentences"] += 1
            continue
        head, _, rest = body.split("*")[0].partition(",")
        head = head[1:]
        typ = head[2:] if len(head) == 5 and head[0] != "P" else head
        parts = rest.split(",")
        counts[typ] += 1
        talkers[typ].add(head[:2] if typ != head else "")
        vs = values[typ]
        for i, v in enumerate(parts[:40]):
            if len(vs[i]) < 200:
                vs[i].append(v.strip())
        first_vals.setdefault(typ, {})
        for i, v in enumerate(parts[:40]):
            if v.strip() and i not in first_vals[typ]:
                first_vals[typ][i] = v.strip()
        t = None
        if smp is not None and smp.time_of_day_ns is not None:
            t = clock.stamp(smp.time_of_day_ns, smp.date)
        elif use_prefix and m.start():
            try:
                pre = prefix_time(line[:m.start()], mode)
            except PrefixTimeError:
                pre = None
            if pre is not None and pre[1] == sc.kind and 0 <= pre[0] + offset < 2**62:
                t = pre[0] + offset
        if t is not None:
            lo, hi = span.get(typ, (t, t))
            span[typ] = (min(lo, t), max(hi, t))
    topics = []
    for typ in sorted(counts, key=lambda k: (-counts[k], k)):
        names = FIELD_NAMES.get(typ, ())
        fields = []
        for i in sorted(values[typ]):
            name = names[i] if i < len(names) else f"f{i + 1}"
            ftype = _field_type(values[typ][i])
            sample = first_vals[typ].get(i)
            if sample is not None and ftype in ("int", "float") and name not in ("time_utc", "date") \
                    and not name.endswith("ddmm"):   # times, dates and ddmm positions stay as written
                sample = int(sample) if ftype == "int" else float(sample)
            fields.append(FieldInfo(path=name, type=f"{ftype} (field {i + 1})", sample=sample))
        tk = sorted(x for x in talkers[typ] if x)
        lo, hi = span.get(typ, (None, None))
        topics.append(TopicInfo(name=typ, type="NMEA " + (", ".join(x + typ for x in tk) if tk else typ),
                                count=counts[typ], first_ns=lo, last_ns=hi, fields=tuple(fields)))
    cat = Catalog(source=str(path), format="nmea", topics=topics,
                  time_base="utc" if (sc.day0 is not None or sc.kind == "utc") else "relative")
    for role, (types, fld) in _ROLE_SOURCES.items():
        have = [t for t in types if counts.get(t)]
        if role == "velocity" and "VTG" in have:
            have = ["VTG"]
        if have:
            cat.mapping[role] = "/".join(f"{t}.{fld}" for t in have)
            cat.reasons[role] = (f"{' and '.join(have)} sentences ({', '.join(str(counts[t]) for t in have)}); "
                                 + {"gnss": "one fix per epoch: GGA, else RMC, else GLL",
                                    "heading": "headings in degrees (HDG corrected by deviation/variation)",
                                    "velocity": "speed over ground (kn) and course"}[role])
        else:
            cat.reasons[role] = f"no {'/'.join(types)} sentence in the file"
    cat.notes.extend(tmp_report.notes)
    cat.notes.extend(f"{n} {what} skipped" for what, n in sorted(bad.items()))
    return cat


class _NoteSink:
    """A report stand-in that keeps only notes and guesses (for :func:`catalog`)."""

    def __init__(self):
        self.notes: list = []
        self.guesses: dict = {}

    def note(self, text: str) -> None:
        if text not in self.notes:
            self.notes.append(text)
