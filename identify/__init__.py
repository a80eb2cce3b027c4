"""Identification of DH parameters from tracked-point measurements (pure computation, no devices)."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("dh-calib")
except PackageNotFoundError:  # running from a source tree that was not installed
    __version__ = "0.0.0+source"
