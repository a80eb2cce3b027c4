"""Continuous-motion benchmark: robot time and accuracy of full mock UR5e sessions, stop-and-go against continuous,
over many noise draws.

    python -m bench.continuous [--draws 50] [--jobs 2] [--free-poses N] [--seed 2026]

Per draw, both modes run ``acquire --robot mock:ur5e --tracker TRACKER --mode MODE`` as fresh processes on the
simulated rig (virtual clock: the timestamps and durations of a real run in seconds of wall time), with the same
TRACKER: the same simulated robot (robot seed 0: one true robot, one plan) and the same tracker noise (0.05 mm per
axis) from the draw's own noise seed, and a clock drawn per draw: latency uniform in 5-50 ms, drift uniform in
±0.1 %, timestamp jitter uniform in 0-0.1 ms (``mock?seed=S&latency=L&drift=D&stamp_jitter=J``; the stop-and-go
session does not stream, only its readings' latency applies).

Reported per mode: robot time (first step's start to last step's end on the rig's clock), tracker samples, the
session's own held-out RMS (at its check poses and home checks, measured: it includes those poses' tracker noise)
and the true error (the accuracy of docs/benchmarks.md: RMS over 200 random poses within the limits of the distance
between
the identified model's TP and the simulated truth's, no noise), each as the median and the RMS over draws; and
the ratio continuous / step of the RMS over draws with a paired bootstrap 95 % interval (the draws resampled
together). The clock: the fitted offset at the fit's reference time against the rig's (its identity records
latency, offset, drift and epoch: drivers/sim/stream.py), its largest error over the draws, and the drift's.
Targets (issue 16): robot time <= 1/4, true held-out error <= 1.1x, offset error < 0.5 ms; (issue 26) the continuous
sessions' own expected error (their reported uncertainty) within ±20 % of the true error, RMS over draws; exit 1
when one is missed.
"""

from __future__ import annotations

import argparse
import math
import os
import sqlite3
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from identify.io.result_io import validation_of

ROBOT = "mock:ur5e"
EVAL_POSES = 200  # random held-out poses of the true error
BOOTSTRAP = 4000  # resamples of the ratio's interval
TARGETS = {"time": 0.25, "accuracy": 1.10, "offset": 0.5e-3, "calibration": 0.2}  # ratios, s, ±fraction


@dataclass(frozen=True)
class Draw:
    """One draw's tracker: noise seed, latency (s), drift (fraction), stamp jitter (s)."""

    index: int
    seed: int
    latency: float
    drift: float
    jitter: float

    @property
    def tracker(self) -> str:
        return f"mock?seed={self.seed}&latency={self.latency:g}&drift={self.drift:g}&stamp_jitter={self.jitter:g}"


@dataclass(frozen=True)
class Result:
    """One session's numbers: robot time (s), tracker samples, held-out RMS and its expectation (m), true error
    (m, RMS over the random poses) and the model's own expected error there (m), verdict, the clock's errors
    (offset s, its standard uncertainty s, drift; NaN for step sessions), wall time (s)."""

    robot_time: float
    samples: int
    held_out: float
    expected: float
    true_error: float
    own_expected: float
    verdict: str
    offset_error: float
    offset_std: float
    drift_error: float
    wall: float


def draws(count: int, seed: int) -> list[Draw]:
    """``count`` seeded draws of the tracker's clock (module docstring)."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(count):
        latency, drift, jitter = rng.uniform(0.005, 0.050), rng.uniform(-1e-3, 1e-3), rng.uniform(0.0, 1e-4)
        out.append(Draw(k, 100 + k, round(float(latency), 5), round(float(drift), 7), round(float(jitter), 7)))
    return out


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


def _acquire(mode: str, draw: Draw, folder: Path, extra: list[str]) -> tuple[Path, float]:
    """Run one session as a fresh process; (its path, wall time s)."""
    session = folder / f"{mode}-{draw.index}.session"
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    started = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "acquire.commands.launch", "--robot", ROBOT, "--tracker", draw.tracker,
                           "--mode", mode, "--session", str(session), "--quiet", *extra], env=env,
                          stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    if done.returncode not in (0, 3):  # 3: identified, verdict fail (still measured)
        raise RuntimeError(f"{mode} session of draw {draw.index} failed ({done.returncode}): {done.stderr[-500:]}")
    return session, time.perf_counter() - started


def measure(session: Path, wall: float, truth, q_eval: np.ndarray) -> Result:
    """The numbers of one finished session against the simulated ``truth`` at ``q_eval``."""
    from acquire.running.session import Session
    from drivers.sim.stream import robot_time_of_stamps
    from identify.io.result_io import load_result
    from kinematics.dh import points_from_joints

    seconds, samples = robot_time(session)
    model, doc = load_result(str(session.with_suffix(".result.yaml")))
    miss = model.points(q_eval) - points_from_joints(truth, q_eval)
    true_error = float(np.sqrt(np.mean(np.sum(miss**2, axis=1))))
    v = validation_of(doc) or {}
    offset_error = offset_std = drift_error = math.nan
    clock = doc.get("clock")
    if clock:
        with Session.open(session) as s:
            details = s.header["tracker"]["details"]
        t_ref = float(clock["t_ref_s"])
        offset_error = clock["offset_s"] - (float(robot_time_of_stamps(details, t_ref)) - t_ref)
        offset_std = float(clock["offset_std_s"])
        drift_error = clock["drift"] - (1.0 / (1.0 + float(details["drift"])) - 1.0)
    return Result(seconds, samples, float(v.get("rms", math.nan)), float(v.get("expected_rms", math.nan)),
                   true_error, model.expected_rms(q_eval), doc["verdict"]["status"], offset_error, offset_std,
                   drift_error, wall)


def rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(values))))


def ratio_interval(cont: np.ndarray, step: np.ndarray, seed: int) -> tuple[float, float, float]:
    """RMS(cont) / RMS(step) over paired draws and its paired bootstrap 95 % interval."""
    rng = np.random.default_rng(seed)
    k = rng.integers(0, len(cont), size=(BOOTSTRAP, len(cont)))
    boot = np.sqrt(np.mean(cont[k] ** 2, axis=1) / np.mean(step[k] ** 2, axis=1))
    low, high = np.percentile(boot, [2.5, 97.5])
    return rms(cont) / rms(step), float(low), float(high)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--draws", type=int, default=50, help="noise draws, each a step and a continuous session (50)")
    p.add_argument("--jobs", type=int, default=2, help="sessions run at once (2)")
    p.add_argument("--free-poses", type=int, help="--free-poses for both modes (default: each mode's own)")
    p.add_argument("--seed", type=int, default=2026, help="seed of the draws' clocks (2026)")
    args = p.parse_args(argv)
    if args.draws < 2 or args.jobs < 1:
        p.error("--draws must be >= 2 and --jobs >= 1")
    from config.robots import load_robot
    from drivers.sim.rig import SimulatedRig
    from identify.simulators.simulate import random_poses

    extra = [] if args.free_poses is None else ["--free-poses", str(args.free_poses)]
    plan = draws(args.draws, args.seed)
    truth = SimulatedRig.from_spec(ROBOT, plan[0].tracker).truth  # the robot seed fixes the truth: one for all
    q_eval = random_poses(load_robot("ur5e").limits, EVAL_POSES, np.random.default_rng(7))
    started = time.perf_counter()
    load = os.getloadavg()[0]
    results: dict[tuple[str, int], Result] = {}
    with tempfile.TemporaryDirectory() as tmp, ThreadPoolExecutor(args.jobs) as pool:
        jobs = {(mode, d.index): pool.submit(_acquire, mode, d, Path(tmp), extra)
                for d in plan for mode in ("step", "continuous")}
        for key, job in jobs.items():
            session, wall = job.result()
            results[key] = measure(session, wall, truth, q_eval)
            session.unlink()
    wall = time.perf_counter() - started
    return report(plan, results, wall, load, args)


def report(plan: list[Draw], results: dict[tuple[str, int], Result], wall: float, load: float,
           args: argparse.Namespace) -> int:
    """Print the per-draw lines and the summary; 0 when every target is met."""
    modes = ("step", "continuous")
    print(f"mock UR5e (robot seed 0), {len(plan)} draws, tracker noise 0.05 mm per axis, noise seeds "
          f"{plan[0].seed}..{plan[-1].seed}; clock per draw: latency 5-50 ms, drift ±0.1 %, stamp jitter 0-0.1 ms"
          f"{'' if args.free_poses is None else f'; --free-poses {args.free_poses}'}")
    print(f"{'draw':>4} {'latency':>8} {'drift':>9} {'jitter':>7} | {'true error [mm]':>15} {'held-out [mm]':>14} | "
          f"{'offset err':>10} {'drift err':>9} | verdicts")
    print(f"{'':>4} {'[ms]':>8} {'[ppm]':>9} {'[µs]':>7} | {'step':>7} {'cont.':>7} {'step':>6} {'cont.':>7} | "
          f"{'[µs]':>10} {'[ppm]':>9} |")
    for d in plan:
        s, c = results["step", d.index], results["continuous", d.index]
        print(f"{d.index:>4} {d.latency * 1e3:>8.2f} {d.drift * 1e6:>9.1f} {d.jitter * 1e6:>7.1f} | "
              f"{s.true_error * 1e3:>7.4f} {c.true_error * 1e3:>7.4f} {s.held_out * 1e3:>6.4f} {c.held_out * 1e3:>7.4f}"
              f" | {c.offset_error * 1e6:>10.2f} {c.drift_error * 1e6:>9.3f} | {s.verdict}/{c.verdict}")
    col = {m: {f: np.array([getattr(results[m, d.index], f) for d in plan]) for f in Result.__dataclass_fields__}
           for m in modes}
    print()
    print(f"{'mode':<11} {'robot time [s]':>14} {'samples':>8} {'true error [mm] median / RMS':>29} "
          f"{'held-out [mm] median / RMS':>27} {'own expected [mm]':>18} {'pass/warn/fail':>15}")
    for m in modes:
        v = col[m]
        counts = "/".join(str(int(np.sum(v["verdict"] == k))) for k in ("pass", "warn", "fail"))
        print(f"{m:<11} {np.median(v['robot_time']):>14.1f} {int(np.median(v['samples'])):>8} "
              f"{np.median(v['true_error']) * 1e3:>20.4f} / {rms(v['true_error']) * 1e3:.4f} "
              f"{np.median(v['held_out']) * 1e3:>18.4f} / {rms(v['held_out']) * 1e3:.4f} "
              f"{rms(v['own_expected']) * 1e3:>18.4f} {counts:>15}")
    time_ratio = float(np.median(col["continuous"]["robot_time"] / col["step"]["robot_time"]))
    acc, acc_lo, acc_hi = ratio_interval(col["continuous"]["true_error"], col["step"]["true_error"], args.seed)
    held, held_lo, held_hi = ratio_interval(col["continuous"]["held_out"], col["step"]["held_out"], args.seed + 1)
    per_draw = col["continuous"]["true_error"] / col["step"]["true_error"]
    offset = np.abs(col["continuous"]["offset_error"])
    z = offset / col["continuous"]["offset_std"]
    drift = np.abs(col["continuous"]["drift_error"])
    print()
    print(f"continuous / step robot time: {time_ratio:.3f} (target <= {TARGETS['time']:g})")
    print(f"continuous / step true error (RMS over draws): {acc:.3f}, paired bootstrap 95 % [{acc_lo:.3f}, "
          f"{acc_hi:.3f}]; per draw median {np.median(per_draw):.3f}, continuous better in "
          f"{int(np.sum(per_draw < 1))} of {len(plan)} (target <= {TARGETS['accuracy']:g})")
    print(f"continuous / step held-out RMS at the check poses: {held:.3f} [{held_lo:.3f}, {held_hi:.3f}] (both "
          "include the check poses' own tracker noise)")
    print(f"clock offset error at t_ref: max {offset.max() * 1e6:.2f} µs, RMS {rms(offset) * 1e6:.2f} µs, largest "
          f"{z.max():.1f} sigma (median sigma {np.median(col['continuous']['offset_std']) * 1e6:.2f} µs); drift error "
          f"max {drift.max() * 1e6:.3f} ppm (target: offset within {TARGETS['offset'] * 1e3:g} ms)")
    for m in modes:  # issue 26: the reported uncertainty within ±20 % of the achieved error
        calib = rms(col[m]["own_expected"]) / rms(col[m]["true_error"])
        print(f"{m}: own expected / true error (RMS over draws) {calib:.3f} (target 1 ± {TARGETS['calibration']:g})")
    walls = {m: float(np.median(col[m]["wall"])) for m in modes}
    print(f"wall time {wall:.0f} s for {2 * len(plan)} sessions, {args.jobs} at once (median per session: step "
          f"{walls['step']:.1f} s, continuous {walls['continuous']:.1f} s); load average at the start {load:.2f}")
    calib = rms(col["continuous"]["own_expected"]) / rms(col["continuous"]["true_error"])
    met = {"robot time": time_ratio <= TARGETS["time"], "accuracy": acc <= TARGETS["accuracy"],
           "latency": offset.max() < TARGETS["offset"], "calibration": abs(calib - 1) <= TARGETS["calibration"]}
    print("targets: " + ", ".join(f"{k} {'met' if v else 'MISSED'}" for k, v in met.items()))
    return 0 if all(met.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
