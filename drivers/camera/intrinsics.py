"""Camera intrinsics (pinhole + OpenCV distortion) and their FileStorage YAML, as OpenCV's tools write it.

The file holds ``camera_matrix`` (3x3, pixels), ``distortion_coefficients`` (1xN, N in 4, 5, 8, 12, 14:
k1 k2 p1 p2 [k3 [k4 k5 k6 [s1 s2 s3 s4 [tx ty]]]]), ``image_width`` and ``image_height`` (pixels); any other
node (``avg_reprojection_error``, ``calibration_time``...) is ignored on reading. Pixel coordinates follow
OpenCV: the centre of the top-left pixel is (0, 0).

Every problem with a file raises :class:`IntrinsicsError` with one line naming the file and what is wrong.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]
DISTORTION_SIZES = (4, 5, 8, 12, 14)


class IntrinsicsError(ValueError):
    """An intrinsics file that cannot be used; the message is one line naming the file."""


@dataclass(frozen=True)
class CameraIntrinsics:
    """``matrix`` 3x3 camera matrix (fx, fy, cx, cy in pixels), ``distortion`` OpenCV coefficients (N,),
    ``width``/``height`` the image size in pixels the calibration belongs to."""

    matrix: Array
    distortion: Array = field(default_factory=lambda: np.zeros(5))
    width: int = 0
    height: int = 0

    def __post_init__(self) -> None:
        matrix = np.array(self.matrix, dtype=float).reshape(3, 3)
        dist = np.array(self.distortion, dtype=float).reshape(-1)
        if dist.size not in DISTORTION_SIZES:
            raise ValueError(f"distortion needs 4, 5, 8, 12 or 14 coefficients, got {dist.size}")
        object.__setattr__(self, "matrix", matrix)
        object.__setattr__(self, "distortion", dist)
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))
        problem = _problem(matrix, dist, self.width, self.height)
        if problem:
            raise ValueError(problem)

    @classmethod
    def from_fov(cls, width: int, height: int, hfov_deg: float, distortion: object = None) -> CameraIntrinsics:
        """Square pixels, principal point at the image centre, horizontal field of view ``hfov_deg``."""
        f = (width / 2) / math.tan(math.radians(hfov_deg) / 2)
        matrix = [[f, 0, (width - 1) / 2], [0, f, (height - 1) / 2], [0, 0, 1]]
        return cls(matrix, np.zeros(5) if distortion is None else distortion, width, height)

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        return self.width, self.height

    def scaled_to(self, width: int, height: int) -> CameraIntrinsics:
        """The same camera at another resolution of the same sensor area (fx, cx scale with the width...)."""
        sx, sy = width / self.width, height / self.height
        m = self.matrix.copy()
        m[0, 0] *= sx
        m[0, 2] = (m[0, 2] + 0.5) * sx - 0.5
        m[1, 1] *= sy
        m[1, 2] = (m[1, 2] + 0.5) * sy - 0.5
        return CameraIntrinsics(m, self.distortion, width, height)


def _problem(matrix: Array, dist: Array, width: int, height: int) -> str:
    if not (np.all(np.isfinite(matrix)) and np.all(np.isfinite(dist))):
        return "the camera matrix and distortion must be finite numbers"
    if not (matrix[0, 0] > 0 and matrix[1, 1] > 0) or np.any(matrix[2] != (0, 0, 1)) or matrix[1, 0] != 0:
        return "camera_matrix must be [[fx, s, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0"
    if width <= 0 or height <= 0:
        return f"image size must be positive, got {width}x{height}"
    return ""


def read_intrinsics(path: str | Path) -> CameraIntrinsics:
    """Read an OpenCV FileStorage file (YAML, XML or JSON); IntrinsicsError with one line if unusable."""
    path = Path(path)
    if not path.is_file():
        raise IntrinsicsError(f"camera file {path}: no such file")
    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as exc:  # OpenCV 5 wraps some parse errors in SystemError
        reason = " ".join(str(exc).split())[-160:]
        raise IntrinsicsError(f"camera file {path}: not an OpenCV FileStorage file ({reason})") from None
    try:
        if not fs.isOpened():
            raise IntrinsicsError(f"camera file {path}: not an OpenCV FileStorage file")
        matrix = _matrix_node(fs, path, "camera_matrix")
        dist = _matrix_node(fs, path, "distortion_coefficients")
        size = []
        for key in ("image_width", "image_height"):
            node = fs.getNode(key)
            if node.empty() or (not node.isInt() and not node.isReal()):
                raise IntrinsicsError(f"camera file {path}: {key} is missing (expected the image size in pixels)")
            size.append(int(node.real()))
    finally:
        fs.release()
    if matrix.shape != (3, 3):
        raise IntrinsicsError(f"camera file {path}: camera_matrix must be 3x3, got {matrix.shape[0]}x{matrix.shape[1]}")
    if dist.size not in DISTORTION_SIZES:
        raise IntrinsicsError(f"camera file {path}: distortion_coefficients must have 4, 5, 8, 12 or 14 values, "
                              f"got {dist.size}")
    problem = _problem(matrix, dist.reshape(-1), size[0], size[1])
    if problem:
        raise IntrinsicsError(f"camera file {path}: {problem}")
    return CameraIntrinsics(matrix, dist.reshape(-1), size[0], size[1])


def _matrix_node(fs: cv2.FileStorage, path: Path, key: str) -> Array:
    node = fs.getNode(key)
    if node.empty():
        raise IntrinsicsError(f"camera file {path}: {key} is missing (expected an opencv-matrix)")
    value = node.mat()
    if value is None:
        raise IntrinsicsError(f"camera file {path}: {key} is not an opencv-matrix")
    return np.asarray(value, dtype=float)


def write_intrinsics(path: str | Path, intrinsics: CameraIntrinsics, **extra: float | str) -> None:
    """Write ``intrinsics`` as OpenCV FileStorage (format from the suffix: .yaml/.yml, .xml, .json);
    ``extra`` scalars (e.g. ``avg_reprojection_error``) are written after the standard nodes."""
    path = Path(path)
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    if not fs.isOpened():
        raise IntrinsicsError(f"camera file {path}: cannot be written")
    try:
        fs.write("image_width", intrinsics.width)
        fs.write("image_height", intrinsics.height)
        fs.write("camera_matrix", intrinsics.matrix)
        fs.write("distortion_coefficients", intrinsics.distortion.reshape(1, -1))
        for key, value in extra.items():
            fs.write(key, value)
    finally:
        fs.release()
