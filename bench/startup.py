"""CPU time of the commands' quick answers: ``--help``, ``--version`` and one-line refusals (issues 25, 39), and the
width of every ``--help`` on an 80-column terminal.

    python -m bench.startup [--repeats 5]

Each case runs the installed console script (``.venv/bin/acquire``, ``.venv/bin/identify``) as a fresh process,
``--repeats`` times, with ``COLUMNS=80``; the CPU time (user + system, of the process and its children) comes from
``getrusage``. Prints the median per case and, for a help, its widest line; exits 1 when any median exceeds
:data:`TARGET` or any help is wider than :data:`COLUMNS`.
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

TARGET = 0.3  # s of CPU: an answer that feels immediate, even on a loaded controller PC
COLUMNS = 80  # the terminal every help must fit
CASES = (("acquire", "--help"), ("acquire", "--version"), ("acquire", "--robot", "moc:ur5e"),
         ("acquire", "--noise", "0.05xx"), ("acquire", "export", "--help"), ("acquire", "backup", "--help"),
         ("acquire", "verify", "--help"), ("acquire", "calibrate-camera", "--help"),
         ("acquire", "print-board", "--help"),
         ("identify", "--help"), ("identify", "--version"), ("identify", "compare", "--help"),
         ("identify", "compensate", "--help"), ("identify", "check", "--help"),
         ("identify", "missing.csv"), ("identify", "x.csv", "--noise", "0.05xx"))


def cpu_seconds(argv: list[str], cwd: str) -> tuple[float, int]:
    """CPU time (s) of one run of ``argv`` at ``COLUMNS`` columns, and the widest line it printed."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    out = subprocess.run(argv, cwd=cwd, capture_output=True, check=False, text=True,
                         env={**os.environ, "COLUMNS": str(COLUMNS)})
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    widest = max((len(line) for line in (out.stdout + out.stderr).splitlines()), default=0)
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime), widest


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    bin_ = Path(sys.executable).parent
    worst, widest = 0.0, 0
    with tempfile.TemporaryDirectory() as cwd:
        print(f"{'command':<40} {'median CPU s':>12} {'max':>8} {'columns':>8}")
        for case in CASES:
            runs = [cpu_seconds([str(bin_ / case[0]), *case[1:]], cwd) for _ in range(args.repeats)]
            times = [t for t, _ in runs]
            median = float(np.median(times))
            worst = max(worst, median)
            width = max(w for _, w in runs) if "--help" in case else 0
            widest = max(widest, width)
            print(f"{' '.join(case):<40} {median:12.3f} {max(times):8.3f} {width or '':>8}")
    ok = worst <= TARGET and widest <= COLUMNS
    print(f"target: every median <= {TARGET} s of CPU, every help <= {COLUMNS} columns: {'met' if ok else 'MISSED'} "
          f"(worst {worst:.3f} s, widest {widest})")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
