"""PX4 .ulg logs through pyulog.

* ``vehicle_gps_position`` or ``sensor_gps`` (``fix_type`` < 3 is "no fix": skipped,
  counted; ``lat``/``lon`` in 1e-7 deg or ``latitude_deg``/``longitude_deg``) -> ``/gnss/fix``;
* ``vehicle_attitude.q`` (w, x, y, z; PX4 is NED/FRD already) -> ``/compass/heading``;
* ``actuator_motors.control[0|1]`` (normalized) or else ``actuator_outputs.output[0|1]``
  (pwm_us) -> ``/thrust/command`` (left = index 0, right = index 1 unless given with
  ``--topic thrust_left=actuator_outputs.output[2]``).

Time: the log's microsecond ``timestamp`` shifted to UTC by the first GPS message with
``time_utc_usec``; without one, by ``--start-utc`` (else the Unix epoch, noted).
"""

from __future__ import annotations

import contextlib
import io
from collections.abc import Iterator

import numpy as np

from ...errors import FormatError, InputError
from .core import clock_offset_fallback, foreign, listing
from .sniff import ULOG_MAGIC, file_head


def _topic(ulog, name):
    return next((d for d in ulog.data_list if d.name == name and d.multi_id == 0), None) or \
        next((d for d in ulog.data_list if d.name == name), None)


def _col(d, key, path):
    """Field ``key`` of ULog topic ``d`` as an array; InputError naming the topic when absent."""
    if key not in d.data:
        raise InputError(f"{path}: topic {d.name} has no field {key!r} "
                         f"(fields: {listing(sorted(d.data), 20)})")
    return np.asarray(d.data[key])


_US_MAX = 2**62 // 1000   # microsecond times beyond this (146 years) are damaged: no int64 ns holds them with an offset


def _time_ns(d, path, offset_ns: int) -> np.ndarray:
    """The topic's ``timestamp`` (us since boot) as UTC ns; -1 (dropped, counted) where it is damaged."""
    us = _col(d, "timestamp", path)
    ok = (us >= 0) & (us < _US_MAX)
    t = np.where(ok, us, 0).astype(np.int64) * 1000 + offset_ns
    return np.where(ok & (t >= 0), t, -1)


def _first(data: dict, names: tuple[str, ...], n: int):
    """The first of ``names`` in ``data`` (altitude: above the WGS-84 ellipsoid, as ``/gnss/fix``
    defines it, when the log has it; else above sea level), else NaN."""
    for name in names:
        if name in data:
            return data[name]
    return np.full(n, np.nan)


def read(path, opts, report, *, fmt="ulog", on_mapping=None) -> Iterator[dict]:
    """The role streams of a PX4 ULog file as one batch (see :mod:`usvlog.io.importers.core`).

    pyulog loads the whole file (only the topics used), so there is a single batch:
    ``gnss`` (deg, m), ``heading`` (rad, from ``vehicle_attitude.q``) and ``thrust``
    (commands with their unit), as this module's docstring describes. Times are the log's
    microsecond ``timestamp`` shifted to ns since the Unix epoch; ``stamp_ns`` equals
    ``t_ns``. pyulog's own console output is swallowed.

    Parameters
    ----------
    path : pathlib.Path
        The ``.ulg`` file.
    opts : usvlog.io.importers.ImportOptions
        ``topics`` (``thrust_left``/``thrust_right`` as ``topic.field`` of one topic),
        ``thrust_unit`` (else normalized for ``actuator_motors``, pwm_us for
        ``actuator_outputs``), ``start_utc_ns`` when the log has no GPS UTC time.
    report : usvlog.io.importers.core.ImportReport
        Filled with samples read, fixes skipped (no fix), the mapping and guesses.
    fmt : str
        Unused (one signature for every reader).
    on_mapping : callable, optional
        Called with ``report`` once the mapping is known.

    Raises
    ------
    FormatError
        Not a ULog file, or pyulog cannot read it (``from`` its exception).
    InputError
        A mapped topic or field is missing, or the thrust topics are given wrongly.
    """
    from pyulog import ULog

    if file_head(path, len(ULOG_MAGIC)) != ULOG_MAGIC:
        raise FormatError(f"{path}: not a PX4 ULog file (bad magic bytes)")
    sink = io.StringIO()
    wanted = ["vehicle_gps_position", "sensor_gps", "vehicle_attitude", "actuator_motors", "actuator_outputs"] + \
        [s.split(".", 1)[0].lstrip("/") for s in opts.topics.values()]
    with foreign(path, "not a readable ULog file"), contextlib.redirect_stdout(sink), \
            contextlib.redirect_stderr(sink):
        ulog = ULog(str(path), wanted)
    gps = _topic(ulog, "vehicle_gps_position") or _topic(ulog, "sensor_gps")
    offset_ns = None
    if gps is not None and "time_utc_usec" in gps.data:
        tu = _col(gps, "time_utc_usec", path)
        ts = _col(gps, "timestamp", path)
        ok = np.flatnonzero((tu > 0) & (tu < _US_MAX) & (ts >= 0) & (ts < _US_MAX))
        if len(ok):
            i = int(ok[0])
            offset_ns = (int(tu[i]) - int(ts[i])) * 1000
    if offset_ns is None:
        offset_ns = clock_offset_fallback(opts, report, "log time")
    batch = {}
    if gps is not None:
        report.mapping["gnss"] = gps.name
        t = _time_ns(gps, path, offset_ns)
        if "latitude_deg" in gps.data:
            lat, lon = _col(gps, "latitude_deg", path).astype(float), _col(gps, "longitude_deg", path).astype(float)
            alt = np.asarray(_first(gps.data, ("altitude_ellipsoid_m", "altitude_msl_m"), len(t)), float)
        else:
            lat = _col(gps, "lat", path).astype(np.int64) * 1e-7
            lon = _col(gps, "lon", path).astype(np.int64) * 1e-7
            alt = np.asarray(_first(gps.data, ("alt_ellipsoid", "alt"), len(t)), float) * 1e-3
        fix = np.asarray(gps.data.get("fix_type", np.full(len(t), 3)))
        nofix = fix < 3
        report.skip("gnss_no_fix", int(nofix.sum()))
        report.records += len(t)
        k = ~nofix
        batch["gnss"] = {"t_ns": t[k], "lat_deg": lat[k], "lon_deg": lon[k], "alt_m": alt[k]}
    att = _topic(ulog, "vehicle_attitude")
    if att is not None:
        report.mapping["heading"] = "vehicle_attitude.q"
        w, x, y, z = (_col(att, f"q[{i}]", path).astype(float) for i in range(4))
        psi = np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
        report.records += len(w)
        batch["heading"] = {"t_ns": _time_ns(att, path, offset_ns),
                            "heading_rad": psi}
    thr = None
    if "thrust_left" in opts.topics or "thrust_right" in opts.topics:
        if not ("thrust_left" in opts.topics and "thrust_right" in opts.topics):
            raise InputError(f"{path}: give both --topic thrust_left= and thrust_right=")
        specs = [opts.topics["thrust_left"].lstrip("/").split(".", 1),
                 opts.topics["thrust_right"].lstrip("/").split(".", 1)]
        if specs[0][0] != specs[1][0] or len(specs[0]) < 2 or len(specs[1]) < 2:
            raise InputError(f"{path}: thrust_left and thrust_right must be fields of one topic "
                             "(e.g. actuator_outputs.output[2])")
        d = _topic(ulog, specs[0][0])
        if d is None:
            raise InputError(f"{path}: topic {specs[0][0]} is not in the log "
                             f"(topics: {listing(sorted({x.name for x in ulog.data_list}))})")
        thr = (d, specs[0][1], specs[1][1], opts.thrust_unit or ("pwm_us" if d.name == "actuator_outputs"
                                                                  else "normalized"))
    else:
        d = _topic(ulog, "actuator_motors")
        if d is not None:
            thr = (d, "control[0]", "control[1]", opts.thrust_unit or "normalized")
        elif (d := _topic(ulog, "actuator_outputs")) is not None:
            thr = (d, "output[0]", "output[1]", opts.thrust_unit or "pwm_us")
        if thr is not None:
            report.guesses["topic thrust_left"] = f"{thr[0].name}.{thr[1]}"
            report.guesses["topic thrust_right"] = f"{thr[0].name}.{thr[2]}"
    if thr is not None:
        d, kl, kr, unit = thr
        report.mapping["thrust_left"] = f"{d.name}.{kl}"
        report.mapping["thrust_right"] = f"{d.name}.{kr}"
        left, right = _col(d, kl, path).astype(float), _col(d, kr, path).astype(float)
        report.records += len(left)
        batch["thrust"] = {"t_ns": _time_ns(d, path, offset_ns),
                           "left": left, "right": right, "unit": np.full(len(left), unit, dtype=object)}
    if on_mapping is not None:
        on_mapping(report)
    yield batch
