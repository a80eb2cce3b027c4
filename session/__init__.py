"""The session file (one SQLite file per acquisition): its schema (``schema``), the one-writer lock (``lock``), the
plan and step records it stores (``plan``, ``records``), their rows (``rows``; stream samples written by
``streams`` and read back by ``stream_data``), the open file (``store``) and its consistent copy (``backup``).
``acquire`` writes through it; ``identify``'s edge (identify/io/session_measurements.py) reads through it. Imports only
``kinematics``, ``common`` and ``drivers.base``."""
