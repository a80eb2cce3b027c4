"""One read from a tracker's TCP link, shared by the clients that frame its bytes themselves (I++ DME lines,
emScon packets): what came, nothing yet, or a dead link said in one line."""

from __future__ import annotations

import socket
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
