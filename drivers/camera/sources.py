"""Where camera frames come from: a live camera, a video file, or a folder / glob of images (replay).

Every source has ``open(timeout)``, ``close()``, ``start_measurement()`` (a hook; the simulated camera in
drivers/camera/renderer.py counts measurements there) and ``grab(timeout) -> (image, timestamp)``:

- :class:`LiveCamera` (``cv2.VideoCapture`` of a camera index or a device path): a reader thread keeps
  only the newest frame, and ``grab`` returns a frame captured after it was called, so nothing from before
  the robot settled is measured. No new frame within the timeout: DeviceTimeout.
- :class:`VideoReplay` (a video file) and :class:`ImageReplay` (a folder or a glob of images, in name
  order): frames in order, one per ``grab``; at the end, ConnectionFailed (the replay is over).

Timestamps of ``grab`` are seconds since the epoch (the time the frame arrived; for a replay, the time it was
read).

Streams (continuous motion, drivers/camera/stream.py): a source that streams has ``start_frames(timeout) ->
(FrameQueue, rate Hz)``, ``capture(timeout)`` (called from ``read_stream``, in the caller's thread) and
``stop_frames()``, and says in ``stamps`` what its frames' times are. :class:`LiveCamera` hands *every* frame
its reader thread grabs to the queue, numbered, stamped with its capture time: the camera's own
(``CAP_PROP_POS_MSEC`` after ``grab()``, s on the camera's clock) when the backend gives a usable one (checked
on the first frames after ``open``: :func:`device_stamps_usable`), else the host time right after ``grab()``;
a frame that finds the queue full (detection behind) is lost, and its number skipped. ``capture`` raises
DeviceTimeout when no frame came for ``timeout`` s. The replays cannot stream (their frames have no live timing).
"""

from __future__ import annotations

import collections
import glob
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from drivers.errors import BadReading, ConnectionFailed, DeviceTimeout

Image = NDArray[np.uint8]
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm", ".webp")
PROBE_FRAMES = 8  # frames after open() whose times decide the stream's timestamps and give the frame rate
RATE_TOLERANCE = 0.2  # CAP_PROP_POS_MSEC must advance at the host clock's rate within this share to be used
QUEUE_SECONDS = 1.0  # a live camera's frames wait at most this long (in frames) for detection, then are lost


@dataclass(frozen=True)
class Frame:
    """One frame of a stream: ``seq`` the source's frame number (a frame the source lost still takes its number,
    so a jump says frames are missing), ``stamp`` its capture time (s, on the clock the source's ``stamps``
    names), ``image`` its pixels."""

    seq: int
    stamp: float
    image: Image


class FrameQueue:
    """Frames waiting for detection, at most ``capacity`` (thread-safe). A live source ``offer``s (a frame that
    finds no room is lost and counted in ``lost``); a simulated one ``put``s, waiting for room."""

    def __init__(self, capacity: int) -> None:
        self.capacity, self.lost, self.closed = max(int(capacity), 1), 0, False
        self._items: collections.deque[Frame] = collections.deque()
        self._cond = threading.Condition()

    def offer(self, frame: Frame) -> bool:
        """Queue ``frame`` if there is room (and the queue is open); False when it is lost."""
        with self._cond:
            if self.closed or len(self._items) >= self.capacity:
                self.lost += 1
                return False
            self._items.append(frame)
            self._cond.notify_all()
            return True

    def put(self, frame: Frame, timeout: float) -> None:
        """Queue ``frame``, waiting up to ``timeout`` s for room; DeviceTimeout if none comes."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while len(self._items) >= self.capacity and not self.closed:
                left = deadline - time.monotonic()
                if left <= 0:
                    raise DeviceTimeout(f"frame detection fell {len(self._items)} frames behind for {timeout:g} s")
                self._cond.wait(left)
            if self.closed:
                self.lost += 1
                return
            self._items.append(frame)
            self._cond.notify_all()

    def get(self, timeout: float) -> Frame | None:
        """The oldest frame, waiting up to ``timeout`` s; None if none came (or the queue is closed and empty)."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while not self._items:
                left = deadline - time.monotonic()
                if self.closed or left <= 0:
                    return None
                self._cond.wait(left)
            frame = self._items.popleft()
            self._cond.notify_all()
            return frame

    def close(self) -> None:
        """No more frames come in (those queued can still be taken)."""
        with self._cond:
            self.closed = True
            self._cond.notify_all()

    @property
    def finished(self) -> bool:
        """Closed and empty."""
        with self._cond:
            return self.closed and not self._items

    def drain(self) -> list[Frame]:
        """Take every queued frame at once."""
        with self._cond:
            items = list(self._items)
            self._items.clear()
            self._cond.notify_all()
            return items


def wait_for_frame(lock: threading.Condition, latest: Callable[[], tuple[Image, float] | None], timeout: float,
                   why: Callable[[], str]) -> tuple[Image, float]:
    """The latest frame and its host time (s) (``latest()``, guarded by ``lock``, notified on each arrival) once one
    has arrived at or after this call; DeviceTimeout with the line ``why()`` (called under the lock) after
    ``timeout`` s without one. A local camera's and a network stream's ``grab``."""
    asked = time.time()
    deadline = time.monotonic() + timeout
    with lock:
        while (frame := latest()) is None or frame[1] < asked:
            left = deadline - time.monotonic()
            if left <= 0:
                raise DeviceTimeout(why())
            lock.wait(left)
        return frame


def device_stamps_usable(host: NDArray[np.float64], device_ms: NDArray[np.float64],
                         tolerance: float = RATE_TOLERANCE) -> tuple[bool, str]:
    """Whether ``CAP_PROP_POS_MSEC`` values ``device_ms`` (ms) read after grabbing consecutive frames at host times
    ``host`` (s) are usable capture times: finite, positive, increasing, and advancing at the host clock's rate
    within ``tolerance`` (a backend that gives 0, -1, a frame count or a file position fails). Returns
    the answer and, when it is no, why."""
    host, device = np.asarray(host, dtype=float), np.asarray(device_ms, dtype=float) / 1e3
    if len(host) < 3:
        return False, f"only {len(host)} frames to check it on"
    if not np.all(np.isfinite(device)) or np.any(device <= 0):
        return False, "the backend gives no time (0, negative or not a number)"
    if np.any(np.diff(device) <= 0):
        return False, "its values do not increase from frame to frame"
    ratio = (device[-1] - device[0]) / max(host[-1] - host[0], 1e-9)
    if abs(ratio - 1.0) > tolerance:
        return False, f"it advances {ratio:.3g} x as fast as the host clock"
    return True, ""


class LiveCamera:
    """A camera through ``cv2.VideoCapture``: ``device`` an index (int) or a path such as /dev/video0;
    ``width``/``height`` the requested frame size (0: the camera's default); ``opener`` makes the capture object
    (``cv2.VideoCapture``; tests give a stand-in). After ``open``: ``rate`` (Hz, measured on the first frames) and
    ``stamps`` (what a streamed frame's time is)."""

    def __init__(self, device: int | str, width: int = 0, height: int = 0,
                 opener: Callable[[int | str], Any] = cv2.VideoCapture) -> None:
        self.device, self.width, self.height, self._opener = device, width, height, opener
        self.description = f"camera {device}"
        self._capture: Any = None
        self._thread: threading.Thread | None = None
        self._lock = threading.Condition()
        self._frame: tuple[Image, float] | None = None
        self._running = False
        self._times: collections.deque[tuple[float, float]] = collections.deque(maxlen=PROBE_FRAMES)
        self._count, self._last_arrival = 0, 0.0  # frames grabbed; host monotonic time of the last one
        self._sink: FrameQueue | None = None  # the stream's queue while streaming
        self._seq, self._device_stamps = 0, False
        self.rate, self.stamps = math.nan, "host time at grab"

    def open(self, timeout: float) -> None:
        self.close()
        capture = self._opener(self.device)
        if not capture.isOpened():
            raise ConnectionFailed(f"cannot open {self.description} (unplugged, busy, or no permission?)")
        if self.width and self.height:
            capture.set(cv2.CAP_PROP_FRAME_WIDTH, self.width)
            capture.set(cv2.CAP_PROP_FRAME_HEIGHT, self.height)
        self._capture, self._running = capture, True
        self._thread = threading.Thread(target=self._read_loop, name=f"camera-{self.device}", daemon=True)
        self._thread.start()
        self.grab(timeout)  # the first frame proves the camera delivers
        self._probe(timeout, capture)

    def _probe(self, timeout: float, capture: Any) -> None:
        """Decide the streamed frames' timestamps and measure the frame rate on the next PROBE_FRAMES frames."""
        deadline = time.monotonic() + timeout
        with self._lock:
            self._times.clear()
            while len(self._times) < PROBE_FRAMES:
                left = deadline - time.monotonic()
                if left <= 0:
                    raise DeviceTimeout(f"{self.description} delivered {len(self._times)} of {PROBE_FRAMES} frames "
                                        f"within {timeout:g} s")
                self._lock.wait(left)
            host, device = (np.array(v) for v in zip(*self._times, strict=True))
        backend = capture.getBackendName()
        usable, why = device_stamps_usable(host, device)
        self._device_stamps = usable
        times = device / 1e3 if usable else host
        self.rate = 1.0 / max(float(np.median(np.diff(times))), 1e-6)
        self.stamps = (f"camera clock (CAP_PROP_POS_MSEC, {backend})" if usable else
                       f"host time at grab (CAP_PROP_POS_MSEC of {backend} not usable: {why})")

    def _read_loop(self) -> None:
        capture = self._capture
        while self._running and capture is not None:
            ok = capture.grab()
            host = time.time()
            if not ok:
                time.sleep(0.01)
                continue
            device = capture.get(cv2.CAP_PROP_POS_MSEC)
            ok, frame = capture.retrieve()
            if not ok:
                continue
            with self._lock:
                self._frame = (frame, host)
                self._times.append((host, device))
                self._count, self._last_arrival = self._count + 1, time.monotonic()
                if self._sink is not None:
                    self._sink.offer(Frame(self._seq, device / 1e3 if self._device_stamps else host, frame))
                    self._seq += 1
                self._lock.notify_all()

    def start_measurement(self) -> None:
        """Nothing to do: ``grab`` already waits for a fresh frame."""

    def grab(self, timeout: float) -> tuple[Image, float]:
        if self._capture is None:
            raise ConnectionFailed(f"{self.description} is not open (connect first)")
        return wait_for_frame(self._lock, lambda: self._frame, timeout,
                              lambda: f"{self.description} delivered no frame within {timeout:g} s")

    def start_frames(self, timeout: float) -> tuple[FrameQueue, float]:
        """Hand every frame grabbed from now on to a new queue (room for :data:`QUEUE_SECONDS` of frames);
        returns it and the frame rate (Hz)."""
        if self._capture is None:
            raise ConnectionFailed(f"{self.description} is not open (connect first)")
        queue = FrameQueue(math.ceil(self.rate * QUEUE_SECONDS))
        with self._lock:
            self._sink, self._seq, self._last_arrival = queue, 0, time.monotonic()
        return queue, self.rate

    def capture(self, timeout: float) -> None:
        """The reader thread captures; DeviceTimeout when no frame has come for ``timeout`` s."""
        with self._lock:
            silent = time.monotonic() - self._last_arrival
        if silent > timeout:
            raise DeviceTimeout(f"{self.description} delivered no frame for {silent:.1f} s while streaming")

    def stop_frames(self) -> None:
        with self._lock:
            self._sink = None

    def close(self) -> None:
        self._running = False
        self.stop_frames()
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
