"""Opening ROS 1 and ROS 2 bags with rosbags (no ROS install): the content checked against the
format, a name rosbags recognises, the message definitions read one topic at a time, and the
``--msg-dir`` files.

rosbags picks its reader from the file name, so a bag whose name does not say what it holds
is opened through a temporary link with the right suffix (removed afterwards). Its typestore is
filled one connection at a time (:func:`_robust_reader_class`): a topic whose definition cannot
be parsed, registered or checked against its digest is marked bad (``bad_types``, with why) and
the others are read. :mod:`usvlog.io.importers.rosbag` lists and reads what is opened here.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path

from ...errors import ConfigError, FormatError
from .core import foreign
from .sniff import MCAP_MAGIC, ROS1_MAGIC, SQLITE_MAGIC, file_head


def _open_path(path: Path, fmt: str, stack) -> Path:
    """rosbags picks the reader from the name: give it one that matches the content."""
    if path.is_dir():
        return path
    want = ".bag" if fmt == "ros1" else None
    if fmt == "ros2":
        want = ".mcap" if file_head(path, len(MCAP_MAGIC)).startswith(MCAP_MAGIC) else ".db3"
    if path.suffix == want:
        return path
    tmp = Path(tempfile.mkdtemp(prefix="usvlog-bag-"))
    stack.append(tmp)
    link = tmp / (path.stem + want)
    os.symlink(path.resolve(), link)
    return link


def _check_kind(path: Path, fmt: str) -> None:
    """A forced format must match the content: ROS 1 is one file, ROS 2 a directory or .db3/.mcap file."""
    head = file_head(path, 16)
    if fmt == "ros1" and not head.startswith(ROS1_MAGIC):
        raise FormatError(f"{path}: not a ROS 1 bag (no '#ROSBAG V2.0' header)")
    if fmt == "ros2" and path.is_file() and not head.startswith((SQLITE_MAGIC, MCAP_MAGIC)):
        raise FormatError(f"{path}: not a ROS 2 bag (neither a bag directory nor a sqlite3/mcap file)")


def printable(text, limit: int = 60) -> str:
    """A name read from the file, safe to print on one line (control characters replaced)."""
    s = "".join(c if c.isprintable() else "?" for c in str(text))
    return " ".join(s.split())[:limit]


def msg_dir_types(dirs) -> tuple[dict, dict[str, list[str]]]:
    """The message types of every ``.msg`` file under each directory, named by package path.

    ``DIR/.../<pkg>/msg/<Name>.msg`` is the type ``<pkg>/msg/<Name>`` (a ``.msg`` file that is
    not in a ``msg`` directory: its directory's name is the package). Field types are resolved
    as ROS does (``Header`` -> ``std_msgs/msg/Header``, a bare name -> the same package); the
    types they name are looked up when the bag is opened (the bag's own definitions, these
    files, then the standard ROS 1 Noetic / ROS 2 Humble types).

    Parameters
    ----------
    dirs : iterable of path-like
        The ``--msg-dir`` directories, in order (the first definition of a type wins).

    Returns
    -------
    types : dict
        rosbags' type name -> parsed definition (``rosbags.typesys`` ``Typesdict``).
    registered : dict
        directory (as given) -> the type names found under it, sorted.

    Raises
    ------
    ConfigError
        A directory does not exist or holds no ``.msg`` file, or a ``.msg`` file does not
        parse (one line naming the file).
    """
    from rosbags.typesys import get_types_from_msg

    types: dict = {}
    registered: dict[str, list[str]] = {}
    for d in dirs:
        for f in _msg_files(d):
            pkg = f.parent.parent.name if f.parent.name == "msg" else f.parent.name
            name = f"{pkg}/msg/{f.stem}"
            try:
                new = get_types_from_msg(f.read_text(encoding="utf-8", errors="replace"), name)
            except Exception as err:  # noqa: BLE001 -- rosbags' parser on the user's file
                raise ConfigError(f"--msg-dir {d}: {f} does not parse as a ROS message definition "
                                  f"({type(err).__name__}: {printable(err, 120)})") from err
            for k, v in new.items():
                types.setdefault(k, v)
            registered.setdefault(str(d), []).append(name)
        registered[str(d)] = sorted(registered.get(str(d), []))
    return types, registered


def _msg_files(d) -> list[Path]:
    """The ``.msg`` files under ``d`` (sorted); ConfigError when there is none or ``d`` is no directory."""
    p = Path(d)
    if not p.is_dir():
        raise ConfigError(f"--msg-dir {d}: not a directory")
    files = sorted(f for f in p.rglob("*.msg") if f.is_file())
    if not files:
        raise ConfigError(f"--msg-dir {d}: no .msg file under it")
    return files


def _robust_reader_class():
    """AnyReader whose typestore is filled one connection at a time (a bad definition skips its type)."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_types_from_idl, get_types_from_msg, get_typestore

    class RobustReader(AnyReader):
        """rosbags' AnyReader; ``bad_types`` maps a message type to why it cannot be read.

        ``extra_types`` (set before ``open()``): types from ``--msg-dir`` files, used where the
        bag stores no definition (or an empty one) and before the standard store's.
        """

        bad_types: dict
        extra_types: dict = {}

        def _open(self) -> None:
            assert self.stack
            for reader in self.readers:
                self.stack.enter_context(reader)
            self.bad_types = {}
            typs: dict = {}
            digests: dict = {}
            connections = [y for x in self.readers for y in x.connections]
            for conn in connections:
                fmt = getattr(conn.msgdef.format, "name", "NONE")
                if fmt == "NONE" or not str(conn.msgdef.data).strip():   # no definition stored
                    if conn.msgtype in self.extra_types and conn.digest:
                        digests[conn.msgtype] = conn.digest   # the --msg-dir file checked against the bag
                    continue
                if conn.msgtype in self.bad_types:
                    continue
                try:
                    if fmt == "MSG":
                        new = get_types_from_msg(conn.msgdef.data, conn.msgtype)
                    else:
                        sep = "=" * 80 + "\n"
                        new = {}
                        if conn.msgdef.data.startswith(f"{sep}IDL: "):
                            for part in conn.msgdef.data.split(sep)[1:]:
                                new.update(get_types_from_idl(part.split("\n", 1)[1]))
                        else:
                            new.update(get_types_from_idl(conn.msgdef.data))
                except Exception:  # noqa: BLE001 -- rosbags' parser on one definition read from the file
                    self.bad_types[conn.msgtype] = "its message definition cannot be parsed"
                    continue
                for k, v in new.items():
                    typs.setdefault(k, v)
                if conn.digest:
                    digests[conn.msgtype] = conn.digest
            for k, v in self.extra_types.items():
                typs.setdefault(k, v)
            if self.default_typestore is not None:
                for k, v in self.default_typestore.fielddefs.items():
                    typs.setdefault(k, v)
            store = get_typestore(Stores.EMPTY)
            try:
                store.register(typs)
            except Exception:  # noqa: BLE001 -- one type at a time, to find the bad ones
                store = get_typestore(Stores.EMPTY)
                for k, v in typs.items():
                    try:
                        store.register({k: v})
                    except Exception:  # noqa: BLE001 -- rosbags' type registry on a definition from the file
                        self.bad_types.setdefault(k, "its message definition cannot be registered")
            func = store.hash_rihs01 if self.is2 else (lambda x: store.generate_msgdef(x)[1])
            for msgtype, digest in digests.items():
                try:
                    ok = func(msgtype) == digest
                except Exception:  # noqa: BLE001 -- a nested type missing from the definitions
                    ok = None
                if ok is None:
                    self.bad_types.setdefault(msgtype, "its message definition cannot be read")
                elif not ok and not self.is2:
                    self.bad_types.setdefault(msgtype, "its message definition does not match its checksum" + (
                        " (the --msg-dir file differs from the one recorded)" if msgtype in self.extra_types else ""))
            self.connections = connections
            self.typestore = store

    return RobustReader


@contextlib.contextmanager
def opened(path: Path, fmt: str, extra_types: dict | None = None):
    """The bag open for reading (rosbags' errors -> one-line FormatError); temporary links removed.

    ``extra_types``: message types from ``--msg-dir`` (:func:`msg_dir_types`).
    """
    from rosbags.typesys import Stores, get_typestore

    _check_kind(path, fmt)
    tmpdirs: list[Path] = []
    try:
        bag = _open_path(path, fmt, tmpdirs)
        store = get_typestore(Stores.ROS1_NOETIC if fmt == "ros1" else Stores.ROS2_HUMBLE)
        with foreign(path, f"not a readable {'ROS 1' if fmt == 'ros1' else 'ROS 2'} bag"):
            reader = _robust_reader_class()([bag], default_typestore=store)
            reader.extra_types = dict(extra_types or {})
            reader.open()
        try:
            yield reader
        finally:
            reader.close()
    finally:
        for d in tmpdirs:
            for f in d.iterdir():
                f.unlink()
            d.rmdir()
