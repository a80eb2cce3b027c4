"""What every package shares and none owns: the software's version, the one-line error of a bad input (``errors``)
and output files written whole or not at all (``outputs``). Imports nothing of the project."""
