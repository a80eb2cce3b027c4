"""The byte trace of a device link (``--trace-io FILE``), for support cases, and one-line error text.

Each chunk sent or received is one line: ``<epoch s> <direction> <bytes repr>``; events are
``<epoch s> # <text>``. The file is opened on connect and closed on close (a file object given by the
caller is left open).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import IO


class ByteTrace:
    """Logs every byte to and from a device when given a path or a text file; does nothing otherwise."""

    def __init__(self, target: str | Path | IO[str] | None) -> None:
        self._target = target
        self._file: IO[str] | None = None

    def open(self) -> None:
        if self._target is not None and self._file is None:
            target = self._target
            self._file = target if hasattr(target, "write") else open(target, "a", encoding="utf-8")  # type: ignore[arg-type]  # noqa: SIM115

    def close(self) -> None:
        if self._file is not None and self._file is not self._target:
            self._file.close()
        self._file = None

    def data(self, direction: str, data: bytes) -> None:
        if self._file is not None and data:
            self._file.write(f"{time.time():.6f} {direction} {data!r}\n")
            self._file.flush()

    def event(self, text: str) -> None:
        if self._file is not None:
            self._file.write(f"{time.time():.6f} # {text}\n")
            self._file.flush()


def one_line(exc: BaseException) -> str:
    """An exception's message on one line (its type name when it has none)."""
    return " ".join(str(exc).split()) or type(exc).__name__
