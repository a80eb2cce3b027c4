"""Identification of a large continuous session: wall time and peak memory against the number of rows.

    .venv/bin/python -m bench.big_stream [--rows 30000 100000 300000] [--keep DIR]

Per size, a continuous UR5e session is simulated (six streamed sweeps of rows/6 samples each, ±1.5 rad about
home at 0.25 rad/s, the tracker at the rate that gives that count, 0.05 mm noise, a 20 ms latency recorded as
12 ms, 0.02 ms timestamp jitter; plus 24 stop-and-go poses of which 10 are held out), written as the measurement
CSV ``acquire export`` writes, and identified by ``identify FILE --json --out R`` as a fresh process (CSV reading
included, no nominal: as the issue's measurement). Reported: wall time and the child's peak resident memory
(``ru_maxrss``), its CPU time (user + system: what a quiet machine's wall time would be, BLAS on one thread),
and the log-log slope of CPU time against rows. Target (issue 26): 300,000 rows in < 30 s and
< 2 GB, cost linear in the rows; exit 1 when missed. Timings depend on the machine's load: the load average is
printed.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

from config.robots import load_robot
from identify.estimator.measurements import Measurements
from identify.io.csvio import format_measurements
from identify.simulators.simulate import random_poses
from identify.simulators.simulate_stream import StreamSettings, joined, move_duration, streamed_sweeps
from kinematics.dh import points_from_joints
from kinematics.truth import perturbed_model, random_base

NOISE = 5e-5
HALF_RANGE = 1.5  # rad
SPEED = 0.25  # rad/s
TARGET_SECONDS, TARGET_BYTES = 30.0, 2e9


def session_csv(rows: int, path: Path, seed: int = 7) -> None:
    """Write the module docstring's session of ``rows`` streamed rows to ``path``."""
    rng = np.random.default_rng(seed)
    robot = load_robot("ur5e")
    home = np.asarray(robot.home, dtype=float)
    truth = perturbed_model(replace(robot.nominal, base=random_base(rng), tool=np.array([0.05, 0.03, 0.08])), rng)
    duration = move_duration(-HALF_RANGE, HALF_RANGE, SPEED, 1.0)
    settings = StreamSettings(robot_rate=500.0, tracker_rate=rows / 6 / duration, speed=SPEED, offset=-0.02,
                              recorded_offset=-0.012, jitter=2e-5, noise=NOISE)
    ranges = [(j, home[j - 1] - HALF_RANGE, home[j - 1] + HALF_RANGE) for j in range(1, 7)]
    stream = streamed_sweeps(truth, home, ranges, settings, rng)
    q = random_poses(robot.limits, 24, rng)
    points = points_from_joints(truth, q) + rng.normal(0, NOISE / np.sqrt(5), (24, 3))
    poses = Measurements("RRRRRR", q, points, np.full(24, 100), np.zeros(24, dtype=np.int64),
                         check=np.arange(24) >= 14)
    path.write_text(format_measurements(joined(stream, poses), {"noise": f"{NOISE} m"}))


def identify_child(csv: Path, out: Path) -> tuple[float, float, float]:
    """(wall s, CPU s, peak resident bytes) of ``identify CSV --json --out OUT`` as a fresh process (its run,
    imports excluded)."""
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    code = ("import resource, sys, time; from identify.commands.launch import main; t = time.perf_counter(); "
            f"rc = main([{str(csv)!r}, '--json', '--out', {str(out)!r}, '--force']); "
            "u = resource.getrusage(resource.RUSAGE_SELF); "
            "print('RESULT', time.perf_counter() - t, u.ru_utime + u.ru_stime, u.ru_maxrss, rc, file=sys.stderr)")
    done = subprocess.run([sys.executable, "-c", code], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                          text=True)
    line = next((x for x in done.stderr.splitlines() if x.startswith("RESULT")), None)
    if line is None:
        raise RuntimeError(f"identify failed: {done.stderr[-800:]}")
    _, seconds, cpu, kib, rc = line.split()
    if rc not in ("0", "3"):
        raise RuntimeError(f"identify exited {rc}: {done.stderr[-800:]}")
    return float(seconds), float(cpu), float(kib) * 1024


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rows", type=int, nargs="+", default=[30_000, 100_000, 300_000], help="streamed rows per case")
    p.add_argument("--keep", type=Path, help="write the CSVs and results here (default: a temporary folder)")
    args = p.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.keep or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        print(f"load average {os.getloadavg()[0]:.1f}; identify CSV --json as a fresh process, CSV reading included")
        print(f"{'rows':>8} {'wall s':>8} {'CPU s':>8} {'peak GB':>8}")
        results = []
        for rows in args.rows:
            csv = folder / f"stream-{rows}.csv"
            if not csv.exists():
                session_csv(rows, csv)
            seconds, cpu, peak = identify_child(csv, folder / f"stream-{rows}.result.yaml")
            results.append((rows, seconds, cpu, peak))
            print(f"{rows:>8} {seconds:>8.1f} {cpu:>8.1f} {peak / 1e9:>8.2f}", flush=True)
    ok = True
    if len(results) > 1:
        slope = np.polyfit(np.log([r[0] for r in results]), np.log([r[2] for r in results]), 1)[0]
        print(f"log-log slope of CPU time against rows: {slope:.2f}")
    big = [r for r in results if r[0] >= 300_000]
    if big:
        ok = big[0][1] < TARGET_SECONDS and big[0][3] < TARGET_BYTES
        print(f"target: 300,000 rows < {TARGET_SECONDS:g} s and < {TARGET_BYTES / 1e9:g} GB: "
              f"{'met' if ok else 'missed'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
