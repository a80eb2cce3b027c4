"""``acquire`` with a simulated camera on the flange, end to end (docs/benchmarks.md, section 24).

    PYTHONPATH=. .venv/bin/python -m bench.flange_acquire [--seeds 1 2] [--views 30] [--check 10]

Per seed: ``acquire --robot mock:ur5e?seed=S --tracker aruco:sim?mount=flange&...`` (the README's A4 ChArUco board
measured with a caliper, 1280x720, 3 frames a view) plans its views (acquire/planning/plan_flange.py), runs them on
the mock rig (rendered images, real OpenCV detection), records the session and identifies it. Reported: the dry
run's estimate and the rig's robot time, the images, the result's stated flange accuracy (``flange_accuracy_rms``,
over the fit poses) and the true flange error (the physical flange origin, through the identified arm and camera
mount, against the rig's truth, board frame) at the fit poses and at 300 random poses over every joint's range.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import math
import re
import tempfile
from pathlib import Path

import numpy as np
import yaml

from acquire.commands.cli import main as acquire_main
from acquire.running.session import Session
from config.robots import load_robot
from drivers.camera.flange_camera import CAMERA_MOUNT
from drivers.sim.rig import SimulatedRig
from identify.applications.calibrated import CalibratedModel
from identify.simulators.simulate import random_poses
from kinematics.dh import frames_from_joints

SPEC = ("aruco:sim?mount=flange&board=charuco&cols=11&rows=8&square=0.025&size=0.018&square_sigma=0.000002"
        "&width=1280&height=720&distance=0.45&tilt=8&roll=5&frames=3")


def flange_error(doc: dict, rig: SimulatedRig, q: np.ndarray) -> float:
    """RMS (m) of the identified flange origin (through the fitted camera frame) against the truth at ``q``."""
    truth = frames_from_joints(rig.truth, q)[:, -1, :3, 3]
    camera = frames_from_joints(CalibratedModel.from_document(doc).model, q)[:, -1] @ np.array(doc["sensor_frame"])
    ours = np.einsum("mij,j->mi", camera, np.linalg.inv(CAMERA_MOUNT)[:, 3])[:, :3]
    return math.sqrt(float(np.mean(np.sum((ours - truth) ** 2, axis=1))))


def run(seed: int, views: int, check: int, folder: Path) -> str:
    site = folder / "site.yaml"
    site.write_text(f"schema: 1\nplan:\n  check_poses: {check}\n", encoding="utf-8")
    robot = f"mock:ur5e?seed={seed}"
    args = ["--robot", robot, "--tracker", SPEC, "--config", str(site), "--free-poses", str(views - check)]
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert acquire_main([*args, "--dry-run"]) == 0
    dry = out.getvalue()
    estimate = re.search(r"estimated duration: (\d+):(\d\d):(\d\d)", dry).groups()
    images = re.search(r"images: (\d+)", dry).group(1)
    session = folder / f"seed{seed}.session"
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = acquire_main([*args, "--session", str(session), "--yes", "--quiet"])
    held = re.search(r"held ([\d.]+) s simulated", out.getvalue()).group(1)
    doc = yaml.safe_load(session.with_suffix(".result.yaml").read_text(encoding="utf-8"))
    with Session.open(session) as s:
        q_fit = np.array([step.q for step in s.plan.steps if step.role == "fit"])
        missing = len(s.missing_indices())
    rig = SimulatedRig.from_spec(robot, SPEC)
    q_random = random_poses(load_robot("ur5e").limits, 300, np.random.default_rng([seed, 38]))
    stated = doc["flange_accuracy_rms"]
    fit, anywhere = flange_error(doc, rig, q_fit), flange_error(doc, rig, q_random)
    scale = next(c["status"] for c in doc["verdict"]["checks"] if c["name"] == "scale")
    est = int(estimate[0]) * 3600 + int(estimate[1]) * 60 + int(estimate[2])
    return (f"{seed:>4} {views:>5} {images:>6} {missing:>7} {est:>10} {float(held):>9.1f} {stated * 1e3:>9.4f} "
            f"{fit * 1e3:>10.4f} {fit / stated:>6.2f} {anywhere * 1e3:>12.4f} {doc['verdict']['status']:>7} "
            f"{scale:>5} {code:>4}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[1])
    parser.add_argument("--views", type=int, default=40)
    parser.add_argument("--check", type=int, default=10)
    args = parser.parse_args()
    print("seed views images missing estimate_s  robot_s stated_mm fit_rms_mm  ratio random_rms_mm verdict scale exit")
    with tempfile.TemporaryDirectory() as tmp:
        for seed in args.seeds:
            print(run(seed, args.views, args.check, Path(tmp)), flush=True)


if __name__ == "__main__":
    main()
