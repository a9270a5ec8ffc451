"""What a file is, from its first bytes: the magic numbers of the binary formats."""

from __future__ import annotations

from pathlib import Path

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
