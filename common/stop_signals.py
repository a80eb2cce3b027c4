"""The signals that mean "stop": Ctrl-C (SIGINT), SIGTERM (``timeout``, ``kill``, a supervisor) and SIGHUP (the
terminal or the SSH session closed). The commands treat the three alike: a run stops its motion and is recorded
``aborted`` (resumable); at any other moment the command stops with one line and exit code 130.

Python raises KeyboardInterrupt for SIGINT; :func:`raising` makes SIGTERM and SIGHUP raise :class:`Stopped`, a
KeyboardInterrupt that remembers its signal, so every ``except KeyboardInterrupt`` handles them too. During the
start-up imports :func:`deferred` only keeps a stop and raises it after them: raised inside a compiled module's
initialisation it would become an ImportError, or be lost in a ``try: import``. (A signal in the interpreter's own
start-up, the ~30 ms before the entry point's first line, still meets the system's default: exit 143.)
"""

from __future__ import annotations

import os
import signal
import sys
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager

#: The stop signals this platform has (SIGHUP is POSIX only).
SIGNALS: tuple[int, ...] = tuple(s for s in (signal.SIGINT, signal.SIGTERM, getattr(signal, "SIGHUP", None))
                                 if s is not None)


def reason(signum: int | None) -> str:
    """Why the command stopped, as recorded in the session and printed: ``stopped by the operator (Ctrl-C)``."""
    if signum is None or signum == signal.SIGINT:
        return "stopped by the operator (Ctrl-C)"
    if signum == getattr(signal, "SIGHUP", None):
        return "stopped by SIGHUP (the terminal or the SSH session closed)"
    return f"stopped by {signal.Signals(signum).name}"


class Stopped(KeyboardInterrupt):
    """A stop signal other than Ctrl-C, raised where Python raises KeyboardInterrupt for Ctrl-C."""

    def __init__(self, signum: int) -> None:
        super().__init__(reason(signum))
        self.signum = signum


def reason_of(exc: BaseException) -> str:
    """The stop reason of a KeyboardInterrupt (a :class:`Stopped` names its signal)."""
    return reason(exc.signum if isinstance(exc, Stopped) else None)


_pending: int | None = None  # the last stop signal received (see guarded), None when none


def _raise(signum: int, _frame: object) -> None:
    global _pending
    _pending = signum
    raise Stopped(signum)


def raise_pending() -> None:
    """Raise :class:`Stopped` when a stop signal has been received under :func:`guarded` (it may have become
    another error on its way, e.g. the ImportError of an interrupted import); else nothing."""
    if _pending is not None:
        raise Stopped(_pending)


def _keep(signum: int) -> None:
    global _pending
    _pending = signum


@contextmanager
def routed(handler: Callable[[int], None], signals: tuple[int, ...] = SIGNALS) -> Iterator[None]:
    """Call ``handler(signum)`` for each of ``signals`` inside the block; the previous handlers afterwards. Does
    nothing outside the main thread (only it may set handlers)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {s: signal.signal(s, lambda signum, _frame: handler(signum)) for s in signals}
    try:
        yield
    finally:
        for s, old in previous.items():
            signal.signal(s, old)


@contextmanager
def raising() -> Iterator[None]:
    """Inside the block SIGTERM and SIGHUP raise :class:`Stopped` (SIGINT keeps Python's KeyboardInterrupt)."""
    with routed(lambda signum: _raise(signum, None), tuple(s for s in SIGNALS if s != signal.SIGINT)):
        yield


@contextmanager
def deferred() -> Iterator[None]:
    """Inside the block a stop signal (Ctrl-C included) is only kept; it is raised (:class:`Stopped`) when the block
    ends. For start-up imports: a KeyboardInterrupt raised inside a compiled module's initialisation becomes an
    ImportError ("initialization failed"), and one raised inside a ``try: import ... except ImportError`` is lost."""
    global _pending
    _pending = None
    with routed(_keep):
        try:
            yield
        finally:
            signum = _pending
            if signum is not None:
                raise Stopped(signum)


def guarded(prog: str, body: Callable[[], int]) -> int:
    """A command's entry point: ``body()`` with SIGTERM and SIGHUP raising as Ctrl-C does; a stop at any moment
    (start-up imports included) is one line on stderr and exit code 130, a closed stdout (``| head``) a quiet
    exit 141 (128 + SIGPIPE, what a shell reports for a command its pipe stopped)."""
    global _pending
    _pending = None
    try:
        with raising():
            return body()
    except KeyboardInterrupt as exc:  # a Stopped says which signal; Python's own KeyboardInterrupt is Ctrl-C
        print(f"{prog}: {str(exc) or reason(None)}", file=sys.stderr)
        return 130
    except BrokenPipeError:  # the reader of stdout went away: stop quietly, as a pipeline expects
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no second error when Python flushes it
        return 141
    except BaseException:  # a stop raised where it became another error (an import's ImportError): still a stop
        if _pending is None:
            raise
        print(f"{prog}: {reason(_pending)}", file=sys.stderr)
        return 130
