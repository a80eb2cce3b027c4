"""ArUco camera tracker: detection + pose speed at 1280x720, and 3D accuracy on rendered images.

    .venv/bin/python -m bench.aruco            # prints the tables recorded in docs/benchmarks.md

Speed: frames per second of detection + pose (one thread of work per frame, as the driver runs it) on
pre-rendered 1280x720 frames with sensor noise (2 grey levels) and blur (0.5 px). Accuracy: mean 3D error
(mm) of the target centre against the rendered truth, over random poses (tilt up to 30 deg, any roll),
for each distance, target (single marker 50 / 100 mm, grid board 100 mm) and corner refinement (OpenCV's
four and ``edges``, drivers/camera/refinement.py): on clean renders (no noise, no blur, 6 poses) at 0.5, 1.0
and 1.5 m, and at 1 m with noise 2 and blur 0.5 (12 poses). Camera: 1280x720, 60 deg horizontal field of
view, no distortion. The machine's load average is printed with the speeds.
"""

from __future__ import annotations

import os
import sys
import time

import numpy as np
from scipy.spatial.transform import Rotation

from drivers.camera.intrinsics import CameraIntrinsics
from drivers.camera.pose import estimate_pose
from drivers.camera.renderer import Optics, Renderer
from drivers.camera.targets import Detector, dictionary_id, grid_board, single_marker

CAMERA = CameraIntrinsics.from_fov(1280, 720, 60)
D4 = dictionary_id("4X4_50")
TARGETS = {"marker 50 mm": single_marker(3, 0.05, D4), "marker 100 mm": single_marker(3, 0.10, D4),
           "grid 3x3 100 mm": grid_board(3, 3, 0.03, 0.005, D4)}
METHODS = ("none", "subpix", "contour", "apriltag", "edges")


def poses(rng: np.random.Generator, distance: float, count: int) -> list[np.ndarray]:
    out = []
    for _ in range(count):
        pose = np.eye(4)
        angles = [180 + rng.uniform(-30, 30), rng.uniform(-30, 30), rng.uniform(0, 360)]
        pose[:3, :3] = Rotation.from_euler("xyz", angles, degrees=True).as_matrix()
        pose[:3, 3] = [rng.uniform(-0.15, 0.15) * distance, rng.uniform(-0.1, 0.1) * distance, distance]
        out.append(pose)
    return out


TARGET_FPS = 30.0  # detection + pose at 1280x720, default refinement, board
TARGET_ERROR = 0.3e-3  # m: mean 3D error of the 100 mm board at 1 m on clean renders, default refinement
DEFAULT_METHOD = "edges"


def speed() -> dict[str, dict[str, float]]:
    """Print and return frames/s per target and refinement method."""
    print(f"detection + pose, 1280x720, noise 2, blur 0.5: frames/s (load average {os.getloadavg()[0]:.2f} "
          f"on {os.cpu_count()} cores)")
    rng = np.random.default_rng(0)
    rates: dict[str, dict[str, float]] = {}
    for name in ("marker 100 mm", "grid 3x3 100 mm"):
        target = TARGETS[name]
        renderer = Renderer(target, CAMERA, Optics(noise=2.0, blur=0.5, supersample=2))
        frames = [renderer.render([p], rng) for p in poses(rng, 1.0, 5)]
        row, rates[name] = [], {}
        for method in METHODS:
            detector = Detector(target, method, CAMERA)
            detector.detect(frames[0])
            start, n = time.perf_counter(), 0
            while time.perf_counter() - start < 2.0:
                obs = detector.detect(frames[n % len(frames)])
                estimate_pose(obs, CAMERA.matrix, CAMERA.distortion, target.kind == "marker")
                n += 1
            rates[name][method] = n / (time.perf_counter() - start)
            row.append(f"{method} {rates[name][method]:.0f}")
        print(f"  {name}: " + ", ".join(row))
    return rates


def accuracy(count: int = 6, optics: Optics | None = None,
             distances: tuple[float, ...] = (0.5, 1.0, 1.5)) -> dict[tuple[str, float, str], float]:
    """Print and return the mean 3D error (m) per (target, distance, method)."""
    means: dict[tuple[str, float, str], float] = {}
    optics = optics or Optics(noise=0.0, blur=0.0)
    print(f"mean 3D error of the centre, mm, noise {optics.noise:g}, blur {optics.blur:g}, {count} poses each "
          "(lost: frames without a pose)")
    print("  target            distance  " + "  ".join(f"{m:>9}" for m in METHODS))
    for name, target in TARGETS.items():
        renderer = Renderer(target, CAMERA, optics)
        detectors = {m: Detector(target, m, CAMERA) for m in METHODS}
        for distance in distances:
            rng = np.random.default_rng(int(distance * 10))
            errors: dict[str, list[float]] = {m: [] for m in METHODS}
            for truth in poses(rng, distance, count):
                image = renderer.render([truth], rng)
                for method, detector in detectors.items():
                    pose = estimate_pose(detector.detect(image), CAMERA.matrix, CAMERA.distortion,
                                         target.kind == "marker", reference=truth[:3, :3])
                    if pose is not None:
                        errors[method].append(float(np.linalg.norm(pose.translation - truth[:3, 3])))
            means.update({(name, distance, m): float(np.mean(e)) for m, e in errors.items() if e})
            cells = [f"{np.mean(e) * 1e3:9.3f}" + (f" ({count - len(e)} lost)" if len(e) < count else "")
                     if e else "     lost" for e in errors.values()]
            print(f"  {name:<17} {distance:5.1f} m  " + "  ".join(cells))
    return means


def main() -> int:
    """Print the tables; exit status 1 if the speed or the accuracy target is missed."""
    fps = speed()["grid 3x3 100 mm"][DEFAULT_METHOD]
    error = accuracy().get(("grid 3x3 100 mm", 1.0, DEFAULT_METHOD), float("inf"))
    accuracy(12, Optics(noise=2.0, blur=0.5), (1.0,))
    print(f"targets ({DEFAULT_METHOD}, 3x3 board): {fps:.0f} frames/s (>= {TARGET_FPS:g}: "
          f"{'ok' if fps >= TARGET_FPS else 'MISSED'}), mean error at 1 m {error * 1e3:.3f} mm "
          f"(< {TARGET_ERROR * 1e3:g} mm: {'ok' if error < TARGET_ERROR else 'MISSED'})")
    return 0 if fps >= TARGET_FPS and error < TARGET_ERROR else 1


if __name__ == "__main__":
    sys.exit(main())
