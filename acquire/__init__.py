"""Acquisition: the plan (``planning``: decided before anything moves, checked against the limits and the cell), the
run (``running``: the orchestrator that moves, settles, measures and records through ``session``), the verification
test (``verification``), and the ``acquire`` command (``commands``)."""
