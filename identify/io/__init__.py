"""Files read and written at identify's edge: the measurement CSV (``csvio``), the result YAML (``result_io``) and
a session's measurements (``session_measurements``)."""
