"""CPU time of the commands' quick answers: ``--help``, ``--version`` and one-line refusals (issue 25).

    python -m bench.startup [--repeats 5]

Each case runs the installed console script (``.venv/bin/acquire``, ``.venv/bin/identify``) as a fresh process,
``--repeats`` times; the CPU time (user + system, of the process and its children) comes from ``getrusage``.
Prints the median per case; exits 1 when any median exceeds :data:`TARGET`.
"""

from __future__ import annotations

import argparse
import resource
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

TARGET = 0.3  # s of CPU: an answer that feels immediate, even on a loaded controller PC
CASES = (("acquire", "--help"), ("acquire", "--version"), ("acquire", "--robot", "moc:ur5e"),
         ("acquire", "--noise", "0.05xx"), ("acquire", "export", "--help"), ("acquire", "backup", "--help"),
         ("acquire", "verify", "--help"),
         ("identify", "--help"), ("identify", "--version"),
         ("identify", "missing.csv"), ("identify", "x.csv", "--noise", "0.05xx"))


def cpu_seconds(argv: list[str], cwd: str) -> float:
    """CPU time (s) of one run of ``argv``."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    subprocess.run(argv, cwd=cwd, capture_output=True, check=False)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    bin_ = Path(sys.executable).parent
    worst = 0.0
    with tempfile.TemporaryDirectory() as cwd:
        print(f"{'command':<40} {'median CPU s':>12} {'max':>8}")
        for case in CASES:
            times = [cpu_seconds([str(bin_ / case[0]), *case[1:]], cwd) for _ in range(args.repeats)]
            median = float(np.median(times))
            worst = max(worst, median)
            print(f"{' '.join(case):<40} {median:12.3f} {max(times):8.3f}")
    ok = worst <= TARGET
    print(f"target: every median <= {TARGET} s of CPU: {'met' if ok else 'MISSED'} (worst {worst:.3f} s)")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
