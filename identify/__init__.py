"""Identification of DH parameters from tracked-point measurements (no devices).

Pure computation in ``estimator`` (the math), ``results`` (the identification as one function and what its result
says), ``applications`` (compensation, comparison, checks, ISO 9283), ``simulators`` and ``programs``; files are
read and written at the edge: ``io`` (measurement CSV, result YAML, a session's measurements), ``report`` (terminal
and HTML) and ``exports`` (URDF, UR calibration, Robotics Toolbox). The ``identify`` command: ``commands``; the
Python API: ``api``."""

from common import __version__ as __version__  # the software's version, as it always was here
