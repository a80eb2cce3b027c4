"""A session as ``acquire`` uses it: the session file (session/store.py: create, open, record, read back) with its
measurements (identify/io/session_measurements.py: the recorded rows as the measurement CSV's).

The file's format, durability and one-writer lock: session/."""

from __future__ import annotations

from pathlib import Path

from identify.estimator.measurements import Measurements
from identify.io.session_measurements import export_csv, session_measurements
from session.store import SessionFile


class Session(SessionFile):
    """An open session file (:class:`session.store.SessionFile`) that also gives its measurements. Create with
    :meth:`create`, reopen with :meth:`open`; use as a context manager."""

    def to_measurements(self) -> Measurements:
        """The ok steps as measurement-CSV rows, in plan order, and a continuous session's streamed rows
        (:func:`identify.io.session_measurements.session_measurements`)."""
        return session_measurements(self)

    def export_csv(self, path: str | Path, force: bool = False) -> int:
        """Write :meth:`to_measurements` as the measurement CSV (with session, robot and tracker metadata lines);
        returns the number of rows. The file appears whole or not at all; an existing file is replaced only with
        ``force``, the session itself never (OutputError)."""
        return export_csv(self, path, force)
