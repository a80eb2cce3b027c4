"""Speed benchmark: wall time of :func:`identify.results.pipeline.identify` in-process (docs/benchmarks.md).

    .venv/bin/python -m bench.speed [--repeats 10] [--datasets 5]

Each case simulates ``--datasets`` seeded data sets (full sweeps, 0.05 mm noise); on each, ``identify`` is
called once to warm up and then ``--repeats`` times (``time.perf_counter``). Reported: the median over all
calls and the slowest data set's median (a target must hold for every data set). Targets:
a 6-joint session with 36 samples per joint (UR5e) under 50 ms; 7 joints × 1,000 samples per joint
(iiwa7) under 1 s; cost linear in samples (log-log slope of time vs samples per joint, UR5e at 36 to
1,000 samples per joint, at most ``SLOPE_TARGET``). The exit status is 1 when a target is missed.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from dataclasses import dataclass

import numpy as np
import scipy

from config.robots import load_robot
from identify.estimator.cpa import geometric_step
from identify.results.pipeline import identify
from identify.simulators.simulate import simulate
from kinematics.truth import random_truth

SEED = 20240602
NOISE = 5e-5
SCALING_STEPS = (36, 100, 300, 1000)
BLAS_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
SLOPE_TARGET = 1.15  # "linear": fixed overheads pull the slope below 1, anything super-linear above


@dataclass(frozen=True)
class Timing:
    robot: str
    steps: int
    samples: int
    median: float  # s, median over all timed calls of all data sets
    worst: float  # s, the slowest data set's median
    worst_set: int  # its index (seed (SEED, steps, index))
    low: float  # s, fastest call
    high: float  # s, slowest call
    geometric: float  # s, median of the geometric step alone


def time_case(robot_name: str, steps: int, repeats: int, datasets: int) -> Timing:
    """Time ``identify`` on ``datasets`` seeded data sets: one warm-up then ``repeats`` calls each."""
    robot = load_robot(robot_name)
    conventional = robot.nominal.dh_table()
    times, geo, per_set = [], [], []
    for index in range(datasets):
        rng = np.random.default_rng((SEED, steps, index))
        truth = random_truth(robot.nominal, robot.home, rng)
        meas, _ = simulate(truth, robot.home, robot.limits, rng, noise=NOISE, steps=steps)
        identify(meas, nominal=robot.nominal)  # warm-up
        mine = []
        for _ in range(repeats):
            start = time.perf_counter()
            identify(meas, nominal=robot.nominal)
            mine.append(time.perf_counter() - start)
            start = time.perf_counter()
            geometric_step(meas, conventional, reference=robot.nominal)
            geo.append(time.perf_counter() - start)
        times += mine
        per_set.append(float(np.median(mine)))
    worst = int(np.argmax(per_set))
    return Timing(robot_name, steps, len(meas), float(np.median(times)), per_set[worst], worst, float(np.min(times)),
                  float(np.max(times)), float(np.median(geo)))


def row(t: Timing, target: float | None) -> str:
    verdict = "" if target is None else ("  yes" if t.worst < target else "  NO")
    goal = "" if target is None else f"< {target * 1e3:g} ms"
    return (f"{t.robot:<7} {t.steps:>6} {t.samples:>7} {t.median * 1e3:>10.1f} {t.worst * 1e3:>9.1f} "
            f"{t.low * 1e3:>8.1f} {t.high * 1e3:>8.1f} {t.geometric * 1e3:>7.1f} {t.median / t.samples * 1e6:>9.1f} "
            f"{goal:>10}{verdict}")


HEADER = (f"{'robot':<7} {'steps':>6} {'samples':>7} {'median ms':>10} {'worst ms':>9} {'min ms':>8} {'max ms':>8} "
          f"{'geo ms':>7} {'µs/sample':>9} {'target':>10}")


def environment() -> str:
    threads = ", ".join(f"{k}={os.environ[k]}" for k in BLAS_VARIABLES if k in os.environ) or "BLAS threads: default"
    load = ", ".join(f"{x:.2f}" for x in os.getloadavg())
    return (f"python {platform.python_version()}, numpy {np.__version__}, scipy {scipy.__version__}, "
            f"{os.cpu_count()} cores, {threads}, load average {load}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.speed", description=__doc__.split("\n")[0])
    parser.add_argument("--repeats", type=int, default=10, help="timed calls per data set (default 10)")
    parser.add_argument("--datasets", type=int, default=5, help="seeded data sets per case (default 5)")
    args = parser.parse_args(argv)
    print(f"identify() wall time, in-process: {args.datasets} seeded data sets per case, one warm-up then "
          f"{args.repeats} timed calls each (iiwa7: {max(2, args.datasets // 2)} sets x {max(3, args.repeats // 3)})")
    print(f"full sweeps, {NOISE * 1e3:g} mm noise; steps = samples per joint")
    print(environment())
    print()
    small = time_case("ur5e", 36, args.repeats, args.datasets)
    large = time_case("iiwa7", 1000, max(3, args.repeats // 3), max(2, args.datasets // 2))
    print(HEADER)
    print("-" * len(HEADER))
    print(row(small, 0.050))
    print(row(large, 1.0))
    print()
    print("Scaling (ur5e):")
    print(HEADER)
    print("-" * len(HEADER))
    scaling = [small if steps == 36 else time_case("ur5e", steps, args.repeats, args.datasets) for steps in
               SCALING_STEPS]
    for t in scaling:
        print(row(t, None))
    samples = np.array([t.samples for t in scaling], dtype=float)
    medians = np.array([t.median for t in scaling])
    slope = float(np.polyfit(np.log(samples), np.log(medians), 1)[0])
    tail = float(np.log(medians[-1] / medians[-2]) / np.log(samples[-1] / samples[-2]))
    print()
    print("median = over all timed calls; worst = the slowest data set's median (the target applies to every")
    print("data set); geo = median of the geometric step alone (part of identify); µs/sample from the median.")
    print(f"log-log slope of median time vs samples: {slope:.2f} over {SCALING_STEPS[0]}..{SCALING_STEPS[-1]} per "
          f"joint ({tail:.2f} between the two largest); target <= {SLOPE_TARGET}")
    print(f"load average after: {', '.join(f'{x:.2f}' for x in os.getloadavg())}")
    missed = []
    if small.worst >= 0.050:
        missed.append(f"ur5e 36 samples/joint: {small.worst * 1e3:.1f} ms >= 50 ms (data set {small.worst_set}, "
                      f"seed ({SEED}, 36, {small.worst_set}); median over sets {small.median * 1e3:.1f} ms)")
    if large.worst >= 1.0:
        missed.append(f"iiwa7 1000 samples/joint: {large.worst:.2f} s >= 1 s (data set {large.worst_set}; median "
                      f"{large.median:.2f} s)")
    if slope > SLOPE_TARGET:
        missed.append(f"scaling slope {slope:.2f} > {SLOPE_TARGET}")
    if missed:
        print("TARGET MISSED: " + "; ".join(missed))
        return 1
    print("all speed targets met")
    return 0


if __name__ == "__main__":
    sys.exit(main())
