"""The one-writer lock of a session file: an exclusive ``flock`` on the file itself, no side file.

``flock`` locks are separate from the POSIX byte-range locks SQLite takes on the same file (on local file
systems), are released by the kernel when the process dies (``kill -9`` included), and stay with the file when it
is renamed or linked. The holder's PID comes from the kernel's lock table (``/proc/locks`` on Linux); elsewhere
from the ``writer`` row the holder recorded in the session. Platforms without ``fcntl`` get no lock.
"""

from __future__ import annotations

import contextlib
import os
import sqlite3
from pathlib import Path

from session.schema import SessionBusy, SessionError

try:
    import fcntl
except ImportError:  # not POSIX: no lock (one writer is then the operator's job)
    fcntl = None  # type: ignore[assignment]


class Locked(Exception):
    """Another process holds the write lock; ``holder`` says which ("process 1234 on host (command)")."""

    def __init__(self, holder: str) -> None:
        super().__init__(holder)
        self.holder = holder


_held: dict[tuple[int, int], int] = {}  # (device, inode) -> descriptor locked by hold() and not yet claimed


def hold(path: Path) -> None:
    """Take the lock of ``path`` now, for this process's next :func:`write_lock` of the same file to claim (the
    ``acquire`` command takes it before its heavy imports). Locked / OSError as :func:`write_lock`."""
    fd = write_lock(path)
    st = os.fstat(fd)
    _held[(st.st_dev, st.st_ino)] = fd


def drop_held() -> None:
    """Release every lock taken by :func:`hold` and not claimed (the command ended before opening its session)."""
    while _held:
        unlock(_held.popitem()[1])


def write_lock(path: Path) -> int:
    """An open descriptor of ``path`` holding its exclusive lock, taken at once or not at all: Locked if another
    process holds it, OSError if the file cannot be opened for writing. Release with :func:`unlock`."""
    fd = os.open(path, os.O_RDWR)
    st = os.fstat(fd)
    if (st.st_dev, st.st_ino) in _held:  # taken by hold() in this process: hand it over
        os.close(fd)
        return _held.pop((st.st_dev, st.st_ino))
    if fcntl is None:
        return fd
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(fd)
        raise Locked(holder(path)) from None
    except OSError:
        os.close(fd)
        raise
    return fd


def busy_message(path: Path, holder: str) -> str:
    """The one line that refuses a second writer of ``path``."""
    return (f"{path} is being written by {holder}; one writer at a time: wait for it to end or stop it (readers "
            "such as identify and export work meanwhile)")


def unlock(fd: int | None) -> None:
    """Release a lock from :func:`write_lock` (closing its descriptor); None does nothing."""
    if fd is not None:
        with contextlib.suppress(OSError):
            os.close(fd)


def holder(path: Path) -> str:
    """Who holds the write lock of ``path``: "process PID" from the kernel's lock table (Linux), with the host
    and command the writer recorded in the session when they agree, else "another process"."""
    pid = _flock_pid(path)
    recorded = None
    try:
        with contextlib.closing(sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro", uri=True, timeout=0.2)) as db:
            recorded = db.execute("SELECT pid, host, command FROM writer WHERE id = 1").fetchone()
    except sqlite3.Error:
        recorded = None
    if recorded is not None and (pid is None or recorded[0] == pid):
        return f"process {recorded[0]} on {recorded[1]} ({recorded[2][:120]})"
    return f"process {pid}" if pid is not None else "another process"


def _flock_pid(path: Path) -> int | None:
    """The PID holding a write flock on ``path`` according to /proc/locks, or None."""
    try:
        st = os.stat(path)
        with open("/proc/locks", encoding="ascii") as fh:
            for line in fh:
                fields = line.split()
                if len(fields) >= 6 and fields[1] == "FLOCK" and fields[3] == "WRITE":
                    major, minor, inode = fields[5].split(":")
                    if (int(inode), int(major, 16), int(minor, 16)) == (st.st_ino, os.major(st.st_dev),
                                                                        os.minor(st.st_dev)):
                        return int(fields[4]) or None
    except (OSError, ValueError):
        return None
    return None


def lock_for_writing(path: Path, shown: Path) -> int:
    """The write lock of ``path`` (:func:`write_lock`), ``shown`` in its messages, errors as SessionError."""
    try:
        return write_lock(path)
    except Locked as exc:
        raise SessionBusy(busy_message(shown, exc.holder)) from None
    except OSError as exc:
        raise SessionError(f"{shown}: cannot be opened for writing ({exc.strerror or exc})") from None


def remove_dead_creations(path: Path) -> None:
    """Remove the hidden files (``.NAME.creating-PID`` and its SQLite journal ``-journal``) that a process killed
    while creating session ``path`` left behind: never committed, so never a session; a live process's files are
    left alone."""
    prefix = f".{path.name}.creating-"
    for stale in path.parent.glob(f"{prefix}*"):
        pid = stale.name[len(prefix):].removesuffix("-journal")
        if not pid.isdigit():
            continue
        try:
            os.kill(int(pid), 0)
        except ProcessLookupError:
            with contextlib.suppress(OSError):
                stale.unlink()
        except PermissionError:  # another user's live process
            pass
