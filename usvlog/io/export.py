"""Export a log: one CSV or Parquet file per channel."""

from __future__ import annotations

from pathlib import Path

from ..errors import ConfigError, StorageError
from ..log.fieldlog import FieldLog
from .atomic import atomic_path, check_output


def channel_filename(topic: str, fmt: str) -> str:
    """File name of a channel's export: ``/gnss/fix`` and ``csv`` -> ``gnss__fix.csv``."""
    return topic.strip("/").replace("/", "__") + ("." + fmt)


def export_log(log: FieldLog, out_dir, *, fmt: str = "csv", force: bool = False) -> list[Path]:
    """Write each channel to ``out_dir/<topic>.<fmt>`` (index ``t_ns`` as the first column).

    Every output is checked before the first one is written; each is written atomically.

    Parameters
    ----------
    log : FieldLog
    out_dir : str or os.PathLike
        Directory for the files (created if missing).
    fmt : {"csv", "parquet"}, default "csv"
        CSV floats are written with 17 significant digits (exact round trip).
    force : bool, default False
        Overwrite existing files.

    Returns
    -------
    list of pathlib.Path
        The files written, one per channel (name from :func:`channel_filename`); ``t_ns``
        is in ns since the Unix epoch.

    Raises
    ------
    usvlog.errors.ConfigError
        On an unknown format.
    usvlog.errors.OutputExistsError
        If an output exists and ``force`` is False.
    usvlog.errors.StorageError
        If the directory cannot be created or a file cannot be written.
    """
    if fmt not in ("csv", "parquet"):
        raise ConfigError(f"export format {fmt!r} is not csv or parquet")
    out = Path(out_dir)
    for topic in log.topics:  # every output checked before the first is written
        check_output(out / channel_filename(topic, fmt), force)
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
                frame.to_csv(tmp, float_format="%.17g")
            else:
                frame.to_parquet(tmp)
        written.append(path)
    return written
