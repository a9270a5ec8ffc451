"""What a file is, from its first bytes: the magic numbers of the binary formats."""

from __future__ import annotations

import functools
import gzip
import zlib
from pathlib import Path

from ...errors import FormatError
from ..atomic import reading

# the first bytes of each binary format (detect_format and the readers' own checks)
ULOG_MAGIC = b"ULog\x01\x12\x35"
DATAFLASH_MAGIC = b"\xa3\x95\x80"
ROS1_MAGIC = b"#ROSBAG V2.0"
SQLITE_MAGIC = b"SQLite format 3\x00"
MCAP_MAGIC = b"\x89MCAP0\r\n"
GZIP_MAGIC = b"\x1f\x8b"   # a CSV or NMEA log may come gzipped


def file_head(path, n: int) -> bytes:
    """The first ``n`` bytes of a file (b"" for a directory); OS errors -> one-line StorageError."""
    p = Path(path)
    if p.is_dir():
        return b""
    with reading(p), open(p, "rb") as fh:
        return fh.read(n)


def check_gzip(path) -> bool:
    """Whether ``path`` is gzip-compressed; a damaged one (cut short, bad data) raises.

    The whole stream is decompressed once (C speed, memory flat; the answer is kept per
    path, size and modification time), so a reader never meets the damage half-way.

    Raises
    ------
    FormatError
        One line naming the file, ``from`` the gzip/zlib error.
    """
    if file_head(path, 2) != GZIP_MAGIC:
        return False
    st = Path(path).stat()
    _gzip_intact(str(path), st.st_size, st.st_mtime_ns)
    return True


@functools.lru_cache(maxsize=16)
def _gzip_intact(path: str, size: int, mtime_ns: int) -> None:
    try:
        with reading(Path(path)), gzip.open(path, "rb") as fh:
            while fh.read(1 << 20):
                pass
    except (EOFError, zlib.error, gzip.BadGzipFile) as err:
        raise FormatError(f"{path}: damaged gzip file ({type(err).__name__}: {err})") from err
