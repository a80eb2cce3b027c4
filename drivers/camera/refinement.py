"""Marker corners refined by fitting straight lines to the four outer edges of each marker (``refine=edges``).

OpenCV's own refinements, measured on clean renders (bench/aruco.py, tests/drivers/camera/test_tracker.py): ``subpix``
(``cornerSubPix``) pulls the convex outer corner of a marker 0.1-0.2 px inwards; ``contour`` and ``none``
0.5-0.7 px; ``apriltag`` is unbiased in scale but off by ~0.04 px in x and y after its half-pixel
convention shift, scatters 0.07-0.12 px, and segments the whole image again (24-34 frames/s at 1280x720).
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
   line is fitted (least squares with Huber weights, all sides of all markers at once), adjacent lines
   are intersected and the corners are distorted back into the image (``cv2.projectPoints``). Two
   passes: the second samples across the lines of the first.

Measured corner error on clean 1280x720 renders: see docs/benchmarks.md (ArUco section).
"""

from __future__ import annotations

import warnings

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
HUBER_K = 1.345  # Huber's constant, in robust standard deviations of an edge point from its line
HUBER_ROUNDS = 3


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
    fitted, cov, ok = _corners_from_edges(found, valid, matrix, distortion, covariance)
    return [(fitted[m], None if cov is None else cov[m]) if ok[m] else (corners[m], None)
            for m in range(len(corners))]


def _corners_from_edges(points: Array, valid: NDArray[np.bool_], matrix: Array | None, distortion: Array | None,
                        covariance: bool) -> tuple[Array, Array | None, NDArray[np.bool_]]:
    """(M, 4, A, 2) edge points of each marker's four sides (pixels; ``valid`` (M, 4, A) those to use) ->
    (M, 4, 2) corners (corner k = side k-1 x side k), their (M, 8, 8) covariance (pixels², x0 y0 x1 y1
    ...; see :func:`_corner_covariance`; None unless ``covariance``) and which markers could be fitted.
    Lines are fitted by least squares with Huber weights (three reweighting rounds), all sides at once."""
    m = len(points)
    if matrix is not None:  # ideal pinhole pixels: the edge is straight there
        points = cv2.undistortPoints(points.reshape(-1, 1, 2), matrix, distortion, P=matrix).reshape(points.shape)
    count = valid.sum(axis=-1)
    ok = np.all(count >= MIN_POINTS, axis=1)
    weight = valid.astype(float)
    for _ in range(HUBER_ROUNDS):
        centre, direction, normal = _weighted_lines(points, weight)
        rho = np.sum((points - centre[:, :, None]) * normal[:, :, None], axis=-1)  # (M, 4, A)
        with warnings.catch_warnings():  # a side without valid points: its marker is not fitted anyway
            warnings.simplefilter("ignore", RuntimeWarning)
            scale = 1.4826 * np.nanmedian(np.where(valid, np.abs(rho), np.nan), axis=-1, keepdims=True)
        limit = HUBER_K * np.maximum(np.nan_to_num(scale), 1e-6)
        weight = valid * np.minimum(1.0, limit / np.maximum(np.abs(rho), 1e-12))
    centre, direction, normal = _weighted_lines(points, weight)
    offset = np.sum(normal * centre, axis=-1)  # (M, 4): line k is normal_k . p = offset_k
    pair = np.stack([np.roll(normal, 1, axis=1), normal], axis=2)  # (M, 4, 2, 2): sides k-1 and k
    rhs = np.stack([np.roll(offset, 1, axis=1), offset], axis=2)  # (M, 4, 2)
    ok &= np.all(np.abs(np.linalg.det(pair)) > 1e-9, axis=1)
    pair[~ok] = np.eye(2)
    corners = np.linalg.solve(pair, rhs[..., None])[..., 0]  # (M, 4, 2)
    cov = _corner_covariance(points, valid, direction, normal, pair, corners) if covariance else None
    if matrix is not None:
        rays = np.concatenate([corners, np.ones((m, 4, 1))], axis=-1).reshape(-1, 3) @ np.linalg.inv(matrix).T
        corners = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), matrix, distortion)[0].reshape(m, 4, 2)
    return corners, cov, ok


def _weighted_lines(points: Array, weight: Array) -> tuple[Array, Array, Array]:
    """Weighted least-squares lines through (M, 4, A, 2) points: centroid, direction, normal (M, 4, 2)."""
    total = np.maximum(weight.sum(axis=-1), 1e-12)[..., None]
    centre = np.sum(weight[..., None] * points, axis=2) / total
    d = points - centre[:, :, None]
    scatter = np.einsum("...a,...ai,...aj->...ij", weight, d, d)
    _, vectors = np.linalg.eigh(scatter)  # eigenvalues ascending: the last vector runs along the line
    direction = vectors[..., :, 1]
    normal = np.stack([-direction[..., 1], direction[..., 0]], axis=-1)
    return centre, direction, normal


def _corner_covariance(points: Array, valid: NDArray[np.bool_], direction: Array, normal: Array, pair: Array,
                       corners: Array) -> Array:
    """Covariance (M, 8, 8) of the corners intersected from the fitted lines, pixels².

    Each line's error is an offset ``dc`` (at the centroid of its N points, variance s²/N) and a turn
    ``dθ`` (variance s²/Σt², t along the line from the centroid), s² the scatter of its points about it.
    Corner k moves by A⁻¹ (dc + t dθ) of its two lines (A: their normals). The corners of one side are
    correlated: a turn moves them oppositely, an offset alike; so the pose (depth above all) is less
    uncertain than independent corners of the same variance would make it (on renders with noise 2,
    independent corners over-predicted the TP's variance 1.4x for one marker, 1.7x for a 2x2 board)."""
    m = len(points)
    w = valid.astype(float)
    count = np.maximum(w.sum(axis=-1), 1.0)  # (M, 4)
    centre = np.sum(w[..., None] * points, axis=2) / count[..., None]
    d = points - centre[:, :, None]
    rho = np.sum(d * normal[:, :, None], axis=-1) * w
    t = np.sum(d * direction[:, :, None], axis=-1) * w
    s2 = np.sum(rho**2, axis=-1) / np.maximum(count - 2, 1)
    variances = np.stack([s2 / count, s2 / np.maximum(np.sum(t**2, axis=-1), 1e-12)], axis=-1).reshape(m, 8)
    a_inv = np.linalg.inv(pair)  # (M, 4, 2, 2)
    jac = np.zeros((m, 8, 8))  # corners (x0 y0 ... x3 y3) <- (dc0, dθ0, ..., dc3, dθ3)
    for k in range(4):
        for row, line in enumerate(((k - 1) % 4, k)):
            along = np.sum((corners[:, k] - centre[:, line]) * direction[:, line], axis=-1)  # (M,)
            jac[:, 2 * k:2 * k + 2, 2 * line] += a_inv[:, k, :, row]
            jac[:, 2 * k:2 * k + 2, 2 * line + 1] += a_inv[:, k, :, row] * along[:, None]
    return (jac * variances[:, None, :]) @ jac.transpose(0, 2, 1)
