"""The error of a bad input, shared by every command (``identify``, ``acquire``): raised by the readers, the checks
and the math alike, caught once by each command, which prints the one-line message and exits with code 2."""


class InputError(ValueError):
    """Measurements that cannot be identified, or an input or option that cannot be used; the message is one line
    meant for the operator."""


#: dh-calib's extras (pyproject.toml) and what each installs; dh-calib itself is installed from its repository
EXTRAS = {"ur": "ur-rtde==1.6.5", "serial": "pyserial>=3.5,<4", "vision": "opencv-contrib-python-headless>=4.9,<6",
          "report": "matplotlib>=3.8,<4"}


def install_hint(extra: str) -> str:
    """How to install what dh-calib's ``extra`` brings: ``pip install 'ur-rtde==1.6.5' (the ur extra)``."""
    return f"pip install '{EXTRAS[extra]}' (the {extra} extra)"
