"""Trust benchmark: are the reported standard uncertainties right?

    .venv/bin/python -m bench.trust [--reps 300] [--jobs 2]

Per family (UR5e and SCARA, 0.05 mm noise, full sweeps) one seeded true robot is identified ``--reps`` times
with fresh noise. For every free parameter the reported standard uncertainty (``ident.std``, RMS over the
repetitions) is compared with the empirical standard deviation of the estimates. Base rotation entries
(``base.rx/ry/rz``) are a rotation increment applied on the left, so for them the spread of
``R_k · mean(R)ᵀ`` (as a rotation vector, tracker frame) is compared instead. Target: reported / empirical
within ±15 % for every compared parameter (the empirical value's own standard error is about
``1/sqrt(2·(reps-1))``, 4 % at 300 repetitions). The exit status is 1 when a parameter misses it.
"""

from __future__ import annotations

import os

# small matrices: BLAS threads only contend with the worker processes (this benchmark measures no time)
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from config.robots import load_robot
from identify.estimator.dh_vector import parameter_names, vector_from_model
from identify.results.pipeline import identify
from identify.simulators.simulate import simulate
from kinematics.truth import random_truth

FAMILIES = ("ur5e", "scara")
NOISE = 5e-5
TOLERANCE = 0.15
SEED = 20240603
ANGLES = ("theta", "alpha")


@dataclass(frozen=True)
class Row:
    family: str
    name: str
    reported: float  # RMS over repetitions of the reported standard uncertainty
    empirical: float  # standard deviation of the estimates

    @property
    def ratio(self) -> float:
        return self.reported / self.empirical

    @property
    def ok(self) -> bool:
        return abs(self.ratio - 1.0) <= TOLERANCE


@dataclass(frozen=True)
class FamilyResult:
    family: str
    reps: int
    used: int  # repetitions with the modal free-parameter mask
    rows: list[Row]
    varying_fixed: list[str]  # fixed parameters whose value changed across repetitions (should be none)
    failures: int
    seconds: float


def _wrapped(values: np.ndarray) -> np.ndarray:
    """Angles unwrapped about their circular mean, so their spread is meaningful near ±pi."""
    centre = np.angle(np.mean(np.exp(1j * values)))
    return centre + np.angle(np.exp(1j * (values - centre)))


def run_family(family: str, family_index: int, reps: int) -> FamilyResult:
    start = time.perf_counter()
    robot = load_robot(family)
    rng = np.random.default_rng((SEED, family_index))
    truth = random_truth(robot.nominal, robot.home, rng)
    names = parameter_names(robot.n_joints)
    estimates, stds, masks, rotations = [], [], [], []
    failures = 0
    for _ in range(reps):
        meas, _ = simulate(truth, robot.home, robot.limits, rng, noise=NOISE)
        try:
            ident = identify(meas, nominal=robot.nominal)
        except Exception as exc:  # recorded, not fatal
            failures += 1
            print(f"  {family}: identify failed: {exc}", file=sys.stderr)
            continue
        estimates.append(vector_from_model(ident.model))
        stds.append(ident.std)
        masks.append(ident.refinement.free.copy())
        rotations.append(ident.model.base[:3, :3])
    masks_arr = np.array(masks)
    patterns, counts = np.unique(masks_arr, axis=0, return_counts=True)
    modal = patterns[np.argmax(counts)]
    use = np.all(masks_arr == modal, axis=1)
    est, std = np.array(estimates)[use], np.array(stds)[use]
    rows: list[Row] = []
    rot = Rotation.from_matrix(np.array(rotations)[use])
    spread = (rot * rot.mean().inv()).as_rotvec()  # left increments about the mean, tracker frame
    for k in range(3):
        if modal[k]:
            rows.append(Row(family, names[k], float(np.sqrt(np.mean(std[:, k] ** 2))), float(np.std(spread[:, k],
                                                                                                       ddof=1))))
    for k in range(3, len(names)):
        if not modal[k]:
            continue
        values = est[:, k]
        if names[k].rstrip("0123456789") in ANGLES:
            values = _wrapped(values)
        rows.append(Row(family, names[k], float(np.sqrt(np.mean(std[:, k] ** 2))), float(np.std(values, ddof=1))))
    varying = [names[k] for k in range(3, len(names)) if not modal[k] and np.ptp(est[:, k]) > 1e-12]
    return FamilyResult(family, reps, int(use.sum()), rows, varying, failures, time.perf_counter() - start)


def _run(args: tuple[str, int, int]) -> FamilyResult:
    return run_family(*args)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.trust", description=__doc__.split("\n")[0])
    parser.add_argument("--reps", type=int, default=300, help="Monte-Carlo repetitions per family (default 300)")
    parser.add_argument("--jobs", type=int, default=os.cpu_count() or 1, help="worker processes (one per family)")
    parser.add_argument("--worst", type=int, default=8, help="how many of the worst parameters to print per family")
    parser.add_argument("--all", action="store_true", help="print every compared parameter")
    args = parser.parse_args(argv)
    start = time.perf_counter()
    todo = [(family, i, args.reps) for i, family in enumerate(FAMILIES)]
    if args.jobs > 1:
        with ProcessPoolExecutor(min(args.jobs, len(todo))) as pool:
            results = list(pool.map(_run, todo))
    else:
        results = [_run(t) for t in todo]
    se = 1.0 / np.sqrt(2 * (args.reps - 1))
    print(f"Reported vs empirical standard uncertainty: {args.reps} repetitions per family, noise {NOISE * 1e3:g} mm, "
          f"full sweeps, seed {SEED}")
    print(f"target: reported/empirical within 1 ± {TOLERANCE:.2f} (standard error of the empirical std ≈ {se:.3f})")
    print()
    missed: list[Row] = []
    for r in results:
        ratios = np.array([row.ratio for row in r.rows])
        print(f"{r.family}: {len(r.rows)} parameters compared over {r.used} of {r.reps} repetitions "
              f"({r.reps - r.used - r.failures} with a different free-parameter set left out, {r.failures} failed); "
              f"ratio range {ratios.min():.3f} .. {ratios.max():.3f}, RMS deviation "
              f"{np.sqrt(np.mean((ratios - 1) ** 2)):.3f}; {r.seconds:.0f} s")
        if r.varying_fixed:
            print(f"  WARNING: fixed parameters that changed across repetitions: {', '.join(r.varying_fixed)}")
        shown = r.rows if args.all else sorted(r.rows, key=lambda row: -abs(row.ratio - 1))[: args.worst]
        print(f"  {'parameter':<10} {'reported':>12} {'empirical':>12} {'ratio':>7}  unit")
        for row in shown:
            unit = "rad" if row.name.rstrip("0123456789") in ANGLES or row.name.startswith("base.r") else "m"
            print(f"  {row.name:<10} {row.reported:>12.4e} {row.empirical:>12.4e} {row.ratio:>7.3f}  {unit}"
                  f"{'' if row.ok else '   MISSED'}")
        missed += [row for row in r.rows if not row.ok]
        print()
    worst = max((row for r in results for row in r.rows), key=lambda row: abs(row.ratio - 1))
    print(f"worst: {worst.family} {worst.name} ratio {worst.ratio:.3f}; total {time.perf_counter() - start:.0f} s")
    if missed:
        print("TARGET MISSED for: " + ", ".join(f"{row.family} {row.name} ({row.ratio:.3f})" for row in missed))
        return 1
    print(f"all compared parameters within ±{TOLERANCE:.0%}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
