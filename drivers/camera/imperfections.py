"""A real camera's errors for the simulated one (``aruco:sim?...``): what the calibration, the sensor, the light and
the print get wrong, each an option of the spec (all off by default).

Options (units: metres, seconds, pixels, grey levels of 255):

- ``dk1``, ``dk2``: **distortion left after calibration**: the lens renders with radial coefficients k1 + dk1 and
  k2 + dk2 while the detection uses the calibrated k1, k2 (``dk1=0.0015`` moves a 1280x720, 60° camera's corner
  pixels by about 0.5 px);
- ``dfocal``, ``dcx``, ``dcy``: **focal length and principal point left off by the calibration**: the lens renders
  with fx and fy times 1 + ``dfocal`` (relative; e.g. 0.002) and its principal point ``dcx``, ``dcy`` px off (e.g.
  3, -2) while the detection uses the calibrated ones (a real calibration's are typically 0.1-0.5 % and 1-5 px off;
  a relative focal error moves a view's distance by about that fraction of it);
- ``shutter``: **rolling shutter**, s to read the rows out (top row first; e.g. 0.03): row v is exposed
  ``shutter · v / height`` s after row 0 (the image is rendered in :data:`SHUTTER_BANDS` bands of rows, each at the
  arm's pose at its own time; a target that moves less than :data:`STILL_PX` over the frame is rendered once, at
  the frame's time: a still arm's image is the one without these options);
- ``exposure``: **motion blur**, s the shutter stays open (e.g. 0.01): the image is the mean of :data:`EXPOSURE_SAMPLES`
  renderings spread over it;
- ``gain``, ``gradient``, ``glare``: **lighting**: the scene's brightness times ``gain`` (1; below 1 a dim cell with
  the same sensor noise), times ``1 + gradient · d`` with d from -1 at the image's top-left corner to +1 at its
  bottom-right (uneven light, vignetting), plus a specular patch of ``glare`` grey levels at its peak (a Gaussian
  spot of sigma 1/12 of the image width at 62 % across and 38 % down, saturating at 255: a lamp's reflection);
- ``bow``: **a board that is not flat**: the print curls into a cylinder about its y axis, its centre ``bow`` m
  out of the plane of its left and right edges (z = bow · (1 - (2x / width)²), towards the camera; negative: away).

The frame's time (its stamp minus ``latency``) is the start of row 0's exposure. ``latency`` (drivers/camera/tracker.py)
delays the delivery: a frame delivered at rig time t was exposed at t - latency. A stop-and-go plan measures a still
arm: ``shutter``, ``exposure`` and ``latency`` change nothing as long as the arm has been still for ``latency`` +
``shutter`` + ``exposure`` s before the reading (``acquire``'s settling: 0.5 s); docs/benchmarks.md, section 24a.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from drivers.camera.intrinsics import CameraIntrinsics

Array = NDArray[np.float64]
OPTIONS = ("dk1", "dk2", "dfocal", "dcx", "dcy", "shutter", "exposure", "gain", "gradient", "glare", "bow")
SHUTTER_BANDS = 24  # bands of rows rendered at one time each (a 720-row image: 30 rows a band)
EXPOSURE_SAMPLES = 5  # renderings averaged over an exposure
GLARE_CENTRE = (0.62, 0.38)  # the specular patch's centre, share of the image's width and height
GLARE_WIDTH = 1.0 / 12.0  # its Gaussian sigma, share of the image's width
STILL_PX = 0.002  # px: a frame whose target moves less is rendered at one time (the corners' noise: ~0.03 px)


@dataclass(frozen=True)
class Imperfections:
    """The options of the module docstring, typed; all zero (gain 1) is a perfect camera."""

    dk1: float = 0.0
    dk2: float = 0.0
    dfocal: float = 0.0
    dcx: float = 0.0
    dcy: float = 0.0
    shutter: float = 0.0
    exposure: float = 0.0
    gain: float = 1.0
    gradient: float = 0.0
    glare: float = 0.0
    bow: float = 0.0

    @property
    def timed(self) -> bool:
        """Whether rows or parts of the exposure see the arm at different times."""
        return self.shutter > 0 or self.exposure > 0

    def lens(self, calibrated: CameraIntrinsics) -> CameraIntrinsics:
        """The true lens: ``calibrated`` with its k1, k2 off by dk1, dk2, its focal lengths by the factor 1 + dfocal
        and its principal point by dcx, dcy px."""
        if self.dk1 == 0 and self.dk2 == 0 and self.dfocal == 0 and self.dcx == 0 and self.dcy == 0:
            return calibrated
        distortion, matrix = calibrated.distortion.copy(), calibrated.matrix.copy()
        distortion[:2] += [self.dk1, self.dk2]
        matrix[:2, :2] *= 1.0 + self.dfocal
        matrix[:2, 2] += [self.dcx, self.dcy]
        return replace(calibrated, matrix=matrix, distortion=distortion)

    def times(self, height: int) -> tuple[Array, Array]:
        """When each part of a frame is exposed, s after the frame's time: the exposure's sample times (k,) and the
        row bands' offsets (b,), band j holding rows ``j·height/b`` up to the next band's."""
        exposure = (np.arange(EXPOSURE_SAMPLES) + 0.5) / EXPOSURE_SAMPLES * self.exposure if self.exposure > 0 else \
            np.zeros(1)
        bands = SHUTTER_BANDS if self.shutter > 0 else 1
        rows = (np.arange(bands) + 0.5) / bands * height
        return exposure, self.shutter * rows / height

    def light(self, image: NDArray[np.float32]) -> NDArray[np.float32]:
        """The scene ``image`` (grey levels, float) under this lighting (before blur and noise)."""
        if self.gain == 1 and self.gradient == 0 and self.glare == 0:
            return image
        h, w = image.shape
        v, u = np.mgrid[0:h, 0:w].astype(np.float32)
        out = image * np.float32(self.gain)
        if self.gradient:
            out = out * (1.0 + np.float32(self.gradient) * (u / max(w - 1, 1) + v / max(h - 1, 1) - 1.0))
        if self.glare:
            cu, cv, s = GLARE_CENTRE[0] * w, GLARE_CENTRE[1] * h, GLARE_WIDTH * w
            out = out + np.float32(self.glare) * np.exp(-((u - cu) ** 2 + (v - cv) ** 2) / np.float32(2 * s * s))
        return out.astype(np.float32)


def parse(raw: dict[str, Any]) -> Imperfections:
    """The imperfections among an ``aruco:sim`` spec's options ``raw`` (strings); ValueError naming the option."""
    values: dict[str, float] = {}
    for key in OPTIONS:
        if key not in raw:
            continue
        try:
            value = float(raw[key])
        except (TypeError, ValueError):
            raise ValueError(f"option {key}={raw[key]} must be a number") from None
        if not math.isfinite(value):
            raise ValueError(f"option {key}={raw[key]} must be finite")
        if key in ("shutter", "exposure", "glare") and value < 0:
            raise ValueError(f"option {key}={raw[key]} must be >= 0")
        if key == "gain" and value <= 0:
            raise ValueError(f"option gain={raw[key]} must be > 0")
        if key == "gradient" and not abs(value) < 1:
            raise ValueError(f"option gradient={raw[key]} must lie between -1 and 1")
        if key == "dfocal" and not abs(value) <= 0.1:
            raise ValueError(f"option dfocal={raw[key]} must be within ±0.1 (relative)")
        if key in ("dcx", "dcy") and not abs(value) <= 100:
            raise ValueError(f"option {key}={raw[key]} must be within ±100 px")
        if key == "bow" and not abs(value) <= 0.05:
            raise ValueError(f"option bow={raw[key]} must be within ±0.05 m")
        values[key] = value
    return Imperfections(**values)


def image_motion(groups: list[list[Array]], points: Array, focal: float) -> float:
    """The largest motion in the image, px, of the target ``points`` (k, 3: target frame, m) between the first group
    of poses (4x4, camera <- target) and any other (lateral motion over depth, times the ``focal`` length, px)."""
    homogeneous = np.column_stack([points, np.ones(len(points))])
    first = [pose @ homogeneous.T for pose in groups[0]]
    largest = 0.0
    for group in groups[1:]:
        if len(group) != len(first):
            return math.inf
        for pose, seen in zip(group, first, strict=True):
            shift = pose @ homogeneous.T - seen
            depth = np.maximum(seen[2], 1e-6)
            largest = max(largest, float(np.max(np.hypot(shift[0], shift[1]) / depth)) * focal)
    return largest
