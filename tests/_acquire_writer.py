"""Helper process for the crash-copy and two-writer tests: runs the real ``acquire`` command in forked children.

    python -m tests._acquire_writer        then, per line on stdin, a JSON list of ``acquire`` arguments

It imports ``acquire.cli`` once (a fresh interpreter costs most of a second of imports), then for each line
forks a child that runs ``acquire.cli.main(ARGS)`` and prints, unbuffered:

    pid N            the child's process id (the test may SIGKILL it)
    opened           the child opened a robot driver (anything after this may move the robot)
    ack I            step I was recorded (printed after ``record_step`` returned: committed)
    exit CODE        the child ended (negative: killed by that signal)

In the child the end-of-run identification (``SESSION.result.yaml`` and the HTML report) and the dry-run style
accuracy prediction are skipped: the tests are about the session file, and these take most of a second.
"""

from __future__ import annotations

import json
import os
import sys

import acquire.cli as cli
import acquire.runner as runner
import drivers.registry as registry


def _say(text: str) -> None:
    os.write(1, f"{text}\n".encode())  # unbuffered: a line printed is a line the test can read, even after a kill


def _child(argv: list[str]) -> int:
    open_robot = registry.open_robot

    def opened(*args, **kwargs):
        _say("opened")
        return open_robot(*args, **kwargs)

    registry.open_robot = opened
    # identification is not under test
    runner.identify_session = lambda *args, **kwargs: {"verdict": {"status": "pass"}}
    cli.predicted_accuracy = lambda *args, **kwargs: None
    cli.format_plan = lambda *args, **kwargs: "(plan)"
    runner.progress_printer = lambda quiet: (lambda p: _say(f"ack {p.step.index}"))
    return cli.main(argv)


def main() -> None:
    for line in sys.stdin:
        if not line.strip():
            break
        argv = json.loads(line)
        pid = os.fork()
        if pid == 0:
            code = 1
            try:
                sys.stdout = open(os.devnull, "w")  # noqa: SIM115  # the command's own output is not the protocol
                code = _child(argv)
            except BaseException as exc:  # never let the child return into the server loop
                _say(f"error {type(exc).__name__}: {exc}")
            os._exit(code)
        _say(f"pid {pid}")
        _, status = os.waitpid(pid, 0)
        _say(f"exit {os.waitstatus_to_exitcode(status)}")


if __name__ == "__main__":
    main()
