"""Second-session benchmark: does a calibration hold on another day's data of the same arm, with the tracker moved?

    .venv/bin/python -m bench.second_session [--pairs 50] [--jobs 1]

Per pair a simulated UR5e (the nominal's axes at home, DH values perturbed: 0.5 mm / 1 mrad; a random base and
TP), 0.02 mm tracker noise, in two cases: ``dh`` (the readings are the true angles) and ``joint errors`` (every
joint's reading scaled by 1 + 2e-4 and off by a once-per-turn 0.02° at a random phase):

1. session 1: 18-sample sweeps, 20 free poses and 20 held-out ones, identified against the nominal (``identify``);
   the result written to YAML and read back;
2. each model of the written result (``plain``: the DH table; ``extended``: with its joint errors, when selected)
   predicts session 1's held-out rows: that model's first-session held-out RMS;
3. session 2 of the same arm: the tracker moved (any rotation, 1.5-2.5 m), 40 free poses, fresh noise;
   ``identify check`` (identify.applications.holds): its cross-validated RMS per model after re-registering the tracker;
4. session 2 of another arm of the same model (another truth, its own joint errors): ``identify check`` again.

Reported per case and model: the RMS over pairs of both figures and of their ratio, the share of same-arm pairs
that pass (and warn), of other-arm pairs that fail, and how often the extended model predicts session 2 no worse
than the plain one. Targets, for the model the result recommends: the same arm passes in >= 95 % of pairs and
another arm fails in >= 95 %; the second session's RMS within 1.1x the first's held-out (RMS over pairs of the
ratio; the registration's 6 parameters alone add about 3 % on 40 poses). Exit status 1 when a target is missed.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass

import numpy as np
import yaml

from config.robots import load_robot
from identify.applications.holds import check_models
from identify.applications.result_models import result_models
from identify.io.result_io import result_to_dict
from identify.results.pipeline import identify
from identify.simulators.simulate import dh_truth, make_scenario, reading_error, transform_lines
from kinematics.truth import random_base

ROBOT = "ur5e"
NOISE = 2e-5
SEED = 20261125
CASES = {"dh": None, "joint errors": (2e-4, np.radians(0.02))}  # reading scale, once-per-turn amplitude (rad)


@dataclass(frozen=True)
class Pair:
    """One arm pair: per model name, the first session's held-out RMS, the second session's cross-validated RMS
    and status (same arm), and the other arm's status; ``use`` the model the result recommends."""

    case: str
    first: dict[str, float]
    second: dict[str, float]
    same: dict[str, str]
    other: dict[str, str]
    use: str
    seconds: float


def one_pair(job: tuple[str, int]) -> Pair:
    case, k = job
    robot = load_robot(ROBOT)
    rng = np.random.default_rng([SEED, list(CASES).index(case), k])
    start = time.perf_counter()
    sizes = CASES[case]

    def arm():
        errors = None if sizes is None else reading_error(robot.joint_types, rng, *sizes)
        return dh_truth(robot.nominal, robot.home, rng), errors

    truth, errors = arm()
    s1 = make_scenario(truth, robot.home, robot.limits, rng, noise=NOISE, steps=18, free_poses=20, check_poses=20,
                       errors=errors)
    doc = yaml.safe_load(yaml.safe_dump(result_to_dict(identify(s1.meas, robot.nominal), robot.nominal, robot.name)))
    held = s1.meas.subset(s1.meas.check)
    first = {m.name: float(np.sqrt(np.mean(np.sum((m.points(held.q, held.tp) - held.points) ** 2, axis=1))))
             for m in result_models(doc, held.q, held.tp).models}
    s2 = make_scenario(transform_lines(truth, random_base(rng)), robot.home, robot.limits, rng, noise=NOISE,
                       free_only=40, errors=errors)
    other_truth, other_errors = arm()
    s3 = make_scenario(transform_lines(other_truth, random_base(rng)), robot.home, robot.limits, rng, noise=NOISE,
                       free_only=40, errors=other_errors)
    checks = []
    for meas in (s2.meas, s3.meas):
        models = result_models(doc, meas.q, meas.tp)
        checks.append(check_models(meas.points, meas.q, meas.tp, models.models, models.use))
    same, other = checks
    return Pair(case, first, {m.name: m.heldout.rms for m in same.models}, {m.name: m.status for m in same.models},
                {m.name: m.status for m in other.models}, same.use, time.perf_counter() - start)


def _rms(values: list[float]) -> float:
    return float(np.sqrt(np.mean(np.square(values))))


def report(pairs: list[Pair]) -> tuple[list[str], bool]:
    lines = ["model     pairs  1st held-out  2nd (check)  2nd/1st  same arm: pass  warn   other arm: fail",
             "                  mm RMS        mm RMS       RMS"]
    ok = True
    for name in ("plain", "extended"):
        have = [p for p in pairs if name in p.first]
        if not have:
            continue
        first, second = [p.first[name] for p in have], [p.second[name] for p in have]
        ratio = _rms([b / a for a, b in zip(first, second, strict=True)])
        passed = sum(p.same[name] == "pass" for p in have) / len(have)
        warned = sum(p.same[name] == "warn" for p in have) / len(have)
        failed = sum(p.other[name] == "fail" for p in have) / len(have)
        lines.append(f"{name:<9} {len(have):5d} {_rms(first) * 1e3:12.4f} {_rms(second) * 1e3:12.4f} {ratio:8.3f} "
                     f"{passed:13.1%} {warned:6.1%} {failed:14.1%}")
    both = [p for p in pairs if "extended" in p.second]
    if both:
        no_worse = sum(p.second["extended"] <= p.second["plain"] for p in both) / len(both)
        lines.append(f"extended no worse than plain on session 2: {no_worse:.1%} of {len(both)} pairs")
    chosen = [(p.same[p.use], p.other[p.use], p.second[p.use] / p.first[p.use]) for p in pairs]
    same_pass = sum(s == "pass" for s, _, _ in chosen) / len(chosen)
    other_fail = sum(o == "fail" for _, o, _ in chosen) / len(chosen)
    ratio = _rms([r for *_, r in chosen])
    ok = same_pass >= 0.95 and other_fail >= 0.95 and ratio <= 1.1
    lines.append(f"recommended model ({', '.join(sorted({p.use for p in pairs}))}): same arm passes "
                 f"{same_pass:.1%}, other arm fails {other_fail:.1%}, 2nd/1st RMS {ratio:.3f}")
    lines.append(f"targets: same arm passes >= 95 %, other arm fails >= 95 %, 2nd/1st <= 1.1: "
                 f"{'met' if ok else 'NOT met'}")
    return lines, ok


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.second_session", description=__doc__.split("\n")[0])
    parser.add_argument("--pairs", type=int, default=50, help="arm pairs per case (default 50)")
    parser.add_argument("--jobs", type=int, default=1, help="worker processes (default 1)")
    args = parser.parse_args(argv)
    start = time.perf_counter()
    jobs = [(case, k) for case in CASES for k in range(args.pairs)]
    if args.jobs > 1:
        with ProcessPoolExecutor(args.jobs) as pool:
            pairs = list(pool.map(one_pair, jobs))
    else:
        pairs = [one_pair(job) for job in jobs]
    print(f"python {sys.version.split()[0]}, numpy {np.__version__}, {time.strftime('%Y-%m-%d')}, "
          f"load average {os.getloadavg()[0]:.1f}")
    print(f"{args.pairs} pairs per case of {ROBOT}, {NOISE * 1e3:.2f} mm noise "
          f"({time.perf_counter() - start:.0f} s; {np.median([p.seconds for p in pairs]):.2f} s per pair)")
    ok = True
    for case in CASES:
        lines, met = report([p for p in pairs if p.case == case])
        print(f"case {case}:\n  " + "\n  ".join(lines))
        ok &= met
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
