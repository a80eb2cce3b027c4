"""Accuracy benchmark: held-out prediction error vs the Cramér-Rao bound (docs/benchmarks.md).

    .venv/bin/python -m bench.accuracy [--draws 50] [--quick] [--jobs 2] [--family ur5e ...]

For every robot family and case (tracker noise × sweep arc, plus a case with gross outliers) one seeded
true robot is drawn, 200 held-out joint configurations are drawn, and then ``--draws`` data sets with fresh
noise are simulated and identified. The error of a draw is the RMS over the held-out poses of the 3D
distance between the identified model's predicted tracked point (TP) and the truth's. The bound is
:func:`identify.estimator.bounds.prediction_rms_bound` for the same fitted joint readings (true outlier rows
excluded) and noise. Reported: ``ratio = sqrt(mean over draws of RMS²) / bound`` for the refined model and
for the geometric step alone (the paper's method). Target: refined ratio <= 1.10 in every case; the exit
status is 1 when a case misses it.

A second part ("study") shows what free poses and wider arcs buy, for a UR5e at 0.05 mm noise.
"""

from __future__ import annotations

import os

# small matrices: BLAS threads only contend with the worker processes (this benchmark's timings are informative)
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass

import numpy as np

from config.robots import load_robot
from identify.estimator.bounds import prediction_rms_bound
from identify.estimator.dh_vector import full_jacobian
from identify.results.pipeline import identify
from identify.simulators.simulate import random_poses, simulate
from kinematics.dh import DHModel, points_from_joints
from kinematics.truth import random_truth

FAMILIES = ("ur5e", "scara", "iiwa7", "track_ur5e", "gantry")
NOISES = (1e-5, 5e-5, 5e-4)  # m per axis
PARTIAL_ARC = float(np.radians(20))  # rad: sweeps of home ± 20°
OUTLIERS = 3  # gross errors (5 mm) in the outlier case
CHECK_POSES = 200
TARGET = 1.10
SEED = 20240601  # base seed; each case's generator is seeded with (SEED, family index, case index)


@dataclass(frozen=True)
class Case:
    family: str
    noise: float
    arc: float | None  # None: full turns
    outliers: int
    family_index: int
    case_index: int

    @property
    def label(self) -> str:
        arc = "full" if self.arc is None else f"±{np.degrees(self.arc):.0f}°"
        return f"{self.noise * 1e3:g} mm, {arc}" + (f", {self.outliers} outliers" if self.outliers else "")


@dataclass(frozen=True)
class CaseResult:
    case: Case
    draws: int
    bound: float  # m, RMS over draws of the per-draw bound
    rms: float  # m, sqrt(mean RMS²) of the refined model
    rms_geo: float  # m, same for the geometric step
    ratio: float
    ratio_se: float  # Monte-Carlo standard error of ratio (delta method)
    ratio_geo: float
    ratio_free: float  # refined RMS vs the bound over the estimator's free parameters only (see free_bound)
    worst_draw: float  # largest single-draw RMS / bound (refined)
    outliers_missed: int  # true outliers not rejected, summed over draws
    false_rejections: int  # clean samples rejected, summed over draws
    failures: int  # draws where identify raised
    seconds: float

    @property
    def ok(self) -> bool:
        return self.failures == 0 and self.ratio <= TARGET


def cases(families: tuple[str, ...] = FAMILIES) -> list[Case]:
    out = []
    for fi, family in enumerate(FAMILIES):
        if family not in families:
            continue
        ci = 0
        for noise in NOISES:
            for arc in (None, PARTIAL_ARC):
                out.append(Case(family, noise, arc, 0, fi, ci))
                ci += 1
        out.append(Case(family, 5e-5, None, OUTLIERS, fi, ci))
    return out


def rms_error(model: DHModel, q: np.ndarray, truth_points: np.ndarray) -> float:
    """RMS 3D distance (m) between ``model``'s predicted TPs at ``q`` and ``truth_points``."""
    return float(np.sqrt(np.mean(np.sum((points_from_joints(model, q) - truth_points) ** 2, axis=1))))


def free_bound(truth: DHModel, q_fit: np.ndarray, q_check: np.ndarray, sigma: float, free: np.ndarray) -> float:
    """The bound for an estimator that knows the fixed parameters (``free`` mask of the full vector).

    Equal to the all-parameter bound when the fixed ones are redundant; smaller when a convention (the
    parallel-axis one) fixes a parameter the data determine only weakly. An estimator that fixes such a
    parameter is biased (slightly) and can beat the all-parameter bound; this one it cannot beat.
    """
    _, jac = full_jacobian(truth, q_fit)
    j = jac.reshape(-1, jac.shape[2])[:, free]
    scale = np.linalg.norm(j, axis=0)
    _, jac_check = full_jacobian(truth, q_check)
    g = (jac_check[:, :, free] / scale) @ np.linalg.pinv(j / scale, rcond=1e-9)
    return float(sigma * np.sqrt(np.mean(np.sum(g**2, axis=(1, 2)))))


def run_case(case: Case, draws: int) -> CaseResult:
    start = time.perf_counter()
    robot = load_robot(case.family)
    rng = np.random.default_rng((SEED, case.family_index, case.case_index))
    truth = random_truth(robot.nominal, robot.home, rng)
    q_check = random_poses(robot.limits, CHECK_POSES, rng)
    p_check = points_from_joints(truth, q_check)
    err2, err2_geo, bound2, free2 = [], [], [], []
    missed = false_rej = failures = 0
    for _ in range(draws):
        meas, bad = simulate(truth, robot.home, robot.limits, rng, noise=case.noise, arc=case.arc,
                             outliers=case.outliers)
        try:
            ident = identify(meas, nominal=robot.nominal)
        except Exception as exc:  # a benchmark records failures instead of stopping
            failures += 1
            print(f"  {case.family} {case.label}: identify failed: {exc}", file=sys.stderr)
            continue
        clean = np.ones(len(meas), dtype=bool)
        clean[bad] = False
        fit = clean & ~meas.check
        bound2.append(prediction_rms_bound(truth, meas.q[fit], q_check, case.noise) ** 2)
        free2.append(free_bound(truth, meas.q[fit], q_check, case.noise, ident.refinement.free) ** 2)
        err2.append(rms_error(ident.model, q_check, p_check) ** 2)
        err2_geo.append(rms_error(ident.geometric.model, q_check, p_check) ** 2)
        rejected = np.array(ident.rejected_rows, dtype=int) - 1  # rows are 1-based
        missed += int(np.sum(~np.isin(bad, rejected)))
        false_rej += int(np.sum(~np.isin(rejected, bad)))
    e2, g2, b2, f2 = np.array(err2), np.array(err2_geo), np.array(bound2), np.array(free2)
    bound = float(np.sqrt(np.mean(b2))) if len(b2) else float("nan")
    ratio = float(np.sqrt(np.mean(e2)) / bound) if len(e2) else float("inf")
    se = 0.5 * ratio * float(np.std(e2, ddof=1) / (np.sqrt(len(e2)) * np.mean(e2))) if len(e2) > 1 else float("nan")
    return CaseResult(
        case=case,
        draws=len(e2),
        bound=bound,
        rms=float(np.sqrt(np.mean(e2))) if len(e2) else float("nan"),
        rms_geo=float(np.sqrt(np.mean(g2))) if len(g2) else float("nan"),
        ratio=ratio,
        ratio_se=se,
        ratio_geo=float(np.sqrt(np.mean(g2)) / bound) if len(g2) else float("inf"),
        ratio_free=float(np.sqrt(np.mean(e2) / np.mean(f2))) if len(e2) else float("inf"),
        worst_draw=float(np.sqrt(np.max(e2 / b2))) if len(e2) else float("inf"),
        outliers_missed=missed,
        false_rejections=false_rej,
        failures=failures,
        seconds=time.perf_counter() - start,
    )


def _run(args: tuple[Case, int]) -> CaseResult:
    return run_case(*args)


def print_table(results: list[CaseResult]) -> None:
    header = (f"{'family':<11} {'case':<25} {'draws':>5} {'bound mm':>9} {'rms mm':>9} {'ratio':>6} {'±se':>5} "
              f"{'geo ratio':>9} {'vs free':>7} {'worst':>6} {'missed':>6} {'false':>5} {'s':>5}  ok")
    print(header)
    print("-" * len(header))
    for r in results:
        print(f"{r.case.family:<11} {r.case.label:<25} {r.draws:>5} {r.bound * 1e3:>9.5f} {r.rms * 1e3:>9.5f} "
              f"{r.ratio:>6.3f} {r.ratio_se:>5.3f} {r.ratio_geo:>9.2f} {r.ratio_free:>7.3f} {r.worst_draw:>6.2f} "
              f"{r.outliers_missed:>6} {r.false_rejections:>5} {r.seconds:>5.1f}  {'yes' if r.ok else 'NO'}")
    print()
    print(f"ratio = sqrt(mean RMS²)/bound of the refined model (target <= {TARGET:.2f}); ±se its Monte-Carlo standard")
    print("error; geo ratio = same for the geometric step alone (the paper's method); vs free = refined RMS over the")
    print("bound for the estimator's own free parameters (below the all-parameter bound when a convention fixes")
    print("a weakly determined parameter: then ratio < 1 is possible); worst = largest single-draw RMS/bound;")
    print("missed = true outliers not rejected and false = clean samples rejected, summed over draws.")
    print()
    print("worst refined ratio per family:")
    for family in dict.fromkeys(r.case.family for r in results):
        worst = max((r for r in results if r.case.family == family), key=lambda r: r.ratio)
        print(f"  {family:<11} {worst.ratio:.3f}  ({worst.case.label})")


# ---------------------------------------------------------------- study: what free poses and wide arcs buy

STUDY_FAMILY = "ur5e"
STUDY_NOISE = 5e-5
STUDY_FREE = 30
STUDY_SETS = 20  # free-pose sets the bound is averaged over (the free poses are random)


def study(fit_draws: int) -> None:
    """Bound (and a few fitted draws) for full / ±20° sweeps, with and without free poses."""
    robot = load_robot(STUDY_FAMILY)
    rng = np.random.default_rng((SEED, 99))
    truth = random_truth(robot.nominal, robot.home, rng)
    q_check = random_poses(robot.limits, CHECK_POSES, rng)
    p_check = points_from_joints(truth, q_check)
    print(f"Study: {STUDY_FAMILY}, noise {STUDY_NOISE * 1e3:g} mm per axis, {CHECK_POSES} held-out poses; "
          f"bound averaged over {STUDY_SETS} free-pose sets, fit over {fit_draws} draws")
    header = f"{'data':<28} {'samples':>7} {'bound mm':>9} {'bound/sigma':>11} {'fit rms mm':>10} {'fit/bound':>9}"
    print(header)
    print("-" * len(header))
    for arc in (None, PARTIAL_ARC):
        for free in (0, STUDY_FREE):
            label = ("full sweeps" if arc is None else "±20° sweeps") + (f" + {free} free poses" if free else "")
            bounds2 = []
            samples = 0
            for _ in range(STUDY_SETS if free else 1):
                meas, _ = simulate(truth, robot.home, robot.limits, rng, noise=STUDY_NOISE, arc=arc, free_poses=free)
                bounds2.append(prediction_rms_bound(truth, meas.q, q_check, STUDY_NOISE) ** 2)
                samples = len(meas)
            bound = float(np.sqrt(np.mean(bounds2)))
            err2, fb2 = [], []
            for _ in range(fit_draws):
                meas, _ = simulate(truth, robot.home, robot.limits, rng, noise=STUDY_NOISE, arc=arc, free_poses=free)
                ident = identify(meas, nominal=robot.nominal)
                err2.append(rms_error(ident.model, q_check, p_check) ** 2)
                fb2.append(prediction_rms_bound(truth, meas.q, q_check, STUDY_NOISE) ** 2)
            fit = float(np.sqrt(np.mean(err2)))
            print(f"{label:<28} {samples:>7} {bound * 1e3:>9.5f} {bound / STUDY_NOISE:>11.3f} {fit * 1e3:>10.5f} "
                  f"{fit / np.sqrt(np.mean(fb2)):>9.3f}")
    print()
    print("bound/sigma: the bound as a multiple of the per-axis noise (one measurement's 3D RMS error is 1.732 sigma).")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.accuracy", description=__doc__.split("\n")[0])
    parser.add_argument("--draws", type=int, default=50, help="noise draws per case (default 50; target needs >= 50)")
    parser.add_argument("--quick", action="store_true", help="10 draws per case, a smoke check")
    parser.add_argument("--jobs", type=int, default=os.cpu_count() or 1,
                        help="worker processes, cases run in parallel (default: all cores)")
    parser.add_argument("--family", action="append", choices=FAMILIES, help="only these families (repeatable)")
    parser.add_argument("--no-study", action="store_true", help="skip the free-pose / arc study")
    args = parser.parse_args(argv)
    draws = 10 if args.quick else args.draws
    todo = cases(tuple(args.family) if args.family else FAMILIES)
    start = time.perf_counter()
    print(f"Accuracy vs Cramér-Rao bound: {draws} draws per case, {CHECK_POSES} held-out poses, seed {SEED}")
    print()
    if args.jobs > 1:
        with ProcessPoolExecutor(args.jobs) as pool:
            results = list(pool.map(_run, [(c, draws) for c in todo]))
    else:
        results = [run_case(c, draws) for c in todo]
    print_table(results)
    print()
    if not args.no_study:
        study(fit_draws=3 if args.quick else 10)
        print()
    missed = [r for r in results if not r.ok]
    print(f"total {time.perf_counter() - start:.1f} s")
    if draws < 50:
        print(f"note: {draws} draws per case; the target is defined over >= 50")
    if missed:
        print(f"TARGET MISSED (refined ratio <= {TARGET}) in {len(missed)} case(s):")
        for r in missed:
            extra = f", {r.failures} failed draw(s)" if r.failures else ""
            print(f"  {r.case.family} {r.case.label}: ratio {r.ratio:.3f}{extra}")
        return 1
    print(f"all {len(results)} cases meet the target (refined ratio <= {TARGET})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
