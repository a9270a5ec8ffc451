"""Atomic outputs: write to a temporary file beside the target, fsync, rename.

The temporary files are named ``.NAME.<random>.tmp`` beside the output (directories:
``.NAME.<random>.tmp/``). They are removed on every exit the process survives: an error, Ctrl-C,
or SIGTERM/SIGHUP (which the command line turns into an exception, so the clean-up runs).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
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


def check_input(path) -> Path:
    """Refuse an input that does not exist, with the one-line error every reader gives.

    Verbs call it before their heavy imports, so a mistyped path fails at once; a file that
    exists but cannot be read is left to the reader (:func:`reading`).

    Parameters
    ----------
    path : str or os.PathLike
        A file (or a directory: a ROS 2 bag) to be read.

    Returns
    -------
    pathlib.Path

    Raises
    ------
    usvlog.errors.StorageError
        If nothing exists at ``path``.
    """
    p = Path(path)
    if not p.exists():
        raise StorageError(f"{p}: no such file")
    return p


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
    if p.is_dir():  # said first: --force would not help
        raise StorageError(f"{p}: output is a directory")
    if (p.exists() or p.is_symlink()) and not force:
        raise OutputExistsError(f"{p}: output exists (use --force to overwrite)")
    if parent:
        d = p.parent if str(p.parent) else Path(".")
        if not d.is_dir():
            raise StorageError(f"{p}: directory {d} does not exist")
    return p


_DEFERRED = tuple(getattr(signal, n) for n in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, n))


@contextlib.contextmanager
def deferred_signals():
    """Hold SIGINT, SIGTERM and SIGHUP back while the block runs; they are handled right after it.

    For the few steps that must not be cut in two: creating a temporary file and recording
    its name (so the clean-up knows it), swapping directories, stopping child processes.
    Blocks them in the calling thread only; a no-op where signals cannot be blocked (Windows).
    """
    if not hasattr(signal, "pthread_sigmask"):
        yield
        return
    old = signal.pthread_sigmask(signal.SIG_BLOCK, _DEFERRED)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


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
    ok = False
    tmp = None
    try:
        with deferred_signals():  # a signal cannot land between creating the file and knowing its name
            try:
                fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".tmp", dir=parent)
            except OSError as err:
                raise StorageError(f"{p}: cannot create output ({err.strerror})") from err
            os.close(fd)
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
        if not ok and tmp is not None:  # any exit: error, Ctrl-C, SIGTERM turned into an exception
            with contextlib.suppress(OSError):
                os.unlink(tmp)


def write_bytes_atomic(path, data: bytes, *, force: bool = False) -> None:
    """Write ``data`` to ``path`` atomically (see :func:`atomic_path` for errors)."""
    with atomic_path(path, force=force) as tmp:
        tmp.write_bytes(data)


def write_text_atomic(path, text: str, *, force: bool = False) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically (see :func:`atomic_path` for errors)."""
    write_bytes_atomic(path, text.encode(), force=force)


@contextlib.contextmanager
def atomic_dir(path, *, force: bool = False):
    """Yield a temporary directory; on success it takes the place of ``path`` (complete or absent).

    The directory is built as a hidden sibling ``.NAME.<random>.tmp`` and renamed into place
    at the end, so a failed or killed writer never leaves a half-written ``path``. An existing
    ``path`` (``force`` only) is first renamed aside and removed once the new one is in place;
    between the two renames ``path`` is briefly absent, never half-written.

    Parameters
    ----------
    path : str or os.PathLike
        Final directory.
    force : bool, default False
        Allow replacing an existing directory (its whole content is replaced).

    Yields
    ------
    pathlib.Path
        Empty temporary directory beside ``path``; write the outputs there.

    Raises
    ------
    usvlog.errors.OutputExistsError
        If ``path`` exists (or appears meanwhile) and ``force`` is False.
    usvlog.errors.StorageError
        If ``path`` is a file, its parent is missing, or the directory cannot be written.
    """
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise StorageError(f"{p}: output is not a directory")
    if p.exists() and not force:
        raise OutputExistsError(f"{p}: output exists (use --force to overwrite)")
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        raise StorageError(f"{p}: directory {parent} does not exist")
    ok = False
    tmp = old = None
    try:
        with deferred_signals():
            try:
                tmp = tempfile.mkdtemp(prefix=f".{p.name}.", suffix=".tmp", dir=parent)
            except OSError as err:
                raise StorageError(f"{p}: cannot create directory ({err.strerror})") from err
        os.chmod(tmp, 0o777 & ~_umask())  # mkdtemp makes 0700; outputs get the usual mode
        yield Path(tmp)
        try:
            with deferred_signals():  # the swap is not cut in two by Ctrl-C or SIGTERM
                if p.exists():
                    if not force:
                        raise OutputExistsError(f"{p}: output exists (use --force to overwrite)")
                    old = tempfile.mkdtemp(prefix=f".{p.name}.", suffix=".old.tmp", dir=parent)
                    os.replace(p, Path(old) / p.name)
                os.replace(tmp, p)
                ok = True
        except OSError as err:
            if isinstance(err, OutputExistsError):
                raise
            raise StorageError(f"{p}: cannot write output ({err.strerror or err})") from err
    finally:
        if not ok and tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
        if old is not None:
            if not ok and not p.exists():  # the swap failed half-way: the old directory goes back
                with contextlib.suppress(OSError):
                    os.replace(Path(old) / p.name, p)
            shutil.rmtree(old, ignore_errors=True)
