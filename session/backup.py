"""A consistent copy of a session file, even while another process writes it (``acquire backup SESSION DEST``)."""

from __future__ import annotations

import contextlib
import os
import sqlite3
import tempfile
from pathlib import Path

from common.outputs import check_outputs, commit_file
from session.schema import SessionError
from session.store import SessionFile


def backup_session(source: str | Path, dest: str | Path, force: bool = False) -> int:
    """Copy the session ``source`` to the new file ``dest`` with SQLite's online backup API: a consistent copy
    even while another process writes the session (its commits wait the few milliseconds the copy takes).
    The copy is one file (rollback journal), built beside ``dest`` and moved into place whole; ``dest`` may not
    be ``source`` and is replaced only with ``force`` (OutputError). Returns the number of steps copied."""
    source, dest = Path(source), Path(dest)
    check_outputs([source], [("DEST", dest)], force)
    fd, tmp = tempfile.mkstemp(prefix=f".{dest.name}.", suffix=".tmp", dir=dest.parent)
    os.close(fd)
    temp = Path(tmp)
    try:
        with (SessionFile.open(source) as session,
              contextlib.closing(sqlite3.connect(temp, isolation_level=None)) as copy):
            session.backup_to(copy)
            copy.execute("PRAGMA journal_mode = DELETE")  # a session of an older version may be in WAL mode
            steps = copy.execute("SELECT count(*) FROM steps").fetchone()[0]
            if copy.execute("PRAGMA quick_check").fetchone()[0] != "ok":
                raise SessionError(f"{dest}: the copy of {source} does not check out; nothing was written")
        with open(temp, "rb+") as fh:
            os.fsync(fh.fileno())
        commit_file(temp, dest, force)
    except sqlite3.Error as exc:
        raise SessionError(f"{dest}: cannot copy {source} ({exc})") from None
    except OSError as exc:
        raise SessionError(f"{dest}: cannot copy {source} ({exc.strerror or exc})") from None
    finally:
        with contextlib.suppress(OSError):
            temp.unlink()
    return int(steps)
