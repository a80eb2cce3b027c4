"""The renderer draws every edge where ``cv2.projectPoints`` puts it (OpenCV's convention: pixel centres at
integer coordinates), with distortion, supersampling and blur: measured without any detector."""

from __future__ import annotations

import numpy as np
import pytest

cv2 = pytest.importorskip("cv2")

from scipy.spatial.transform import Rotation  # noqa: E402

from drivers.camera.intrinsics import CameraIntrinsics  # noqa: E402
from drivers.camera.renderer import BLACK, WHITE, Optics, Renderer  # noqa: E402
from drivers.camera.targets import dictionary_id, grid_board, single_marker  # noqa: E402

D4 = dictionary_id("4X4_50")
PINHOLE = CameraIntrinsics.from_fov(640, 480, 60)
BARREL = CameraIntrinsics.from_fov(640, 480, 60, [-0.08, 0.02, 0.0, 0.0, 0.0])


def _left_edge_errors(image: np.ndarray, camera: CameraIntrinsics, pose: np.ndarray, corners: np.ndarray,
                      module: float) -> np.ndarray:
    """Rendered minus projected column (pixels) of a marker's left outer edge, on every third image row.

    The row integral ``a - 1/2 + sum((I - black) / (white - black))`` over pixels a..b, white on the left
    and black on the right, is exactly the edge's column for a straight edge under any symmetric blur."""
    left, right = corners[0], corners[3]  # top-left and bottom-left corner, target frame (m)
    s = np.linspace(0.1, 0.9, 300)[:, None]
    rvec = cv2.Rodrigues(pose[:3, :3])[0]

    def project(points: np.ndarray) -> np.ndarray:
        uv = cv2.projectPoints(points, rvec, pose[:3, 3], camera.matrix, camera.distortion)[0].reshape(-1, 2)
        return uv[np.argsort(uv[:, 1])]

    edge = project(left + s * (right - left))
    inner = project(left + s * (right - left) + [module / 2, 0, 0])  # the middle of the black border
    rows = np.arange(int(np.ceil(edge[0, 1])) + 1, int(edge[-1, 1]), 3)
    errors = []
    for v in rows:
        u_true = np.interp(v, edge[:, 1], edge[:, 0])
        a, b = int(np.floor(u_true)) - 2, int(np.floor(np.interp(v, inner[:, 1], inner[:, 0])))
        coverage = (image[v, a:b + 1].astype(float) - BLACK) / (WHITE - BLACK)
        errors.append(a - 0.5 + coverage.sum() - u_true)
    return np.array(errors)


@pytest.mark.parametrize("camera", [PINHOLE, BARREL], ids=["pinhole", "barrel"])
@pytest.mark.parametrize("supersample, blur", [(2, 0.0), (3, 0.8)])
def test_edges_are_drawn_where_opencv_projects_them(camera, supersample, blur):
    """A half-pixel shift (0.5 px) or a supersample-grid offset ((s-1)/2s px) would fail by 20x the bound;
    a 3x3 grid board whose gap is no whole number of modules checks that no marker is rounded to a texel."""
    board = grid_board(3, 3, 0.03, 0.006, D4)
    marker = single_marker(5, 0.1, D4)
    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_euler("xyz", [200, 15, 7], degrees=True).as_matrix()
    pose[:3, 3] = [-0.04, 0.03, 0.4]
    errors = []
    for target, module in ((marker, 0.1 / 6), (board, 0.03 / 6)):
        image = Renderer(target, camera, Optics(blur=blur, supersample=supersample)).render([pose])
        for corners in target.corners.values():
            errors.append(_left_edge_errors(image, camera, pose, corners, module))
    errors = np.concatenate(errors)
    assert len(errors) > 100
    print(f"mean {errors.mean():+.4f} rms {np.sqrt(np.mean(errors**2)):.4f} max {np.abs(errors).max():.4f} px")
    # a straight edge on a supersampled grid is not perfectly antialiased: +-0.03 px ripple along it
    assert abs(errors.mean()) < 0.01 and np.sqrt(np.mean(errors**2)) < 0.02 and np.abs(errors).max() < 0.05


def test_tracing_only_the_targets_window_gives_the_same_image():
    """The renderer traces only the pixels around the target's projected outline: bit for bit the image that
    tracing every pixel gives, for one copy, two copies, a target half out of view and none."""
    board = grid_board(3, 3, 0.03, 0.006, D4)
    rng = np.random.default_rng(5)
    for camera in (PINHOLE, BARREL):
        renderer = Renderer(board, camera, Optics(blur=0.7, supersample=2))
        for k in range(4):
            pose = np.eye(4)
            pose[:3, :3] = Rotation.from_euler("xyz", [180 + rng.uniform(-40, 40), rng.uniform(-40, 40),
                                                       rng.uniform(0, 360)], degrees=True).as_matrix()
            pose[:3, 3] = [0.25 if k == 3 else rng.uniform(-0.05, 0.05), rng.uniform(-0.04, 0.04), 0.45]
            twin = pose.copy()
            twin[:3, 3] += [0.09, 0.0, 0.03]
            for poses in ([pose], [pose, twin], []):
                cropped, full = renderer.render(poses, crop=True), renderer.render(poses, crop=False)
                assert np.array_equal(cropped, full)
                assert poses == [] or np.count_nonzero(full != full[0, 0]) > 100  # the target is in the image
