"""Kernel receive times (drivers/receive_time.py): a reader that comes late still learns when the data arrived."""

from __future__ import annotations

import socket
import sys
import threading
import time

import pytest

from drivers.receive_time import enable_receive_times, receive

LATE = 0.2  # s the reader sleeps before reading


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="SO_TIMESTAMPNS is Linux's")
def test_a_late_reader_gets_the_arrival_time_not_its_own() -> None:
    server = socket.create_server(("127.0.0.1", 0))
    sent: list[float] = []

    def send() -> None:
        conn, _ = server.accept()
        with conn:
            time.sleep(0.05)
            sent.append(time.time())
            conn.sendall(b"E0001 # X(1), Y(2), Z(3)\r\n")
            time.sleep(LATE + 0.2)

    thread = threading.Thread(target=send, daemon=True)
    thread.start()
    with server, socket.create_connection(server.getsockname()) as sock:
        assert enable_receive_times(sock)
        time.sleep(0.05 + LATE)
        data, arrived = receive(sock, 65536, True)
        read = time.time()
        plain, at_read = receive(sock, 0, False)
    thread.join(2.0)
    assert data.startswith(b"E0001 #") and plain == b""
    assert abs(arrived - sent[0]) < 0.01  # loopback: the kernel stamps it within microseconds of the send
    assert read - arrived > LATE - 0.06 and at_read >= read  # without the kernel's time: the read's own
