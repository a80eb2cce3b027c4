"""The ``ur_rtde`` interfaces in a worker process owned by the UR driver (drivers/ur/driver.py).

ur_rtde 1.6.5 can crash its host process after a dropped link (its own reconnect thread segfaults) and
some of its calls block for long. So the driver never loads it: a child process (``python -m
drivers.ur.worker``: a fresh interpreter that imports only this module, not the caller's main module as
multiprocessing's spawn would) holds ``RTDEReceiveInterface`` and ``RTDEControlInterface`` and answers
requests over a socket pair (``multiprocessing.connection.Connection`` framing, pickled tuples). Every
request has a timeout; a worker that dies (a crash included), hangs or reports a lost link becomes
:class:`LinkLost`, and the driver starts a fresh worker (a bounded number of times) or gives up with
ConnectionFailed. The driver process survives either way.

- The worker ignores the stop signals (SIGINT, SIGTERM, SIGHUP): Ctrl-C in the terminal, ``timeout`` and a
  closed terminal reach the whole process group, and the driver must still be able to send stopJ through its
  worker after them. The worker ends when the driver's end of its socket closes.
- One I/O thread per worker does every exchange on the socket, one request at a time, and the caller waits
  for its answer. A Ctrl-C handler that calls the driver's ``stop()`` while a request is in flight (Python
  runs signal handlers in the main thread, between any two bytecodes) only queues its stopJ behind it, and a
  KeyboardInterrupt that abandons a wait cannot leave half a message on the socket.
- A request is one round trip of small pickled tuples (about 0.1 ms on loopback; ``bench/ur.py``).

Requests (``Worker.call(name, *args)``): ``snapshot`` → :data:`Snapshot` tuple, ``move`` (q, speed rad/s,
acceleration rad/s²; asynchronous moveJ) → bool, ``stop`` (deceleration rad/s²; stopJ, waits for it) → None,
``reupload`` → bool (reupload ur_rtde's control script), ``progress`` → int (``getAsyncOperationProgress``:
< 0 when no asynchronous move runs), ``close`` (stopScript, then the worker exits). The joint stream
(drivers/ur/recorder.py: a thread of the worker records every RTDE package with its controller timestamp):
``stream_start`` (frequency Hz; restarts a running one) → None, ``stream_read`` (at most N samples) →
:data:`drivers.ur.recorder.Batch`, ``stream_stop`` → the recorder's counters (dict), or None if none ran.

This module imports only the standard library; the child imports ``rtde_control`` and ``rtde_receive``.
"""

from __future__ import annotations

import contextlib
import os
import queue
import signal
import socket
import subprocess
import sys
import threading
from collections.abc import Iterator
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

START_TIMEOUT = 10.0  # s, at most, for the worker to start and open both interfaces
CALL_TIMEOUT = 3.0  # s, default for one request (stopJ waits for the arm to stop: seconds)
CLOSE_TIMEOUT = 2.0  # s, for stopScript at close before the worker is killed
#: the signals the worker ignores (see above); SIGHUP is POSIX only
STOP_SIGNALS = {s for s in (signal.SIGINT, signal.SIGTERM, getattr(signal, "SIGHUP", None)) if s is not None}

#: (link_ok, timestamp s, robot_mode, safety_mode, actual_q rad (6), actual_qd rad/s (6), program_running)
Snapshot = tuple[bool, float, int, int, list[float], list[float], bool]


class LinkLost(Exception):
    """The worker died, hung, or ur_rtde lost the link to the controller (one line: what happened)."""


class WorkerError(Exception):
    """ur_rtde raised inside the worker although the link is up (one line: its message)."""


# --- the worker process ------------------------------------------------------------------------------------


def _snapshot(receive: Any, control: Any) -> Snapshot:
    link_ok = bool(receive.isConnected()) and bool(control.isConnected())
    return (link_ok, float(receive.getTimestamp()), int(receive.getRobotMode()), int(receive.getSafetyMode()),
            list(receive.getActualQ()), list(receive.getActualQd()), bool(control.isProgramRunning()))


def _handle(receive: Any, control: Any, name: str, args: tuple[Any, ...], streams: dict[str, Any]) -> Any:
    if name == "snapshot":
        return _snapshot(receive, control)
    if name == "stream_read":
        recorder = streams.get("recorder")
        return ([], [], [], 0) if recorder is None else recorder.take(int(args[0]))
    if name == "progress":
        return int(control.getAsyncOperationProgress())
    if name in ("stream_start", "stream_stop"):
        from drivers.ur.recorder import Recorder

        old = streams.pop("recorder", None)
        if old is not None:
            old.stop()
        if name == "stream_start":
            streams["recorder"] = Recorder(receive, float(args[0]))
            return None
        return None if old is None else old.stats()
    if name == "move":
        q, speed, acceleration = args
        return bool(control.moveJ(list(q), float(speed), float(acceleration), True))
    if name == "stop":
        control.stopJ(float(args[0]), False)
        return None
    if name == "reupload":
        return bool(control.reuploadScript())
    raise ValueError(f"unknown request {name!r}")


def serve(conn: Any, host: str, frequency: float, quiet: bool = True) -> None:
    """The worker's main loop (runs in the child): open the interfaces, then answer requests until ``close``
    or until the driver's end of the pipe closes. ``quiet``: ur_rtde's own printing goes to /dev/null."""
    for signum in STOP_SIGNALS:
        signal.signal(signum, signal.SIG_IGN)
    with contextlib.suppress(AttributeError, OSError):
        signal.pthread_sigmask(signal.SIG_UNBLOCK, STOP_SIGNALS)
    if quiet:  # ur_rtde prints its reconnection attempts and errors; the driver reports what happened instead
        null = os.open(os.devnull, os.O_WRONLY)
        os.dup2(null, 1)
        os.dup2(null, 2)
    try:
        import rtde_control
        import rtde_receive

        receive = rtde_receive.RTDEReceiveInterface(host, frequency)
        control = rtde_control.RTDEControlInterface(host, frequency)
    except Exception as exc:  # ur_rtde raises RuntimeError and others: report them all
        conn.send((0, "error", " ".join(str(exc).split()) or type(exc).__name__))
        return
    conn.send((0, "ok", None))
    streams: dict[str, Any] = {}  # the joint-stream recorder, when one runs
    while True:
        try:
            number, name, args = conn.recv()
        except (EOFError, OSError):
            break  # the driver went away
        if name == "close":
            with contextlib.suppress(Exception):
                control.stopScript()
            with contextlib.suppress(OSError):
                conn.send((number, "ok", None))
            break
        try:
            reply = (number, "ok", _handle(receive, control, name, args, streams))
        except Exception as exc:  # becomes WorkerError in the driver
            reply = (number, "error", f"{type(exc).__name__}: {' '.join(str(exc).split())}")
        try:
            conn.send(reply)
        except OSError:
            break
    # Exit without ur_rtde's disconnect(): it sleeps 0.5 s per interface, and its threads must not outlive us;
    # the operating system closes the sockets.
    os._exit(0)


# --- the driver's side -------------------------------------------------------------------------------------


@contextlib.contextmanager
def _stop_signals_blocked() -> Iterator[None]:
    """Hold the stop signals back in this thread for the block; they are delivered (the handlers run) right
    after."""
    try:
        old = signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)
    except (AttributeError, OSError, ValueError):  # no pthread_sigmask (Windows)
        yield
        return
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


class Worker:
    """One worker process connected to the controller at ``host`` (see the module docstring).

    ``Worker(host, timeout)`` starts it and waits until both interfaces are open: LinkLost if it cannot
    (the message is ur_rtde's, on one line). ``frequency``: RTDE rate in Hz (-1: the controller's default).
    """

    def __init__(self, host: str, timeout: float = START_TIMEOUT, frequency: float = -1.0) -> None:
        self.host = host
        ours, theirs = socket.socketpair()
        self._number = 0
        self._requests: queue.SimpleQueue[Any] = queue.SimpleQueue()
        self._closed = False
        root = str(Path(__file__).resolve().parents[2])  # the folder holding the drivers package
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, (root, os.environ.get("PYTHONPATH"))))}
        command = [sys.executable, "-m", "drivers.ur.worker", host, str(theirs.fileno()), repr(float(frequency))]
        try:
            with _stop_signals_blocked():  # the child inherits the mask: no window before it ignores them
                self._process = subprocess.Popen(command, pass_fds=(theirs.fileno(),), env=env,
                                                 stdin=subprocess.DEVNULL)
        except OSError as exc:
            ours.close()
            raise LinkLost(f"cannot start the ur_rtde worker: {exc}") from None
        finally:
            theirs.close()
        self._conn = Connection(ours.detach())
        try:
            status, detail = self._reply(0, timeout)
        except LinkLost:
            self.kill()
            raise
        if status != "ok":
            self.kill()
            raise LinkLost(str(detail))
        self._io = threading.Thread(target=self._serve_requests, daemon=True, name=f"ur-rtde-io-{host}")
        self._io.start()

    @property
    def alive(self) -> bool:
        return self._process.poll() is None

    @property
    def pid(self) -> int:
        return self._process.pid

    def call(self, name: str, *args: Any, timeout: float = CALL_TIMEOUT) -> Any:
        """The worker's answer to request ``name``. LinkLost (the worker is killed) when it died or did not
        answer within ``timeout`` s (after the requests queued before it); WorkerError when ur_rtde raised."""
        if self._closed:
            raise LinkLost("the ur_rtde worker was ended")
        answer: list[tuple[str, Any]] = []
        done = threading.Lock()  # released by the I/O thread when the answer is in (lighter than an Event)
        done.acquire()
        self._requests.put((name, args, timeout, answer, done))
        if not done.acquire(timeout=2 * timeout + 1.0):  # its own timeout, and one request in flight before it
            self.kill()
            raise LinkLost(f"the ur_rtde worker did not answer within {timeout:g} s")
        status, result = answer[0]
        if status == "ok":
            return result
        if status == "error":
            raise WorkerError(str(result))
        raise result  # LinkLost

    def _serve_requests(self) -> None:
        """The I/O thread: every exchange on the socket, in order, until the worker is ended."""
        while True:
            item = self._requests.get()
            if item is None:  # ended: whatever is still queued gets LinkLost at once
                while True:
                    try:
                        item = self._requests.get_nowait()
                    except queue.Empty:
                        return
                    if item is not None:
                        item[3].append(("lost", LinkLost("the ur_rtde worker was ended")))
                        item[4].release()
            name, args, timeout, answer, done = item
            try:
                if self._closed:
                    raise LinkLost("the ur_rtde worker was ended")
                self._number += 1
                try:
                    self._conn.send((self._number, name, args))
                except (OSError, ValueError) as exc:
                    self.kill()
                    raise LinkLost(f"the ur_rtde worker is gone ({exc})") from None
                answer.append(self._reply(self._number, timeout))
            except LinkLost as exc:
                answer.append(("lost", exc))
            finally:
                done.release()

    def _reply(self, number: int, timeout: float) -> tuple[str, Any]:
        try:
            while self._conn.poll(timeout):
                got, status, result = self._conn.recv()
                if got == number:
                    return status, result
            # poll timed out
        except (EOFError, OSError) as exc:
            with contextlib.suppress(subprocess.TimeoutExpired):
                self._process.wait(0.5)
            code = self._process.returncode
            how = f"exit code {code}" if code is None or code >= 0 else f"signal {-code}"
            self.kill()
            raise LinkLost(f"the ur_rtde worker process died ({how})") from exc
        self.kill()
        raise LinkLost(f"the ur_rtde worker did not answer within {timeout:g} s")

    def close(self, timeout: float = CLOSE_TIMEOUT) -> None:
        """Stop ur_rtde's control script and end the worker (killed if it does not end in ``timeout`` s)."""
        if self.alive and not self._closed:
            with contextlib.suppress(LinkLost, WorkerError):
                self.call("close", timeout=timeout)
            with contextlib.suppress(subprocess.TimeoutExpired):
                self._process.wait(timeout)
        self.kill()

    def kill(self) -> None:
        """End the worker now (SIGKILL) and its I/O thread; never raises."""
        self._closed = True
        with contextlib.suppress(Exception):
            if self._process.poll() is None:
                self._process.kill()
            self._process.wait(1.0)
        with contextlib.suppress(Exception):
            self._conn.close()
        self._requests.put(None)


def main(argv: list[str]) -> None:
    """``python -m drivers.ur.worker HOST FD FREQUENCY``: serve on the inherited socket ``FD``."""
    host, fd, frequency = argv
    serve(Connection(int(fd)), host, float(frequency))


if __name__ == "__main__":
    main(sys.argv[1:])
