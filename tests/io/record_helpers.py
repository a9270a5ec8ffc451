"""Helpers for the recorder tests: free loopback ports, a TCP server, waiting."""

from __future__ import annotations

import socket
import threading
import time


def free_udp_port() -> int:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


class TcpServer:
    """One-client TCP server on 127.0.0.1: ``send(bytes)`` writes to the connected client (drops before it connects)."""

    def __init__(self):
        self.sock = socket.create_server(("127.0.0.1", 0))
        self.port = self.sock.getsockname()[1]
        self.conn = None
        self.connected = threading.Event()
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self):
        self.sock.settimeout(20)
        try:
            self.conn, _ = self.sock.accept()
            self.connected.set()
        except OSError:
            pass

    def send(self, data: bytes) -> None:
        if self.conn is not None:
            self.conn.sendall(data)

    def close(self):
        for s in (self.conn, self.sock):
            if s is not None:
                s.close()


def wait_for(pred, timeout_s: float, what: str):
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout_s:
        if pred():
            return
        time.sleep(0.02)
    raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")
