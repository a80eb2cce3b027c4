"""What a UR controller says about itself outside RTDE: the dashboard server (port 29999: model, PolyScope
version, serial number, remote control) and the factory calibration in the kinematics info that the primary
client interface (port 30001) sends after connecting. Plain sockets, every read with a timeout."""

from __future__ import annotations

import contextlib
import socket
import struct
import time
from typing import Any

DASHBOARD_PORT, PRIMARY_PORT = 29999, 30001
ROBOT_STATE_MESSAGE, KINEMATICS_INFO = 16, 5  # primary interface: message type, sub-package type
#: Robot state messages without kinematics info after which a controller is taken not to send it (it sends
#: it in the first one after connecting when it has it; these messages come at 10 Hz).
STATE_MESSAGES_WITHOUT_KINEMATICS = 3


class Dashboard:
    """A minimal dashboard-server client (port 29999): one command, one reply line; ``timeout`` s per read."""

    def __init__(self, host: str, timeout: float) -> None:
        self.sock = socket.create_connection((host, DASHBOARD_PORT), timeout=timeout)
        self.file = self.sock.makefile("rb")
        self.greeting = self._line()

    def _line(self) -> str:
        line = self.file.readline()
        if not line:
            raise ConnectionError("the dashboard server closed the connection")
        return line.decode(errors="replace").strip()

    def ask(self, command: str) -> str:
        self.sock.sendall(command.encode() + b"\n")
        return self._line()

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self.sock.sendall(b"quit\n")
        with contextlib.suppress(OSError):
            self.file.close()
            self.sock.close()


def dashboard_model(name: str) -> str:
    """ur5e -> UR5 (what ``get robot model`` answers; e-Series and CB3 alike)."""
    name = name.upper()
    return name[:-1] if name.endswith("E") else name


def polyscope_major(text: str) -> int | None:
    """The major version in a ``PolyscopeVersion`` answer (5 = e-Series, 3 = CB3), None if there is none."""
    for word in text.split():
        head = word.split(".")[0]
        if "." in word and head.isdigit():
            return int(head)
    return None


def read_factory_calibration(host: str, timeout: float) -> dict[str, Any]:
    """The controller's own calibrated DH values, from the kinematics info (robot state sub-package 5) that the
    primary client interface (port 30001) sends after connecting: ``{"theta": [6], "a": [6], "d": [6],
    "alpha": [6], "checksum": [6], "status": int}`` in UR's convention (rad, m). OSError / ValueError when it
    cannot be read within ``timeout`` s."""
    deadline = time.monotonic() + timeout
    without = 0  # robot state messages without the kinematics info
    with socket.create_connection((host, PRIMARY_PORT), timeout=timeout) as sock:
        buffer = b""
        while time.monotonic() < deadline and without < STATE_MESSAGES_WITHOUT_KINEMATICS:
            sock.settimeout(max(deadline - time.monotonic(), 0.01))
            chunk = sock.recv(65536)
            if not chunk:
                raise ValueError(f"the controller closed port {PRIMARY_PORT} before sending its kinematics info")
            buffer += chunk
            while len(buffer) >= 5:
                size, kind = struct.unpack_from(">iB", buffer)
                if size < 5 or size > 1 << 20:
                    raise ValueError(f"garbled primary-interface message (length {size})")
                if len(buffer) < size:
                    break
                message, buffer = buffer[5:size], buffer[size:]
                if kind == ROBOT_STATE_MESSAGE:
                    if (found := _kinematics_info(message)) is not None:
                        return found
                    without += 1
    if without:
        raise ValueError(f"the controller sends no kinematics info on port {PRIMARY_PORT}")
    raise ValueError(f"no kinematics info from port {PRIMARY_PORT} within {timeout:g} s")


def _kinematics_info(message: bytes) -> dict[str, Any] | None:
    offset = 0
    while offset + 5 <= len(message):
        size, kind = struct.unpack_from(">iB", message, offset)
        if size < 5:
            return None
        if kind == KINEMATICS_INFO and size >= 5 + 24 + 192:
            body = message[offset + 5:offset + size]
            checksum = list(struct.unpack_from(">6I", body))
            values = struct.unpack_from(">24d", body, 24)
            status = struct.unpack_from(">I", body, 216)[0] if len(body) >= 220 else -1
            keys = ("theta", "a", "d", "alpha")
            return {**{key: list(values[6 * i:6 * i + 6]) for i, key in enumerate(keys)}, "checksum": checksum,
                    "status": status}
        offset += size
    return None


