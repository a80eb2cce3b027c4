"""Record ``make demo`` in an 80-column terminal with ``script`` (util-linux) and list every line wider than 80.

    python scripts/demo_width.py [--columns 80] [--keep FILE]

A line is what the terminal shows: the text after its last carriage return (a progress bar redraws itself in
place), without escape sequences. ``script``'s own first and last lines (its start and end stamps) are left out.
Exit status 0 when every line fits, 1 otherwise, 2 when ``script`` or ``make demo`` fails. The demo's sessions are
written to ``sessions/`` as ``make demo`` always does (about a minute).
"""

from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
ESCAPE = re.compile(r"\x1b(\[[0-9;?]*[ -/]*[@-~]|[()][0-9A-Za-z]|[=>])")


def shown_lines(typescript: str) -> list[str]:
    """The lines a terminal shows for ``typescript`` (the raw recording), escape sequences removed."""
    out = []
    for raw in typescript.split("\n"):
        parts = [ESCAPE.sub("", p) for p in raw.split("\r")]
        shown = next((p for p in reversed(parts) if p.strip()), "")
        out.append(shown)
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--columns", type=int, default=80)
    p.add_argument("--keep", type=Path, help="keep the recording in this file")
    args = p.parse_args(argv)
    if shutil.which("script") is None:
        print("demo_width: needs script (util-linux)", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory() as folder:
        record = args.keep or Path(folder) / "demo.typescript"
        done = subprocess.run(["script", "-q", "-e", "-c", f"stty cols {args.columns} rows 40; make demo",
                               str(record)], cwd=ROOT, stdin=subprocess.DEVNULL, capture_output=True)
        text = record.read_text(encoding="utf-8", errors="replace")
    if done.returncode != 0:
        print(f"demo_width: make demo exited {done.returncode}", file=sys.stderr)
        return 2
    lines = [line for line in shown_lines(text) if not line.startswith("Script ")]
    wide = [line for line in lines if len(line) > args.columns]
    for line in wide:
        print(f"{len(line):4d}  {line}")
    print(f"make demo at {args.columns} columns: {len(lines)} lines, {len(wide)} wider, widest "
          f"{max(map(len, lines), default=0)}")
    return 1 if wide else 0


if __name__ == "__main__":
    sys.exit(main())
