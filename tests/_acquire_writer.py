"""Helper process for the crash tests: runs the real ``acquire`` command in forked children; :class:`Writer` is its
client in the test process.

    python -m tests._acquire_writer        then, per line on stdin, a JSON list of ``acquire`` arguments

It imports ``acquire.commands.cli`` once (a fresh interpreter costs most of a second of imports), then for each line
forks a child that runs ``acquire.commands.cli.main(ARGS)`` and prints, unbuffered:

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
import subprocess
import sys
import time
from pathlib import Path

import acquire.commands.cli as cli
import acquire.running.runner as runner
import drivers.registry as registry

ROOT = Path(__file__).resolve().parents[1]


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
    runner.progress_printer = lambda quiet, display: (lambda p: _say(f"ack {p.step.index}"))
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


class Writer:
    """One tests/_acquire_writer.py server: ``start(args)`` forks a child running ``acquire ARGS``."""

    def __init__(self, tmp_path: Path, name: str = "writer") -> None:
        env = {**os.environ, "PYTHONPATH": str(ROOT), "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1",
               "MKL_NUM_THREADS": "1"}
        self.err = (tmp_path / f"{name}.err").open("w")
        # run with -m: as a script its folder, tests/, would come first on sys.path, and tests/ holds packages named
        # like the project's (tests/acquire/...)
        self.proc = subprocess.Popen([sys.executable, "-m", "tests._acquire_writer"], stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, stderr=self.err, text=True, cwd=tmp_path, env=env)
        self.lines: list[str] = []

    def start(self, args: list[str]) -> int:
        """Fork a child running ``acquire ARGS``; its pid."""
        self.lines = []
        self.proc.stdin.write(json.dumps([str(a) for a in args]) + "\n")
        self.proc.stdin.flush()
        word, value = self._line()
        assert word == "pid", (word, value)
        return int(value)

    def finish(self, timeout: float = 60.0) -> int:
        """Read the child's lines until it ends; its exit code (negative: killed by that signal)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            word, value = self._line()
            if word == "exit":
                return int(value)
        raise AssertionError("the writer child did not end in time")

    def until(self, text: str) -> None:
        """Read the child's lines until ``text`` (e.g. ``ack 1``); AssertionError if the child ends first."""
        while True:
            word, value = self._line()
            assert word != "exit", f"the child ended ({value}) before {text!r}: {self.lines}"
            if f"{word} {value}" == text:
                return

    def until_acks(self, count: int) -> int | None:
        """Read the child's lines until it has recorded ``count`` steps (None) or ended (its exit code)."""
        while True:
            word, value = self._line()
            if word == "exit":
                return int(value)
            if word == "ack" and len(self.acked()) >= count:
                return None

    def acked(self) -> set[int]:
        return {int(line.split()[1]) for line in self.lines if line.startswith("ack ")}

    def opened(self) -> bool:
        return "opened" in self.lines

    def _line(self) -> tuple[str, str]:
        line = self.proc.stdout.readline()
        assert line, f"the writer server died: {Path(self.err.name).read_text()[-2000:]}"
        line = line.strip()
        if line.startswith("error "):
            raise AssertionError(f"writer child failed: {line}")
        self.lines.append(line)
        word, _, value = line.partition(" ")
        return word, value

    def close(self) -> None:
        self.proc.stdin.close()
        self.proc.wait(timeout=10)
        self.err.close()


if __name__ == "__main__":
    main()
