"""What a calibration's errors do to a flange camera's views, what a fitted mount takes up of them, and what the
tracker's reading-by-reading correction leaves against the session's final estimate (docs/benchmarks.md, 24a).

    PYTHONPATH=. .venv/bin/python -m bench.lens_estimate [--seeds 5] [--views 40]

The tracker (drivers/camera/board_and_lens.py, ``BoardAndLens.take``) corrects each frame's pose by the estimate of
the lens's errors from the frames so far; the first readings of a session are corrected by an estimate from one or
two views. This measures what that costs, without rendering (seconds, not the flange bench's hours): the corners of
the bench's A4 ChArUco board (11x8 squares of 25 mm: 70 corners) projected through the true camera (1280x720, 60°
wide, its errors below), each view's corners off by a bias drawn once per view (``VIEW_TURN_BIAS_PX``, 0.015 px per
coordinate: the detection's error at that angle and scale) and each frame's by noise (0.03 px), 3 frames a view; a
first view near the board's normal at 0.45 m (the home reading), then ``--views`` views 0.3-0.75 m away within 40°
of the board's normal, rolled ±90° (as the flange plan draws them); the pose by ``cv2.solvePnP`` with the
calibrated camera. Reported per case, over the seeds: the flat poses' error (the board's centre, mm RMS over the
frames), the tracker's corrected poses' error and the lens estimate's share of the ``shared`` error it states (RMS
of ``sqrt(3)`` x the per-axis value; the detection's own noise and bias are not in it), the error with every frame
corrected by the final estimate instead, and the final estimate against the truth in its own standard deviations
(the largest over the parameters and seeds).

First, per lens parameter of a typical calibration's error (:data:`TYPICAL`), over the views of the first seed: how
far it moves each view's least-squares pose (``pose_shifts``: the board centre, mm RMS, and its turn, mrad RMS), and
what is left after the one change of the camera's mount (a turn and a translation, the same in every view) that
takes up most of it (least squares, turns weighted by a 0.5 m lever): a fitted mount absorbs that much of it, the
rest no rigid part of the fit can.
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from drivers.camera.board_and_lens import BoardAndLens, pose_shifts
from drivers.camera.imperfections import Imperfections
from drivers.camera.intrinsics import CameraIntrinsics
from drivers.camera.pose import VIEW_TURN_BIAS_PX

CAMERA = CameraIntrinsics.from_fov(1280, 720, 60.0)
CORNERS = np.array([[(i - 4.5) * 0.025, (j - 3.0) * 0.025, 0.0] for i in range(10) for j in range(7)])
EXTENT = (0.275, 0.2)  # m: the A4 board's 11 x 8 squares
NOISE_PX, FRAMES = 0.03, 3
#: case: (the true camera's errors, the tracker's priors: flatness, lens_sigma, focal_sigma, centre_sigma)
TYPICAL = {"dk1": 0.0015, "dfocal": 0.002, "dcx": 3.0, "dcy": -2.0}
CASES = {"focal 0.2 %, centre (3, -2) px": (Imperfections(dfocal=0.002, dcx=3.0, dcy=-2.0), (0.0, 0.0, 0.005, 5.0)),
         "k1 +0.0015": (Imperfections(dk1=0.0015), (0.0, 0.005, 0.0, 0.0)),
         "both": (Imperfections(dk1=0.0015, dfocal=0.002, dcx=3.0, dcy=-2.0), (0.0, 0.005, 0.005, 5.0))}


@dataclass(frozen=True)
class _Pose:
    rotation: np.ndarray
    translation: np.ndarray
    rms: float = 0.0  # px: the tracker's corrected pose carries the residuals' RMS the estimate leaves


@dataclass(frozen=True)
class _Seen:
    object_points: np.ndarray
    image_points: np.ndarray


def views(count: int, rng: np.random.Generator) -> list[tuple[np.ndarray, np.ndarray]]:
    """Camera <- board (rotation, translation m): a first view 8° off the board's normal at 0.45 m, then ``count``."""
    out = []
    for k in range(count + 1):
        distance, angle = (0.45, math.radians(8.0)) if k == 0 else (rng.uniform(0.3, 0.75),
                                                                      math.radians(40.0) * math.sqrt(rng.uniform()))
        azimuth, roll = rng.uniform(0.0, 2 * math.pi), rng.uniform(-math.pi / 2, math.pi / 2)
        rotation = (Rotation.from_rotvec([angle * math.cos(azimuth), angle * math.sin(azimuth), 0.0])
                    * Rotation.from_rotvec([0.0, 0.0, roll])).as_matrix() @ np.diag([1.0, -1.0, -1.0])
        out.append((rotation, np.array([rng.uniform(-0.05, 0.05), rng.uniform(-0.03, 0.03), distance])))
    return out


def mount_part(name: str, amount: float, seen: list[tuple[np.ndarray, np.ndarray]]) -> tuple[float, ...]:
    """Lens parameter ``name`` off by ``amount``: the views' pose shifts (m, rad RMS) and what is left of them (m,
    rad RMS) after the best common change of the camera's mount (a turn w and translation tau: a view at translation
    t moves by w and ``w x t + tau``)."""
    shifts = np.array([pose_shifts(r, t, CORNERS, (EXTENT[0] / 2, EXTENT[1] / 2), CAMERA, (name,))[-1] * amount
                       for r, t in seen])
    lever = 0.5
    rows, rhs = [], []
    for (_, t), shift in zip(seen, shifts, strict=True):
        cross = np.array([[0.0, t[2], -t[1]], [-t[2], 0.0, t[0]], [t[1], -t[0], 0.0]])  # w -> w x t
        rows += [np.hstack([lever * np.eye(3), np.zeros((3, 3))]), np.hstack([cross, np.eye(3)])]
        rhs += [lever * shift[:3], shift[3:]]
    design, target = np.vstack(rows), np.concatenate(rhs)
    left = (target - design @ np.linalg.lstsq(design, target, rcond=None)[0]).reshape(len(seen), 2, 3)

    def rms(values: np.ndarray) -> float:
        return float(np.sqrt(np.mean(np.sum(values**2, axis=1))))

    return rms(shifts[:, 3:]), rms(shifts[:, :3]), rms(left[:, 1]), rms(left[:, 0] / lever)


def session(truth: Imperfections, priors: tuple[float, ...], count: int, seed: int) -> dict[str, float]:
    """One synthetic session: the errors (m) of the flat, the tracker's and the final estimate's poses, the stated
    shared error (m), the final estimate's largest error in its standard deviations."""
    rng = np.random.default_rng([seed, 36])
    true_camera = truth.lens(CAMERA)
    shape = BoardAndLens(priors[0], priors[1], EXTENT, priors[2], priors[3])
    flat, tracker, stated, frames = [], [], [], []
    for rotation, translation in views(count, rng):
        bias = rng.normal(0.0, VIEW_TURN_BIAS_PX, (len(CORNERS), 2))
        exact = cv2.projectPoints(CORNERS, cv2.Rodrigues(rotation)[0], translation, true_camera.matrix,
                                  true_camera.distortion)[0].reshape(-1, 2)
        for _ in range(FRAMES):
            image = exact + bias + rng.normal(0.0, NOISE_PX, exact.shape)
            _, rvec, tvec = cv2.solvePnP(CORNERS, image, CAMERA.matrix, CAMERA.distortion)
            pose = _Pose(cv2.Rodrigues(rvec)[0], tvec.ravel())
            corrected, correction = shape.take(pose, _Seen(CORNERS, image), CAMERA, np.zeros(3))
            shared = correction.bias
            flat.append(np.linalg.norm(pose.translation - translation))
            tracker.append(np.linalg.norm(corrected.translation - translation))
            stated.append(math.sqrt(3) * shared)
            frames.append((pose, translation))
    value, covariance = shape.estimate()
    final = [np.linalg.norm(pose.translation - (pose_shifts(pose.rotation, pose.translation, CORNERS,
                                                            (EXTENT[0] / 2, EXTENT[1] / 2), CAMERA, shape.lens).T
                                                @ value)[3:] - translation) for pose, translation in frames]
    truth_values = np.array([getattr(truth, name) for name in shape.lens])
    off = np.abs(value[3:] - truth_values) / np.sqrt(np.diag(covariance)[3:])

    def rms(errors: list[float]) -> float:
        return float(np.sqrt(np.mean(np.square(errors))))

    return {"flat": rms(flat), "tracker": rms(tracker), "stated": rms(stated), "final": rms(final),
            "off": float(off.max())}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.lens_estimate", description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=5, help="sessions per case (default 5)")
    parser.add_argument("--views", type=int, default=40, help="views after the first (default 40)")
    args = parser.parse_args(argv)
    seen = views(args.views, np.random.default_rng([1, 36]))
    print(f"{'parameter off by':<20} {'pose shift mm':>13} {'mrad':>6} {'left after a mount mm':>21} {'mrad':>6}")
    for name, amount in TYPICAL.items():
        moved, turned, left, left_turn = mount_part(name, amount, seen)
        print(f"{name + ' ' + format(amount, 'g'):<20} {moved * 1e3:>13.3f} {turned * 1e3:>6.3f} {left * 1e3:>21.3f} "
              f"{left_turn * 1e3:>6.3f}")
    print()
    print(f"A4 board (70 corners), 1280x720 camera, {args.views + 1} views of {FRAMES} frames, noise {NOISE_PX} px a "
          f"frame, a view's bias {VIEW_TURN_BIAS_PX} px; the board centre's error, mm RMS over the frames and "
          f"{args.seeds} seeds")
    header = f"{'case':<32} {'flat':>7} {'tracker':>8} {'stated':>7} {'final estimate':>14} {'estimate off, sd':>16}"
    print(header)
    print("-" * len(header))
    for name, (truth, priors) in CASES.items():
        runs = [session(truth, priors, args.views, seed) for seed in range(1, args.seeds + 1)]
        pooled = {key: math.sqrt(np.mean([r[key] ** 2 for r in runs])) * 1e3 for key in ("flat", "tracker", "stated",
                                                                                        "final")}
        print(f"{name:<32} {pooled['flat']:>7.3f} {pooled['tracker']:>8.3f} {pooled['stated']:>7.3f} "
              f"{pooled['final']:>14.3f} {max(r['off'] for r in runs):>16.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
