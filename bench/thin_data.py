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

``--orientation SIGMA_R`` (mrad per axis): every sample is a 6-DoF reading (a target frame turned at random from the
last DH frame, per arm; :func:`identify.simulators.simulate.with_orientations`), and the target frame's turn (about
frame n's axes, relative to the first draw's) is scored beside the parameters. Then every parameter must also be
determined in every draw: the conditioning check finds no parameter poorly determined and no near-redundant group,
and nothing is held at the nominal; the parameters fixed are printed with the reason the result gives (the
conventions a DH table always holds: what the base or the target frame already places, a common normal's position
between parallel axes, and on a SCARA the two its all-parallel axes leave to a convention in any data).

Run: ``python -m bench.thin_data [--draws 40] [--arms 3] [--noise 0.02] [--orientation 0.2] [--jobs 2]``.
Exit 1 on a miss.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import re
import sys
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from config.robots import load_robot
from identify.applications.calibrated import CalibratedModel
from identify.estimator.dh_vector import parameter_names, vector_from_model
from identify.estimator.orientation import matrices_from_rotvecs
from identify.results.pipeline import identify
from identify.results.stages import identifiability_of
from identify.results.written import robot_size
from identify.simulators.simulate import random_poses, simulate, with_orientations
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
    orientation: bool = False  # 6-DoF readings
    determined: int = 0  # draws in which no parameter is poorly determined or near-redundant, none held at the nominal
    fixed: tuple[tuple[str, str], ...] = ()  # parameters held by a convention in some draw: (name, reason)
    ratios: tuple[tuple[str, float], ...] = ()  # every free parameter's spread/sigma

    @property
    def draws(self) -> int:
        return sum(self.statuses.values())

    @property
    def missed(self) -> bool:
        return (bool(self.outside) or self.statuses.get("pass", 0) > 0 or self.metres > 0 or self.failures > 0
                or (self.orientation and self.determined < self.draws))


def band(draws: int) -> tuple[float, float]:
    """99.9 % band of (sample standard deviation / true sigma) from ``draws`` normal draws."""
    dof = draws - 1
    return float(np.sqrt(chi2.ppf(0.0005, dof) / dof)), float(np.sqrt(chi2.ppf(0.9995, dof) / dof))


def one_arm(family: str, with_nominal: bool, arm: int, draws: int, steps: int, noise: float = NOISE,
            noise_r: float | None = None) -> ArmResult:
    """One true arm of ``family`` over ``draws`` noise draws (module docstring); ``noise`` m per axis, ``noise_r``
    rad per axis for 6-DoF readings (None: positions only)."""
    robot = load_robot(family)
    rng = np.random.default_rng((SEED, FAMILIES.index(family), arm))
    truth = random_truth(robot.nominal, robot.home, rng)
    q_all = random_poses(robot.limits, 200, rng)
    frame = None if noise_r is None else matrices_from_rotvecs(rng.normal(0.0, 1.0, (1, 3)))[0]
    true_points = points_from_joints(truth, q_all)
    size = float(np.max(np.linalg.norm(true_points - truth.base[:3, 3], axis=1)))  # m: the arm's reach
    names = parameter_names(truth.n_joints) + (["frame.rx", "frame.ry", "frame.rz"] if frame is not None else [])
    angle = np.array([n.startswith(("theta", "alpha")) for n in names])
    vectors, sigmas, statuses = [], [], {}
    metres = failures = determined = 0
    fixed: dict[str, str] = {}
    err2, stated2 = [], []
    base_ref = frame_ref = None
    for _ in range(draws):
        meas, _ = simulate(truth, robot.home, robot.limits, rng, noise=noise, arc=ARC, steps=steps)
        if frame is not None:
            meas = with_orientations(meas, truth, frame, rng, noise, noise_r)
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
        sigma = ident.std
        if frame is not None:  # the target frame's turn about frame n's axes, as its written uncertainty is
            written = ident.plain.frames[0]
            frame_ref = written if frame_ref is None else frame_ref
            vector = np.concatenate([vector, Rotation.from_matrix(written @ frame_ref.T).as_rotvec()])
            sigma = np.concatenate([sigma, ident.plain.frame_std])
        vectors.append(vector)
        sigmas.append(sigma)
        fixed.update((f.name, f.reason) for f in ident.plain.fixed if f.name not in fixed)
        found = identifiability_of(ident.used, robot_size(ident.plain.lines, meas.points))
        determined += int(not found.poor and not found.redundant and ident.used.held is None)
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
    free_names = np.array(names)[free]
    outside = [f"{n} {r:.2f}" for n, r, b in zip(free_names, ratio, bad, strict=True) if b]
    return ArmResult(family, with_nominal, arm, int(free.sum()), outside, float(ratio.max()), statuses, metres,
                     float(np.sqrt(np.mean(err2))), float(np.sqrt(np.mean(stated2))), failures, frame is not None,
                     determined, tuple(fixed.items()),
                     tuple((str(n), float(r)) for n, r in zip(free_names, ratio, strict=True)))


def _run(args: tuple[str, bool, int, int, int, float, float | None]) -> ArmResult:
    return one_arm(*args)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.thin_data", description=__doc__.split("\n\n")[0])
    parser.add_argument("--draws", type=int, default=40)
    parser.add_argument("--arms", type=int, default=3, help="true arms per family")
    parser.add_argument("--steps", type=int, default=8, help="samples per sweep")
    parser.add_argument("--noise", type=float, default=NOISE * 1e3, help="tracker noise per axis, mm")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--family", action="append", choices=FAMILIES)
    parser.add_argument("--orientation", type=float, default=None, metavar="SIGMA_R",
                        help="6-DoF readings: orientation noise per axis, mrad (default: positions only)")
    args = parser.parse_args(argv)
    noise = args.noise * 1e-3
    noise_r = None if args.orientation is None else args.orientation * 1e-3
    families = args.family or FAMILIES
    work = [(f, nominal, arm, args.draws, args.steps, noise, noise_r) for f in families
            for nominal in (False, True) for arm in range(args.arms)]
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        results = list(pool.map(_run, work))
    low, high = band(args.draws)
    kind = "positions only" if noise_r is None else f"6-DoF readings, {noise_r * 1e3:g} mrad per axis"
    print(f"±20° arcs, {args.steps} samples per sweep, no free poses, {noise * 1e3:g} mm, {kind}; {args.draws} draws "
          f"per arm; spread/sigma band {low:.2f}-{high:.2f} (99.9 %)")
    print("family  nominal arm  free  worst  outside the band            verdicts          metres  error  stated (mm)"
          + ("  determined" if noise_r is not None else ""))
    for r in results:
        verdicts = ", ".join(f"{k} {v}" for k, v in sorted(r.statuses.items()))
        print(f"{r.family:7s} {'yes' if r.nominal else 'no ':3s}  {r.arm:4d}{r.free:6d}{r.worst:7.2f}  "
              f"{', '.join(r.outside) or '-':26s}  {verdicts:16s}{r.metres:8d}{r.error * 1e3:7.2f}{r.stated * 1e3:8.2f}"
              + (f"  {r.determined:4d} of {r.draws}" if r.orientation else "") + ("  MISS" if r.missed else ""))
    if noise_r is not None:
        _per_parameter(results, families)
    missed = sum(r.missed for r in results)
    print(f"arms missing a target: {missed} of {len(results)}")
    print("targets: " + ("met" if not missed else "MISSED"))
    return 0 if not missed else 1


def _per_parameter(results: list[ArmResult], families: list[str] | tuple[str, ...]) -> None:
    """Per family: every free parameter's spread/sigma (lowest-highest over the arms) without and with the nominal,
    and the parameters a convention fixed, with the reason the results give."""
    for family in families:
        mine = {n: [r for r in results if (r.family, r.nominal) == (family, n)] for n in (False, True)}
        names = list(dict.fromkeys(n for r in mine[False] + mine[True] for n, _ in r.ratios))
        print(f"\n{family}: spread/sigma per parameter, lowest-highest over the arms")
        print(f"{'parameter':<10} {'no nominal':>12} {'nominal':>12}")
        for name in names:
            cells = []
            for nominal in (False, True):
                values = [v for r in mine[nominal] for n, v in r.ratios if n == name]
                cells.append(f"{min(values):.2f}-{max(values):.2f}" if values else "fixed")
            print(f"{name:<10} {cells[0]:>12} {cells[1]:>12}")
        fixed: dict[str, str] = {}
        for r in mine[False] + mine[True]:
            fixed.update((name, re.split(r", or |: |; ", why)[0]) for name, why in r.fixed if name not in fixed)
        print("fixed by a convention: " + ("; ".join(f"{k} ({v})" for k, v in fixed.items()) or "none"))


if __name__ == "__main__":
    sys.exit(main())
