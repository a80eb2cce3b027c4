"""Issue 23's targets: what is written is what was validated, and it holds on another day.

For simulated arms with joint errors a DH table cannot hold (eccentricity, gear ratio, compliance; sizes drawn per
arm, on random joints) and with several reflectors, it identifies session 1 and reads the written result back from
YAML. Every figure below is computed here, with the shared forward model, from the written numbers:
- stated vs scored: each written model's held-out RMS on the check rows against the figure the result states;
- plain vs DH-only: the plain model against a DH-only maximum-likelihood fit of the same rows
(identify.estimator.refine's
  DH parameterisation from the nominal placed on the data: another estimator; no outlier rejection, as the data
  hold no gross outliers and a rejection that differs would compare other rows);
- second session: the same arm, the tracker moved (random rotation, up to 2 m), new free poses; each model is
  registered to it by a rigid fit (Kabsch) on half of the poses and scored on the other half;
- caps: the largest |a| or |d| of every default table against the robot's size.

- false rejection (``--false-rejection``): data sets without a gross outlier that still lose a row to the outlier
  test, at 4, 6, 8, 12 and 36 samples per sweep, 1 or 3 reflectors, with and without joint errors.

Run: ``python -m bench.one_model [--arms 50] [--seed 0] [--false-rejection [--draws 20]]``. Exit status 1 when a
target is missed.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace

import numpy as np
import yaml

from config.robots import load_robot
from identify.estimator.estimate import place_nominal
from identify.estimator.refine import refine
from identify.io.result_io import result_to_dict
from identify.results.pipeline import identify
from identify.simulators.simulate import random_poses
from identify.simulators.simulate_joints import RealArm, measure, reflector_plate, sweeps_and_poses
from kinematics.dh import model_from_dict, points_from_joints
from kinematics.joint_errors import JointErrors, gravity_torques
from kinematics.truth import random_base, random_truth

NOISE = 2e-5  # m per axis


def written_points(section: dict, q: np.ndarray, tp: np.ndarray, terms: dict | None, robot) -> np.ndarray:
    """What a written model section predicts (tracker frame, m) at DH joint values ``q`` for tracked point ids."""
    model = model_from_dict(section)
    if terms is not None:
        home = np.array(terms["home"])
        dq = np.zeros_like(q)
        for t in terms["terms"]:
            name, joint = t["name"].rsplit("_", 1)
            j = int(joint) - 1
            if name == "compliance":
                tau = gravity_torques(robot.nominal, robot.links, q)[:, j]
                tau0 = gravity_torques(robot.nominal, robot.links, home[None])[0, j]
                dq[:, j] += t["value"] * (tau - tau0)
                continue
            f = {"scale": lambda x: x, "ecc_sin": np.sin, "ecc_cos": np.cos}[name]
            dq[:, j] += t["value"] * (f(q[:, j]) - f(home[j]))
        q = q + dq
    tools = {int(k): np.array(v) for k, v in (section.get("tools") or {1: section["tool"]}).items()}
    out = np.empty((len(q), 3))
    for k, tool in tools.items():
        rows = tp == k
        out[rows] = points_from_joints(replace(model, tool=tool), q[rows])
    return out


def rms(err: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum(err**2, axis=1))))


def registered_rms(pred: np.ndarray, meas: np.ndarray, pose: np.ndarray) -> float:
    """Rigid registration (Kabsch) of predictions onto measurements on the even poses, RMS on the odd ones."""
    fit = pose % 2 == 0
    a, b = pred[fit], meas[fit]
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    u, _, vt = np.linalg.svd((a - ca).T @ (b - cb))
    d = np.sign(np.linalg.det(vt.T @ u.T))
    rot = vt.T @ np.diag([1, 1, d]) @ u.T
    moved = (pred[~fit] - ca) @ rot.T + cb
    return rms(moved - meas[~fit])


def arm_errors(robot, rng: np.random.Generator) -> JointErrors:
    """Joint errors of one simulated arm: on two random joints each of eccentricity (0.05-0.3 mrad), gear ratio
    (50-300 ppm), and compliance on joints 2 and 3 (0-1e-5 rad/(N m))."""
    n = robot.n_joints
    e = JointErrors.none(n)
    pick = rng.choice(n, 2, replace=False)
    ecc = np.zeros(n)
    ecc[pick] = rng.uniform(5e-5, 3e-4, 2) * rng.choice([-1, 1], 2)
    pick = rng.choice(n, 2, replace=False)
    scale = np.zeros(n)
    scale[pick] = rng.uniform(5e-5, 3e-4, 2) * rng.choice([-1, 1], 2)
    comp = np.zeros(n)
    comp[1:3] = rng.uniform(0.0, 1e-5, 2)
    return replace(e, ecc_sin=ecc, scale=scale, compliance=comp)


def one_arm(robot, seed: int, reflectors: int) -> dict[str, float]:
    rng = np.random.default_rng(seed)
    truth = random_truth(robot.nominal, robot.home, rng)
    tools = reflector_plate(rng, reflectors) if reflectors > 1 else None
    arm = RealArm(truth, errors=arm_errors(robot, rng), links=robot.links, tools=tools)
    q, sweep, joint, held = sweeps_and_poses(robot.joint_types, robot.home, robot.limits, rng, 8, 30, 20)
    meas = measure(arm, q, sweep, joint, NOISE, rng, held)
    t0 = time.perf_counter()
    ident = identify(meas, robot.nominal, links=robot.links)
    seconds = time.perf_counter() - t0
    doc = yaml.safe_load(yaml.safe_dump(result_to_dict(ident, robot.nominal, robot.name)))
    c = meas.check
    out: dict[str, float] = {"seconds": seconds, "extended": float(doc["use"] == "extended")}
    sections = {"plain": (doc, None)}
    if doc["use"] == "extended":
        sections["extended"] = (doc["extensions"]["model"], doc["extensions"])
    for name, (section, terms) in sections.items():
        scored = rms(meas.points[c] - written_points(section, meas.q[c], meas.tp[c], terms, robot))
        out[f"stated_{name}"] = scored / doc["validation"][name]["rms"]
    # a DH-only maximum-likelihood fit of the same rows, from the nominal placed on them
    f = ~c
    placed, tools0 = place_nominal(robot.nominal, meas.q[f], meas.points[f], meas.tp[f] - meas.tp.min())
    dh = refine(placed, meas.q[f], meas.points[f], None, robot.nominal.dh_table(), (), NOISE, False, 0.0,
                meas.tp[f] - meas.tp.min(), tools0)
    dh_pred = np.empty((int(c.sum()), 3))
    for k, tool in enumerate(dh.tools):
        rows = meas.tp[c] == meas.tp.min() + k
        dh_pred[rows] = points_from_joints(replace(dh.model, tool=tool), meas.q[c][rows])
    out["plain_vs_dh_mle"] = doc["validation"]["plain"]["rms"] / rms(meas.points[c] - dh_pred)
    # the second session: tracker moved, new free poses
    moved = RealArm(replace(truth, base=random_base(rng)), errors=arm.errors, links=arm.links, tools=tools)
    q2 = random_poses(robot.limits, 40, rng)
    second = measure(moved, q2, np.arange(40), np.zeros(40, dtype=np.int64), NOISE, rng)
    pose = second.sweep
    for name, (section, terms) in sections.items():
        out[f"day2_{name}"] = registered_rms(written_points(section, second.q, second.tp, terms, robot),
                                             second.points, pose)
    size = float(np.max(np.linalg.norm(meas.points - ident.lines.points[0], axis=1)))
    model = model_from_dict(doc)
    out["cap"] = float(max(np.max(np.abs(model.d)), np.max(np.abs(model.a)))) / size
    return out


def false_rejections(robot, steps: int, reflectors: int, with_errors: bool, draws: int) -> int:
    """Data sets of ``draws`` with no gross outlier in which a row is rejected as one anyway."""
    count = 0
    for seed in range(draws):
        rng = np.random.default_rng(seed + 100 * steps)
        truth = random_truth(robot.nominal, robot.home, rng)
        errors = JointErrors.none(robot.n_joints)
        if with_errors:
            n = robot.n_joints
            errors = replace(errors, ecc_sin=rng.uniform(-3e-4, 3e-4, n), scale=rng.uniform(-3e-4, 3e-4, n))
        arm = RealArm(truth, errors=errors, tools=reflector_plate(rng, reflectors) if reflectors > 1 else None)
        q, sweep, joint, held = sweeps_and_poses(robot.joint_types, robot.home, robot.limits, rng, steps, 10, 5)
        ident = identify(measure(arm, q, sweep, joint, NOISE, rng, held), robot.nominal)
        count += bool(ident.rejected_rows)
    return count


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--arms", type=int, default=50)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--robot", default="ur5e")
    parser.add_argument("--false-rejection", action="store_true", help="the false-rejection table instead")
    parser.add_argument("--draws", type=int, default=20, help="data sets per row of the false-rejection table")
    args = parser.parse_args(argv)
    robot = load_robot(args.robot)
    if args.false_rejection:
        worst = 0.0
        print("samples/sweep  reflectors  joint errors  data sets with a rejected row")
        for steps in (4, 6, 8, 12, 36):
            for reflectors in (1, 3):
                for with_errors in (False, True):
                    k = false_rejections(robot, steps, reflectors, with_errors, args.draws)
                    worst = max(worst, k / args.draws)
                    print(f"{steps:>13}  {reflectors:>10}  {'yes' if with_errors else 'no':>12}  {k} / {args.draws}")
        print("targets met" if worst <= 0.01 else "TARGET MISSED (<= 1 % of clean data sets)")
        return 0 if worst <= 0.01 else 1
    rows = [one_arm(robot, args.seed * 10_000 + k, 3 if k % 2 else 1) for k in range(args.arms)]
    col = {key: np.array([r.get(key, np.nan) for r in rows]) for key in rows[0] | rows[-1]}
    ext = col["extended"] > 0
    stated = np.concatenate([np.abs(col["stated_plain"] - 1), np.abs(col["stated_extended"][ext] - 1)])
    day2 = col["day2_extended"][ext] / col["day2_plain"][ext]
    print(f"{args.arms} simulated {robot.name} arms (joint errors on random joints, 1 or 3 reflectors, "
          f"noise {NOISE * 1e3:.3f} mm); extended model used on {ext.sum()}")
    print(f"stated vs scored held-out RMS: worst |ratio - 1| {stated.max():.2e} (target <= 0.02)")
    print(f"plain model / DH-only MLE held-out RMS: median {np.median(col['plain_vs_dh_mle']):.3f}, "
          f"worst {col['plain_vs_dh_mle'].max():.3f} (target <= 1.02)")
    if ext.any():
        pooled = np.mean(col["day2_extended"][ext] ** 2) / np.mean(col["day2_plain"][ext] ** 2)
        print(f"second session (tracker moved, registered), extended / plain RMS: median {np.median(day2):.3f}, "
              f"worst {day2.max():.3f}; pooled mean-square ratio {pooled:.3f} (target: extended no worse, <= 1)")
    print(f"largest |a| or |d| of the default tables / robot size: {col['cap'].max():.3f} (target <= 1)")
    print(f"time per identification: median {np.median(col['seconds']):.2f} s")
    ok = (stated.max() <= 0.02 and col["plain_vs_dh_mle"].max() <= 1.02 and col["cap"].max() <= 1
          and (not ext.any() or np.mean(col["day2_extended"][ext] ** 2) <= np.mean(col["day2_plain"][ext] ** 2)))
    print("targets met" if ok else "TARGET MISSED")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
