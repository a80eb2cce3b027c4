"""Output files that never lose data: checked before any work, written whole or not at all.

Every command that writes files (``identify --out`` and its exports, ``acquire export``, ``acquire backup``, the
result and report beside a session, a new session) goes through this module:

- :func:`check_outputs` runs first, before anything is read or computed: an output that is one of the inputs
  (same resolved path or same file through a link), the same file as another output, an existing file
  without ``force``, a folder, or a file whose parent folder does not exist is refused with an
  :class:`OutputError` (one line). Folders are never created.
- :func:`write_output` writes to a temporary file beside the target, flushes it to disk and renames it into
  place, so a crash leaves the old file or the new one, never half a file. Without ``force`` it links the file
  into place instead, which fails if another process created the target in the meantime.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Callable, Iterable
from pathlib import Path

from common.errors import InputError


class OutputError(InputError):
    """An output that would overwrite data or cannot be written; the message is one line for the operator."""


def same_file(a: str | Path, b: str | Path) -> bool:
    """True when ``a`` and ``b`` name one file: equal resolved paths, or (both existing) the same inode."""
    a, b = Path(a), Path(b)
    if a.resolve() == b.resolve():
        return True
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def check_outputs(inputs: Iterable[str | Path | None], outputs: Iterable[tuple[str, str | Path | None]],
                  force: bool = False) -> None:
    """Refuse (OutputError) outputs that would destroy data or cannot be written, before any work.

    ``inputs``: files the command reads (None entries are skipped). ``outputs``: ``(option, path)`` pairs, the
    option naming the output in the message (e.g. ``"--out"``); None paths are skipped. ``force`` allows
    replacing an existing output that is not an input.
    """
    ins = [Path(p) for p in inputs if p is not None]
    seen: list[tuple[str, Path]] = []
    for option, raw in outputs:
        if raw is None:
            continue
        path = Path(raw)
        for source in ins:
            if same_file(path, source):
                raise OutputError(f"{option} {path} is the input {source}; an input is never overwritten "
                                  "(choose another output name)")
        for other_option, other in seen:
            if same_file(path, other):
                raise OutputError(f"{option} {path} is also the output of {other_option}; choose two different files")
        seen.append((option, path))
        check_target(path, force, option)


def check_target(path: str | Path, force: bool = False, option: str = "output") -> None:
    """Refuse (OutputError) one output path: an existing folder, a missing parent folder, a folder where no file
    can be made (tried: a temporary file is created and removed, which no permission bit can fake), or an existing
    file without ``force``."""
    path = Path(path)
    parent = path.parent
    if path.is_dir():
        raise OutputError(f"{option} {path} is a folder; give a file name")
    if not parent.is_dir():
        raise OutputError(f"{option} {path}: the folder {parent} does not exist (it is not created; make it first)")
    if (path.exists() or path.is_symlink()) and not force:
        raise OutputError(f"{option} {path} already exists; pass --force to replace it")
    try:
        fd, probe = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".probe", dir=parent)
    except OSError as exc:
        raise OutputError(f"{option} {path}: no file can be written in {parent} ({exc.strerror})") from None
    os.close(fd)
    os.unlink(probe)


def write_output(path: str | Path, data: str | bytes, force: bool = False) -> None:
    """Write ``data`` (text as UTF-8) to ``path`` through a temporary file beside it, fsync'd, then put in place.

    With ``force`` the target is replaced atomically (``os.replace``); without it, an existing target is refused
    (OutputError), even one created after :func:`check_outputs` ran.
    """
    payload = data.encode("utf-8") if isinstance(data, str) else data
    place_file(path, lambda fh: fh.write(payload), force)


def place_file(path: str | Path, fill: Callable, force: bool = False) -> None:
    """Create a temporary file beside ``path``, let ``fill(binary_file)`` write it, flush it to disk and move it
    into place (replacing only with ``force``). OutputError (one line) if it cannot be written."""
    path = Path(path)
    check_target(path, force)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    except OSError as exc:
        raise OutputError(f"{path}: cannot be written ({exc.strerror or exc})") from None
    try:
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes it private; an output is an ordinary file
        with os.fdopen(fd, "wb") as fh:
            fill(fh)
            fh.flush()
            os.fsync(fh.fileno())
        commit_file(Path(tmp), path, force)
    except OSError as exc:
        raise OutputError(f"{path}: cannot be written ({exc.strerror or exc})") from None
    finally:
        with contextlib.suppress(OSError):
            os.unlink(tmp)


def commit_file(tmp: Path, path: Path, force: bool = False) -> None:
    """Move the complete, flushed file ``tmp`` to ``path`` (same folder) and flush the folder. Without ``force``
    the move fails (OutputError) if ``path`` exists: a hard link never replaces a file."""
    if force:
        os.replace(tmp, path)
    else:
        try:
            os.link(tmp, path)
        except FileExistsError:
            raise OutputError(f"{path} already exists; pass --force to replace it") from None
        except OSError:  # a file system without hard links: checked just before that the name is free
            if path.exists():
                raise OutputError(f"{path} already exists; pass --force to replace it") from None
            os.replace(tmp, path)
    fsync_folder(path.parent)


def fsync_folder(folder: Path) -> None:
    """Flush a folder's entries (a rename or link) to disk; skipped where folders cannot be opened."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)
