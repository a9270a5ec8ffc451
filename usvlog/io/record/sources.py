"""Live sources: NMEA 0183 or JSON lines from a serial port, UDP or a TCP server.

URLs: ``serial:///dev/ttyUSB0?baud=4800``, ``udp://0.0.0.0:10110`` (listen),
``tcp://host:port`` (connect; reconnects with back-off when the link drops).
Each source runs in its own thread, splits what it reads into lines, stamps each
read with the monotonic clock at the moment it is read and hands the lines to the
recorder, which maps that time to its receive clock.

Standard library only (and pyserial for a serial port): ``usvlog record`` opens its
sources and starts their threads *before* it imports numpy, pandas and the MCAP
writer, so nothing sent after the process starts is lost and nothing is stamped
late. Until a recorder is attached a source keeps what it reads, with its read
time, in a backlog (at most ``_MAX_BACKLOG`` reads; more are counted as dropped);
the first read after :meth:`Source.attach` hands the backlog over first, in order.

A UDP datagram's receive time is when the kernel received it (``SO_TIMESTAMPNS``,
Linux: the wall clock at arrival, mapped to the monotonic clock with the two clocks'
difference at the read), so a datagram that waited in the socket buffer while the
main thread held the interpreter (importing numpy takes it for tens of ms at a time)
is not stamped late. Elsewhere, and for TCP and serial, it is the monotonic clock
when the source thread read it: at most a few tens of ms late during the imports.
"""

from __future__ import annotations

import contextlib
import os
import socket
import struct
import threading
import time
from dataclasses import dataclass
from urllib.parse import parse_qs, urlsplit

from ...errors import ConfigError, StorageError

_MAX_LINE = 4096
_MAX_BACKLOG = 1 << 18     # reads kept before a recorder is attached (more are counted as dropped)
_SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35 if os.uname().sysname == "Linux" else None)
_TIMESPEC = struct.Struct("@qq")   # struct timespec on 64-bit Linux: seconds, nanoseconds


@dataclass(frozen=True)
class SourceSpec:
    """A parsed source URL.

    Attributes
    ----------
    url : str
        The URL as given.
    scheme : str
        ``serial``, ``udp`` or ``tcp``.
    host : str
        Address to listen on (UDP) or connect to (TCP).
    port : int
        UDP or TCP port (0: any free port, UDP).
    device : str
        Serial device (or pyserial URL).
    baud : int
        Serial line speed, bit/s.
    """

    url: str
    scheme: str          # serial | udp | tcp
    host: str = ""
    port: int = 0
    device: str = ""
    baud: int = 4800


def parse_source(url: str, what: str = "source") -> SourceSpec:
    """Parse a source URL.

    Parameters
    ----------
    url : str
        ``serial:///dev/ttyUSB0?baud=4800``, ``udp://0.0.0.0:10110`` or ``tcp://host:port``.
    what : str
        The option named in an error message (e.g. ``--gnss``).

    Returns
    -------
    SourceSpec

    Raises
    ------
    ConfigError
        A URL that does not parse or has an unsupported scheme.
    """
    try:
        u = urlsplit(url)
        scheme = u.scheme.lower()
        if scheme == "serial":
            dev = u.path or u.netloc
            if not dev:
                raise ValueError("no device")
            q = parse_qs(u.query)
            baud = int(q.get("baud", ["4800"])[0])
            if baud <= 0:
                raise ValueError(f"baud {baud}")
            return SourceSpec(url, "serial", device=dev, baud=baud)
        if scheme in ("udp", "tcp"):
            if not u.hostname and scheme == "tcp":
                raise ValueError("no host")
            port = u.port
            if port is None or not (0 <= port <= 65535):
                raise ValueError("no port")
            return SourceSpec(url, scheme, host=u.hostname or "0.0.0.0", port=port)
    except ValueError as err:
        raise ConfigError(f"{what} {url!r}: bad URL ({err}); use serial:///dev/ttyUSB0?baud=4800, "
                          f"udp://0.0.0.0:10110 or tcp://host:port") from None
    raise ConfigError(f"{what} {url!r}: unsupported scheme {u.scheme!r}; use serial://, udp:// or tcp://")


def udp_drops(sock: socket.socket) -> int:
    """Datagrams the kernel dropped for a UDP socket.

    Parameters
    ----------
    sock : socket.socket
        A bound UDP socket.

    Returns
    -------
    int
        The socket's drop counter from Linux ``/proc/net/udp`` (or ``udp6``); -1 when unknown.
    """
    try:
        inode = os.fstat(sock.fileno()).st_ino
    except OSError:
        return -1
    for table in ("/proc/net/udp", "/proc/net/udp6"):
        try:
            with open(table) as fh:
                next(fh)
                for line in fh:
                    f = line.split()
                    if len(f) >= 13 and f[9] == str(inode):
                        return int(f[-1])
        except (OSError, StopIteration, ValueError):
            continue
    return -1


class Source(threading.Thread):
    """One live source feeding a :class:`~usvlog.io.record.recorder.Recorder`.

    Endpoints that listen (UDP, serial) are opened in the constructor, so a wrong
    port or device fails before recording starts. The thread may be started before
    a recorder is attached: what it reads meanwhile waits in a backlog with its read
    time (see the module notes) and goes to the recorder, in order, once attached.

    Parameters
    ----------
    name : str
        Source name in the log (``gnss``, ``compass``, ``gnss+compass``, ``thrust``).
    spec : SourceSpec
        Where to read.
    recorder : Recorder, optional
        Where the lines go; or :meth:`attach` one later.
    kind : str
        ``nmea`` (sentences -> ``recorder.nmea``) or ``json`` (lines -> ``recorder.json_line``).
    """

    def __init__(self, name: str, spec: SourceSpec, recorder=None, kind: str = "nmea"):
        super().__init__(name=f"usvlog-source-{name}", daemon=True)
        if kind not in ("nmea", "json"):
            raise ConfigError(f"source {name}: kind {kind!r} is not nmea or json")
        self.source_name = name
        self.spec = spec
        self.rec = recorder
        self.kind = kind
        self.error: str | None = None
        self.reconnects = 0
        self.backlog_dropped = 0
        self._backlog: list[tuple[int, bytes | None, bool, str | None]] = []
        self._buf = bytearray()       # a line not ended yet (TCP, serial)
        self._stop_ev = threading.Event()
        self._sock = None
        self._serial = None
        # the wall clock and the monotonic clock read together: a receive clock may start here
        self.opened_ns = (time.time_ns(), time.monotonic_ns())
        if spec.scheme == "udp":
            s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            with contextlib.suppress(OSError):
                s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 << 20)
            # no SO_REUSEADDR: a second listener on the port would silently take half the datagrams
            try:
                s.bind((spec.host, spec.port))
            except OSError as err:
                s.close()
                raise StorageError(f"source {name} {spec.url}: cannot listen ({err.strerror})") from err
            if _SO_TIMESTAMPNS is not None:
                with contextlib.suppress(OSError):   # kernel receive times (see the module notes)
                    s.setsockopt(socket.SOL_SOCKET, _SO_TIMESTAMPNS, 1)
            s.settimeout(0.2)
            self._sock = s
        elif spec.scheme == "serial":
            self._serial = self._open_serial()

    # -- endpoints -----------------------------------------------------------------
    def _open_serial(self):
        import serial

        try:
            return serial.serial_for_url(self.spec.device, baudrate=self.spec.baud, timeout=0.2)
        except (serial.SerialException, OSError, ValueError) as err:
            raise StorageError(f"source {self.source_name} {self.spec.url}: cannot open serial port ({err})") from err

    @property
    def address(self) -> tuple[str, int] | None:
        """The bound (host, port) of a UDP source (useful with port 0); None for other schemes."""
        return self._sock.getsockname() if self._sock is not None and self.spec.scheme == "udp" else None

    @property
    def dropped(self) -> int:
        """Datagrams dropped before they were read: by the kernel (UDP; -1 when unknown) plus
        reads beyond the backlog's bound before a recorder was attached."""
        if self.spec.scheme != "udp" or self._sock is None:
            return -1
        k = udp_drops(self._sock)
        return k + self.backlog_dropped if k >= 0 else k

    def attach(self, recorder) -> None:
        """Send the lines to ``recorder`` (before or after ``start()``; the backlog follows).

        Parameters
        ----------
        recorder : Recorder
            Needs ``nmea``, ``json_line``, ``event``, ``set_dropped`` and ``receive_ns``.
        """
        self.rec = recorder

    def stop(self) -> None:
        """Ask the thread to finish (within about 0.2 s); what it read is handed over first."""
        self._stop_ev.set()

    def close(self) -> None:
        """Release the endpoint (of a source that was never started, or has stopped)."""
        for h in (self._sock, self._serial):
            if h is not None:
                with contextlib.suppress(Exception):
                    h.close()

    # -- reads ---------------------------------------------------------------------
    def _deliver(self, mono_ns: int, data: bytes | None, datagram: bool = False, event: str | None = None) -> None:
        """A read (``data``, with its monotonic read time) or an ``event`` note: to the recorder,
        or into the backlog while none is attached."""
        if self.rec is None:
            if len(self._backlog) < _MAX_BACKLOG:
                self._backlog.append((mono_ns, data, datagram, event))
            else:
                self.backlog_dropped += 1
            return
        if self._backlog:
            self._drain()
        self._process(mono_ns, data, datagram, event)

    def _drain(self) -> None:
        """Hand the backlog to the attached recorder, in order (source thread only)."""
        if self.rec is None:
            return
        backlog, self._backlog = self._backlog, []
        for item in backlog:
            self._process(*item)

    def _process(self, mono_ns: int, data: bytes | None, datagram: bool, event: str | None) -> None:
        t_ns = self.rec.receive_ns(mono_ns)
        if event is not None:
            self.rec.event(event, t_ns=t_ns, source=self.source_name)
            return
        if data:
            self._feed(self._buf, data, t_ns)
        if self._buf and (datagram or data is None):   # a datagram (or the end of a stream) ends its last line
            self._emit(bytes(self._buf), t_ns)
            self._buf.clear()

    def _emit(self, line: bytes, t_ns: int) -> None:
        line = line.rstrip(b"\r\n")
        if not line.strip():
            return
        text = line.decode("utf-8", errors="backslashreplace")
        if self.kind == "nmea":
            self.rec.nmea(text, source=self.source_name, t_ns=t_ns)
        else:
            self.rec.json_line(text, source=self.source_name, t_ns=t_ns)

    def _feed(self, buf: bytearray, data: bytes, t_ns: int) -> None:
        buf += data
        while True:
            i = buf.find(b"\n")
            if i < 0:
                break
            self._emit(bytes(buf[:i]), t_ns)
            del buf[:i + 1]
        if len(buf) > _MAX_LINE:  # no line ending for too long: keep it as one (malformed) line
            self._emit(bytes(buf), t_ns)
            buf.clear()

    def _set_dropped(self) -> None:
        if self.rec is not None:
            self.rec.set_dropped(self.source_name, self.dropped)

    # -- loops -------------------------------------------------------------------------
    def run(self) -> None:
        """The thread: read until :meth:`stop`, then hand over what is left."""
        try:
            {"udp": self._run_udp, "tcp": self._run_tcp, "serial": self._run_serial}[self.spec.scheme]()
            if self.rec is not None:
                self._drain()
        except StorageError as err:  # the recorder failed: stop quietly, the session reports it
            self.error = str(err)
        except Exception as err:  # keep the thread's failure visible in the status
            self.error = f"{type(err).__name__}: {err}"
        finally:
            self.close()

    def _run_udp(self) -> None:
        sock = self._sock
        anc_size = socket.CMSG_SPACE(_TIMESPEC.size)
        n = 0
        while not self._stop_ev.is_set():
            try:
                data, anc, _flags, _addr = sock.recvmsg(65535, anc_size)
            except TimeoutError:
                if self._backlog:
                    self._drain()
                self._set_dropped()
                continue
            self._deliver(_arrival_ns(anc), data, datagram=True)
            n += 1
            if n % 256 == 0:
                self._set_dropped()
        self._set_dropped()

    def _run_tcp(self) -> None:
        backoff = 0.2
        while not self._stop_ev.is_set():
            try:
                sock = socket.create_connection((self.spec.host, self.spec.port), timeout=2.0)
            except OSError as err:
                self.error = f"cannot connect to {self.spec.host}:{self.spec.port} ({err.strerror or err})"
                self._stop_ev.wait(backoff)
                backoff = min(backoff * 2, 5.0)
                continue
            self.error = None
            backoff = 0.2
            self._deliver(time.monotonic_ns(), None, event=f"{self.source_name}: connected to {self.spec.url}")
            sock.settimeout(0.2)
            self._sock = sock
            try:
                while not self._stop_ev.is_set():
                    try:
                        data = sock.recv(65536)
                    except TimeoutError:
                        if self._backlog:
                            self._drain()
                        continue
                    if not data:
                        break
                    self._deliver(time.monotonic_ns(), data)
            except OSError as err:
                self.error = f"connection lost ({err.strerror or err})"
            finally:
                with contextlib.suppress(OSError):
                    sock.close()
                self._sock = None
            self._deliver(time.monotonic_ns(), None)   # the end of the stream ends its last line
            if not self._stop_ev.is_set():
                self.reconnects += 1
                self._deliver(time.monotonic_ns(), None, event=f"{self.source_name}: connection to "
                                                              f"{self.spec.url} lost, reconnecting")

    def _run_serial(self) -> None:
        import serial

        while not self._stop_ev.is_set():
            if self._serial is None:
                try:
                    self._serial = self._open_serial()
                    self.error = None
                except StorageError as err:
                    self.error = str(err)
                    self._stop_ev.wait(1.0)
                    continue
            try:
                data = self._serial.read(max(1, self._serial.in_waiting))
            except (serial.SerialException, OSError) as err:
                self.error = f"serial port lost ({err})"
                with contextlib.suppress(Exception):
                    self._serial.close()
                self._serial = None
                self.reconnects += 1
                continue
            if data:
                self._deliver(time.monotonic_ns(), data)
            elif self._backlog:
                self._drain()


def _arrival_ns(ancdata) -> int:
    """When a datagram arrived, on the monotonic clock (ns): the kernel's time stamp when the
    socket has one (a wall-clock time, shifted by the clocks' difference now), else now."""
    mono = time.monotonic_ns()
    for level, kind, raw in ancdata:
        if level == socket.SOL_SOCKET and kind == _SO_TIMESTAMPNS and len(raw) >= _TIMESPEC.size:
            sec, nsec = _TIMESPEC.unpack_from(raw)
            arrived = sec * 1_000_000_000 + nsec - (time.time_ns() - mono)
            return min(arrived, mono)   # never after the read (a wall clock stepped back)
    return mono


def open_sources(gnss: str | None = None, compass: str | None = None,
                 thrust: str | None = None) -> list[Source]:
    """Sources for the given URLs, endpoints open, threads not started.

    Standard library only, so ``usvlog record`` calls it (and starts the threads)
    before its heavy imports; then ``attach`` a recorder.

    Parameters
    ----------
    gnss, compass : str, optional
        NMEA 0183 source URLs; they may be the same URL (one source, ``gnss+compass``).
    thrust : str, optional
        JSON-lines source URL.

    Returns
    -------
    list of Source
        One per distinct URL.

    Raises
    ------
    ConfigError
        A bad URL, or one URL given for NMEA and for JSON lines.
    StorageError
        A port that cannot be listened on, a serial device that cannot be opened.
    """
    wanted = [("gnss", gnss, "nmea"), ("compass", compass, "nmea"), ("thrust", thrust, "json")]
    by_url: dict[str, list] = {}
    for name, url, kind in wanted:
        if url:
            spec = parse_source(url, f"--{name}")
            entry = by_url.setdefault(spec.url, [[], spec, kind])
            if entry[2] != kind:
                raise ConfigError(f"--{name} {url}: one source cannot carry both NMEA and JSON lines")
            entry[0].append(name)
    out: list[Source] = []
    try:
        for names, spec, kind in by_url.values():
            out.append(Source("+".join(names), spec, None, kind))
    except Exception:
        for s in out:
            s.close()
        raise
    return out


def shutdown(sources: list[Source], timeout_s: float = 2.0) -> None:
    """Stop the sources' threads (each hands over what it read first) and release their endpoints.

    Parameters
    ----------
    sources : list of Source
        Started or not.
    timeout_s : float
        Longest wait for each thread, s.
    """
    for s in sources:
        s.stop()
    for s in sources:
        if s.is_alive():
            s.join(timeout=timeout_s)
    for s in sources:
        if not s.is_alive():
            s.close()
