"""Live sources: NMEA 0183 or JSON lines from a serial port, UDP or a TCP server.

URLs: ``serial:///dev/ttyUSB0?baud=4800``, ``udp://0.0.0.0:10110`` (listen),
``tcp://host:port`` (connect; reconnects with back-off when the link drops).
Each source runs in its own thread, splits what it reads into lines, stamps each
read with the recorder's receive clock and hands the lines to the recorder.
"""

from __future__ import annotations

import contextlib
import os
import socket
import threading
from dataclasses import dataclass
from urllib.parse import parse_qs, urlsplit

from ...errors import ConfigError, StorageError

_MAX_LINE = 4096


@dataclass(frozen=True)
class SourceSpec:
    url: str
    scheme: str          # serial | udp | tcp
    host: str = ""
    port: int = 0
    device: str = ""
    baud: int = 4800


def parse_source(url: str, what: str = "source") -> SourceSpec:
    """Parse a source URL; a bad one raises :class:`ConfigError` naming the option."""
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
    """Datagrams the kernel dropped for this socket (Linux /proc/net/udp*), -1 when unknown."""
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

    ``kind`` is "nmea" (sentences -> ``rec.nmea``) or "json" (lines -> ``rec.json_line``).
    Endpoints that listen (UDP, serial) are opened in the constructor so a wrong
    port or device fails before recording starts.
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
        self._stop_ev = threading.Event()
        self._sock = None
        self._serial = None
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
        """The bound (host, port) of a UDP source (useful with port 0)."""
        return self._sock.getsockname() if self._sock is not None and self.spec.scheme == "udp" else None

    @property
    def dropped(self) -> int:
        return udp_drops(self._sock) if self.spec.scheme == "udp" and self._sock is not None else -1

    def attach(self, recorder) -> None:
        """The recorder the lines go to (before ``start()``)."""
        self.rec = recorder

    def stop(self) -> None:
        self._stop_ev.set()

    def close(self) -> None:
        """Release an endpoint of a source that was never started."""
        for h in (self._sock, self._serial):
            if h is not None:
                with contextlib.suppress(Exception):
                    h.close()

    # -- lines -----------------------------------------------------------------------
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

    # -- loops -------------------------------------------------------------------------
    def run(self) -> None:
        try:
            {"udp": self._run_udp, "tcp": self._run_tcp, "serial": self._run_serial}[self.spec.scheme]()
        except StorageError as err:  # the recorder failed: stop quietly, the session reports it
            self.error = str(err)
        except Exception as err:  # keep the thread's failure visible in the status
            self.error = f"{type(err).__name__}: {err}"
        finally:
            self.close()

    def _run_udp(self) -> None:
        sock, rec = self._sock, self.rec
        buf = bytearray()
        n = 0
        while not self._stop_ev.is_set():
            try:
                data = sock.recv(65535)
            except TimeoutError:
                rec.set_dropped(self.source_name, self.dropped)
                continue
            t = rec.now_ns()
            self._feed(buf, data, t)
            if buf:  # a datagram ends its last line
                self._emit(bytes(buf), t)
                buf.clear()
            n += 1
            if n % 256 == 0:
                rec.set_dropped(self.source_name, self.dropped)
        rec.set_dropped(self.source_name, self.dropped)

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
            self.rec.event(f"{self.source_name}: connected to {self.spec.url}", source=self.source_name)
            sock.settimeout(0.2)
            self._sock = sock
            buf = bytearray()
            try:
                while not self._stop_ev.is_set():
                    try:
                        data = sock.recv(65536)
                    except TimeoutError:
                        continue
                    if not data:
                        break
                    self._feed(buf, data, self.rec.now_ns())
            except OSError as err:
                self.error = f"connection lost ({err.strerror or err})"
            finally:
                with contextlib.suppress(OSError):
                    sock.close()
                self._sock = None
            if buf:
                self._emit(bytes(buf), self.rec.now_ns())
            if not self._stop_ev.is_set():
                self.reconnects += 1
                self.rec.event(f"{self.source_name}: connection to {self.spec.url} lost, reconnecting",
                               source=self.source_name)

    def _run_serial(self) -> None:
        import serial

        buf = bytearray()
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
                self._feed(buf, data, self.rec.now_ns())
