"""Atomic outputs: write to a temporary file beside the target, fsync, rename."""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path

from ..errors import OutputExistsError, StorageError


@contextlib.contextmanager
def reading(path):
    """Turn the OS errors of reading ``path`` into one-line StorageErrors."""
    try:
        yield
    except FileNotFoundError as err:
        raise StorageError(f"{path}: no such file") from err
    except OSError as err:
        raise StorageError(f"{path}: cannot read ({err.strerror})") from err


def check_output(path, force: bool, *, parent: bool = False) -> Path:
    """Refuse an existing output without ``force``; with ``parent``, also a missing directory.

    Verbs call it (with ``parent=True``) before their work, so a bad ``--out`` fails at once.

    Parameters
    ----------
    path : str or os.PathLike
        The output to be written.
    force : bool
        Allow overwriting an existing file.
    parent : bool, default False
        Also require the parent directory to exist.

    Returns
    -------
    pathlib.Path

    Raises
    ------
    usvlog.errors.OutputExistsError
        If ``path`` exists and ``force`` is False.
    usvlog.errors.StorageError
        If ``path`` is a directory, or (``parent``) its directory does not exist.
    """
    p = Path(path)
    if p.exists() and not force:
        raise OutputExistsError(f"{p}: output exists (use --force to overwrite)")
    if p.exists() and p.is_dir():
        raise StorageError(f"{p}: output is a directory")
    if parent:
        d = p.parent if str(p.parent) else Path(".")
        if not d.is_dir():
            raise StorageError(f"{p}: directory {d} does not exist")
    return p


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_path(path, *, force: bool = False):
    """Yield a temporary path; on success it replaces ``path`` atomically.

    On any error the temporary file is removed and ``path`` is left untouched.

    Parameters
    ----------
    path : str or os.PathLike
        Final output path.
    force : bool, default False
        Allow replacing an existing file.

    Yields
    ------
    pathlib.Path
        Temporary file in the same directory; write the output there.

    Raises
    ------
    usvlog.errors.OutputExistsError
        If ``path`` exists (or appears meanwhile) and ``force`` is False.
    usvlog.errors.StorageError
        If the directory is missing or the file cannot be created or written.
    """
    p = check_output(path, force)
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        raise StorageError(f"{p}: directory {parent} does not exist")
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".tmp", dir=parent)
    except OSError as err:
        raise StorageError(f"{p}: cannot create output ({err.strerror})") from err
    os.close(fd)
    ok = False
    try:
        yield Path(tmp)
        try:
            with open(tmp, "rb+") as fh:
                os.fsync(fh.fileno())
            os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; outputs get the usual mode
            if p.exists() and not force:  # appeared meanwhile
                raise OutputExistsError(f"{p}: output exists (use --force to overwrite)")
            os.replace(tmp, p)
        except OSError as err:
            if isinstance(err, OutputExistsError):
                raise
            raise StorageError(f"{p}: cannot write output ({err.strerror or err})") from err
        ok = True
    finally:
        if not ok:
            with contextlib.suppress(OSError):
                os.unlink(tmp)


def write_bytes_atomic(path, data: bytes, *, force: bool = False) -> None:
    """Write ``data`` to ``path`` atomically (see :func:`atomic_path` for errors)."""
    with atomic_path(path, force=force) as tmp:
        tmp.write_bytes(data)


def write_text_atomic(path, text: str, *, force: bool = False) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically (see :func:`atomic_path` for errors)."""
    write_bytes_atomic(path, text.encode(), force=force)
