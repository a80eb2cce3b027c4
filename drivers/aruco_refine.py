"""Marker corners refined by fitting straight lines to the four outer edges of each marker (``refine=edges``).

OpenCV's own refinements, measured on clean renders (bench/aruco.py, tests/test_aruco.py): ``subpix``
(``cornerSubPix``) pulls the convex outer corner of a marker 0.1-0.2 px inwards; ``contour`` and ``none``
0.5-0.7 px; ``apriltag`` is unbiased in scale but off by ~0.04 px in x and y after its half-pixel
convention shift, scatters 0.07-0.12 px, and segments the whole image again (22-27 frames/s at 1280x720).
This refinement starts from the fast detection's corners (no refinement) and only looks at the pixels
along each marker's border:

1. Along each side, between 15 % and 85 % of its length, the image is sampled (``cv2.remap``, bilinear,
   OpenCV's pixel convention: pixel centres at integers) on short profiles across the edge, from the white
   quiet zone outside to the middle of the black border inside (half a module in, at most
   ``MAX_REACH_PX``; the module measured across each side, so a foreshortened marker's profiles stay
   within its border).
2. The edge on each profile is where the step is: ``s0 + ∫ f ds`` with ``f`` the profile scaled to 1
   outside and 0 inside. For a straight edge under any symmetric blur (defocus, the pixel's own area)
   this integral is exactly the edge position; thresholds and gradient peaks are not.
3. The edge points of a side are undistorted (``cv2.undistortPoints``: straight lines stay straight), a
   line is fitted (``cv2.fitLine``, Huber-weighted), adjacent lines are intersected and the corners are
   distorted back into the image (``cv2.projectPoints``). Two passes: the second samples across the
   lines of the first.

Measured corner error on clean 1280x720 renders: see docs/benchmarks.md (ArUco section).
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]

SPAN = (0.15, 0.85)  # part of each side sampled (the corners themselves are rounded by blur)
STEP_PX = 0.5  # sample spacing along a profile, pixels
SPACING_PX = 2.0  # profiles this far apart share no pixel of their bilinear samples: independent noise
MAX_REACH_PX = 4.0  # a profile reaches at most this far on either side of the edge, pixels
MIN_REACH_PX = 1.0
MIN_CONTRAST = 15.0  # grey levels between the two ends of a profile; weaker profiles are dropped
MIN_POINTS = 3  # edge points per side needed for a line
PASSES = 2


def refine_corners(gray: NDArray[np.uint8], corners: list[Array], modules: int, matrix: Array | None = None,
                   distortion: Array | None = None) -> tuple[list[Array], list[Array | None]]:
    """``corners``: per marker (4, 2) pixels (OpenCV's order, clockwise in the image) from a detection
    without refinement; ``modules``: modules across a marker, border included (markerSize + 2 for a
    1-module border). Returns the refined corners (a marker whose edges cannot be fitted keeps its input)
    and their (8, 8) covariance, pixels² (None for a marker kept as it was). With ``matrix`` and
    ``distortion`` the lines are fitted in undistorted coordinates (the covariance is taken there too:
    distortion changes it by a few percent at most)."""
    if not corners:
        return [], []
    image = gray.astype(np.float32)
    undistort = matrix is not None and distortion is not None and bool(np.any(distortion))
    out: list[tuple[Array, Array | None]] = [(np.asarray(c, dtype=float).reshape(4, 2), None) for c in corners]
    for k in range(PASSES):
        out = _one_pass(image, [c for c, _ in out], modules, matrix if undistort else None, distortion,
                        covariance=k == PASSES - 1)
    return [c for c, _ in out], [v for _, v in out]


def _one_pass(image: NDArray[np.float32], corners: list[Array], modules: int, matrix: Array | None,
              distortion: Array | None, covariance: bool) -> list[tuple[Array, Array | None]]:
    quads = np.stack(corners)  # (M, 4, 2)
    start, end = quads, np.roll(quads, -1, axis=1)  # side k runs from corner k to corner k+1
    length = np.linalg.norm(end - start, axis=2)  # (M, 4)
    direction = (end - start) / np.maximum(length, 1e-9)[..., None]
    inward = np.stack([-direction[..., 1], direction[..., 0]], axis=-1)  # left of the side in image coords
    centre = quads.mean(axis=1, keepdims=True)
    flip = np.sum(inward * (centre - (start + end) / 2), axis=-1) < 0
    inward[flip] *= -1
    # a module across each side (the marker may be foreshortened): its distance to the opposite side / modules
    middle = (start + end) / 2
    width = np.abs(np.sum(inward * (np.roll(middle, -2, axis=1) - middle), axis=-1))  # (M, 4) pixels
    reach = np.clip(0.5 * width / modules, MIN_REACH_PX, MAX_REACH_PX)  # (M, 4)
    n_along = int(np.clip((SPAN[1] - SPAN[0]) * np.max(length) / SPACING_PX, 6, 40))
    t = np.linspace(SPAN[0], SPAN[1], n_along)
    n_prof = int(np.ceil(MAX_REACH_PX / STEP_PX))
    s = np.arange(-n_prof, n_prof + 1) * STEP_PX  # (P,) positive = inward
    scale = (reach / MAX_REACH_PX)[:, :, None, None]  # each side's profiles span +-reach
    base = start[:, :, None, :] + t[None, None, :, None] * (end - start)[:, :, None, :]  # (M, 4, A, 2)
    offsets = s[None, None, None, :, None] * scale[..., None] * inward[:, :, None, None, :]  # (M, 4, 1, P, 2)
    points = base[:, :, :, None, :] + offsets  # (M, 4, A, P, 2)
    flat = points.reshape(-1, len(s), 2).astype(np.float32)
    profiles = cv2.remap(image, flat[..., 0], flat[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    profiles = profiles.reshape(points.shape[:4]).astype(float)
    outside = profiles[..., :2].mean(axis=-1)
    inside = profiles[..., -2:].mean(axis=-1)
    contrast = outside - inside
    f = np.clip((profiles - inside[..., None]) / np.where(contrast > 0, contrast, 1.0)[..., None], 0.0, 1.0)
    ds = STEP_PX * (reach / MAX_REACH_PX)[:, :, None]  # (M, 4, 1) profile step of each side, pixels
    area = (f[..., 1:] + f[..., :-1]).sum(axis=-1) / 2 * ds  # trapezoid integral of f over the profile
    edge = -n_prof * ds + area  # (M, 4, A) offset of the edge from the base point along ``inward``
    found = base + edge[..., None] * inward[:, :, None, :]
    valid = (contrast >= MIN_CONTRAST) & (np.abs(edge) < reach[:, :, None] * 0.9)
    refined: list[tuple[Array, Array | None]] = []
    for m in range(len(corners)):
        fitted = _corners_from_edges(found[m], valid[m], matrix, distortion, covariance)
        refined.append((corners[m], None) if fitted is None else fitted)
    return refined


def _corners_from_edges(points: Array, valid: NDArray[np.bool_], matrix: Array | None,
                        distortion: Array | None, covariance: bool = True) -> tuple[Array, Array | None] | None:
    """(4, A, 2) edge points of the four sides (pixels) -> (4, 2) corners, corner k = side k-1 x side k,
    and their (8, 8) covariance (pixels², x0 y0 x1 y1 ...) from the scatter of the edge points about the
    lines (see :func:`_corner_covariance`; None unless ``covariance``)."""
    lines = []
    for k in range(4):
        pts = points[k][valid[k]]
        if len(pts) < MIN_POINTS:
            return None
        if matrix is not None:  # ideal pinhole pixels: the edge is straight there
            pts = cv2.undistortPoints(pts.reshape(-1, 1, 2), matrix, distortion, P=matrix).reshape(-1, 2)
        vx, vy, x0, y0 = cv2.fitLine(pts.astype(np.float32), cv2.DIST_HUBER, 0, 1e-3, 1e-4).reshape(4)
        direction, normal = np.array([vx, vy], dtype=float), np.array([-vy, vx], dtype=float)
        lines.append((normal, float(normal @ np.array([x0, y0], dtype=float)), direction, pts))
    out = np.empty((4, 2))
    for k in range(4):
        (n1, c1, *_), (n2, c2, *_) = lines[k - 1], lines[k]
        a = np.array([n1, n2])
        if abs(np.linalg.det(a)) < 1e-9:
            return None
        out[k] = np.linalg.solve(a, [c1, c2])
    cov = _corner_covariance(lines, out) if covariance else None
    if matrix is not None:
        rays = np.column_stack([out, np.ones(4)]) @ np.linalg.inv(matrix).T
        out = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), matrix, distortion)[0].reshape(4, 2)
    return out, cov


def _corner_covariance(lines: list[tuple[Array, float, Array, Array]], corners: Array) -> Array:
    """Covariance (8, 8) of four corners intersected from four fitted lines, pixels².

    Each line's error is an offset ``dc`` (at the centroid of its points, variance s²/N) and a turn
    ``dθ`` (variance s²/Σt², t along the line from the centroid), s² the scatter of its N points about
    it. Corner k moves by A⁻¹ (dc + t dθ) of its two lines (A: their normals). The corners of one side
    are correlated: a turn moves them oppositely, an offset alike; so the pose (depth above all) is
    less uncertain than independent corners of the same variance would make it (on renders with noise 2,
    independent corners over-predicted the TP's variance 1.4x for one marker, 1.7x for a 2x2 board)."""
    jac = np.zeros((8, 8))  # corners (x0 y0 ... x3 y3) <- (dc0, dθ0, ..., dc3, dθ3)
    variances = np.zeros(8)
    centres = []
    for k, (normal, _, direction, pts) in enumerate(lines):
        centre = pts.mean(axis=0)
        rho = (pts - centre) @ normal
        t = (pts - centre) @ direction
        s2 = float(rho @ rho) / max(len(pts) - 2, 1)
        variances[2 * k:2 * k + 2] = s2 / len(pts), s2 / max(float(t @ t), 1e-12)
        centres.append(centre)
    for k in range(4):
        a_inv = np.linalg.inv(np.array([lines[k - 1][0], lines[k][0]]))
        for row, line in enumerate(((k - 1) % 4, k)):
            t = float((corners[k] - centres[line]) @ lines[line][2])
            jac[2 * k:2 * k + 2, 2 * line] += a_inv[:, row]
            jac[2 * k:2 * k + 2, 2 * line + 1] += a_inv[:, row] * t
    return (jac * variances) @ jac.T
