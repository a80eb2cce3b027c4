"""What the camera looks for: one ArUco marker, a grid board, a ChArUco board, or markers on a rigid body.

Every target has one **target frame** (metres): origin at the centre of the marker or board, x to the right
and y up as the target is seen from the front (printed side), z out of the printed face towards the viewer.
(OpenCV's single-marker frame is this frame; OpenCV's board frame, origin at the top-left corner with y
down and z into the board, is converted.) A layout file describes markers on a rigid body in that frame::

    # layout.yaml: marker id -> its four corners (top-left, top-right, bottom-right, bottom-left as printed),
    # metres in the target frame; the markers need not be coplanar
    dictionary: 4X4_50
    markers:
      3: [[-0.06, 0.02, 0], [-0.02, 0.02, 0], [-0.02, -0.02, 0], [-0.06, -0.02, 0]]
      4: [[0.02, 0.02, 0], [0.06, 0.02, 0], [0.06, -0.02, 0], [0.02, -0.02, 0]]

Detection (:func:`detect`) returns the visible object points and their image points (pixels, OpenCV
convention: the centre of the top-left pixel is (0, 0)); a marker id of the target seen twice raises
:class:`DuplicateMarker`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import yaml
from numpy.typing import NDArray
from scipy.linalg import block_diag

from drivers.camera.intrinsics import CameraIntrinsics
from drivers.camera.refinement import refine_corners
from drivers.errors import BadReading

Array = NDArray[np.float64]

#: Corner refinement methods (spec option ``refine``).
REFINEMENTS = {"none": cv2.aruco.CORNER_REFINE_NONE, "subpix": cv2.aruco.CORNER_REFINE_SUBPIX,
               "contour": cv2.aruco.CORNER_REFINE_CONTOUR, "apriltag": cv2.aruco.CORNER_REFINE_APRILTAG,
               "edges": cv2.aruco.CORNER_REFINE_NONE}  # edges: drivers/camera/refinement.py after a plain detection
#: Offset (pixels) added to corners refined by the AprilTag method: OpenCV's AprilTag quad fit puts pixel
#: centres at half-integers (apriltag's own convention), the rest of OpenCV at integers. Measured against
#: ``projectPoints`` on renders whose edges are proven to 0.01 px (tests/drivers/camera/test_renderer.py): after this
#: shift the AprilTag corners are still off by -0.04 px in x and y at every distance and blur tried, the
#: quad fit's own bias (not corrected: the default refinement is ``edges``).
APRILTAG_SHIFT = -0.5
#: Gaussian blur (pixels) before the AprilTag quad segmentation: without it, sensor noise of 2 grey levels
#: makes the segmentation ~10x slower (many noise clusters); the corners are still fitted on the original.
APRILTAG_QUAD_SIGMA = 0.8


class DuplicateMarker(BadReading):
    """A marker id of the target was seen more than once in one frame (a second copy in view)."""


def dictionary_id(name: str) -> int:
    """``4X4_50``, ``ARUCO_ORIGINAL``, ``APRILTAG_36h11``... -> the OpenCV dictionary constant; ValueError."""
    key = "DICT_" + name.upper().removeprefix("DICT_")
    value = getattr(cv2.aruco, key, None)
    if not isinstance(value, int):
        known = sorted(n[5:] for n in dir(cv2.aruco) if n.startswith("DICT_") and not n[-1].islower())
        raise ValueError(f"unknown ArUco dictionary {name!r} (known: {', '.join(known)})")
    return value


@dataclass(frozen=True)
class Target:
    """A marker, board or rigid body of markers. ``kind``: "marker", "grid", "charuco" or "layout";
    ``corners``: marker id -> (4, 3) corners in the target frame, m; ``board``: the OpenCV board (grid,
    charuco; None otherwise); ``extent``: (width, height) of the printed area, m; ``dictionary``: OpenCV id."""

    kind: str
    dictionary: int
    corners: dict[int, Array]
    extent: tuple[float, float]
    board: cv2.aruco.Board | None = None

    @property
    def planar(self) -> bool:
        pts = np.concatenate(list(self.corners.values()))
        return bool(np.ptp(pts[:, 2]) < 1e-9)

    def charuco_points(self) -> Array:
        """(M, 3) chessboard corners of a ChArUco board in the target frame, m (index = ChArUco corner id)."""
        assert isinstance(self.board, cv2.aruco.CharucoBoard)
        return self._from_board(np.asarray(self.board.getChessboardCorners(), dtype=float))

    def _from_board(self, points: Array) -> Array:
        """OpenCV board frame (top-left origin, y down, z in) -> target frame."""
        w, h = self.extent
        return np.column_stack([points[:, 0] - w / 2, h / 2 - points[:, 1], -points[:, 2]])

    def texture(self, pixels_per_metre: float, margin: int = 0) -> tuple[NDArray[np.uint8], Array]:
        """The printed target as an 8-bit image and the 3x3 affine map from target-frame (x, y, 1), m, to
        its pixel coordinates (OpenCV convention). ``margin`` white pixels around it (the quiet zone)."""
        w, h = self.extent
        size = (round(w * pixels_per_metre), round(h * pixels_per_metre))
        if self.kind == "marker":
            (marker_id,) = self.corners
            image = cv2.aruco.generateImageMarker(cv2.aruco.getPredefinedDictionary(self.dictionary), marker_id,
                                                  size[0], borderBits=1)
        elif self.board is not None:
            image = self.board.generateImage(size, marginSize=0, borderBits=1)
        else:
            raise ValueError("a layout of markers has no single printed image; print its markers one by one")
        image = cv2.copyMakeBorder(image, margin, margin, margin, margin, cv2.BORDER_CONSTANT, value=255)
        sx, sy = size[0] / w, size[1] / h
        affine = np.array([[sx, 0, margin + size[0] / 2 - 0.5], [0, -sy, margin + size[1] / 2 - 0.5], [0, 0, 1]])
        return image, affine


def single_marker(marker_id: int, size: float, dictionary: int) -> Target:
    """One marker of side ``size`` m (the black square, border included)."""
    h = size / 2
    corners = np.array([[-h, h, 0], [h, h, 0], [h, -h, 0], [-h, -h, 0]], dtype=float)
    _check_ids([marker_id], dictionary)
    return Target("marker", dictionary, {int(marker_id): corners}, (size, size))


def grid_board(cols: int, rows: int, size: float, gap: float, dictionary: int, first: int = 0) -> Target:
    """A grid of ``cols`` x ``rows`` markers of side ``size`` m, ``gap`` m apart, ids from ``first``."""
    ids = np.arange(first, first + cols * rows, dtype=np.int32)
    _check_ids(ids, dictionary)
    board = cv2.aruco.GridBoard((cols, rows), size, gap, cv2.aruco.getPredefinedDictionary(dictionary), ids)
    extent = (cols * size + (cols - 1) * gap, rows * size + (rows - 1) * gap)
    return _from_opencv_board("grid", board, dictionary, extent)


def charuco_board(cols: int, rows: int, square: float, size: float, dictionary: int, first: int = 0) -> Target:
    """A ChArUco board of ``cols`` x ``rows`` squares of ``square`` m, markers of side ``size`` m."""
    if not size < square:
        raise ValueError(f"ChArUco markers ({size:g} m) must be smaller than the squares ({square:g} m)")
    count = (cols * rows) // 2
    ids = np.arange(first, first + count, dtype=np.int32)
    _check_ids(ids, dictionary)
    board = cv2.aruco.CharucoBoard((cols, rows), square, size, cv2.aruco.getPredefinedDictionary(dictionary), ids)
    return _from_opencv_board("charuco", board, dictionary, (cols * square, rows * square))


def _from_opencv_board(kind: str, board: cv2.aruco.Board, dictionary: int, extent: tuple[float, float]) -> Target:
    target = Target(kind, dictionary, {}, extent, board)
    for marker_id, pts in zip(np.asarray(board.getIds()).reshape(-1), board.getObjPoints(), strict=True):
        target.corners[int(marker_id)] = target._from_board(np.asarray(pts, dtype=float).reshape(4, 3))
    return target


def load_layout(path: str | Path, dictionary: int | None = None) -> Target:
    """Markers on a rigid body from a layout YAML (module docstring); ValueError with one line."""
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (OSError, yaml.YAMLError) as exc:
        raise ValueError(f"layout {path}: cannot be read ({' '.join(str(exc).split())[:120]})") from None
    if not isinstance(data, dict) or not isinstance(data.get("markers"), dict) or not data["markers"]:
        raise ValueError(f"layout {path}: expected a mapping with 'markers: {{ID: [4 corners [x, y, z]]}}'")
    if dictionary is None:
        dictionary = dictionary_id(str(data.get("dictionary", "4X4_50")))
    corners: dict[int, Array] = {}
    for key, value in data["markers"].items():
        pts = np.asarray(value, dtype=float) if _numeric(value) else None
        if not isinstance(key, int) or pts is None or pts.shape != (4, 3) or not np.all(np.isfinite(pts)):
            raise ValueError(f"layout {path}: marker {key!r} needs an integer id and 4 corners [x, y, z] in metres")
        corners[key] = pts
    _check_ids(list(corners), dictionary)
    pts = np.concatenate(list(corners.values()))
    extent = (float(np.ptp(pts[:, 0])), float(np.ptp(pts[:, 1])))
    return Target("layout", dictionary, corners, extent)


def _numeric(value: object) -> bool:
    try:
        np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        return False
    return True


def _check_ids(ids: object, dictionary: int) -> None:
    count = cv2.aruco.getPredefinedDictionary(dictionary).bytesList.shape[0]
    bad = [int(i) for i in np.asarray(ids).reshape(-1) if not 0 <= int(i) < count]
    if bad:
        raise ValueError(f"marker id {bad[0]} is not in the dictionary (ids 0..{count - 1})")


@dataclass(frozen=True)
class Observation:
    """The target's points seen in one frame: ``object_points`` (N, 3) m in the target frame,
    ``image_points`` (N, 2) pixels, ``ids`` the marker ids seen (sorted); ``corner_ids`` the ChArUco
    corner id of each point (ChArUco boards only); ``covariance`` (2N, 2N) pixels² of the image points
    (x0 y0 x1 y1 ...), when the refinement gives one (``edges``)."""

    object_points: Array
    image_points: Array
    ids: tuple[int, ...]
    corner_ids: tuple[int, ...] = ()
    covariance: Array | None = None


class Detector:
    """The OpenCV detector for ``target`` with corner refinement ``refine`` (a key of :data:`REFINEMENTS`)."""

    def __init__(self, target: Target, refine: str = "edges", camera: CameraIntrinsics | None = None) -> None:
        if refine not in REFINEMENTS:
            raise ValueError(f"unknown corner refinement {refine!r} (known: {', '.join(REFINEMENTS)})")
        self.target, self.refine, self.camera = target, refine, camera
        params = cv2.aruco.DetectorParameters()
        params.cornerRefinementMethod = REFINEMENTS[refine]
        params.cornerRefinementMaxIterations = 50
        params.cornerRefinementMinAccuracy = 0.01
        params.aprilTagQuadSigma = APRILTAG_QUAD_SIGMA
        dictionary = cv2.aruco.getPredefinedDictionary(target.dictionary)
        self._modules = int(dictionary.markerSize) + 2 * params.markerBorderBits
        self._aruco = cv2.aruco.ArucoDetector(dictionary, params)
        self._charuco = None
        if target.kind == "charuco":
            charuco_params = cv2.aruco.CharucoParameters()
            charuco_params.tryRefineMarkers = True
            self._charuco = cv2.aruco.CharucoDetector(target.board, charuco_params, params)
            self._charuco_points = target.charuco_points()

    def markers(self, image: NDArray[np.uint8]) -> tuple[list[Array], list[int]]:
        """All markers of the dictionary in ``image``: corners (4, 2) pixels each and their ids."""
        corners, ids, _ = self._markers(image)
        return corners, ids

    def _markers(self, image: NDArray[np.uint8]) -> tuple[list[Array], list[int], list[Array | None]]:
        """:meth:`markers` and each marker's (8, 8) corner covariance (pixels², ``refine=edges`` only)."""
        gray = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        corners, ids, _ = self._aruco.detectMarkers(gray)
        if ids is None:
            return [], [], []
        shift = APRILTAG_SHIFT if self.refine == "apriltag" else 0.0
        found = [np.asarray(c, dtype=float).reshape(4, 2) + shift for c in corners]
        covariances: list[Array | None] = [None] * len(found)
        if self.refine == "edges":
            cam = self.camera
            found, covariances = refine_corners(gray, found, self._modules, None if cam is None else cam.matrix,
                                                None if cam is None else cam.distortion)
        return found, [int(i) for i in ids.reshape(-1)], covariances

    def detect(self, image: NDArray[np.uint8]) -> Observation:
        """The target's visible points in ``image`` (possibly none); DuplicateMarker for an id seen twice.
        With ``refine=edges`` a marker whose edges cannot be fitted is left out (its unrefined corners are
        off by up to a pixel), except as a ChArUco board's anchor for its chessboard corners."""
        gray = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        corners, ids, covariances = self._markers(gray)
        mine = [i for i in ids if i in self.target.corners]
        twice = sorted({i for i in mine if mine.count(i) > 1})
        if twice:
            raise DuplicateMarker(f"marker id {twice[0]} is seen {mine.count(twice[0])} times in one frame "
                                  "(a second copy in view?)")
        if self._charuco is not None:
            return self._detect_charuco(gray, corners, ids)
        obj, img, seen, covs = [], [], [], []
        for c, i, v in zip(corners, ids, covariances, strict=True):
            if self.refine == "edges" and v is None:
                continue  # its edges could not be fitted (cut by the image border, too little contrast)
            if i in self.target.corners:
                obj.append(self.target.corners[i])
                img.append(c)
                seen.append(i)
                covs.append(v)
        if not seen:
            return Observation(np.zeros((0, 3)), np.zeros((0, 2)), ())
        cov = None if any(v is None for v in covs) else block_diag(*covs)
        return Observation(np.concatenate(obj), np.concatenate(img), tuple(sorted(seen)), covariance=cov)

    def _detect_charuco(self, gray: NDArray[np.uint8], corners: list[Array], ids: list[int]) -> Observation:
        assert self._charuco is not None
        keep = [k for k, i in enumerate(ids) if i in self.target.corners]
        if not keep:
            return Observation(np.zeros((0, 3)), np.zeros((0, 2)), ())
        # markers found above (with their refinement) feed the chessboard-corner interpolation
        marker_corners = tuple(np.asarray(corners[k], dtype=np.float32).reshape(1, 4, 2) for k in keep)
        marker_ids = np.array([ids[k] for k in keep], dtype=np.int32).reshape(-1, 1)
        ch_corners, ch_ids, _, _ = self._charuco.detectBoard(gray, markerCorners=marker_corners,
                                                             markerIds=marker_ids)
        seen = tuple(sorted(ids[k] for k in keep))
        if ch_ids is None or len(ch_ids) == 0:
            return Observation(np.zeros((0, 3)), np.zeros((0, 2)), seen)
        index = ch_ids.reshape(-1)
        return Observation(self._charuco_points[index], np.asarray(ch_corners, dtype=float).reshape(-1, 2), seen,
                           tuple(int(i) for i in index))
