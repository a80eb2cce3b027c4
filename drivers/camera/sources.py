"""Where camera frames come from: a live camera, a video file, or a folder / glob of images (replay).

Every source has ``open(timeout)``, ``close()``, ``start_measurement()`` (a hook; the simulated camera in
drivers/camera/renderer.py counts measurements there) and ``grab(timeout) -> (image, timestamp)``:

- :class:`LiveCamera` (``cv2.VideoCapture`` of a camera index or a device path): a reader thread keeps
  only the newest frame, and ``grab`` returns a frame captured after it was called, so nothing from before
  the robot settled is measured. No new frame within the timeout: DeviceTimeout.
- :class:`VideoReplay` (a video file) and :class:`ImageReplay` (a folder or a glob of images, in name
  order): frames in order, one per ``grab``; at the end, ConnectionFailed (the replay is over).

Timestamps are seconds since the epoch (the time the frame arrived; for a replay, the time it was read).
"""

from __future__ import annotations

import glob
import threading
import time
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from drivers.errors import BadReading, ConnectionFailed, DeviceTimeout

Image = NDArray[np.uint8]
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm", ".webp")


class LiveCamera:
    """A camera through ``cv2.VideoCapture``: ``device`` an index (int) or a path such as /dev/video0;
    ``width``/``height`` the requested frame size (0: the camera's default)."""

    def __init__(self, device: int | str, width: int = 0, height: int = 0) -> None:
        self.device, self.width, self.height = device, width, height
        self.description = f"camera {device}"
        self._capture: cv2.VideoCapture | None = None
        self._thread: threading.Thread | None = None
        self._lock = threading.Condition()
        self._frame: tuple[Image, float] | None = None
        self._running = False

    def open(self, timeout: float) -> None:
        self.close()
        capture = cv2.VideoCapture(self.device)
        if not capture.isOpened():
            raise ConnectionFailed(f"cannot open {self.description} (unplugged, busy, or no permission?)")
        if self.width and self.height:
            capture.set(cv2.CAP_PROP_FRAME_WIDTH, self.width)
            capture.set(cv2.CAP_PROP_FRAME_HEIGHT, self.height)
        self._capture, self._running = capture, True
        self._thread = threading.Thread(target=self._read_loop, name=f"camera-{self.device}", daemon=True)
        self._thread.start()
        self.grab(timeout)  # the first frame proves the camera delivers

    def _read_loop(self) -> None:
        capture = self._capture
        while self._running and capture is not None:
            ok, frame = capture.read()
            if not ok:
                time.sleep(0.01)
                continue
            with self._lock:
                self._frame = (frame, time.time())
                self._lock.notify_all()

    def start_measurement(self) -> None:
        """Nothing to do: ``grab`` already waits for a fresh frame."""

    def grab(self, timeout: float) -> tuple[Image, float]:
        if self._capture is None:
            raise ConnectionFailed(f"{self.description} is not open (connect first)")
        asked = time.time()
        deadline = time.monotonic() + timeout
        with self._lock:
            while self._frame is None or self._frame[1] < asked:
                left = deadline - time.monotonic()
                if left <= 0:
                    raise DeviceTimeout(f"{self.description} delivered no frame within {timeout:g} s")
                self._lock.wait(left)
            return self._frame

    def close(self) -> None:
        self._running = False
        if self._thread is not None:
            self._thread.join(timeout=1.0)
        if self._capture is not None:
            self._capture.release()
        self._capture, self._thread, self._frame = None, None, None


class VideoReplay:
    """The frames of a video file, in order."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.description = f"video {self.path}"
        self._capture: cv2.VideoCapture | None = None
        self.frames_read = 0

    def open(self, timeout: float) -> None:
        if not self.path.is_file():
            raise ConnectionFailed(f"video {self.path}: no such file")
        self._capture = cv2.VideoCapture(str(self.path))
        if not self._capture.isOpened():
            raise ConnectionFailed(f"video {self.path}: OpenCV cannot read it (not a video, or no codec)")
        self.frames_read = 0

    def start_measurement(self) -> None:
        """Nothing to do for a replay."""

    def grab(self, timeout: float) -> tuple[Image, float]:
        if self._capture is None:
            raise ConnectionFailed(f"{self.description} is not open (connect first)")
        ok, frame = self._capture.read()
        if not ok:
            raise ConnectionFailed(f"{self.description} ended after {self.frames_read} frames")
        self.frames_read += 1
        return frame, time.time()

    def close(self) -> None:
        if self._capture is not None:
            self._capture.release()
        self._capture = None


class ImageReplay:
    """Image files (a folder's, or those matching a glob pattern), in name order."""

    def __init__(self, pattern: str | Path) -> None:
        self.pattern = str(pattern)
        self.description = f"images {self.pattern}"
        self.files: list[Path] = []
        self._next = 0

    def open(self, timeout: float) -> None:
        folder = Path(self.pattern)
        if folder.is_dir():
            files = [p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES]
        else:
            files = [Path(p) for p in glob.glob(self.pattern) if Path(p).is_file()]
        if not files:
            raise ConnectionFailed(f"{self.description}: no image files ({', '.join(IMAGE_SUFFIXES)})")
        self.files, self._next = sorted(files), 0

    def start_measurement(self) -> None:
        """Nothing to do for a replay."""

    def grab(self, timeout: float) -> tuple[Image, float]:
        if not self.files:
            raise ConnectionFailed(f"{self.description} is not open (connect first)")
        if self._next >= len(self.files):
            raise ConnectionFailed(f"{self.description}: all {len(self.files)} images were used")
        path = self.files[self._next]
        self._next += 1
        image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if image is None:
            raise BadReading(f"image {path} cannot be read")
        return image, time.time()

    def close(self) -> None:
        self.files, self._next = [], 0


def source_for(target: str, width: int = 0, height: int = 0) -> LiveCamera | VideoReplay | ImageReplay:
    """The source of an ``aruco:TARGET`` spec: a camera index (``0``), a device (``/dev/video0``), an
    image folder or glob (``run/*.png``), or a video file."""
    if target.isdigit():
        return LiveCamera(int(target), width, height)
    if target.startswith("/dev/"):
        return LiveCamera(target, width, height)
    path = Path(target)
    if any(c in target for c in "*[") or path.is_dir() or path.suffix.lower() in IMAGE_SUFFIXES:
        return ImageReplay(target)
    return VideoReplay(target)
