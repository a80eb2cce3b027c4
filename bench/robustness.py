"""Robustness benchmark (issue 11): identification on realistic cells, scored against a singularity-free bound.

    .venv/bin/python -m bench.robustness [--draws 50] [--quick] [--jobs 2] [--robot ur5e ...] [--case outliers ...]

Every draw simulates a fresh true cell (``identify.simulators.simulate``: a perturbed robot as axis lines, a random base
and TP) and one data set of a case, identifies it with ``identify.results.pipeline.identify(meas, nominal, noise)`` and
scores it at 200 random held-out joint configurations (readings as the controller reports them):

- ``ratio``: sqrt(mean over draws of (RMS/bound)²), RMS = 3D error of ``ident.predict`` against where the TP
  truly is, bound = :func:`lines_bound` (Cramér-Rao, axis-lines model with per-row nuisance angles for rows
  without a reading). With one fixed truth this is sqrt(mean RMS²)/bound; here every draw has its own truth.
- verdict counts (pass / warn / fail; ``err`` = identify raised), **silent** = verdict pass with RMS > 3× bound,
- ``false``: data sets with at least one clean row rejected; ``missed``: gross outliers not rejected (rows),
- ``calib``: sqrt(mean (RMS / reported ``ident.prediction_rms``)²): 1 when the reported uncertainty is right,
- time per identification (ms, median and max).

Targets (issue 11): ratio <= 1.10 where the model is right and the noise Gaussian; zero silent failures over
all draws (>= 2,000 in the full run); fail <= 1 % of clean, well-posed draws (pooled); false rejections at the
design rate, 1 % of data sets (a case misses when its count exceeds the 95 % binomial quantile at 1 %); no
outlier missed; calib within 1 ± 0.15 (1 ± 0.20 with model error); median time < 200 ms. Exit status 1 when a
target is missed.
"""

from __future__ import annotations

import os

# small matrices: BLAS threads only contend with the worker processes and the timing
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import sys
import time
from collections import Counter
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field, replace
from functools import lru_cache
from types import SimpleNamespace

import numpy as np
from numpy.typing import NDArray
from scipy.stats import binom

from bench.robustness_cells import FANUC_SIM, GRID_ROBOT, gravity_sag, grid_scenario
from config.robots import RobotModel
from config.robots import load_robot as _load_robot
from identify.estimator.estimate import fit_lines
from identify.estimator.poe import AxisLines, points_from_lines
from identify.results import pipeline
from identify.simulators.simulate import (
    Scenario,
    dh_truth,
    line_parameter_count,
    make_scenario,
    moved_lines,
    random_poses,
    reading_error,
    tilted_truth,
    wrist_joints,
)
from kinematics.dh import DHModel

Array = NDArray[np.float64]


@lru_cache
def load_robot(name: str) -> RobotModel:
    """The bundled robot model ``name`` (read once per process)."""
    return _load_robot(name)

ROBOTS = ("ur5e", "scara", "iiwa7")
CHECK_POSES = 200
SEED = 20261124
RATIO_TARGET = 1.10
SILENT_FACTOR = 3.0
RATE_TARGET = 0.01  # fail rate on clean well-posed draws; false-rejection rate of data sets
CALIB_TOL, CALIB_TOL_MODEL = 0.15, 0.20
TIME_TARGET = 0.2  # s, median per identification
RCOND = 1e-9
FD_STEP = 1e-6  # rad or m: central differences for the nuisance columns


def lines_jacobian(lines: AxisLines, q: Array) -> Array:
    """Jacobian (3m, size) of the TPs predicted at true joint values ``q`` (m, n) with respect to the lines
    parameters of ``identify.simulators.simulate.moved_lines`` (rad, m) at zero; central differences (``FD_STEP``),
    relative error ~1e-9."""
    size = line_parameter_count(lines.joint_types)
    jac = np.empty((3 * len(q), size))
    for k in range(size):
        step = np.zeros(size)
        step[k] = FD_STEP
        diff = points_from_lines(moved_lines(lines, step), q) - points_from_lines(moved_lines(lines, -step), q)
        jac[:, k] = diff.ravel() / (2 * FD_STEP)
    return jac


def lines_bound(lines: AxisLines, q_fit: Array, unknown: NDArray[np.bool_], moved: NDArray[np.int64],
                q_check: Array, sigma: float) -> float:
    """Cramér-Rao bound (m) on the RMS 3D error of predicted TPs at true joint values ``q_check`` (k, n).

    Model: the axis lines at home (per revolute joint 2 tilts + 2 shifts, per prismatic 2 tilts) and the TP at
    home (3), plus one nuisance joint value per fitted row whose moved joint's reading is unknown (``unknown``
    (m,), ``moved`` (m,) 1-based). ``q_fit`` (m, n): the true joint values of the fitted rows. Bound:
    ``sigma² · Jc · pinv(JᵀJ) · Jcᵀ`` over all parameters (the check predictions do not depend on the
    nuisances), RMS over the check poses = sqrt(mean trace). ``sigma``: isotropic noise, m per axis.
    """
    size = line_parameter_count(lines.joint_types)
    jac = lines_jacobian(lines, q_fit)
    rows = np.flatnonzero(unknown)
    if len(rows):
        cols = moved[rows] - 1
        plus, minus = q_fit[rows].copy(), q_fit[rows].copy()
        plus[np.arange(len(rows)), cols] += FD_STEP
        minus[np.arange(len(rows)), cols] -= FD_STEP
        deriv = (points_from_lines(lines, plus) - points_from_lines(lines, minus)) / (2 * FD_STEP)
        nuisance = np.zeros((len(q_fit), 3, len(rows)))
        nuisance[rows, :, np.arange(len(rows))] = deriv
        jac = np.hstack([jac, nuisance.reshape(-1, len(rows))])
    jac_check = np.zeros((3 * len(q_check), jac.shape[1]))
    jac_check[:, :size] = lines_jacobian(lines, q_check)
    scale = np.maximum(np.linalg.norm(jac, axis=0), 1e-300)
    _, s, vt = np.linalg.svd(jac / scale, full_matrices=False)
    keep = s > RCOND * s[0]
    g = (jac_check / scale) @ (vt[keep].T / s[keep])
    return float(sigma * np.sqrt(np.sum(g**2) / len(q_check)))


class Oracle:
    """The bench's self-check (``--oracle``): a maximum-likelihood fit of the axis lines
    (identify.estimator.estimate.fit_lines) started at the truth, to the clean fitted rows that have readings, with
    the true
    outliers as its rejections and the lines bound at its own estimate as its reported uncertainty. Its ratio near 1
    shows the bound is attainable on a case; it needs readings, so it does not run the positions-only and jogged
    cases."""

    def __init__(self, scen: Scenario):
        fit = ~scen.meas.check & np.all(np.isfinite(scen.meas.q), axis=1)
        fit[scen.outliers] = False
        start = replace(scen.truth, home=scen.home)
        self.lines = fit_lines(start, scen.meas.q[fit], scen.meas.points[fit])[0]
        self.q_fit, self.noise = scen.meas.q[fit], scen.noise
        self.rejected_rows = [int(r) for r in scen.meas.row[scen.outliers]]
        self.verdict = SimpleNamespace(status="pass", checks=[])

    def predict(self, q: Array) -> Array:
        return points_from_lines(self.lines, q)

    def prediction_rms(self, q: Array) -> float:
        none = np.zeros(len(self.q_fit), dtype=bool)
        return lines_bound(self.lines, self.q_fit, none, none.astype(np.int64), q, self.noise)


@dataclass(frozen=True)
class Case:
    """One benchmark case: how the truth and the data set are drawn (see ``make_scenario``)."""

    key: str
    label: str
    truth: str = "dh"  # "dh" (perturbed DH values) or "tilted" (axes tilted in any direction)
    noise: float = 5e-5  # m per axis
    steps: int = 36
    arc: float | None = None
    wrist: bool = False
    free_poses: int = 0
    free_only: int = 0
    check_poses: int = 0
    holdout_in_sweep: int = 0
    missing_in_sweep: int = 0
    outliers: float = 0.0
    readings: str = "all"
    model_error: tuple[float, float] | None = None
    reading_error: bool = False
    last_radius: float | None = None
    nominal: bool = False
    compliance: float = 0.0  # rad/(N m) on joints 2 and 3 under gravity (bench.robustness_cells.GravitySag)
    grid: bool = False  # the zhang2016 A1 x A2 grid on the two-joint iiwa nominal (bench.robustness_cells)
    robot: str | None = None  # a robot file of the case's own, drawn once in the slot of ``slot``
    slot: str = "ur5e"
    heavy: float = 0.0  # > 0: Student-t noise of that many degrees of freedom, scale ``noise`` (0: Gaussian)
    zero_off: float = 0.0  # deg added to the nominal's theta of joint 2 (a nominal with the wrong zero)

    @property
    def correct_model(self) -> bool:
        """Gaussian noise and a model that can explain the data: the ratio target applies."""
        return self.model_error is None and not self.reading_error and not self.compliance and not self.heavy

    @property
    def clean_well_posed(self) -> bool:
        """No gross error, no model error, not an ill-posed short-arc problem: the fail-rate target applies."""
        return self.correct_model and not self.outliers and self.arc is None


CASES = (
    Case("s6", "6 samples, full turns", steps=6),
    Case("s12", "12 samples, full turns", steps=12),
    Case("s36", "36 samples, full turns", steps=36),
    Case("arc20", "±20° arcs, 12 samples", steps=12, arc=float(np.radians(20))),
    Case("outliers", "5% outliers 5-20 mm, 12 s.", steps=12, outliers=0.05),
    Case("posonly", "positions only, 12 samples", steps=12, readings="none"),
    Case("jogged", "one jogged sweep, 12 s.", steps=12, readings="jogged"),
    Case("free", "60 free poses only, nominal", free_only=60, check_poses=10, nominal=True),
    Case("tp5mm", "TP 5 mm off last axis, 36 s.", last_radius=5e-3),
    Case("modelerr", "1 µm noise + 10-30 µm model err", noise=1e-6, model_error=(1e-5, 3e-5)),
    Case("tilted", "tilted axes, 36 samples", truth="tilted"),
    Case("tiltfree", "tilted, 12 s. + 20 free + 10 chk", truth="tilted", steps=12, free_poses=20, check_poses=10),
    Case("nongeo", "reading scale 1e-4 + 0.01°/turn", noise=1e-5, reading_error=True),
    Case("wrist6", "wrist 6 at 144°, 2 held out", steps=12, wrist=True, holdout_in_sweep=2),
    Case("gap20", "36 s., 20 in a row lost in 1 sweep", missing_in_sweep=20),
    # from the real sets (bench/realdata, issue 27)
    Case("elastic", "J2/J3 sag 3e-5 rad/Nm, 6 s.", steps=6, compliance=3e-5),
    Case("grid2", "A1 x A2 grid in sweeps, nominal", noise=2e-5, nominal=True, grid=True, robot=GRID_ROBOT,
         slot="iiwa7"),
    Case("zero90", "nominal J2 -90°, t(2) noise, 6 s.", noise=2e-5, steps=6, nominal=True, robot=FANUC_SIM,
         heavy=2.0, zero_off=-90.0),
)


def case_robot(case: Case, robot_name: str) -> str:
    """The robot a draw of ``case`` runs on: ``robot_name``, or the case's own."""
    return case.robot or robot_name


def scenario(case: Case, robot_name: str, rng: np.random.Generator) -> Scenario:
    """One data set of ``case`` on a fresh true ``robot_name`` cell."""
    robot = load_robot(case_robot(case, robot_name))
    if case.grid:
        return grid_scenario(robot, rng, case.noise)
    if case.truth == "tilted":
        truth = tilted_truth(robot.nominal, robot.home, rng, last_radius=case.last_radius)
    else:
        truth = dh_truth(robot.nominal, robot.home, rng, last_radius=case.last_radius)
    errors = reading_error(robot.joint_types, rng) if case.reading_error else None
    if case.compliance:
        errors = gravity_sag(robot, robot.nominal, case.compliance)  # type: ignore[assignment]  # the same interface
    scen = make_scenario(truth, robot.home, robot.limits, rng, noise=0.0 if case.heavy else case.noise,
                         steps=case.steps, arc=case.arc, wrist=case.wrist, free_poses=case.free_poses,
                         free_only=case.free_only, check_poses=case.check_poses,
                         holdout_in_sweep=case.holdout_in_sweep, missing_in_sweep=case.missing_in_sweep,
                         outlier_fraction=case.outliers, readings=case.readings, model_error=case.model_error,
                         errors=errors)
    if case.heavy:
        scen.meas.points[:] += case.noise * rng.standard_t(case.heavy, scen.meas.points.shape)
        scen = replace(scen, noise=case.noise)  # the scale declared to identify and used by the bound
    return scen


def case_nominal(case: Case, robot: RobotModel) -> DHModel | None:
    """The nominal model ``identify`` is given in ``case`` (None: none), with its joint-2 zero moved by
    ``case.zero_off``."""
    if not case.nominal:
        return None
    theta = robot.nominal.theta.copy()
    theta[1] += np.radians(case.zero_off)
    return replace(robot.nominal, theta=theta)


def applicable(case: Case, robot_name: str) -> bool:
    robot = load_robot(robot_name)
    if case.robot:
        return robot_name == case.slot  # once: the case has its own robot
    if case.compliance and robot.links is None:
        return False
    return not case.wrist or bool(wrist_joints(robot.joint_types, robot.limits))


@dataclass
class CaseResult:
    robot: str
    case: Case
    draws: int = 0
    ratios2: list[float] = field(default_factory=list)  # (RMS/bound)² per scored draw
    calib2: list[float] = field(default_factory=list)  # (RMS/reported)² per scored draw
    bounds: list[float] = field(default_factory=list)
    status: dict[str, int] = field(default_factory=lambda: {"pass": 0, "warn": 0, "fail": 0, "err": 0})
    silent: list[int] = field(default_factory=list)  # draw numbers
    false_sets: list[int] = field(default_factory=list)  # draw numbers with a clean row rejected
    false_rows: int = 0
    missed: int = 0
    outliers: int = 0
    times: list[float] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)
    worst: tuple[float, int] = (0.0, -1)  # largest RMS/bound and its draw
    checks: Counter[str] = field(default_factory=Counter)  # "name:status" of every check not passing

    @property
    def ratio(self) -> float:
        return float(np.sqrt(np.mean(self.ratios2))) if self.ratios2 else float("inf")

    @property
    def ratio_se(self) -> float:
        r2 = np.array(self.ratios2)
        if len(r2) < 2:
            return float("nan")
        return float(0.5 * self.ratio * np.std(r2, ddof=1) / (np.sqrt(len(r2)) * np.mean(r2)))

    @property
    def calib(self) -> float:
        return float(np.sqrt(np.mean(self.calib2))) if self.calib2 else float("nan")

    @property
    def calib_se(self) -> float:
        c2 = np.array(self.calib2)
        if len(c2) < 2 or not np.all(np.isfinite(c2)):
            return float("nan")
        return float(0.5 * self.calib * np.std(c2, ddof=1) / (np.sqrt(len(c2)) * np.mean(c2)))

    @property
    def failed(self) -> int:
        return self.status["fail"] + self.status["err"]

    def missed_targets(self) -> list[str]:
        out = []
        c = self.case
        if c.correct_model and not self.ratio <= RATIO_TARGET:
            out.append(f"ratio {self.ratio:.3f} > {RATIO_TARGET}")
        if self.silent:
            out.append(f"{len(self.silent)} silent failure(s) (draws {self.silent[:5]})")
        allowed = int(binom.ppf(0.95, self.draws, RATE_TARGET))
        if len(self.false_sets) > allowed:
            out.append(f"false rejections in {len(self.false_sets)}/{self.draws} data sets (> {allowed} allowed "
                       f"at {RATE_TARGET:.0%})")
        if self.missed:
            out.append(f"{self.missed} of {self.outliers} outliers missed")
        tol = CALIB_TOL if c.correct_model else CALIB_TOL_MODEL
        if not abs(self.calib - 1) <= tol:
            out.append(f"calib {self.calib:.2f} outside 1 ± {tol:.2f}")
        if self.times and not np.median(self.times) < TIME_TARGET:
            out.append(f"median time {np.median(self.times) * 1e3:.0f} ms >= {TIME_TARGET * 1e3:.0f} ms")
        return out


def _rms(a: Array) -> float:
    return float(np.sqrt(np.mean(np.sum(a**2, axis=1))))


def draw(robot_name: str, case_key: str, k: int) -> tuple[Scenario, Array]:
    """Draw ``k`` of a case: the data set and the held-out readings (200, n). A reproducer of any draw:
    ``scen, q_check = draw("ur5e", "jogged", 3)``, then ``identify(scen.meas, noise=scen.noise)``."""
    case_index = [c.key for c in CASES].index(case_key)
    rng = np.random.default_rng((SEED, ROBOTS.index(robot_name), case_index, k))
    scen = scenario(CASES[case_index], robot_name, rng)
    return scen, random_poses(load_robot(case_robot(CASES[case_index], robot_name)).limits, CHECK_POSES, rng)


def run_case(robot_name: str, case_key: str, draws: int, oracle: bool = False) -> CaseResult:
    """``draws`` data sets of the case keyed ``case_key`` (:func:`draw` 0 .. draws-1) on ``robot_name``.
    With ``oracle`` the :class:`Oracle` replaces the estimator."""
    case = next(c for c in CASES if c.key == case_key)
    robot = load_robot(case_robot(case, robot_name))
    nominal = case_nominal(case, robot)
    result = CaseResult(robot_name, case)
    for k in range(draws):
        scen, q_check = draw(robot_name, case.key, k)
        result.draws += 1
        start = time.perf_counter()
        try:
            ident = Oracle(scen) if oracle else pipeline.identify(scen.meas, nominal=nominal, noise=scen.noise)
        except Exception as exc:  # recorded (a failure the user sees), not fatal
            result.status["err"] += 1
            result.errors.append(f"draw {k}: {type(exc).__name__}: {exc}")
            continue
        result.times.append(time.perf_counter() - start)
        readings = scen.predictor_readings(q_check)
        err = _rms(ident.predict(readings) - scen.truth_points(q_check))
        err = err if np.isfinite(err) else float("inf")  # a NaN prediction is an infinite error, not a pass
        status = ident.verdict.status
        reported = float(ident.prediction_rms(readings))
        rejected = np.asarray(ident.rejected_rows, dtype=int) - 1  # meas.row is 1-based, row k is index k-1
        fit = ~scen.meas.check
        clean_fit = fit.copy()
        clean_fit[scen.outliers] = False
        bound = lines_bound(scen.truth, scen.true_q[clean_fit], scen.unknown[clean_fit], scen.meas.joint[clean_fit],
                            scen.true_values(q_check), scen.noise)
        result.status[status] += 1
        for check in ident.verdict.checks:
            if check.status != "pass":
                result.checks[f"{check.name}:{check.status}"] += 1
        result.bounds.append(bound)
        result.ratios2.append((err / bound) ** 2)
        result.calib2.append((err / reported) ** 2 if reported > 0 else float("inf"))
        if err / bound > result.worst[0]:
            result.worst = (err / bound, k)
        if status == "pass" and err > SILENT_FACTOR * bound:
            result.silent.append(k)
        false = int(np.sum(~np.isin(rejected, scen.outliers)))
        result.false_rows += false
        if false:
            result.false_sets.append(k)
        result.outliers += len(scen.outliers)
        result.missed += int(np.sum(~np.isin(scen.outliers, rejected)))
    return result


def _run(args: tuple[str, str, int, bool]) -> CaseResult:
    return run_case(*args)


def print_table(results: list[CaseResult]) -> None:
    header = (f"{'robot':<6} {'case':<33} {'n':>3} {'bound mm':>9} {'ratio':>7} {'±se':>5} {'worst':>7} "
              f"{'pass':>4} {'warn':>4} {'fail':>4} {'err':>3} {'silent':>6} {'false':>5} {'missed':>6} "
              f"{'calib':>6} {'±se':>4} {'ms med':>6} {'ms max':>6}  ok")
    print(header)
    print("-" * len(header))
    for r in results:
        st = r.status
        med = np.median(r.times) * 1e3 if r.times else float("nan")
        mx = np.max(r.times) * 1e3 if r.times else float("nan")
        bound = np.sqrt(np.mean(np.square(r.bounds))) * 1e3 if r.bounds else float("nan")
        missed = f"{r.missed}/{r.outliers}" if r.outliers else "-"
        print(f"{r.robot:<6} {r.case.label:<33} {r.draws:>3} {bound:>9.5f} {r.ratio:>7.3f} {r.ratio_se:>5.2f} "
              f"{r.worst[0]:>7.2f} {st['pass']:>4} {st['warn']:>4} {st['fail']:>4} {st['err']:>3} "
              f"{len(r.silent):>6} {len(r.false_sets):>5} {missed:>6} {r.calib:>6.2f} {r.calib_se:>4.2f} "
              f"{med:>6.0f} {mx:>6.0f}  "
              f"{'NO' if r.missed_targets() else 'yes'}")
    print()
    print("ratio = sqrt(mean (RMS/bound)²) at 200 held-out poses (target <= 1.10 unless the model is wrong: model err,")
    print("reading scale); ±se its Monte-Carlo standard error; worst = largest single-draw RMS/bound; err = identify")
    print("raised; silent = verdict pass with RMS > 3x bound; false = data sets with a clean row rejected; missed =")
    print("outlier rows not rejected / planted; calib = sqrt(mean (RMS / reported prediction_rms)²), 1 is right.")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.robustness", description=__doc__.split("\n")[0])
    parser.add_argument("--draws", type=int, default=50, help="draws per case (default 50; targets need >= 50)")
    parser.add_argument("--quick", action="store_true", help="5 draws per case, a smoke check")
    parser.add_argument("--jobs", type=int, default=2, help="worker processes, cases in parallel (default 2)")
    parser.add_argument("--robot", action="append", choices=ROBOTS, help="only these robots (repeatable)")
    parser.add_argument("--case", action="append", choices=[c.key for c in CASES], help="only these cases")
    parser.add_argument("--oracle", action="store_true",
                        help="self-check: score a lines fit started at the truth instead of identify (see Oracle)")
    args = parser.parse_args(argv)
    draws = 5 if args.quick else args.draws
    robots = tuple(args.robot) if args.robot else ROBOTS
    todo = [(name, case.key, draws, args.oracle) for name in ROBOTS if name in robots
            for case in CASES if (not args.case or case.key in args.case) and applicable(case, name)
            and not (args.oracle and case.readings != "all")]
    start = time.perf_counter()
    who = "identify"
    if args.oracle:
        who = "ORACLE (lines fit started at the truth; a check of the bench, not of identify)"
    print(f"Robustness on realistic cells: {who}, {draws} draws per case, {CHECK_POSES} held-out poses, seed {SEED}")
    print()
    if args.jobs > 1:
        with ProcessPoolExecutor(args.jobs) as pool:
            results = list(pool.map(_run, todo))
    else:
        results = [_run(t) for t in todo]
    print_table(results)
    print()
    print("checks not passing (name:status x draws) and exceptions, per case:")
    for r in results:
        if r.checks:
            print(f"  {r.robot} {r.case.key}: " + ", ".join(f"{k} x{v}" for k, v in r.checks.most_common(6)))
        for message in r.errors[:3]:
            print(f"  {r.robot} {r.case.key}: {message}")
    total = sum(r.draws for r in results)
    silent = sum(len(r.silent) for r in results)
    clean = [r for r in results if r.case.clean_well_posed]
    clean_draws = sum(r.draws for r in clean)
    clean_fail = sum(r.failed for r in clean)
    allowed = int(binom.ppf(0.95, clean_draws, RATE_TARGET)) if clean_draws else 0
    print(f"load average at the end {os.getloadavg()[0]:.1f} (2 cores shared: timings are indicative)")
    print(f"total {total} draws in {time.perf_counter() - start:.0f} s; silent failures {silent}; fail on clean "
          f"well-posed draws {clean_fail}/{clean_draws} ({clean_fail / max(clean_draws, 1):.1%}, <= {allowed} "
          f"allowed at {RATE_TARGET:.0%})")
    missed = [(r, m) for r in results for m in r.missed_targets()]
    if clean_fail > allowed:
        missed.append((None, f"fail on {clean_fail}/{clean_draws} clean well-posed draws"))
    if total < 2000:
        print(f"note: {total} draws; the silent-failure target is defined over >= 2,000")
    if missed:
        print(f"TARGETS MISSED ({len(missed)}):")
        for r, message in missed:
            where = f"{r.robot} {r.case.key}" if r is not None else "all"
            print(f"  {where}: {message}")
        return 1
    print("all targets met")
    return 0


if __name__ == "__main__":
    sys.exit(main())
