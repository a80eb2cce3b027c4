"""What every package shares and none owns: the software's version (``__version__``), the one-line error of a bad
input (``errors``) and output files written whole or not at all (``outputs``). Imports nothing of the project."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("dh-calib")
except PackageNotFoundError:  # running from a source tree that was not installed
    __version__ = "0.0.0+source"
