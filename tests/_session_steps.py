"""Reading a session file that another process is writing, from a test."""

from __future__ import annotations

import sqlite3
from pathlib import Path


def recorded_steps(path: Path) -> int:
    """Steps recorded so far, read without disturbing the writer (0 before the file exists)."""
    if not path.exists():
        return 0
    try:
        with sqlite3.connect(f"file:{path}?mode=ro", uri=True, timeout=1) as db:
            return int(db.execute("SELECT count(*) FROM steps").fetchone()[0])
    except sqlite3.Error:
        return 0
