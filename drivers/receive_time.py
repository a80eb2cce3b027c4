"""When data reached the host, not when a Python thread got round to reading it: the kernel's receive time of a
TCP segment (Linux ``SO_TIMESTAMPNS``), for streams stamped on the host (I++ ``OnMoveReportE`` reports carry no
device time).

A reader thread stamps late by whatever held it (the scheduler, the interpreter lock, a commit in another thread):
on a busy 2-core host tenths of a millisecond and, now and then, several milliseconds, an error of that delay times
the tracked point's speed. The kernel stamps each segment as it arrives. One ``recvmsg`` returns the time of the
last segment it read, so lines that arrived together share it, as they did with the read time. Elsewhere than
Linux, or where the option is refused, the read time (``time.time()``) is used as before.
"""

from __future__ import annotations

import socket
import struct
import sys
import time

SO_TIMESTAMPNS = 35  # Linux (asm-generic): receive times as struct timespec in SCM_TIMESTAMPNS messages
_TIMESPEC = struct.Struct("ll")  # struct timespec as SO_TIMESTAMPNS gives it: seconds, nanoseconds (C longs)
_ANCILLARY = socket.CMSG_SPACE(_TIMESPEC.size) if hasattr(socket, "CMSG_SPACE") else 0
STALE = 60.0  # s: a kernel time this far from the read time is not trusted (a wrong layout, a clock step)


def enable_receive_times(sock: socket.socket) -> bool:
    """Ask the kernel to stamp ``sock``'s incoming data; False where it cannot (then :func:`receive` stamps reads)."""
    if not sys.platform.startswith("linux") or not _ANCILLARY:
        return False
    try:
        sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
    except OSError:
        return False
    return True


def receive(sock: socket.socket, size: int, stamped: bool) -> tuple[bytes, float]:
    """Up to ``size`` bytes from ``sock`` and when they arrived (s since the epoch, the clock of ``time.time()``):
    the kernel's time of the last segment read when ``stamped`` (see :func:`enable_receive_times`) and the kernel
    gave one, else the time of the read. Raises what ``recv`` raises."""
    if not stamped:
        return sock.recv(size), time.time()
    data, ancillary, _, _ = sock.recvmsg(size, _ANCILLARY)
    now = time.time()
    for level, kind, raw in ancillary:
        if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS and len(raw) >= _TIMESPEC.size:
            seconds, nanoseconds = _TIMESPEC.unpack(raw[:_TIMESPEC.size])
            arrived = seconds + nanoseconds * 1e-9
            if 0.0 <= now - arrived < STALE:
                return data, arrived
    return data, now
