"""Acquisition: the plan (decided before anything moves, checked against the limits and the cell), the orchestrator
that moves, settles, measures and records through ``session``, and the ``acquire`` command."""
