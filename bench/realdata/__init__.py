"""Public robot-calibration measurement sets: one converter per set into the measurement CSV, and a benchmark of
the product against a DH-only baseline on them (``python -m bench.realdata DATA``; see README.md here)."""
