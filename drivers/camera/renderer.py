"""Rendered camera images: a printed target seen through a pinhole camera with distortion, blur and noise.

Only the pixels are simulated; the detection that reads them is OpenCV's. :func:`render` draws a target
(its :meth:`~drivers.camera.targets.Target.texture`) at a pose in the camera frame: every output pixel is
supersampled, its ray undistorted with the camera's own model (``cv2.undistortPoints``, iterated to 1e-10), intersected
with the target plane, and the texture sampled there; the supersamples are averaged (area filter), then
the image is blurred (Gaussian, and motion along a line) and Gaussian sensor noise is added. Pixel
convention: OpenCV's (the centre of the top-left pixel is (0, 0)).

:class:`SimulatedCamera` is a frame source (see drivers/camera/sources.py) that renders the target mounted
on the simulated robot's flange (``rig.flange_pose()``) at each frame's time on the rig's clock.

Its stream (continuous motion): frame k is exposed at ``τ_k = τ_0 + k / fps`` (s, rig clock; τ_0 when the
stream starts), drawn with the arm's true pose at τ_k, stamped and delivered ``latency`` s later (the camera's
timestamp ``τ_k + latency``: a sample stamped t shows the arm at rig time ``t - latency``). ``capture`` (called
from the tracker's ``read_stream``) renders every frame delivered by ``clock.now()`` in the caller's thread, the
only one that reads the rig, and queues it for detection, waiting for room (rendering costs real CPU; on a
virtual clock the simulated time stands still meanwhile). ``drop`` loses a frame with that probability (its
number is skipped); ``lost=(D, S)`` hides the target in the frames exposed from S to S + D s into the stream.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from drivers.camera.imperfections import STILL_PX, Imperfections, image_motion
from drivers.camera.intrinsics import CameraIntrinsics
from drivers.camera.sources import Frame, FrameQueue
from drivers.camera.targets import Target
from drivers.errors import ConnectionFailed, DeviceTimeout

Array = NDArray[np.float64]
BLACK, WHITE, BACKGROUND = 30.0, 220.0, 110.0  # grey levels of the print and of what lies behind it
WINDOW_PAD = 2  # output pixels traced around the target's projected outline
STREAM_QUEUE = 2  # rendered frames waiting for detection before the simulated camera waits for room
_EPS = 1e-6  # s: time comparisons on the rig's clock (epoch values near 1.8e9 s)


@dataclass(frozen=True)
class Optics:
    """Image degradations: ``noise`` grey levels (of 255) of Gaussian sensor noise, ``blur`` pixels (sigma of
    a Gaussian defocus), ``motion`` pixels (length of a horizontal motion streak), ``supersample`` rays per
    pixel side."""

    noise: float = 0.0
    blur: float = 0.0
    motion: float = 0.0
    supersample: int = 3


class _Rays:
    """Undistorted normalised rays (x/z, y/z) of every supersample of a camera's image, computed once."""

    def __init__(self, camera: CameraIntrinsics, supersample: int) -> None:
        s = supersample
        w, h = camera.width * s, camera.height * s
        u = (np.arange(w, dtype=np.float64) + 0.5) / s - 0.5
        v = (np.arange(h, dtype=np.float64) + 0.5) / s - 0.5
        uu, vv = np.meshgrid(u, v)
        pixels = np.stack([uu.ravel(), vv.ravel()], axis=1).reshape(-1, 1, 2)
        if np.any(camera.distortion):
            criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 20, 1e-10)
            rays = cv2.undistortPoints(pixels, camera.matrix, camera.distortion, None, None, None, criteria)
            rays = rays.reshape(h, w, 2)
        else:
            k = camera.matrix
            y = (vv - k[1, 2]) / k[1, 1]
            rays = np.stack([(uu - k[0, 2] - k[0, 1] * y) / k[0, 0], y], axis=2)
        self.x = rays[..., 0].astype(np.float32)
        self.y = rays[..., 1].astype(np.float32)
        self.shape, self.supersample = (h, w), s


def texture_scale(target: Target, approximate: float) -> float:
    """Texels per metre near ``approximate`` (and not below it) that put every edge of the printed target on
    a texel boundary: a whole number of texels per module (marker bit), per gap of a grid board, per square
    and per square-to-marker margin of a ChArUco board. Otherwise ``generateImage`` rounds each marker's
    position to a texel, which moved the corners of a 3x3 grid board by up to 0.35 texel (0.14 px at
    0.5 m). Falls back to ``approximate`` when no scale within a factor 2 fits (a layout, odd sizes)."""
    modules = cv2.aruco.getPredefinedDictionary(target.dictionary).markerSize + 2
    side = float(np.linalg.norm(np.diff(next(iter(target.corners.values()))[:2], axis=0)))
    lengths = [side / modules]
    board = target.board
    if isinstance(board, cv2.aruco.CharucoBoard):
        lengths += [board.getSquareLength(), (board.getSquareLength() - board.getMarkerLength()) / 2]
    elif isinstance(board, cv2.aruco.GridBoard):
        lengths.append(board.getMarkerSeparation())
    lengths += list(target.extent)
    base = lengths[0]
    for per_module in range(max(int(np.ceil(approximate * base - 1e-9)), 1), int(2 * approximate * base) + 2):
        ppm = per_module / base
        if all(abs(q * ppm - round(q * ppm)) < 1e-3 for q in lengths):  # OpenCV keeps float32 lengths
            return ppm
    return approximate


class Renderer:
    """Renders one target through one camera (the rays and the texture are prepared once). ``imperfections``
    (drivers/camera/imperfections.py): the lens renders with its residual distortion (``camera`` is the calibrated
    one), the print is bowed, the light uneven."""

    def __init__(self, target: Target, camera: CameraIntrinsics, optics: Optics | None = None,
                 pixels_per_metre: float | None = None, imperfections: Imperfections | None = None) -> None:
        self.imperfections = imperfections or Imperfections()
        self.target, self.camera, self.optics = target, self.imperfections.lens(camera), optics or Optics()
        self._rays = _Rays(self.camera, self.optics.supersample)
        ppm = texture_scale(target, pixels_per_metre or 40.0 / (min(target.extent) / 10))
        margin = max(int(0.15 * min(target.extent) * ppm), 2)  # the white quiet zone around the print
        texture, self._affine = target.texture(ppm, margin)
        self._texture = (BLACK + (WHITE - BLACK) * (texture.astype(np.float32) / 255.0)).astype(np.float32)
        # a little blur keeps the print's edges from aliasing on the supersample grid (it does not move them)
        self._pyramid = [cv2.GaussianBlur(self._texture, (0, 0), 0.5)]
        while min(self._pyramid[-1].shape) > 64:
            self._pyramid.append(cv2.pyrDown(self._pyramid[-1]))
        self._texels_per_metre = abs(self._affine[0, 0])

    def render(self, poses: list[Array], rng: np.random.Generator | None = None,
               crop: bool = True) -> NDArray[np.uint8]:
        """An 8-bit grey image with the target at each pose in ``poses`` (4x4, camera frame <- target frame,
        metres; several poses draw several copies); ``rng`` draws the sensor noise. Only the window of whole
        pixels that holds the targets is traced (``crop=False``: every pixel; the image is the same)."""
        return self.finish(self.scene([poses], crop), rng)

    def scene(self, bands: list[list[Array]], crop: bool = True) -> NDArray[np.float32]:
        """The scene's grey levels (float, before light, blur and noise) with the rows cut into ``len(bands)``
        equal bands, band j showing the targets at the poses ``bands[j]`` (a rolling shutter; one band: one
        time)."""
        s = self._rays.supersample
        height, width = self._rays.shape[0] // s, self._rays.shape[1] // s
        bands = [[np.asarray(pose, dtype=float) for pose in poses] for poses in bands]
        every = [pose for poses in bands for pose in poses]
        boxes = [self._window(pose) if crop else (0, height, 0, width) for pose in every]
        image = np.full((height, width), BACKGROUND, dtype=np.float32)
        if boxes:
            r0, r1 = min(b[0] for b in boxes), max(b[1] for b in boxes)
            c0, c1 = min(b[2] for b in boxes), max(b[3] for b in boxes)
            acc = np.full(((r1 - r0) * s, (c1 - c0) * s), BACKGROUND, dtype=np.float32)
            depth = np.full(acc.shape, np.inf, dtype=np.float32)
            edges = np.linspace(0, height, len(bands) + 1).round().astype(int)
            for j, poses in enumerate(bands):
                lo, hi = max(int(edges[j]), r0), min(int(edges[j + 1]), r1)
                if hi <= lo:
                    continue
                rows = slice((lo - r0) * s, (hi - r0) * s)  # a view: drawing into it draws into acc
                for pose in poses:
                    self._draw(pose, acc[rows], depth[rows], (lo * s, c0 * s))
            image[r0:r1, c0:c1] = cv2.resize(acc, (c1 - c0, r1 - r0), interpolation=cv2.INTER_AREA) if s > 1 else acc
        return image

    def finish(self, scene: NDArray[np.float32], rng: np.random.Generator | None = None) -> NDArray[np.uint8]:
        """The 8-bit image of a ``scene``: lit, blurred (defocus, motion streak), with sensor noise drawn by ``rng``."""
        image = self.imperfections.light(scene)
        o = self.optics
        if o.blur > 0:
            image = cv2.GaussianBlur(image, (0, 0), o.blur)
        if o.motion > 0:
            length = max(round(o.motion), 1)
            kernel = np.full((1, length), 1.0 / length, dtype=np.float32)
            image = cv2.filter2D(image, -1, kernel, borderType=cv2.BORDER_REFLECT)
        if o.noise > 0:
            rng = rng or np.random.default_rng()
            image = image + rng.normal(0.0, o.noise, image.shape).astype(np.float32)
        return np.clip(np.rint(image), 0, 255).astype(np.uint8)

    def _window(self, pose: Array) -> tuple[int, int, int, int]:
        """Rows r0:r1 and columns c0:c1 (output pixels) that hold every pixel the printed target (its quiet zone
        included) can touch at ``pose``: its outline projected (``cv2.projectPoints``, 32 points a side), widened
        by :data:`WINDOW_PAD` pixels; the whole image when the outline leaves it or reaches behind the camera
        (a distortion model is not to be trusted outside the image)."""
        s = self._rays.supersample
        height, width = self._rays.shape[0] // s, self._rays.shape[1] // s
        th, tw = self._pyramid[0].shape
        corners = np.linalg.solve(self._affine, np.array([[-0.5, -0.5, 1], [tw - 0.5, -0.5, 1], [tw - 0.5, th - 0.5, 1],
                                                          [-0.5, th - 0.5, 1]]).T).T  # target (x, y, 1), m
        steps = np.linspace(0.0, 1.0, 32, endpoint=False)[:, None]
        outline = np.vstack([a + steps * (b - a) for a, b in zip(corners, np.roll(corners, -1, axis=0), strict=True)])
        points = outline[:, :2] @ pose[:3, :2].T + pose[:3, 3]
        if np.any(points[:, 2] <= 1e-6):
            return 0, height, 0, width
        uv = cv2.projectPoints(points, np.zeros(3), np.zeros(3), self.camera.matrix, self.camera.distortion)[0]
        u, v = uv[:, 0, 0], uv[:, 0, 1]
        if u.min() < -0.5 or v.min() < -0.5 or u.max() > width - 0.5 or v.max() > height - 0.5:
            return 0, height, 0, width
        return (max(int(np.floor(v.min())) - WINDOW_PAD, 0), min(int(np.ceil(v.max())) + WINDOW_PAD + 1, height),
                max(int(np.floor(u.min())) - WINDOW_PAD, 0), min(int(np.ceil(u.max())) + WINDOW_PAD + 1, width))

    def _draw(self, pose: Array, acc: NDArray[np.float32], depth: NDArray[np.float32], origin: tuple[int, int]) -> None:
        """Draw the target at ``pose`` into the supersampled window ``acc`` (and its ``depth``) whose top-left
        supersample is ``origin`` (row, column) of the whole supersampled image."""
        r, t = pose[:3, :3], pose[:3, 3]
        plane = np.column_stack([r[:, 0], r[:, 1], t])  # target (x, y, 1) -> camera ray scaled by depth
        try:
            to_plane = np.linalg.inv(plane)
        except np.linalg.LinAlgError:
            return  # seen edge-on
        level = self._level(pose)
        scale = np.diag([0.5**level, 0.5**level, 1.0])  # pyrDown keeps texel j of level L at 2^L·j of level 0
        m = (scale @ self._affine @ to_plane).astype(np.float32)
        rows = slice(origin[0], origin[0] + acc.shape[0])
        cols = slice(origin[1], origin[1] + acc.shape[1])
        x, y = self._rays.x[rows, cols], self._rays.y[rows, cols]
        if self.imperfections.bow:
            map_x, map_y, z = self._bowed(pose, (scale @ self._affine).astype(np.float32), x, y)
            q2 = 1.0 / z
        else:
            q2 = to_plane[2, 0] * x + to_plane[2, 1] * y + to_plane[2, 2]  # 1 / depth along the ray
            with np.errstate(divide="ignore", invalid="ignore"):
                wz = m[2, 0] * x + m[2, 1] * y + m[2, 2]
                map_x = (m[0, 0] * x + m[0, 1] * y + m[0, 2]) / wz
                map_y = (m[1, 0] * x + m[1, 1] * y + m[1, 2]) / wz
                z = 1.0 / q2
        texture = self._pyramid[level]
        th, tw = texture.shape
        inside = (q2 > 0) & (map_x > -0.5) & (map_x < tw - 0.5) & (map_y > -0.5) & (map_y < th - 0.5) & (z < depth)
        if not inside.any():
            return
        sampled = cv2.remap(texture, np.where(inside, map_x, -10).astype(np.float32),
                            np.where(inside, map_y, -10).astype(np.float32), cv2.INTER_LINEAR,
                            borderMode=cv2.BORDER_REPLICATE)
        acc[inside] = sampled[inside]
        depth[inside] = z[inside]

    def _bowed(self, pose: Array, affine: NDArray[np.float32], x: NDArray[np.float32], y: NDArray[np.float32]
               ) -> tuple[NDArray[np.float32], NDArray[np.float32], NDArray[np.float32]]:
        """Where the rays (x/z, y/z) meet the bowed print (drivers/camera/imperfections.py: its height h(u) along
        its z axis at u along its x axis): texel coordinates through ``affine`` (target (u, v, 1) -> texel) and
        depth. Each ray meets the plane lifted by h at the last point's u; three rounds (a 0.5 mm bow's slope is
        below 0.01, so each round shrinks the error a hundredfold)."""
        r, t = pose[:3, :3].astype(np.float32), pose[:3, 3].astype(np.float32)
        n, a, b = r[:, 2], r[:, 0], r[:, 1]
        bow, half = np.float32(self.imperfections.bow), np.float32(self.target.extent[0] / 2)
        with np.errstate(divide="ignore", invalid="ignore"):
            facing = n[0] * x + n[1] * y + n[2]  # n · ray
            height = np.zeros_like(x)
            for _ in range(3):
                depth = (float(n @ t) + height) / facing
                px, py, pz = depth * x - t[0], depth * y - t[1], depth - t[2]
                u = a[0] * px + a[1] * py + a[2] * pz
                height = bow * (1.0 - (u / half) ** 2)
            v = b[0] * px + b[1] * py + b[2] * pz
            map_x = affine[0, 0] * u + affine[0, 1] * v + affine[0, 2]
            map_y = affine[1, 0] * u + affine[1, 1] * v + affine[1, 2]
        return map_x, map_y, depth

    def _level(self, pose: Array) -> int:
        """Pyramid level whose texels are at least one supersample wide at the target's distance."""
        f = float(self.camera.matrix[0, 0]) * self._rays.supersample
        samples_per_metre = f / max(float(pose[2, 3]), 1e-6)
        ratio = self._texels_per_metre / samples_per_metre
        return int(np.clip(np.ceil(np.log2(max(ratio, 1.0))), 0, len(self._pyramid) - 1))


class SimulatedCamera:
    """A frame source rendering ``target`` mounted on the simulated robot's flange.

    ``mount``: 4x4, flange frame <- target frame (m). One frame every ``1/fps`` s on the rig's clock, drawn
    at the arm's actual pose at that time and delivered and stamped ``latency`` s later; ``imperfections``: a real
    camera's errors (drivers/camera/imperfections.py: rows and the exposure at their own times). The rig's
    tracker faults act per measurement (:meth:`start_measurement`): ``target_lost`` hides the target,
    ``bad_reading`` puts a second copy of it in view (duplicate ids), ``slow`` delivers no frames, ``disconnect``
    loses the camera until ``open()``.
    Streams: the module docstring (``drop`` a probability, ``lost`` (duration, start) s).
    """

    def __init__(self, rig: object, target: Target, camera: CameraIntrinsics, mount: Array,
                 optics: Optics | None = None, fps: float = 30.0, latency: float = 0.0, drop: float = 0.0,
                 lost: tuple[float, float] = (0.0, 0.0), imperfections: Imperfections | None = None) -> None:
        self.rig, self.camera, self.mount, self.fps = rig, camera, np.asarray(mount, dtype=float), fps
        self.latency, self.drop, self.lost = latency, drop, lost
        self.renderer = Renderer(target, camera, optics, imperfections=imperfections)
        self._rng = np.random.default_rng([getattr(rig, "tracker_seed", 0), 7])
        self._drop_rng = np.random.default_rng([getattr(rig, "tracker_seed", 0), 8])
        self._fault: str | None = None
        self._queue: FrameQueue | None = None
        self._tau0, self._next = 0.0, 0  # the stream's first exposure (rig clock, s) and next frame number
        self.description = f"simulated camera {camera.width}x{camera.height}"
        self.rate = fps
        self.stamps = f"simulated: the rig's clock at exposure + latency {latency:g} s"
        self.latency_basis = "the simulated camera's"

    def now(self) -> float:
        """The rig's clock (s), on which ``grab`` stamps its frames (drivers/camera/latency.py)."""
        return float(self.rig.clock.now())  # type: ignore[attr-defined]

    def target_pose(self, t: float) -> Array:
        """The target's pose at rig time ``t``: 4x4, camera frame <- target frame (m): on the flange, at ``mount``."""
        return self.rig.flange_pose(t) @ self.mount  # type: ignore[attr-defined]

    def open(self, timeout: float) -> None:
        self.rig.tracker_connected = True  # type: ignore[attr-defined]

    def close(self) -> None:
        self.stop_frames()
        self.rig.tracker_connected = False  # type: ignore[attr-defined]

    def start_measurement(self) -> None:
        """A new measurement begins: count it on the rig and take its scheduled fault, if any."""
        rig = self.rig
        number = rig.measurements = rig.measurements + 1  # type: ignore[attr-defined]
        self._fault = rig._take("tracker", number)  # type: ignore[attr-defined]
        if self._fault == "disconnect":
            rig.tracker_connected = False  # type: ignore[attr-defined]

    def grab(self, timeout: float) -> tuple[NDArray[np.uint8], float]:
        """The next frame and its timestamp (s, rig clock: when it is delivered, ``latency`` s after its exposure);
        DeviceTimeout / ConnectionFailed for the faults."""
        rig = self.rig
        self._require_link()
        if self._fault == "slow":
            rig.clock.sleep(timeout)  # type: ignore[attr-defined]
            raise DeviceTimeout(f"the simulated camera delivered no frame within {timeout:g} s")
        rig.clock.sleep(1.0 / self.fps)  # type: ignore[attr-defined]
        t = rig.clock.now()  # type: ignore[attr-defined]
        return self._image(t - self.latency, self._fault == "target_lost", self._fault == "bad_reading"), t

    def _poses(self, t: float, hidden: bool, twin: bool) -> list[Array]:
        """The targets in view at rig time ``t``: none when ``hidden``, with a second copy beside it if ``twin``."""
        if hidden:
            return []
        pose = self.target_pose(t)
        if not twin:
            return [pose]
        twin = pose.copy()
        twin[:3, 3] += pose[:3, 0] * 1.6 * max(self.renderer.target.extent)  # beside the real one
        return [pose, twin]

    def _image(self, t: float, hidden: bool = False, twin: bool = False) -> NDArray[np.uint8]:
        """The frame whose exposure starts at rig time ``t`` (row 0's; the rolling shutter's rows and the exposure's
        parts each at their own time, rendered once when the arm stands still meanwhile)."""
        renderer = self.renderer
        imperfections = renderer.imperfections
        if not imperfections.timed:
            return renderer.render(self._poses(t, hidden, twin), self._rng)
        exposure, rows = imperfections.times(self.camera.height)
        scenes = [[self._poses(t + e + r, hidden, twin) for r in rows] for e in exposure]
        outline = np.array([[x, y, 0.0] for x in (-0.5, 0.5) for y in (-0.5, 0.5)]) * [*renderer.target.extent, 0]
        motion = image_motion([poses for scene in scenes for poses in scene], outline, float(self.camera.matrix[0, 0]))
        if motion < STILL_PX:
            return renderer.render(scenes[0][0], self._rng)
        mean = np.mean([renderer.scene(scene) for scene in scenes], axis=0).astype(np.float32)
        return renderer.finish(mean, self._rng)

    # --- the stream -------------------------------------------------------------------------------------------

    def start_frames(self, timeout: float) -> tuple[FrameQueue, float]:
        """Start the stream: the first frame is exposed now. Returns the queue it fills and the rate (Hz)."""
        self._require_link()
        self._queue = FrameQueue(STREAM_QUEUE)
        self._tau0, self._next = self.rig.clock.now(), 0  # type: ignore[attr-defined]
        return self._queue, self.fps

    def capture(self, timeout: float) -> None:
        """Render and queue every frame delivered by now (waiting up to ``timeout`` s for room for each one);
        ConnectionFailed without a link, DeviceTimeout when detection does not take a frame in time."""
        queue = self._queue
        if queue is None:
            return
        self._require_link()
        rig = self.rig
        now = rig.clock.now()  # type: ignore[attr-defined]
        last = math.floor((now - self.latency - self._tau0) * self.fps + _EPS)
        lo, hi = self.lost[1], self.lost[1] + self.lost[0]
        while self._next <= last:
            k = self._next
            self._next += 1
            if self.drop > 0 and self._drop_rng.random() < self.drop:
                continue  # lost by the camera: its number is skipped
            tau = self._tau0 + k / self.fps
            hidden = self.lost[0] > 0 and lo - _EPS <= tau - self._tau0 <= hi + _EPS
            queue.put(Frame(k, tau + self.latency, self._image(tau, hidden)), timeout)

    def stop_frames(self) -> None:
        """End the stream (frames not yet delivered are never made)."""
        if self._queue is not None:
            self._queue.close()
        self._queue = None

    def _require_link(self) -> None:
        if not self.rig.tracker_connected:  # type: ignore[attr-defined]
            raise ConnectionFailed("the simulated camera is not connected (lost link: connect again)")
