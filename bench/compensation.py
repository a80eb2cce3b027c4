"""Compensation, verification and change-over-time benchmark (issue 15).

    .venv/bin/python -m bench.compensation [--draws 50] [--compare-draws 200]

1. Speed: 10,000 targets compensated (nominal solution first, then the identified model; status, residual and
   expected accuracy per target), as TP positions in the tracker frame and as 6D poses in the base frame, median
   of 3 runs. Target: < 5 s.
2. Accuracy: per draw a simulated UR5e (a perturbed nominal, 0.05 mm tracker noise, the simulator's default
   sweeps with 20 free and 10 held-out poses), identified, then 200 random reachable targets (the truth's TP at
   random poses) compensated: the real error (the truth at the solved joints) against the RMS the result's
   covariance predicts. Target: sqrt(mean ratio²) ≤ 1.2 (the issue's test, pooled here over ``--draws``); the
   nominal model's miss beside it.
3. Verification on the mock rig: ``acquire`` (the default plan, mock:ur5e, 0.05 mm noise) then ``acquire verify``
   (10 cycles, 5 readings per visit), in-process; AP and RP per pose before and after, and the AP the simulated
   truth implies for the commands recorded. Targets: after within 2x the tracker noise; measured AP within the
   barycentre's noise of the truth's (chi-square 3 dof, 1e-4).
4. Change over time: per draw a truth, calibrations A and B of it (independent 0.02 mm noise) and C after joint 3's
   offset moved by 0.05°. Targets: A -> B "no significant change" in >= 95 % of the draws; A -> C names theta3 in
   >= 95 %.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # small matrices: a threaded BLAS only waits on a busy machine
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import contextlib
import io
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import yaml
from scipy.stats import chi2

from config.robots import load_robot
from identify.applications.calibrated import CalibratedModel
from identify.applications.compare import compare
from identify.applications.compensate import compensate
from identify.results.pipeline import identify
from identify.simulators.simulate import random_poses, simulate
from kinematics.dh import points_from_joints
from kinematics.truth import random_truth

ROBOT = load_robot("ur5e")
SPEED_TARGET = 5.0
RATIO_TARGET = 1.2
SHARE_TARGET = 0.95


def _calibrate(truth, rng, noise: float) -> CalibratedModel:
    meas, _ = simulate(truth, ROBOT.home, ROBOT.limits, rng, noise=noise, free_poses=20, check_poses=10)
    return CalibratedModel.from_identification(identify(meas, ROBOT.nominal))


def _nominal(model: CalibratedModel, base: np.ndarray) -> CalibratedModel:
    return CalibratedModel.exact(replace(ROBOT.nominal, base=base, tool=model.tool()))


def speed() -> tuple[list[str], list[str]]:
    rng = np.random.default_rng(15)
    truth = random_truth(ROBOT.nominal, ROBOT.home, rng)
    model = _calibrate(truth, rng, 5e-5)
    q = random_poses(ROBOT.limits, 10_000, rng)
    lines, missed = [], []
    cases = {"TP positions, tracker frame": (model, points_from_joints(truth, q), None, "tracker"),
             "6D poses, base frame": (model.with_base(np.eye(4)), None, None, "base")}
    for label, (m, targets, rotations, frame) in cases.items():
        if targets is None:
            flange = m.flanges(q)
            targets, rotations = flange[:, :3, :3] @ m.tool() + flange[:, :3, 3], flange[:, :3, :3]
        base = np.eye(4) if frame == "base" else model.base
        seeds = q + rng.normal(0, 0.02, q.shape)
        times = []
        for _ in range(3):
            t = time.perf_counter()
            result = compensate(m, targets, seeds, ROBOT.limits, rotations, nominal=_nominal(model, base), frame=frame)
            times.append(time.perf_counter() - t)
        status = {s: int(np.sum(result.solution.status == s)) for s in ("ok", "singular", "limit", "unreachable")}
        took = float(np.median(times))
        lines.append(f"{label:<28} 10,000 targets in {took:.2f} s (median of 3; {min(times):.2f}-{max(times):.2f}); "
                     + ", ".join(f"{v} {k}" for k, v in status.items()))
        if took >= SPEED_TARGET:
            missed.append(f"{label}: {took:.2f} s")
    return lines, missed


def accuracy(draws: int) -> tuple[list[str], list[str]]:
    ratios, predicted, nominal = [], [], []
    for k in range(draws):
        rng = np.random.default_rng([15, k])
        truth = random_truth(ROBOT.nominal, ROBOT.home, rng)
        model = _calibrate(truth, rng, 5e-5)
        q = random_poses(ROBOT.limits, 200, rng)
        targets = points_from_joints(truth, q)
        result = compensate(model, targets, q, ROBOT.limits, nominal=_nominal(model, model.base))
        ok = result.solution.reached
        err = np.linalg.norm(points_from_joints(truth, result.solution.q[ok]) - targets[ok], axis=1)
        rms_pred = float(np.sqrt(np.mean(result.expected[ok] ** 2)))
        ratios.append(float(np.sqrt(np.mean(err**2))) / rms_pred)
        predicted.append(rms_pred)
        nerr = np.linalg.norm(points_from_joints(truth, result.nominal.q[ok]) - targets[ok], axis=1)
        nominal.append(float(np.sqrt(np.mean(nerr**2))))
    r = np.array(ratios)
    pooled = float(np.sqrt(np.mean(r**2)))
    lines = [f"{draws} draws x 200 targets: real / predicted RMS: pooled {pooled:.3f}, median {np.median(r):.3f}, "
             f"5-95 % {np.percentile(r, 5):.3f}-{np.percentile(r, 95):.3f}, max {r.max():.3f}; predicted RMS "
             f"{np.median(predicted) * 1e3:.4f} mm (median); nominal model misses by {np.median(nominal) * 1e3:.3f} "
             f"mm RMS (median; {min(nominal) * 1e3:.2f}-{max(nominal) * 1e3:.2f})"]
    return lines, [] if pooled <= RATIO_TARGET else [f"pooled ratio {pooled:.3f} > {RATIO_TARGET}"]


def verification() -> tuple[list[str], list[str]]:
    from acquire.commands.cli import main as acquire
    from acquire.running.session import Session
    from drivers.sim.rig import SimulatedRig

    noise, cycles, samples = 5e-5, 10, 5
    with tempfile.TemporaryDirectory() as folder:
        cal, ver = Path(folder) / "cal.session", Path(folder) / "v.session"
        t = time.perf_counter()
        with contextlib.redirect_stdout(io.StringIO()):
            code_a = acquire(["--robot", "mock:ur5e", "--tracker", "mock", "--session", str(cal), "--quiet"])
            t_verify = time.perf_counter()
            code_v = acquire(["verify", "--result", str(cal.with_suffix(".result.yaml")), "--session", str(ver),
                              "--quiet", "--cycles", str(cycles)])
        done = time.perf_counter()
        if code_a or code_v:
            return [f"acquire exit {code_a}, verify exit {code_v}"], ["the mock runs failed"]
        summary = yaml.safe_load(ver.with_suffix(".verify.yaml").read_text())
        with Session.open(ver) as s:
            info = s.header["config"]["verification"]
    truth = SimulatedRig("ur5e", seed=0).truth
    base, targets = np.array(info["base"]), np.array(info["targets"])
    tol = float(np.sqrt(chi2.ppf(1 - 1e-4, 3))) * noise / np.sqrt(cycles * samples) + 5e-6
    lines = [f"mock:ur5e, default plan then {cycles} cycles x {samples} readings per visit; acquisition + "
             f"identification {t_verify - t:.1f} s, verification {done - t_verify:.1f} s (in-process, virtual clock)",
             "pose  AP before (truth)      AP after (truth)       RP before  RP after   [mm]"]
    worst_gap, worst_after = 0.0, 0.0
    for k in range(5):
        implied = {}
        for mode in ("before", "after"):
            reached = points_from_joints(truth, np.array(info["q"][mode][k])[None])[0]
            implied[mode] = float(np.linalg.norm(base[:3, :3].T @ (reached - base[:3, 3]) - targets[k]))
        b, a = summary["runs"]["before"]["poses"][k], summary["runs"]["after"]["poses"][k]
        worst_gap = max(worst_gap, abs(b["ap"] - implied["before"]), abs(a["ap"] - implied["after"]))
        worst_after = max(worst_after, a["ap"])
        lines.append(f"P{k + 1}    {b['ap'] * 1e3:.4f} ({implied['before'] * 1e3:.4f})      {a['ap'] * 1e3:.4f} "
                     f"({implied['after'] * 1e3:.4f})      {b['rp'] * 1e3:.4f}     {a['rp'] * 1e3:.4f}")
    lines.append(f"verdict: {summary['verdict']['status']}: {summary['verdict']['message']}")
    lines.append(f"largest |AP measured - AP the truth implies| {worst_gap * 1e3:.4f} mm (allowed {tol * 1e3:.4f}); "
                 f"worst AP after {worst_after * 1e3:.4f} mm (target < {2 * noise * 1e3:.2f} mm = 2x noise)")
    missed = []
    if worst_gap > tol:
        missed.append(f"measured AP {worst_gap * 1e3:.4f} mm from the truth's")
    if worst_after >= 2 * noise:
        missed.append(f"AP after {worst_after * 1e3:.4f} mm >= 2x noise")
    return lines, missed


def change(draws: int) -> tuple[list[str], list[str]]:
    noise = 2e-5
    quiet = found = 0
    stats = []
    for k in range(draws):
        truth = random_truth(ROBOT.nominal, ROBOT.home, np.random.default_rng([16, k]))
        a = _calibrate(truth, np.random.default_rng([16, k, 1]), noise)
        b = _calibrate(truth, np.random.default_rng([16, k, 2]), noise)
        moved = replace(truth, theta=truth.theta + np.radians([0, 0, 0.05, 0, 0, 0]))
        c = _calibrate(moved, np.random.default_rng([16, k, 3]), noise)
        same = compare([a, b], ["A", "B"], ROBOT.limits, poses=100).pairs[0]
        diff = compare([a, c], ["A", "C"], ROBOT.limits, poses=100).pairs[0]
        quiet += not same.significant
        found += [ch.name for ch in diff.changed] == ["theta3"]
        stats.append(same.statistic / same.dof)
    lines = [f"{draws} draws at {noise * 1e3:g} mm noise: same truth -> no significant change in {quiet}/{draws} "
             f"({quiet / draws:.1%}); 0.05 deg on theta3 -> found (theta3 alone) in {found}/{draws} "
             f"({found / draws:.1%}); chi-square per dof of the unchanged pairs {np.mean(stats):.3f} (mean)"]
    missed = [f"{label} {v / draws:.1%} < 95 %" for label, v in (("quiet", quiet), ("found", found))
              if v < SHARE_TARGET * draws]
    return lines, missed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--draws", type=int, default=50, help="accuracy draws (50)")
    parser.add_argument("--compare-draws", type=int, default=200, help="change-over-time draws (200)")
    args = parser.parse_args()
    print(f"python {sys.version.split()[0]}, numpy {np.__version__}, {time.strftime('%Y-%m-%d')}, "
          f"load average {os.getloadavg()[0]:.1f}")
    missed: list[str] = []
    for title, run in (("1. speed", speed), ("2. accuracy of compensated targets", lambda: accuracy(args.draws)),
                       ("3. verification on the mock rig", verification),
                       ("4. change over time", lambda: change(args.compare_draws))):
        t = time.perf_counter()
        lines, miss = run()
        print(f"{title} ({time.perf_counter() - t:.0f} s)")
        print("\n".join(f"  {line}" for line in lines))
        missed += miss
    print(f"targets: 10,000 targets < {SPEED_TARGET:g} s; real/predicted RMS <= {RATIO_TARGET}; AP after < 2x noise "
          "and AP as the truth implies; change-over-time >= 95 % right both ways")
    if missed:
        sys.exit("TARGET MISSED: " + "; ".join(missed))


if __name__ == "__main__":
    main()
