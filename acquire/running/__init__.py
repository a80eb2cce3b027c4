"""A session run on the devices: the orchestrator, continuous sweeps, the session file, progress, rehearsal, resume."""
