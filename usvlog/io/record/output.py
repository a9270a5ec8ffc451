"""The recorder's files: one MCAP writer per part, chunks to disk, rotation by size or age.

:class:`PartWriter` knows nothing of samples or threads: it opens part files
(``run.mcap`` or ``run_000.mcap``, ``run_001.mcap``, ... when rotating), registers
channels, adds messages and metadata records, pushes the open chunk to the OS
(``flush_to_os``) or to disk (``sync``) and finishes a part. OS errors come out as
they are (the recorder turns them into its one sticky :class:`StorageError`), except
that a part that cannot be created is a :class:`StorageError` at once.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import re
from pathlib import Path

from ...errors import ConfigError, OutputExistsError, StorageError
from ...log.channels import MESSAGE_ENCODING, SCHEMA_ENCODING, schema_for_topic


def part_path(path, part: int | None) -> Path:
    """The file of one part of a rotating recording.

    Parameters
    ----------
    path : str or os.PathLike
        The output as given (``run.mcap``).
    part : int or None
        Part number; None when not rotating.

    Returns
    -------
    pathlib.Path
        ``run_000.mcap``, ``run_001.mcap``, ... (``part=None``: the path itself).
    """
    p = Path(path)
    if part is None:
        return p
    return p.with_name(f"{p.stem}_{part:03d}{p.suffix or '.mcap'}")


def check_outputs(path, *, rotating: bool, force: bool) -> None:
    """Fail before recording when the output (or, rotating, any part of it) exists or cannot be made.

    Parameters
    ----------
    path : str or os.PathLike
        The output as given.
    rotating : bool
        Parts ``NAME_000.mcap``, ... are written instead.
    force : bool
        Existing outputs may be overwritten.

    Raises
    ------
    StorageError
        The output is a directory, or its directory does not exist.
    OutputExistsError
        An output exists and ``force`` is False.
    """
    p = Path(path)
    if p.exists() and p.is_dir():
        raise StorageError(f"{p}: output is a directory")
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        raise StorageError(f"{p}: directory {parent} does not exist")
    if force:
        return
    first = part_path(p, 0 if rotating else None)
    if first.exists():
        raise OutputExistsError(f"{first}: output exists (use --force to overwrite)")
    if rotating:
        pat = re.compile(re.escape(p.stem) + r"_\d{3,}" + re.escape(p.suffix or ".mcap") + "$")
        for q in parent.iterdir():
            if pat.match(q.name):
                raise OutputExistsError(f"{q}: output exists (use --force to overwrite)")


def storage_error(path, err: OSError, what: str) -> StorageError:
    """A one-line StorageError for an OS error on a file.

    Parameters
    ----------
    path : str or os.PathLike
        The file.
    err : OSError
        What the OS said.
    what : str
        What failed (e.g. "recording stopped").

    Returns
    -------
    StorageError
        ``PATH: WHAT (disk full | disk quota exceeded | file too large ... | the OS's reason)``.
    """
    reason = {errno.ENOSPC: "disk full", errno.EFBIG: "file too large for the file system or limit",
              errno.EDQUOT: "disk quota exceeded"}.get(err.errno, err.strerror or str(err))
    return StorageError(f"{path}: {what} ({reason})")


def compression_type(name: str):
    """mcap's CompressionType of a compression name.

    Parameters
    ----------
    name : str
        ``zstd``, ``lz4`` or ``none``.

    Returns
    -------
    mcap.writer.CompressionType

    Raises
    ------
    ConfigError
        Another name.
    """
    from mcap.writer import CompressionType

    try:
        return {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}[name]
    except KeyError:
        raise ConfigError(f"compression {name!r}: use zstd, lz4 or none") from None


class PartWriter:
    """The MCAP part files of one recording.

    Parameters
    ----------
    base : path-like
        The output path (parts get ``_000``, ``_001``, ... before the suffix when rotating).
    rotating : bool
        Name parts by number.
    rotate_bytes : int, optional
        Start a new part once the current one holds this many bytes.
    rotate_ns : int, optional
        Start a new part once the current one is this old (ns of the recorder's clock).
    compression : str
        ``zstd``, ``lz4`` or ``none`` (chunk compression).
    chunk_size : int
        Bytes of messages after which mcap closes a chunk by itself.
    """

    def __init__(self, base, *, rotating: bool, rotate_bytes: int | None, rotate_ns: int | None,
                 compression: str, chunk_size: int):
        self.base = Path(base)
        self.rotating = rotating
        self.rotate_bytes = rotate_bytes
        self.rotate_ns = rotate_ns
        self._compression = compression_type(compression)
        self._chunk_size = int(chunk_size)
        self.paths: list[Path] = []
        self.part = 0
        self.bytes_done = 0            # bytes of finished parts
        self.opened_ns = 0             # when the current part was opened
        self._fh = None
        self._w = None
        self._chan: dict[str, int] = {}
        self._schema_ids: dict[str, int] = {}

    @property
    def path(self) -> Path:
        """The part being written (or the last one)."""
        return self.paths[-1]

    def open(self, now_ns: int) -> None:
        """Create the next part file; :meth:`start` writes its header.

        Parameters
        ----------
        now_ns : int
            The receive time now, ns since the Unix epoch (the part's age counts from it).

        Raises
        ------
        StorageError
            The file cannot be made.
        """
        from mcap.writer import Writer

        p = part_path(self.base, self.part if self.rotating else None)
        try:
            fh = open(p, "wb")  # noqa: SIM115 -- open until finish() or abandon()
        except OSError as err:
            raise storage_error(p, err, "cannot create output") from err
        self._fh = fh
        self.paths.append(p)
        self.opened_ns = now_ns
        self._w = Writer(fh, chunk_size=self._chunk_size, compression=self._compression)
        self._chan = {}
        self._schema_ids = {}

    def start(self, library: str) -> None:
        """The MCAP header of the part just opened.

        Parameters
        ----------
        library : str
            The header's ``library`` field (``usvlog VERSION``).
        """
        self._w.start(profile="", library=library)

    def sync_directory(self) -> None:
        """Make the new part's directory entry durable (best effort)."""
        p = self.path
        with contextlib.suppress(OSError):
            dfd = os.open(p.parent if str(p.parent) else ".", os.O_RDONLY)
            try:
                os.fsync(dfd)
            finally:
                os.close(dfd)

    def _channel(self, topic: str) -> int:
        cid = self._chan.get(topic)
        if cid is None:
            schema = schema_for_topic(topic)
            name = schema.get("title", topic)
            sid = self._schema_ids.get(name)
            if sid is None:
                sid = self._w.register_schema(name=name, encoding=SCHEMA_ENCODING, data=json.dumps(schema).encode())
                self._schema_ids[name] = sid
            cid = self._w.register_channel(topic=topic, message_encoding=MESSAGE_ENCODING, schema_id=sid)
            self._chan[topic] = cid
        return cid

    def add_message(self, topic: str, data: bytes, t_ns: int, sequence: int) -> None:
        """One encoded message.

        Parameters
        ----------
        topic : str
            Canonical topic (its channel is registered on first use).
        data : bytes
            The encoded message (JSON).
        t_ns : int
            Log and publish time, ns since the Unix epoch.
        sequence : int
            The message's sequence number in its channel (kept modulo 2**32).
        """
        self._w.add_message(channel_id=self._channel(topic), log_time=t_ns, data=data, publish_time=t_ns,
                            sequence=sequence & 0xFFFFFFFF)

    def add_metadata(self, name: str, record: dict[str, str]) -> None:
        """A metadata record, written between chunks.

        Parameters
        ----------
        name : str
            Record name (``usvlog.datum``, ``usvlog.provenance/0``, ...).
        record : dict
            {key: text}.
        """
        self._w.add_metadata(name, record)

    def flush_to_os(self) -> None:
        """Close the open chunk and hand it to the OS (a killed process loses nothing more)."""
        self._w.flush()
        self._fh.flush()

    def sync(self) -> None:
        """Close the open chunk and fsync: on disk (a power cut loses nothing more)."""
        self.flush_to_os()
        os.fsync(self._fh.fileno())

    def fileno(self) -> int:
        """The current part's file descriptor (the flush thread fsyncs it outside the lock).

        Returns
        -------
        int
        """
        return self._fh.fileno()

    def size(self) -> int:
        """Bytes of the current part so far (what the OS was given)."""
        return self._fh.tell()

    def bytes_on_disk(self) -> int:
        """Bytes of every part, the current one as far as written."""
        try:
            cur = self._fh.tell() if self._fh is not None else self.path.stat().st_size
        except (OSError, ValueError):
            cur = 0
        return self.bytes_done + cur

    def rotation_due(self, now_ns: int) -> bool:
        """Whether the current part is as large or as old as a part may be.

        Parameters
        ----------
        now_ns : int
            The receive time now, ns since the Unix epoch.

        Returns
        -------
        bool
        """
        return ((self.rotate_bytes is not None and self.size() >= self.rotate_bytes) or
                (self.rotate_ns is not None and now_ns - self.opened_ns >= self.rotate_ns))

    def finish(self) -> None:
        """Summary and footer, fsync, close the part."""
        self._w.finish()
        self._fh.flush()
        os.fsync(self._fh.fileno())
        self._fh.close()
        self._fh = None

    def next_part(self, size: int) -> None:
        """Count a finished part; the next :meth:`open` makes the one after it.

        Parameters
        ----------
        size : int
            The finished part's size, bytes.
        """
        self.bytes_done += size
        self.part += 1

    def abandon(self) -> None:
        """Close the file without finishing it (after a storage error)."""
        fh, self._fh = self._fh, None
        if fh is not None:
            with contextlib.suppress(Exception):
                fh.close()
