"""A thread serving a simulated device's byte stream (tests/tracker_devices.py, tests/ipp_device.py)."""

from __future__ import annotations

import socket
import threading
from typing import Any

from drivers.trackers.socket_reads import accept_each


class _Served:
    """A thread serving a byte stream on file descriptor ``fd`` until ``stop()``."""

    fd: int

    def __init__(self) -> None:
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.received = bytearray()

    def _start(self) -> None:
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)

    def __enter__(self) -> Any:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _serve(self) -> None:
        raise NotImplementedError

    def _accept_each(self, server: socket.socket, serve: Any) -> None:
        """Accept loopback connections on ``server`` until stopped, ``serve(conn)`` each, then close it."""
        accept_each(server, serve, self._stop)
