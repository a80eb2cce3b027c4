"""Is the ArUco camera's stated uncertainty honest? Real OpenCV detection on rendered images of a board on the
simulated arm, readings at many poses against the rendered truth (issue 35).

    PYTHONPATH=. .venv/bin/python -m bench.camera_honesty [--draws 4] [--poses 12]

For each draw (a robot seed: another arm, another board mounting) the arm visits ``--poses`` random poses about
home (joints 1-3 within ±15°, 4-5 within ±40°, 6 within ±60°: the oblique views a calibration's sweeps give; a
pose where the board is not seen is skipped, as a session records it missing) and takes ``--readings`` readings at
each, averaged as a session step is (acquire.running.orchestrator: average_readings, average_frames). Per step:
the position error against the true TP over its ``sigma`` and the orientation error (rotation vector of
R_measured R_trueᵀ) over its ``sigma_r``, per axis. ``z`` = RMS of those ratios (1 when the stated uncertainty is
honest); ``z 1`` the same for single readings; ``spread``: the readings' RMS per-axis scatter about their step's
mean over their stated sigma (what frame-to-frame noise alone gives). Where ``z`` exceeds what ``z 1`` and
``spread`` imply, the excess is an error that stays with the view (the detection's bias for it): averaging frames
and readings does not shrink it, and the driver states it (drivers.camera.pose.Pose.view_bias): ``--bias PX``
(VIEW_BIAS_PX: the corners' image scaled by PX at its RMS radius, over cos² of the obliquity, for the TP) and
``--turn-bias PX`` (VIEW_TURN_BIAS_PX: independent corner errors, for the orientation). Last, ``z pos`` of all the
steps by the view's obliquity (the angle between the board's normal and the line of sight to it).
"""

from __future__ import annotations

import argparse
import itertools
import time

import numpy as np
from scipy.spatial.transform import Rotation

from acquire.running.orchestrator import average_frames, average_readings
from drivers.camera import pose as camera_pose
from drivers.camera.tracker import open_tracker
from drivers.clock import VirtualClock
from drivers.errors import MeasurementError
from drivers.sim.rig import SimulatedRig
from drivers.sim.robot import open_robot
from drivers.spec import RobotSpec, TrackerSpec

SPEC = "aruco:sim?board=grid&cols=2&rows=2&size=0.05&tilt=0&distance=0.8"  # docs/benchmarks.md section 23's camera
SPREAD = np.radians([15.0, 15.0, 15.0, 40.0, 40.0, 60.0])
KINDS = ("pos", "rot", "pos1", "rot1", "pos_spread", "rot_spread", "sigma", "sigma_r", "q", "obliquity")
OBLIQUITY_BINS = (0.0, 20.0, 40.0, 55.0, 90.0)  # deg


def draw(seed: int, poses: int, readings: int, spec: str, plan: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Per-axis error ratios of one arm (``seed``; module docstring) and the stated sigmas of its steps; ``plan``
    (k, 6): the joint values to visit in turn (a session plan's) instead of random poses."""
    tracker_spec = TrackerSpec.parse(f"{spec}&seed={seed}")
    robot_spec = RobotSpec.parse(f"mock:ur5e?seed={seed}")
    rig = SimulatedRig.from_spec(robot_spec, tracker_spec, VirtualClock())
    robot, tracker = open_robot(robot_spec, rig=rig), open_tracker(tracker_spec, rig=rig)
    robot.connect(1.0)
    tracker.connect(1.0)
    rng = np.random.default_rng(seed)
    home = rig.rest_joints.copy()
    out: dict[str, list] = {k: [] for k in KINDS}
    visits = iter(plan) if plan is not None else None
    while len(out["sigma"]) < poses:
        q = home + rng.uniform(-SPREAD, SPREAD) if visits is None else next(visits, None)
        if q is None:
            break
        robot.move_joints(q, np.full(len(q), 1.0), np.full(len(q), 2.0), 60.0)
        robot.wait_until_still(0.2, 10.0)
        try:
            taken = tracker.measure(readings, 30.0)
        except MeasurementError:  # the board not seen from here: the session records the step missing
            continue
        truth = rig.flange_pose() @ tracker.source.mount
        true_r, true_p = Rotation.from_matrix(truth[:3, :3]), rig.true_point()
        mean, sigma, used = average_readings(taken)
        (frame,) = average_frames(taken, list(used))
        out["pos"].append((mean - true_p) / sigma)
        out["rot"].append((Rotation.from_rotvec(frame.rotvec) * true_r.inv()).as_rotvec() / frame.sigma_r)
        out["sigma"].append(sigma)
        out["q"].append(q)
        sight = truth[:3, 3] / np.linalg.norm(truth[:3, 3])
        out["obliquity"].append(np.degrees(np.arccos(min(abs(float(truth[:3, 2] @ sight)), 1.0))))
        out["sigma_r"].append(frame.sigma_r)
        turns = np.array([(Rotation.from_rotvec(r.rotvec) * true_r.inv()).as_rotvec() for r in taken])
        points = np.array([r.position for r in taken]) - true_p
        s1, s1_r = np.array([r.sigma for r in taken]), np.array([r.sigma_r for r in taken])
        out["pos1"].extend(points / s1[:, None])
        out["rot1"].extend(turns / s1_r[:, None])
        scale = np.sqrt(readings / (readings - 1))  # the scatter about the mean of these readings, unbiased
        out["pos_spread"].extend(scale * (points - points.mean(axis=0)) / s1[:, None])
        out["rot_spread"].extend(scale * (turns - turns.mean(axis=0)) / s1_r[:, None])
    tracker.close()
    robot.close()
    return {k: np.array(v) for k, v in out.items()}


def z(values: np.ndarray) -> float:
    """RMS of per-axis ratios."""
    return float(np.sqrt(np.mean(np.square(values))))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--draws", type=int, default=4)
    parser.add_argument("--first", type=int, default=1, help="the first draw's seed")
    parser.add_argument("--poses", type=int, default=12)
    parser.add_argument("--readings", type=int, default=5)
    parser.add_argument("--bias", type=float, default=None, help="VIEW_BIAS_PX to state (default: the driver's)")
    parser.add_argument("--turn-bias", type=float, default=None, help="VIEW_TURN_BIAS_PX (default: the driver's)")
    parser.add_argument("--plan", default=None, help="visit this session's plan steps (in order) instead")
    parser.add_argument("--spec", default=SPEC)
    args = parser.parse_args(argv)
    if args.bias is not None:
        camera_pose.VIEW_BIAS_PX = args.bias
    if args.turn_bias is not None:
        camera_pose.VIEW_TURN_BIAS_PX = args.turn_bias
    plan = None
    if args.plan:
        from session.store import SessionFile

        with SessionFile.open(args.plan) as session:
            plan = np.array([s.q for s in session.plan.steps])
    start = time.perf_counter()
    print(f"camera: {args.spec}; view bias stated {camera_pose.VIEW_BIAS_PX:g} px, orientation "
          f"{camera_pose.VIEW_TURN_BIAS_PX:g} px; {args.poses} seen poses per draw "
          f"({'random' if plan is None else args.plan + ' plan'}), {args.readings} readings each")
    head = (f"{'draw':>4} {'sigma mm':>9} {'sigma_r mrad':>12} {'z pos':>6} {'z pos 1':>7} {'spread':>6} "
            f"{'z rot':>6} {'z rot 1':>7} {'spread':>6}")
    print(head)
    pooled: dict[str, list] = {}
    for seed in range(args.first, args.first + args.draws):
        d = draw(seed, args.poses, args.readings, args.spec, None if plan is None else plan[seed::2])
        for k, v in d.items():
            pooled.setdefault(k, []).append(v)
        print(_row(str(seed), d))
    every = {k: np.concatenate(v) for k, v in pooled.items()}
    print(_row("all", every))
    cells = []
    for lo, hi in itertools.pairwise(OBLIQUITY_BINS):
        k = (every["obliquity"] >= lo) & (every["obliquity"] < hi)
        cells.append(f"{lo:g}-{hi:g}°: {z(every['pos'][k]):.2f} ({int(k.sum())})" if k.any() else f"{lo:g}-{hi:g}°: -")
    print("z pos by obliquity (steps): " + ", ".join(cells))
    print(f"total {time.perf_counter() - start:.1f} s")
    return 0


def _row(label: str, d: dict[str, np.ndarray]) -> str:
    return (f"{label:>4} {np.median(d['sigma']) * 1e3:>9.4f} {np.median(d['sigma_r']) * 1e3:>12.4f} "
            f"{z(d['pos']):>6.2f} {z(d['pos1']):>7.2f} {z(d['pos_spread']):>6.2f} {z(d['rot']):>6.2f} "
            f"{z(d['rot1']):>7.2f} {z(d['rot_spread']):>6.2f}")


if __name__ == "__main__":
    raise SystemExit(main())
