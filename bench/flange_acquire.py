"""``acquire`` with a simulated camera on the flange, end to end through the locate phase (docs/benchmarks.md, 24c).

    PYTHONPATH=. .venv/bin/python -m bench.flange_acquire [--seeds 1 2] [--views 40] [--check 10] [--mount ...]
        [--options ...] [--keep FOLDER]

Per seed: ``acquire --robot mock:ur5e?seed=S --tracker aruco:sim?mount=flange&... --camera-mount M`` (the README's
A4 ChArUco board measured with a caliper, 1280x720, 3 frames a view; ``M`` a bracket drawing 12 mm and 5° off the
simulation's true mount, which the planner never reads) locates the mount and the board from wrist turns about
the start pose (acquire/planning/flange_locate.py), plans its views from them (acquire/planning/plan_flange.py),
runs them on the mock rig (rendered images, real OpenCV detection), records the session and identifies it.
Reported: the locate's error of the mount and the board against the truth (mm, mrad; the board in the true arm's
base frame) and its stated 1 sigma, the views seen, the run's estimate and the rig's robot time (the locate's and
the views'), the images, the accuracy the run predicted before the views (the bound, camera noise only), the
result's stated flange accuracy (``flange_accuracy_rms``, over the fit poses) and the true flange error (the
physical flange origin, through the identified arm and camera mount, against the rig's truth, board frame) at the
fit poses and at 300 random poses over every joint's range, beside what the result states there (``flange.workspace``,
its own 300 random poses within the joint limits, and the 90 % range of one calibration's RMS).
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
from scipy.spatial.transform import Rotation

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


def located_error(doc_locate: dict, rig: SimulatedRig) -> tuple[float, float, float, float]:
    """The located mount's and board's position (m) and orientation (rad) errors against the rig's truth."""
    mount, board = np.array(doc_locate["mount"]), np.array(doc_locate["board"])
    true_board = np.linalg.inv(rig.truth.base)  # DH frame 0 <- board

    def turn(a: np.ndarray, b: np.ndarray) -> float:
        return float(np.linalg.norm(Rotation.from_matrix(a[:3, :3] @ b[:3, :3].T).as_rotvec()))

    return (float(np.linalg.norm(mount[:3, 3] - CAMERA_MOUNT[:3, 3])), turn(mount, CAMERA_MOUNT),
            float(np.linalg.norm(board[:3, 3] - true_board[:3, 3])), turn(board, true_board))


def run(seed: int, views: int, check: int, mount: str, folder: Path, options: str = "") -> tuple[str, str]:
    spec = SPEC + options
    site = folder / "site.yaml"
    site.write_text(f"schema: 1\nplan:\n  check_poses: {check}\n", encoding="utf-8")
    robot = f"mock:ur5e?seed={seed}"
    args = ["--robot", robot, "--tracker", spec, "--config", str(site), "--free-poses", str(views - check),
            "--camera-mount", mount]
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert acquire_main([*args, "--dry-run"]) == 0
    dry = re.search(r"the flange to ([\d.]+) mm RMS at the fitted views, ([\d.]+) mm", out.getvalue()).groups()
    session = folder / f"seed{seed}.session"
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = acquire_main([*args, "--session", str(session), "--yes", "--quiet"])
    text = out.getvalue()
    seen = re.search(r"the board seen in (\d+) of (\d+) views", text).groups()
    locate_held = float(re.search(r"locate: robot held ([\d.]+) s", text).group(1))
    estimate = re.search(r"estimated duration: (\d+):(\d\d):(\d\d)", text).groups()
    images = re.search(r"images: (\d+)", text).group(1)
    predicted = re.search(r"the flange to ([\d.]+) mm RMS at the fitted views, ([\d.]+) mm", text).groups()
    held = re.search(r"held ([\d.]+) s simulated", text).group(1)
    doc = yaml.safe_load(session.with_suffix(".result.yaml").read_text(encoding="utf-8"))
    with Session.open(session) as s:
        q_fit = np.array([step.q for step in s.plan.steps if step.role == "fit"])
        missing = len(s.missing_indices())
        located = s.header["config"]["flange_locate"]
    rig = SimulatedRig.from_spec(robot, spec)
    q_random = random_poses(load_robot("ur5e").limits, 300, np.random.default_rng([seed, 38]))
    stated = doc["flange_accuracy_rms"]
    workspace = doc["flange"]["workspace"]  # the result's statement at random poses within the joint limits
    fit, anywhere = flange_error(doc, rig, q_fit), flange_error(doc, rig, q_random)
    scale = next(c["status"] for c in doc["verdict"]["checks"] if c["name"] == "scale")
    est = int(estimate[0]) * 3600 + int(estimate[1]) * 60 + int(estimate[2])
    m_pos, m_rot, b_pos, b_rot = located_error(located, rig)
    locate_row = (f"{seed:>4} {seen[0]:>2}/{seen[1]:<2} {m_pos * 1e3:>9.3f} {located['mount_sigma_m'] * 1e3:>9.3f} "
                  f"{m_rot * 1e3:>10.3f} {located['mount_sigma_rad'] * 1e3:>10.3f} {b_pos * 1e3:>9.3f} "
                  f"{located['board_sigma_m'] * 1e3:>9.3f} {b_rot * 1e3:>10.3f} "
                  f"{located['board_sigma_rad'] * 1e3:>10.3f} {located['sigma_px']:>8.4f} {locate_held:>8.1f}")
    run_row = (f"{seed:>4} {views:>5} {images:>6} {missing:>7} {est:>10} {float(held):>9.1f} {float(dry[0]):>7.4f} "
               f"{float(predicted[0]):>9.4f} {float(predicted[1]):>9.4f} {stated * 1e3:>9.4f} {fit * 1e3:>10.4f} "
               f"{anywhere * 1e3:>12.4f} {workspace['accuracy_rms'] * 1e3:>9.4f} "
               f"{workspace['likely_rms'][0] * 1e3:>6.4f}-{workspace['likely_rms'][1] * 1e3:<6.4f} "
               f"{doc['verdict']['status']:>7} {scale:>5} {code:>4}"
               + "".join(f"  {c['name']}: {c['status']}" for c in doc["verdict"]["checks"] if c["status"] != "pass"))
    return locate_row, run_row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[1])
    parser.add_argument("--views", type=int, default=40)
    parser.add_argument("--check", type=int, default=10)
    parser.add_argument("--mount", default="0.005,-0.05,0.045,0,0,85", help="--camera-mount given to acquire")
    parser.add_argument("--options", default="", help="appended to the camera's spec, e.g. "
                        "'&dfocal=0.002&dcx=3&dcy=-2&focal_sigma=0.005&centre_sigma=5' (errors that leave the board's "
                        "frame where it is: not bow=)")
    parser.add_argument("--keep", type=Path, help="a new folder to keep the sessions and results in (default: none)")
    args = parser.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) if args.keep is None else args.keep
        folder.mkdir(parents=True, exist_ok=args.keep is None)
        for seed in args.seeds:
            rows.append(run(seed, args.views, args.check, args.mount, folder, args.options))
            print(*rows[-1], sep="\n", flush=True)
    print("\nlocate: errors against the truth and the stated 1 sigma (mm, mrad), corner noise (px), robot time (s)")
    print("seed seen mount_mm  sigma_mm mount_mrad sigma_mrad board_mm  sigma_mm board_mrad sigma_mrad sigma_px "
          "locate_s")
    print(*(r[0] for r in rows), sep="\n")
    print("\nrun: robot time (s) of the views, predicted (dry run; after the locate: fit, random) and achieved (mm)")
    print("seed views images missing estimate_s  robot_s dry_fit pred_fit pred_rand stated_mm fit_rms_mm random_rms_mm "
          "ws_stated ws_90%_range  verdict scale exit  (checks not passed)")
    print(*(r[1] for r in rows), sep="\n")


if __name__ == "__main__":
    main()
