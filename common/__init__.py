"""What every package shares and none owns: the software's version (``__version__``), the one-line error of a bad
input (``errors``), output files written whole or not at all (``outputs``) and the signals that stop a command
(``stop_signals``). Imports nothing of the project; ``__version__`` is looked up on first use (importlib.metadata
costs tens of milliseconds that a command's ``--help`` or refusal need not pay)."""


def __getattr__(name: str) -> str:
    if name != "__version__":
        raise AttributeError(f"module 'common' has no attribute {name!r}")
    from importlib.metadata import PackageNotFoundError, version

    try:
        value = version("dh-calib")
    except PackageNotFoundError:  # running from a source tree that was not installed
        value = "0.0.0+source"
    globals()["__version__"] = value
    return value
