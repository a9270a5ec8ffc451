"""Export a log: one CSV or Parquet file per channel.

File names (:func:`channel_filename`, inverse :func:`filename_topic`) are unique and reversible:

* the topic's leading ``/`` is dropped and every other ``/`` becomes ``__``;
* letters, digits, ``-`` and ``.`` stay (a ``.`` opening the name is escaped: no hidden files);
* ``_`` stays when it stands alone; next to another ``_`` or a ``/`` it is written ``%5F``
  (so in a name a single ``_`` is an underscore and ``__`` a slash);
* every other character is percent-encoded as its UTF-8 bytes (``%20`` for a space, upper-case hex);
* a topic without a leading ``/`` is marked by a leading ``%%``; the topic ``/`` alone is ``%``.

``/gnss/fix`` -> ``gnss__fix.csv``, ``/a/b`` -> ``a__b.csv``, ``/a__b`` -> ``a%5F%5Fb.csv``,
``/imu/raw data`` -> ``imu__raw%20data.csv``.
"""

from __future__ import annotations

from pathlib import Path

from ..errors import ConfigError, InputError, StorageError
from ..log.fieldlog import FieldLog
from .atomic import atomic_path, check_output

_FMTS = ("csv", "parquet")
_HEX = frozenset("0123456789ABCDEF")
_PLAIN = frozenset("ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789-.")


def _pct(c: str) -> str:
    return "".join(f"%{b:02X}" for b in c.encode("utf-8", "surrogatepass"))


def channel_filename(topic: str, fmt: str) -> str:
    """File name of a channel's export: ``/gnss/fix`` and ``csv`` -> ``gnss__fix.csv``.

    Distinct topics give distinct names (the escaping is in the module docstring);
    :func:`filename_topic` is the inverse.

    Parameters
    ----------
    topic : str
        Channel topic.
    fmt : {"csv", "parquet"}
        File format, the name's extension.

    Returns
    -------
    str
    """
    body = topic[1:] if topic.startswith("/") else topic
    if topic == "/":
        return "%." + fmt
    out = [] if topic.startswith("/") else ["%%"]
    for i, c in enumerate(body):
        if c == "/":
            out.append("__")
        elif c == "_":
            alone = (i == 0 or body[i - 1] not in "_/") and (i == len(body) - 1 or body[i + 1] not in "_/")
            out.append("_" if alone else "%5F")
        elif c in _PLAIN and not (c == "." and i == 0):
            out.append(c)
        else:
            out.append(_pct(c))
    return "".join(out) + "." + fmt


def filename_topic(name: str) -> str:
    """The topic a file name of :func:`channel_filename` stands for: ``gnss__fix.csv`` -> ``/gnss/fix``.

    Parameters
    ----------
    name : str
        A file name (not a path) ending in ``.csv`` or ``.parquet``.

    Returns
    -------
    str

    Raises
    ------
    ValueError
        If ``name`` is not a name :func:`channel_filename` writes.
    """
    stem, dot, ext = name.rpartition(".")
    if not dot or ext not in _FMTS:
        raise ValueError(f"{name!r}: not an exported channel's file name (.csv or .parquet)")
    if stem == "%":
        return "/"
    slash = not stem.startswith("%%")
    if not slash:
        stem = stem[2:]
    raw = bytearray()
    i = 0
    while i < len(stem):
        c = stem[i]
        if c == "%":
            hex2 = stem[i + 1:i + 3]
            if len(hex2) != 2 or not set(hex2) <= _HEX:
                raise ValueError(f"{name!r}: bad escape at character {i}")
            raw.append(int(hex2, 16))
            i += 3
        elif c == "_":
            j = i
            while j < len(stem) and stem[j] == "_":
                j += 1
            run = j - i
            if run != 1 and run % 2:
                raise ValueError(f"{name!r}: {run} underscores in a row (1 or an even number)")
            raw += b"_" if run == 1 else b"/" * (run // 2)
            i = j
        elif c in _PLAIN:
            raw += c.encode()
            i += 1
        else:
            raise ValueError(f"{name!r}: character {c!r} is escaped in exported names")
    try:
        body = raw.decode("utf-8", "surrogatepass")
    except UnicodeDecodeError:
        raise ValueError(f"{name!r}: escapes are not UTF-8") from None
    topic = "/" + body if slash else body
    if channel_filename(topic, ext) != name:  # one name per topic: other spellings are not ours
        raise ValueError(f"{name!r}: not the name {channel_filename(topic, ext)!r} that topic {topic!r} is written to")
    return topic


def export_log(log: FieldLog, out_dir, *, fmt: str = "csv", force: bool = False) -> list[Path]:
    """Write each channel to ``out_dir/<topic>.<fmt>`` (index ``t_ns`` as the first column).

    Every output is checked before the first one is written; each is written atomically.

    Parameters
    ----------
    log : FieldLog
    out_dir : str or os.PathLike
        Directory for the files (created if missing).
    fmt : {"csv", "parquet"}, default "csv"
        CSV floats are written as the shortest text that reads back as the same
        double (exact round trip; :func:`write_csv`).
    force : bool, default False
        Overwrite existing files.

    Returns
    -------
    list of pathlib.Path
        The files written, one per channel (name from :func:`channel_filename`, unique and
        reversible with :func:`filename_topic`); ``t_ns`` is in ns since the Unix epoch.

    Raises
    ------
    usvlog.errors.ConfigError
        On an unknown format.
    usvlog.errors.InputError
        If two topics differ only in letter case (their files would collide on macOS/Windows).
    usvlog.errors.OutputExistsError
        If an output exists and ``force`` is False.
    usvlog.errors.StorageError
        If the directory cannot be created or a file cannot be written.
    """
    if fmt not in _FMTS:
        raise ConfigError(f"export format {fmt!r} is not csv or parquet")
    out = Path(out_dir)
    folded: dict[str, str] = {}
    for topic in log.topics:  # every output checked before the first is written
        name = channel_filename(topic, fmt)
        other = folded.setdefault(name.casefold(), topic)
        if other != topic:
            raise InputError(f"{log.source or 'log'}: topics {other} and {topic} differ only in letter case: their "
                             f"files would be one file on a case-insensitive file system")
        check_output(out / name, force)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise StorageError(f"{out}: cannot create directory ({err.strerror})") from err
    written = []
    for topic in log.topics:
        path = out / channel_filename(topic, fmt)
        frame = log.channels[topic]
        with atomic_path(path, force=force) as tmp:
            if fmt == "csv":
                write_csv(frame, tmp)
            else:
                frame.to_parquet(tmp)
        written.append(path)
    return written


def write_csv(frame, path) -> None:
    """Write ``frame`` (its index as the first column) as CSV through pyarrow's writer.

    Floats are written as the shortest text that reads back as the same double (an exact
    round trip, as ``%.17g`` but shorter), NaN as an empty field, booleans as
    ``true``/``false``; a header name or string is quoted only when it needs it.

    Parameters
    ----------
    frame : pandas.DataFrame
        One channel (index ``t_ns``, int64 ns since the Unix epoch).
    path : str or os.PathLike
        The file to write.
    """
    # heavy: pyarrow, only when a CSV is written
    import csv

    import pyarrow as pa
    import pyarrow.csv as pacsv

    names = [str(frame.index.name or "")] + [str(c) for c in frame.columns]
    cols = [pa.Array.from_pandas(frame.index)] + [pa.Array.from_pandas(frame[c]) for c in frame.columns]  # NaN -> null
    table = pa.Table.from_arrays(cols, names=[f"c{i}" for i in range(len(cols))])
    with open(path, "w", newline="", encoding="utf-8") as fh:
        csv.writer(fh, lineterminator="\n").writerow(names)   # the header as pandas writes it
    with open(path, "ab") as fh:
        pacsv.write_csv(table, fh, pacsv.WriteOptions(include_header=False, quoting_style="needed",
                                                      batch_size=1 << 16))
