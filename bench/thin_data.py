"""Issue 34's thin-data targets: short arcs, no free poses, are the reported sigmas honest?

Per case (a family, with or without its nominal) and per true arm (``--arms`` seeded draws of the family's DH values
perturbed by :func:`kinematics.truth.random_truth`), ``--draws`` data sets of the same acquisition with fresh tracker
noise: every joint swept home ± 20 deg in ``--steps`` samples, no free poses, nothing held out, 0.02 mm per axis.
Each draw is identified as ``identify`` does it. Then, per arm:

- every free parameter's spread over the draws (base rotation relative to the first draw's, angles wrapped) against
  the RMS of the sigmas the results report: without a nominal the ratio must lie in the 99.9 % band of a standard
  deviation from that many draws (chi distribution); with the nominal the reported sigma also carries the nominal's
  own tolerance, which does not vary from draw to draw, so only the upper end of the band applies;
- no written table with a length beyond the robot's size (a second minimum "of metres");
- the verdict of each draw: nothing is held out, so none may pass;
- the written model's error at 200 random poses over the whole joint space against what the result states there
  (``CalibratedModel.expected_errors``; outside the domain the result calls it a lower bound: printed, no target).

Run: ``python -m bench.thin_data [--draws 40] [--arms 3] [--noise 0.02] [--jobs 2]``. Exit 1 on a miss.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import sys
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from config.robots import load_robot
from identify.applications.calibrated import CalibratedModel
from identify.estimator.dh_vector import parameter_names, vector_from_model
from identify.results.pipeline import identify
from identify.simulators.simulate import random_poses, simulate
from kinematics.dh import points_from_joints
from kinematics.truth import random_truth

FAMILIES = ("ur5e", "iiwa7", "scara")
NOISE = 2e-5  # m per axis
ARC = float(np.radians(20.0))
SEED = 3400


@dataclass(frozen=True)
class ArmResult:
    family: str
    nominal: bool
    arm: int
    free: int  # free parameters (reported sigma > 0 in every draw)
    outside: list[str]  # free parameters whose spread/sigma leaves the band, with the ratio
    worst: float  # largest spread/sigma
    statuses: dict[str, int]  # verdict status -> draws
    metres: int  # draws whose written table has |d| or |a| beyond the robot's size
    error: float  # m, RMS over draws and poses of the model's error over the joint space
    stated: float  # m, RMS of what the results state there
    failures: int


def band(draws: int) -> tuple[float, float]:
    """99.9 % band of (sample standard deviation / true sigma) from ``draws`` normal draws."""
    dof = draws - 1
    return float(np.sqrt(chi2.ppf(0.0005, dof) / dof)), float(np.sqrt(chi2.ppf(0.9995, dof) / dof))


def one_arm(family: str, with_nominal: bool, arm: int, draws: int, steps: int, noise: float = NOISE) -> ArmResult:
    robot = load_robot(family)
    rng = np.random.default_rng((SEED, FAMILIES.index(family), arm))
    truth = random_truth(robot.nominal, robot.home, rng)
    q_all = random_poses(robot.limits, 200, rng)
    true_points = points_from_joints(truth, q_all)
    size = float(np.max(np.linalg.norm(true_points - truth.base[:3, 3], axis=1)))  # m: the arm's reach
    names = parameter_names(truth.n_joints)
    angle = np.array([n.startswith(("theta", "alpha")) for n in names])
    vectors, sigmas, statuses = [], [], {}
    metres = failures = 0
    err2, stated2 = [], []
    base_ref = None
    for _ in range(draws):
        meas, _ = simulate(truth, robot.home, robot.limits, rng, noise=noise, arc=ARC, steps=steps)
        try:
            ident = identify(meas, nominal=robot.nominal if with_nominal else None, noise=noise)
        except Exception as exc:  # a benchmark records failures instead of stopping
            failures += 1
            print(f"  {family} arm {arm}: identify failed: {exc}", file=sys.stderr)
            continue
        model = ident.used.model
        vector = vector_from_model(ident.model)
        base_ref = ident.model.base[:3, :3] if base_ref is None else base_ref
        vector[:3] = Rotation.from_matrix(ident.model.base[:3, :3] @ base_ref.T).as_rotvec()
        vectors.append(vector)
        sigmas.append(ident.std)
        statuses[ident.verdict.status] = statuses.get(ident.verdict.status, 0) + 1
        table = model.dh_table()
        metres += int(np.any(np.abs(table[:, 1:3]) > size))
        calibrated = CalibratedModel.from_identification(ident)
        err2.append(np.mean(np.sum((calibrated.points(q_all) - true_points) ** 2, axis=1)))
        stated2.append(np.mean(calibrated.expected_errors(q_all) ** 2))
    values, reported = np.array(vectors), np.array(sigmas)
    delta = values - values[0]
    delta[:, angle] = (delta[:, angle] + np.pi) % (2.0 * np.pi) - np.pi
    spread = delta.std(axis=0, ddof=1)
    free = np.all(reported > 0.0, axis=0)
    ratio = spread[free] / np.sqrt(np.mean(reported[:, free] ** 2, axis=0))
    low, high = band(len(values))
    bad = (ratio > high) | ((ratio < low) & (not with_nominal))
    outside = [f"{n} {r:.2f}" for n, r, b in zip(np.array(names)[free], ratio, bad, strict=True) if b]
    return ArmResult(family, with_nominal, arm, int(free.sum()), outside, float(ratio.max()), statuses, metres,
                     float(np.sqrt(np.mean(err2))), float(np.sqrt(np.mean(stated2))), failures)


def _run(args: tuple[str, bool, int, int, int, float]) -> ArmResult:
    return one_arm(*args)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.thin_data", description=__doc__.split("\n\n")[0])
    parser.add_argument("--draws", type=int, default=40)
    parser.add_argument("--arms", type=int, default=3, help="true arms per family")
    parser.add_argument("--steps", type=int, default=8, help="samples per sweep")
    parser.add_argument("--noise", type=float, default=NOISE * 1e3, help="tracker noise per axis, mm")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--family", action="append", choices=FAMILIES)
    args = parser.parse_args(argv)
    noise = args.noise * 1e-3
    work = [(f, nominal, arm, args.draws, args.steps, noise) for f in (args.family or FAMILIES)
            for nominal in (False, True) for arm in range(args.arms)]
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        results = list(pool.map(_run, work))
    low, high = band(args.draws)
    print(f"±20° arcs, {args.steps} samples per sweep, no free poses, {noise * 1e3:g} mm; {args.draws} draws per arm; "
          f"spread/sigma band {low:.2f}-{high:.2f} (99.9 %)")
    print("family  nominal arm  free  worst  outside the band            verdicts          metres  error  stated (mm)")
    missed = 0
    for r in results:
        verdicts = ", ".join(f"{k} {v}" for k, v in sorted(r.statuses.items()))
        miss = bool(r.outside) or r.statuses.get("pass", 0) > 0 or r.metres > 0 or r.failures > 0
        missed += miss
        print(f"{r.family:7s} {'yes' if r.nominal else 'no ':3s}  {r.arm:4d}{r.free:6d}{r.worst:7.2f}  "
              f"{', '.join(r.outside) or '-':26s}  {verdicts:16s}{r.metres:8d}{r.error * 1e3:7.2f}{r.stated * 1e3:8.2f}"
              + ("  MISS" if miss else ""))
    print(f"arms missing a target: {missed} of {len(results)}")
    print("targets: " + ("met" if not missed else "MISSED"))
    return 0 if not missed else 1


if __name__ == "__main__":
    sys.exit(main())
