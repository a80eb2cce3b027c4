"""One read from a tracker's TCP link, shared by the clients that frame its bytes themselves (I++ DME lines,
emScon packets): what came, nothing yet, or a dead link said in one line; and the accept loop the simulated servers
share (``emscon:sim``, the tests' I++ server)."""

from __future__ import annotations

import socket
import threading
from collections.abc import Callable

from drivers.errors import ConnectionFailed
from drivers.trace import one_line


def receive(sock: socket.socket, timeout: float, where: str, server: str, drop: Callable[[], None]) -> bytes | None:
    """At most 64 KiB from ``sock`` within ``timeout`` s, or None when nothing came in that time. A failed or
    closed link is dropped (``drop()``) and raised as ConnectionFailed naming ``where`` (``server``: what listens
    there, e.g. ``the I++ server``)."""
    try:
        sock.settimeout(timeout)
        chunk = sock.recv(65536)
    except TimeoutError:
        return None
    except OSError as exc:
        drop()
        raise ConnectionFailed(f"lost the connection to {where}: {one_line(exc)}") from exc
    if not chunk:
        drop()
        raise ConnectionFailed(f"{server} {where} closed the connection")
    return chunk


def accept_each(server: socket.socket, serve: Callable[[socket.socket], None], stop: threading.Event) -> None:
    """The accept loop of a simulated server (tests' devices, ``emscon:sim``): accept connections on ``server``
    until ``stop`` is set, ``serve(conn)`` each in turn, close it; then close ``server``."""
    server.settimeout(0.05)
    while not stop.is_set():
        try:
            conn, _ = server.accept()
        except TimeoutError:
            continue
        with conn:
            serve(conn)
    server.close()
