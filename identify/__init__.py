"""Identification of DH parameters from tracked-point measurements (pure computation, no devices).

The estimation is the flat modules here; files are read and written at the edge: ``io`` (measurement CSV, result
YAML, a session's measurements), ``report`` (terminal and HTML) and ``exports`` (URDF, UR calibration, Robotics
Toolbox). The commands: ``cli`` (``identify``), ``compare_cli``, ``compensate_cli``; the Python API: ``api``."""

from common import __version__ as __version__  # the software's version, as it always was here
