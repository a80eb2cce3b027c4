"""Continuous-motion benchmark: robot time of a full mock UR5e session, stop-and-go against continuous.

    python -m bench.continuous [--tracker mock?latency=0.02] [--free-poses N] [--no-identify]

Each mode runs ``acquire --robot mock:ur5e --tracker TRACKER --mode MODE`` as a fresh process on the simulated
rig (virtual clock: the timestamps and durations of a real run, in seconds of wall time). Robot time = from the
first step's start to the last step's end on that clock (moves, settling, measuring, streaming). Samples: the
tracker readings a step-mode session records, or the streamed tracker samples plus the stop-and-go readings.
Also shown: the identification's held-out RMS (from the result YAML; the lead's sync fit will improve the
continuous one, whose timing here is the coarse clock offset). Target: continuous robot time <= 1/4 of step.
"""

from __future__ import annotations

import argparse
import sqlite3
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml


def robot_time(session: Path) -> tuple[float, int]:
    """(seconds from the first step's start to the last step's end on the rig's clock, tracker samples)."""
    with sqlite3.connect(session) as db:
        start, end = db.execute("SELECT min(t_start), max(t_end) FROM steps").fetchone()
        samples = db.execute("SELECT count(*) FROM readings").fetchone()[0]
        tables = {r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
        if "tracker_samples" in tables:
            samples += db.execute("SELECT count(*) FROM tracker_samples t JOIN streams s ON s.id = t.stream "
                                  "WHERE s.superseded = 0 AND s.status = 'complete'").fetchone()[0]
    return float(end - start), int(samples)


def held_out(result: Path) -> float | None:
    """The held-out RMS (m) of a result YAML, None when absent."""
    if not result.exists():
        return None
    doc = yaml.safe_load(result.read_text())
    validation = doc.get("validation") or {}
    value = validation.get("rms") if isinstance(validation, dict) else None
    return None if value is None else float(value)


def run(mode: str, tracker: str, folder: Path, extra: list[str]) -> tuple[float, int, float | None, float]:
    session = folder / f"{mode}.session"
    started = time.perf_counter()
    subprocess.run([sys.executable, "-m", "acquire.launch", "--robot", "mock:ur5e", "--tracker", tracker, "--mode",
                    mode, "--session", str(session), "--quiet", *extra], check=True, stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - started
    seconds, samples = robot_time(session)
    return seconds, samples, held_out(session.with_suffix(".result.yaml")), wall


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--tracker", default="mock?latency=0.02")
    p.add_argument("--free-poses", type=int)
    args = p.parse_args(argv)
    extra = [] if args.free_poses is None else ["--free-poses", str(args.free_poses)]
    with tempfile.TemporaryDirectory() as tmp:
        rows = {mode: run(mode, args.tracker, Path(tmp), extra) for mode in ("step", "continuous")}
    print(f"mock UR5e, tracker {args.tracker}{'' if not extra else ', ' + ' '.join(extra)}")
    print(f"{'mode':<11} {'robot time [s]':>14} {'samples':>8} {'held-out RMS [mm]':>18} {'wall [s]':>9}")
    for mode, (seconds, samples, rms, wall) in rows.items():
        shown = "n/a" if rms is None else f"{rms * 1e3:.4f}"
        print(f"{mode:<11} {seconds:>14.1f} {samples:>8} {shown:>18} {wall:>9.1f}")
    ratio = rows["continuous"][0] / rows["step"][0]
    print(f"continuous / step robot time: {ratio:.2f} (target <= 0.25)")
    return 0 if ratio <= 0.25 else 1


if __name__ == "__main__":
    sys.exit(main())
