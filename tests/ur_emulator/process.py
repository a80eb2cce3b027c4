"""The emulator in a child process (the ur_rtde client holds the GIL in some calls); see __init__.py."""

from __future__ import annotations

import contextlib
import os
import signal
import threading
from typing import Any

from tests.ur_emulator.controller import UREmulator

_next_address = [0]


def free_loopback_address() -> str:
    """A fresh loopback address 127.a.b.c for this process: a.b from the process id (concurrent test runs do not
    collide), c counts up. The UR ports are fixed, so every emulator needs an address of its own."""
    _next_address[0] += 1
    pid, k = os.getpid(), _next_address[0]
    a = 64 + ((pid >> 8) % 128)
    b = ((pid & 255) + 256 * 0 + (k - 1) // 254) % 256
    return f"127.{a}.{b}.{(k - 1) % 254 + 1}"


def _child(host: str, options: dict[str, Any], conn: Any) -> None:
    """The emulator process: start, then serve calls from the parent until "close". It ignores SIGINT, as a
    controller would (tests deliver Ctrl-C to the driver's processes)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        emulator = UREmulator(host, **options).start()
    except Exception as exc:  # e.g. the address is in use
        conn.send(("error", f"{type(exc).__name__}: {exc}"))
        return
    conn.send(("ok", None))
    while True:
        try:
            name, args, kwargs = conn.recv()
        except EOFError:
            name, args, kwargs = "close", (), {}
        if name == "close":
            emulator.close()
            with contextlib.suppress(OSError):
                conn.send(("ok", None))
            return
        try:
            if name == "set":
                setattr(emulator, args[0], args[1])
                result = None
            else:
                target = getattr(emulator, name)
                result = target(*args, **kwargs) if callable(target) else target
            conn.send(("ok", result))
        except Exception as exc:
            conn.send(("error", f"{type(exc).__name__}: {exc}"))


class EmulatorProcess:
    """A :class:`UREmulator` in a child process, driven from the test.

    The ``ur_rtde`` client holds the GIL in some blocking calls (its constructors), so an emulator running in
    threads of the same process would starve; the child process avoids that. Methods: ``protective_stop()``,
    ``emergency_stop()``, ``clear_stop()``, ``drop_connections()``, ``set(name, value)`` (``remote_control``,
    ``stall``), ``get(name)`` (``log``, ``safety_mode``, ``program_running``...), ``actual_q()``, ``close()``.
    """

    def __init__(self, host: str | None = None, **options: Any) -> None:
        import multiprocessing

        context = multiprocessing.get_context("spawn")
        self._call_lock = threading.Lock()
        for attempt in range(1 if host else 5):  # an address taken by someone else: try the next one
            self.host = host or free_loopback_address()
            self._conn, child_conn = context.Pipe()
            self._process = context.Process(target=_child, args=(self.host, options, child_conn), daemon=True)
            self._process.start()
            status, detail = self._receive(timeout=30.0)
            if status == "ok":
                return
            self._process.join(timeout=2.0)
            if "in use" not in str(detail) or attempt == 4:
                break
        raise RuntimeError(f"UR emulator at {self.host} did not start: {detail}")

    def _receive(self, timeout: float) -> tuple[str, Any]:
        if not self._conn.poll(timeout):
            raise TimeoutError("the UR emulator process does not answer")
        return self._conn.recv()  # type: ignore[no-any-return]

    def call(self, name: str, *args: Any, **kwargs: Any) -> Any:
        with self._call_lock:
            self._conn.send((name, args, kwargs))
            status, result = self._receive(timeout=10.0)
        if status != "ok":
            raise RuntimeError(f"UR emulator: {name}: {result}")
        return result

    def set(self, name: str, value: Any) -> None:
        with self._call_lock:
            self._conn.send(("set", (name, value), {}))
            self._receive(timeout=10.0)

    def get(self, name: str) -> Any:
        return self.call(name)

    def __getattr__(self, name: str) -> Any:
        if name.startswith("_"):
            raise AttributeError(name)
        return lambda *args, **kwargs: self.call(name, *args, **kwargs)

    def close(self) -> None:
        if self._process.is_alive():
            with contextlib.suppress(Exception):
                self.call("close")
            self._process.join(timeout=5.0)
            if self._process.is_alive():
                self._process.kill()

    def __enter__(self) -> EmulatorProcess:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def connected_robot(emu: EmulatorProcess, spec: str = "ur5e", options: str = ""):
    """The UR driver for model ``spec`` connected to ``emu`` (``options``: the spec's query, e.g. "reconnects=2")."""
    from drivers.registry import open_robot

    robot = open_robot(f"{spec}@{emu.host}{'?' + options if options else ''}")
    robot.connect(5.0)
    return robot
