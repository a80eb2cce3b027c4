"""An RFC 2217 server for tests: pyserial's ``serial.rfc2217.PortManager`` bridging a loopback TCP port to a
serial port (a simulated device's pty from :mod:`tests.tracker_devices`)."""

from __future__ import annotations

import contextlib
import select
import socket
import threading
from typing import Any

from tests.tracker_devices import _Served


class _SocketWriter:
    """The ``write`` end PortManager needs, thread safe, on a connected socket."""

    def __init__(self, conn: socket.socket) -> None:
        self.conn, self._lock = conn, threading.Lock()

    def write(self, data: bytes) -> None:
        with self._lock, contextlib.suppress(OSError):
            self.conn.sendall(data)


def _pty_port(path: str) -> Any:
    """``path`` (a pty) opened as a pyserial port. A pty has no modem control lines (their ioctls fail):
    they read as on a null-modem cable (CTS, DSR, CD on; RI off) and setting RTS/DTR does nothing."""
    import serial

    class PtyPort(serial.Serial):  # type: ignore[misc]
        cts = dsr = cd = True
        ri = False

        def _update_rts_state(self) -> None:
            pass

        def _update_dtr_state(self) -> None:
            pass

    return PtyPort(path, timeout=0)


class Rfc2217Bridge(_Served):
    """An RFC 2217 (Telnet COM port control) server on loopback, ``url`` = ``rfc2217://127.0.0.1:N``, that
    bridges one client at a time to the serial port ``port`` (e.g. an :class:`AsciiDevice`'s pty), written
    with pyserial's ``serial.rfc2217.PortManager`` (the client's baud rate, parity, purges and control lines
    go to the real port). ``mute`` (an Event): while set, the device's bytes are dropped on the way to the
    client (a cut receive line); :meth:`kick` closes the client's connection (a server restart)."""

    def __init__(self, port: str) -> None:
        super().__init__()
        self.serial = _pty_port(port)
        self._server = socket.create_server(("127.0.0.1", 0))
        self.url = f"rfc2217://127.0.0.1:{self._server.getsockname()[1]}"
        self.mute = threading.Event()
        self._kick = threading.Event()
        self.connections = 0
        self._start()

    def kick(self) -> None:
        self._kick.set()

    def stop(self) -> None:
        super().stop()
        self.serial.close()

    def _serve(self) -> None:
        self._accept_each(self._server, self._bridge)

    def _bridge(self, conn: socket.socket) -> None:
        from serial.rfc2217 import PortManager

        self.connections += 1
        self._kick.clear()
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        writer = _SocketWriter(conn)
        manager = PortManager(self.serial, writer)
        while not self._stop.is_set() and not self._kick.is_set():
            ready, _, _ = select.select([conn, self.serial.fileno()], [], [], 0.02)
            if conn in ready:
                try:
                    data = conn.recv(4096)
                except OSError:
                    return
                if not data:
                    return
                self.serial.write(b"".join(manager.filter(data)))
            if self.serial.fileno() in ready:
                out = self.serial.read(self.serial.in_waiting or 1)
                if out and not self.mute.is_set():
                    writer.write(b"".join(manager.escape(out)))
