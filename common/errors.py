"""The error of a bad input, shared by every command (``identify``, ``acquire``): raised by the readers, the checks
and the math alike, caught once by each command, which prints the one-line message and exits with code 2."""


class InputError(ValueError):
    """Measurements that cannot be identified, or an input or option that cannot be used; the message is one line
    meant for the operator."""
