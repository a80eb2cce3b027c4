"""Eye-to-hand with a real camera's errors: a camera in the cell, a board on the flange (docs/benchmarks.md, 24d).

    PYTHONPATH=. .venv/bin/python -m bench.eye_to_hand [--cases perfect,...,all] [--seeds 3] [--views 40] [--jobs 1]
    PYTHONPATH=. .venv/bin/python -m bench.eye_to_hand --quick      # one 'all' session of 24 views

Each case is one rendered session of a simulated UR5e (``mock:ur5e?seed=S``: its true DH table perturbed 0.5 mm and
1 mrad per value) carrying a ChArUco board on its flange (8x6 squares of 25 mm, 200 x 150 mm, markers 18 mm, 4X4_50;
its centre is the rig's true tracked point, ``aruco:sim`` with ``mount=cell``) seen by a 1280x720 camera fixed in
the cell (60° wide, noise 2 grey levels, blur 0.5 px; the rig places it 0.7 m from the board at home, facing it).
Real OpenCV detection (``refine=edges``, 3 frames a view); stop-and-go: the arm moves, is still for 0.2 s after its
ringing, and the camera measures the board's pose, position and orientation (a 6-DoF reading).

1. The plan: one reading at home places the camera in the base frame (nominal kinematics, the board's place on the
   flange from its drawing: the true one rounded to 5 mm); ``--views`` views of the board 0.45-0.95 m from the
   camera, its centre anywhere in the image's inner 70 %, its normal within 40° of the line of sight (any azimuth),
   turned ±90° about it, each solved for the joints with the nominal and kept when the whole board stays in the image
   (acquire/planning/flange_views.py ``board_seen``, the same rules as for a flange camera); a quarter held out.
2. identify (the fixed device's rows, with orientations), --robot ur5e: the DH table, the camera (the tracker frame)
   in the base frame, the board's centre and axes on the flange in one fit. The board is printed true (the camera's
   length scale is its board's: a misprint is not simulated for a camera in the cell).
3. The truth: the tracked point (the board's centre on the flange; a bowed print's mean plane, 2/3 of the bow out of
   its edges' plane) at 300 random poses over every joint's range, and at 300 random poses inside the result's
   domain (the joints' ranges the views covered), in the camera frame. Reported per case: the RMS error of the
   identified model there, what the result states there (the predicted point's covariance and the model error:
   ``Identification.prediction_rms``) and their ratio, the views' own readings against the truth (RMS 3D, and
   ``z``: the RMS over the views of the 3D error over ``√3 · sigma``, 1 when stated honestly), the result's
   held-out RMS and verdict, images, robot time.

Cases (``--cases``): ``perfect``; each error of a real camera alone (bench/flange_camera.py ``REAL_ERRORS``:
``distortion`` with ``lens_sigma``, ``shutter``, ``blur``, ``lighting``, ``bow`` with ``flatness``, ``latency``);
``undeclared`` (every error, neither ``flatness=`` nor ``lens_sigma=``); ``all`` (every error, both declared);
``perfect``, ``undeclared`` and ``all`` on seeds 1..``--seeds``, the others on seed 1. Exit status 1 when a case
other than ``undeclared`` is more than 0.3 mm off over the workspace, or the ``all`` sessions' pooled ratio (over the
workspace or inside the domain) leaves 0.7-1.3.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import math
import sys
import time
from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial.transform import Rotation

from acquire.planning.flange_views import FlangeCamera, board_seen, look_at, solve_joints
from bench.flange_camera import (
    ACCELERATION,
    FOV,
    FRAMES,
    HEIGHT,
    REAL_ERRORS,
    SPEED,
    TARGET_RATIO,
    TARGET_RMS,
    WIDTH,
    camera_rows,
    opened,
    ran,
    reading_pose,
    visited,
)
from config.robots import load_robot
from drivers.camera.tracker import parse_settings
from drivers.spec import TrackerSpec
from identify.io.result_io import result_to_dict
from identify.results.pipeline import identify
from identify.simulators.simulate import random_poses
from kinematics.dh import frames_from_joints, points_from_joints

COLS, ROWS, SQUARE, MARKER = 8, 6, 0.025, 0.018  # the board on the flange (m)
DISTANCE, NEAR, FAR, MAX_ANGLE = 0.7, 0.45, 0.95, math.radians(40.0)  # m at home, the views' depth range, rad
CHECK_POSES = 300  # random poses for the truth (a quarter of the views held out: flange_camera.CHECK_SHARE)
CASES = ("perfect", "distortion", "shutter", "blur", "lighting", "bow", "latency", "undeclared", "all")
SEEDED = ("perfect", "undeclared", "all")  # the cases run on every seed; the others on seed 1


@dataclass(frozen=True)
class Case:
    errors: str  # a key of REAL_ERRORS, or "perfect"
    seed: int
    views: int

    @property
    def label(self) -> str:
        return f"seed {self.seed}, {self.errors}"


@dataclass(frozen=True)
class Outcome:
    label: str
    views: int  # seen (fitted and held out)
    missing: int  # planned but not seen
    images: int
    robot_seconds: float
    rms: float  # m, TP at random poses over every joint's range
    stated: float  # m, what the result states there
    rms_domain: float  # m, TP at random poses inside the result's domain
    stated_domain: float  # m
    view_error: float  # m, the views' readings against the truth (RMS 3D)
    view_z: float  # RMS over the views of the 3D error over sqrt(3) sigma (1: stated honestly)
    holdout: float  # m, the result's held-out RMS
    model_error: float  # m per axis, the fit's model error (the rows' scatter beyond their sigmas)
    status: str
    checks: str  # the verdict's checks that did not pass
    seconds: float


def spec(case: Case) -> str:
    """The camera's ``aruco:sim`` spec of ``case``."""
    errors = "" if case.errors == "perfect" else "&" + REAL_ERRORS[case.errors]
    return (f"aruco:sim?board=charuco&dict=4X4_50&cols={COLS}&rows={ROWS}&square={SQUARE}&size={MARKER}"
            f"&width={WIDTH}&height={HEIGHT}&fov={FOV}&distance={DISTANCE}&tilt=10&roll=5&frames={FRAMES}"
            f"&seed={case.seed}{errors}")


def board_views(nominal, home: np.ndarray, limits: np.ndarray, camera_in_base: np.ndarray, board_on_flange: np.ndarray,
                view: FlangeCamera, count: int, rng: np.random.Generator) -> np.ndarray:
    """``count`` joint configurations (count, n) that show the board on the flange (``board_on_flange``: flange <-
    board) whole to the camera at ``camera_in_base`` (base <- camera) by the nominal kinematics: a view drawn as
    :func:`acquire.planning.flange_views.look_at` draws a flange camera's (depth, tilt from the board's normal,
    azimuth, roll), then turned about the camera's centre to put the board's centre at a random point of the image's
    inner 70 %; solved from ``home``, kept when exact, within π of home in every joint, and seen."""
    out: list[np.ndarray] = []
    inverse = np.linalg.inv(board_on_flange)
    cap = 1.0 - math.cos(0.9 * view.max_angle)
    pixel_to_ray = np.linalg.inv(view.matrix)
    for _ in range(50 * count):
        depth = view.near + (view.far - view.near) * rng.uniform(0.1, 0.9)
        tilt = math.acos(1.0 - rng.uniform(0.0, cap))
        on_axis = np.linalg.inv(look_at(np.eye(4), depth, tilt, rng.uniform(0, 2 * math.pi),
                                        rng.uniform(-math.pi / 2, math.pi / 2)))  # camera <- board
        ray = pixel_to_ray @ [rng.uniform(0.15, 0.85) * view.size[0], rng.uniform(0.15, 0.85) * view.size[1], 1.0]
        turn = np.eye(4)
        turn[:3, :3] = Rotation.align_vectors([ray / np.linalg.norm(ray)], [[0.0, 0.0, 1.0]])[0].as_matrix()
        q, miss = solve_joints(nominal, camera_in_base @ turn @ on_axis @ inverse, home, limits)
        if miss > 1e-6 or np.any(np.abs(q - home) > math.pi):
            continue
        seen = np.linalg.inv(camera_in_base) @ frames_from_joints(nominal, q[None])[0, -1] @ board_on_flange
        if board_seen(seen, view)[0][0]:
            out.append(q)
            if len(out) == count:
                return np.array(out)
    raise ValueError(f"found only {len(out)} of {count} poses in which the camera sees the board")


def run_case(case: Case) -> Outcome:
    start = time.perf_counter()
    robot = load_robot("ur5e")
    nominal, home, limits = robot.nominal, np.array(robot.home), robot.limits
    camera_spec = spec(case)
    rig, arm, camera = opened(case.seed, camera_spec)
    t0 = rig.clock.now()

    def visit(q: np.ndarray):
        arm.move_joints(q, [SPEED] * 6, [ACCELERATION] * 6, 60.0)
        arm.wait_until_still(0.2, 10.0)
        return arm.read_joints(), camera.measure(1, 10.0)[0]

    _, at_home = visit(home)
    board_on_flange = np.eye(4)
    board_on_flange[:3, 3] = np.round(rig.truth.tool / 0.005) * 0.005  # the board's place from its drawing
    at_home_flange = frames_from_joints(nominal, home[None])[0, -1]
    camera_in_base = at_home_flange @ board_on_flange @ np.linalg.inv(reading_pose(at_home))  # base <- camera
    view = FlangeCamera(camera.camera.matrix, (WIDTH, HEIGHT), (COLS * SQUARE, ROWS * SQUARE), near=NEAR, far=FAR,
                        max_angle=MAX_ANGLE, margin=0.04)
    plan = board_views(nominal, home, limits, camera_in_base, board_on_flange, view, case.views,
                       np.random.default_rng([case.seed, 40]))
    q_read, readings = (list(column) for column in zip(*visited(plan, visit, case.label), strict=True))
    robot_seconds = rig.clock.now() - t0
    m, q_read = len(readings), np.array(q_read)
    meas = camera_rows(q_read, readings, np.random.default_rng([case.seed, 41]))
    ident = identify(meas, nominal)
    doc = result_to_dict(ident, nominal, "ur5e")
    # the truth: the board's centre; a bowed print's frame is its mean plane, 2/3 of the bow towards the camera
    bow = parse_settings(TrackerSpec.parse(camera_spec)).sim["imperfections"].bow
    truth = replace(rig.truth, tool=rig.truth.tool + np.array([0.0, 0.0, 2.0 / 3.0 * bow]))
    view_errors = np.linalg.norm(meas.points - points_from_joints(truth, q_read), axis=1)
    view_z = float(np.sqrt(np.mean((view_errors / (math.sqrt(3) * meas.sigma)) ** 2)))
    rng = np.random.default_rng([case.seed, 42])
    domain = np.array(doc["domain"]["joints"])
    figures = []
    for q_check in (random_poses(limits, CHECK_POSES, rng), rng.uniform(domain[:, 0], domain[:, 1], (CHECK_POSES, 6))):
        error = ident.predict(q_check) - points_from_joints(truth, q_check)
        figures += [float(np.sqrt(np.mean(np.sum(error**2, axis=1)))), ident.prediction_rms(q_check)]
    validation = ((doc.get("validation") or {}).get("plain") or {}).get("rms", math.nan)
    failed = ",".join(c["name"] for c in doc["verdict"]["checks"] if c["status"] != "pass")
    return Outcome(case.label, m, len(plan) - m, (m + 1) * FRAMES, robot_seconds, *figures,
                   float(np.sqrt(np.mean(view_errors**2))), view_z, validation,
                   ident.adequacy.model_error, doc["verdict"]["status"], failed or "-", time.perf_counter() - start)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.eye_to_hand", description=__doc__.split("\n")[0])
    parser.add_argument("--cases", default=",".join(CASES), help=f"of {', '.join(CASES)} (default: all of them)")
    parser.add_argument("--seeds", type=int, default=3, help=f"simulated arms for {', '.join(SEEDED)} (default 3)")
    parser.add_argument("--views", type=int, default=40, help="views planned per session (default 40)")
    parser.add_argument("--jobs", type=int, default=1, help="worker processes (default 1)")
    parser.add_argument("--every-seed", action="store_true", help="every case on every seed")
    parser.add_argument("--quick", action="store_true", help="one 'all' session of 24 views")
    args = parser.parse_args(argv)
    start = time.perf_counter()
    names = ["all"] if args.quick else [c for c in args.cases.split(",") if c]
    if not set(names) <= set(CASES):
        parser.error(f"--cases: of {', '.join(CASES)}")
    views = 24 if args.quick else args.views
    seeds = range(1, (1 if args.quick else args.seeds) + 1)
    every = set(names) if args.every_seed else set(SEEDED)
    cases = [Case(name, seed, views) for name in names for seed in (seeds if name in every else [1])]
    results = ran(cases, spec, run_case, args.jobs)
    print(f"UR5e with a ChArUco board on the flange ({COLS}x{ROWS} squares of {SQUARE * 1e3:g} mm), camera "
          f"{WIDTH}x{HEIGHT} in the cell ({FOV:g}° wide), {FRAMES} frames a view, {views} views planned; the TP "
          f"against the truth at {CHECK_POSES} random poses over the joints' ranges and inside the result's domain")
    header = (f"{'case':<22} {'views':>5} {'lost':>4} {'images':>6} {'robot s':>7} {'TP RMS mm':>9} {'stated':>7} "
              f"{'ratio':>5} {'domain mm':>9} {'stated':>7} {'ratio':>5} {'views mm':>8} {'z':>4} {'held-out':>8} "
              f"{'model err':>9} {'verdict':>7} {'s':>4}  checks not passed")
    print(header)
    print("-" * len(header))
    missed = []
    for case, r in zip(cases, results, strict=True):
        print(f"{r.label:<22} {r.views:>5} {r.missing:>4} {r.images:>6} {r.robot_seconds:>7.0f} {r.rms * 1e3:>9.4f} "
              f"{r.stated * 1e3:>7.4f} {r.rms / r.stated:>5.2f} {r.rms_domain * 1e3:>9.4f} "
              f"{r.stated_domain * 1e3:>7.4f} {r.rms_domain / r.stated_domain:>5.2f} {r.view_error * 1e3:>8.4f} "
              f"{r.view_z:>4.2f} {r.holdout * 1e3:>8.4f} {r.model_error * 1e3:>9.4f} {r.status:>7} {r.seconds:>4.0f}  "
              f"{r.checks}")
        if case.errors != "undeclared" and r.rms > TARGET_RMS:
            missed.append(r.label)
    declared = [r for c, r in zip(cases, results, strict=True) if c.errors == "all"]
    for name, rms, stated in (("workspace", "rms", "stated"), ("domain", "rms_domain", "stated_domain")):
        if declared:
            pooled = math.sqrt(np.mean([getattr(r, rms) ** 2 for r in declared]) /
                               np.mean([getattr(r, stated) ** 2 for r in declared]))
            print(f"pooled ratio over the 'all' sessions, {name}: {pooled:.2f} "
                  f"(target {TARGET_RATIO[0]:g}-{TARGET_RATIO[1]:g})")
            if not TARGET_RATIO[0] <= pooled <= TARGET_RATIO[1]:
                missed.append(f"pooled ratio ({name})")
    print(f"total {time.perf_counter() - start:.0f} s")
    if missed:
        print("TARGET MISSED in: " + "; ".join(missed))
        return 1
    print("all targets met")
    return 0


if __name__ == "__main__":
    sys.exit(main())
