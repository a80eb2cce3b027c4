"""A network camera over HTTP (``aruco:http://HOST[:PORT]/PATH[?QUERY]#OPTIONS``): an MJPEG stream or a snapshot URL.

The kind is what the server answers, as browsers and go2rtc tell them apart: ``Content-Type:
multipart/x-mixed-replace; boundary=B`` is an **MJPEG stream** (one JPEG per part: mjpg-streamer's
``/?action=stream``, the ESP32-CAM web server's ``:81/stream``, Axis' ``/axis-cgi/mjpg/video.cgi``, go2rtc's
``/api/stream.mjpeg``), ``image/*`` a **snapshot URL** (one JPEG per GET: ``/?action=snapshot``, ``/capture``,
``/axis-cgi/jpg/image.cgi``, ``/api/frame.jpeg``). Images are decoded by ``cv2.imdecode`` (grey). Plain HTTP or
HTTPS; no authentication (a camera that answers 401 is refused in one line).

Frame times (s):

- MJPEG: a part's ``X-Timestamp: SECONDS.MICROSECONDS`` header, as mjpg-streamer, camera-streamer and the ESP32
  camera web server send it, is the frame's capture time on the **camera's clock** (its epoch is the device's: often
  its boot, the epoch where its clock is set). It is used when the first :data:`~drivers.camera.sources.PROBE_FRAMES`
  frames carry it and it advances at the host clock's rate within :data:`STAMP_RATE_TOLERANCE`
  (:func:`~drivers.camera.sources.device_stamps_usable`);
  otherwise a frame's time is the host time when its part began to arrive. A ``Date`` header (whole seconds) is
  not a frame time; Axis and go2rtc send no frame time.
- Snapshot: the middle of the request (host time between sending the GET and holding the whole image), uncertain
  by half the round trip. A stream polls it at ``rate``: :data:`MAX_SNAPSHOT_RATE` at most, and no faster than
  every :data:`PACE_TRIPS` median round trips (measured at ``open``).

Latency, measured on the frames right after ``open`` (``measured_latency`` and ``latency_spread``, s, in the tracker's
identity as ``latency_measured`` and ``latency_spread``; ``acquire --probe`` prints them):

- MJPEG with frame times: the host receive time minus the frame's time (median; spread: standard deviation). That is
  the latency plus the offset of the camera's clock from the host's: the latency itself only where both clocks
  agree (e.g. both set by NTP);
- MJPEG without: not measurable (nothing says when a frame was exposed); the spread of the arrival intervals is
  given (the timing noise the host stamps carry);
- snapshot: half the round trip (median and spread).

How a stream uses them: a continuous session's rows carry these stamps; the constant part (latency, the camera
clock's offset) is the clock offset that identify fits with the kinematics (identify/estimator/sync.py), and the
spread is timing noise, as for every streaming tracker.

How a stop-and-go reading uses them (drivers/camera/latency.py): it skips the frames that arrived before its request
plus ``latency`` (s), the tracker's ``latency=`` when given, else: an MJPEG stream's measured latency when it lies in
0 to :data:`MAX_MEASURED_LATENCY` (taken as a latency: the clocks agree, or the camera's runs behind by less than a
second, which only makes the wait longer), 0 otherwise (a camera clock counting from its boot, or set by hand and
ahead: an offset, not a latency); 0 for a stream without frame times (not measurable) and for a snapshot URL (the
image is taken while the request is answered). Where 0 is not right, give ``latency=`` (``--probe`` says which).

Failures, each one line naming the URL: connection refused, a host that does not resolve, an HTTP status other
than 200, a server that serves neither a multipart stream nor an image, a body that is not a JPEG -> ConnectionFailed
at ``open`` (BadReading for one bad frame later); every read has a timeout. A stream that stalls (no byte for the
timeout) or breaks: the reader reconnects at once and then every :data:`RETRY_WAIT` s while the source is open;
``grab`` / ``capture`` raise DeviceTimeout naming the last failure when no frame came within their timeout.
"""

from __future__ import annotations

import contextlib
import http.client
import math
import socket
import threading
import time
import urllib.parse
from typing import Any

import cv2
import numpy as np

from drivers.camera.sources import (
    PROBE_FRAMES,
    QUEUE_SECONDS,
    Frame,
    FrameQueue,
    Image,
    device_stamps_usable,
    wait_for_frame,
)
from drivers.errors import BadReading, ConnectionFailed, DeviceTimeout

RETRY_WAIT = 0.5  # s between reconnection attempts of a broken stream
LINE_LIMIT = 65536  # bytes: longest header line (a part's body without Content-Length is read in lines this long)
MAX_PART = 64 << 20  # bytes: a part larger than this is not a camera frame
# a snapshot URL has no frame rate of its own: a stream polls it at most this often (faster than its sensor it would
# answer the same image twice, under two times) and every PACE_TRIPS median round trips at the fastest (so that a
# request of ordinary length never delays the next beyond the stream's gap limit, 1.5 periods)
MAX_SNAPSHOT_RATE = 30.0
PACE_TRIPS = 1.5
MAX_QUEUE = 60  # frames waiting for detection at most (a snapshot URL on a fast link answers hundreds a second)
STAMP_HEADERS = ("x-timestamp",)  # a part's header holding its frame time (s on the camera's clock)
# X-Timestamp must advance at the host clock's rate within this share over the probe frames: arrivals jitter by the
# network and the host (tens of ms over the 8 frames' quarter second on WiFi or a loaded host); the check is there to
# refuse a frame counter or the wrong unit (ms), which are off by far more
STAMP_RATE_TOLERANCE = 0.5
# s: a measured delay (host receive time - X-Timestamp) up to this is taken as the latency (the clocks agree, as NTP
# sets them, and cameras deliver within a few frames); beyond it, or below 0, it is the camera clock's offset
MAX_MEASURED_LATENCY = 1.0


class StreamBroken(Exception):
    """The stream ended or broke (one line: why)."""


def parse_camera_url(url: str) -> tuple[str, str, int, str]:
    """``(scheme, host, port, path with query)`` of an ``http(s)://`` camera URL; ValueError in one line."""
    parts = urllib.parse.urlsplit(url)
    if parts.scheme not in ("http", "https") or not parts.hostname:
        raise ValueError(f"{url!r} is not an http:// or https:// URL with a host")
    if parts.username or parts.password:
        raise ValueError(f"{url!r}: credentials in the URL are not supported (the spec is recorded in the session)")
    try:
        port = parts.port or (443 if parts.scheme == "https" else 80)
    except ValueError:
        raise ValueError(f"{url!r}: the port is not a number from 1 to 65535") from None
    return parts.scheme, parts.hostname, port, (parts.path or "/") + (f"?{parts.query}" if parts.query else "")


def failure_line(exc: BaseException, timeout: float) -> str:
    """One line for a network failure ``exc`` of a request whose reads wait ``timeout`` s."""
    if isinstance(exc, ConnectionRefusedError):
        return "connection refused (is the camera's server running, the port right?)"
    if isinstance(exc, socket.gaierror):
        return "the host name does not resolve"
    if isinstance(exc, TimeoutError):
        return f"stalled: no data for {timeout:g} s"
    if isinstance(exc, (http.client.RemoteDisconnected, ConnectionResetError, BrokenPipeError,
                        http.client.IncompleteRead)):
        return "the server closed the connection"
    if isinstance(exc, StreamBroken):
        return str(exc)
    if isinstance(exc, http.client.HTTPException):
        return f"not an HTTP answer ({type(exc).__name__})"
    if isinstance(exc, OSError):
        return exc.strerror or str(exc) or type(exc).__name__
    return f"{type(exc).__name__}: {exc}"


def decode_jpeg(body: bytes) -> Image | None:
    """The grey image of ``body`` (JPEG or any format OpenCV reads), None when it is not an image."""
    if not body:
        return None
    return cv2.imdecode(np.frombuffer(body, dtype=np.uint8), cv2.IMREAD_GRAYSCALE)


class MultipartReader:
    """The parts of a ``multipart/x-mixed-replace`` body: ``next_part()`` -> (headers with lower-case names, body,
    host time when the part's boundary arrived). A part with ``Content-Length`` is read to that length; one
    without, up to the next boundary line."""

    def __init__(self, stream: Any, boundary: str) -> None:
        self.stream = stream
        bare = boundary.strip().strip('"').encode("latin-1")
        # some servers declare the boundary with its leading dashes (boundary=--B): accept both spellings
        self.delimiters = {b"--" + bare, bare}
        self.closers = {d + b"--" for d in self.delimiters}
        self._at_part = False  # the boundary of the next part has been read already

    def _line(self) -> bytes:
        line = self.stream.readline(LINE_LIMIT)
        if not line:
            raise StreamBroken("the server ended the stream")
        return line

    def next_part(self) -> tuple[dict[str, str], bytes, float]:
        skipped = 0
        while not self._at_part:
            line = self._line().strip()
            if line in self.closers:
                raise StreamBroken("the server ended the stream (closing boundary)")
            self._at_part = line in self.delimiters
            skipped += len(line)
            if skipped > MAX_PART:
                raise StreamBroken("no part boundary in the stream (is it multipart?)")
        arrived = time.time()
        self._at_part = False
        headers: dict[str, str] = {}
        while line := self._line().strip():
            key, _, value = line.decode("latin-1").partition(":")
            headers[key.strip().lower()] = value.strip()
        length = headers.get("content-length", "")
        if length.isdigit():
            if int(length) > MAX_PART:
                raise StreamBroken(f"a part of {length} bytes is not a camera frame")
            body = self.stream.read(int(length))
            if len(body) < int(length):
                raise StreamBroken("the server ended the stream inside a frame")
            return headers, body, arrived
        chunks: list[bytes] = []
        while True:
            line = self._line()
            bare = line.strip()
            if bare in self.delimiters or bare in self.closers:
                self._at_part = bare in self.delimiters
                body = b"".join(chunks)
                return headers, body[:-2] if body.endswith(b"\r\n") else body, arrived
            chunks.append(line)


def boundary_of(content_type: str) -> str:
    """The ``boundary`` parameter of a ``multipart/...`` Content-Type ("" when it has none)."""
    for param in content_type.split(";")[1:]:
        key, _, value = param.partition("=")
        if key.strip().lower() == "boundary":
            return value.strip()
    return ""


def part_stamp(headers: dict[str, str]) -> float:
    """The frame time (s, camera clock) a part's headers carry, NaN when none does."""
    for key in STAMP_HEADERS:
        try:
            value = float(headers.get(key, "nan"))
        except ValueError:
            continue
        if math.isfinite(value):
            return value
    return math.nan


class NetworkCamera:
    """An HTTP camera (module docstring): ``url`` as given. After ``open``: ``kind`` (``mjpeg`` or ``snapshot``),
    ``rate`` (Hz: an MJPEG stream's measured; the pace a snapshot URL is polled at), ``stamps`` (what a streamed
    frame's time is), ``measured_latency`` and ``latency_spread`` (s; NaN when not measurable)."""

    def __init__(self, url: str, width: int = 0, height: int = 0) -> None:
        self.url, self.width, self.height = url, width, height
        self.scheme, self.host, self.port, self.path = parse_camera_url(url)
        self.description = f"network camera {url}"
        self.kind = ""
        self.rate, self.stamps = math.nan, "host time (not open)"
        self.measured_latency = self.latency_spread = math.nan
        self.latency, self.latency_basis = 0.0, "not open"  # what stop-and-go readings take (drivers/camera/latency.py)
        self.last_round_trip = math.nan  # s: the last snapshot's (its stamp is uncertain by half of it)
        self.timeout = 2.0
        self._lock = threading.Condition()
        self._running = False
        self._thread: threading.Thread | None = None
        self._connection: http.client.HTTPConnection | None = None
        self._socket: socket.socket | None = None
        self._response: http.client.HTTPResponse | None = None
        self._frame: tuple[Image, float] | None = None  # newest frame and its host time
        self._sink: FrameQueue | None = None
        self._seq, self._device_stamps, self._last_arrival, self._bad_parts = 0, False, 0.0, 0
        self._error = ""  # the last failure, one line
        self._probe: list[tuple[float, float]] = []  # (host time, frame time or round trip) of the frames after open

    # --- requests -----------------------------------------------------------------------------------------

    def _fail(self, why: str) -> str:
        return f"{self.description}: {why}"

    def _network_error(self, exc: BaseException, timeout: float) -> ConnectionFailed | DeviceTimeout:
        """DeviceTimeout for a read that timed out, else ConnectionFailed; one line naming the URL."""
        kind = DeviceTimeout if isinstance(exc, TimeoutError) else ConnectionFailed
        return kind(self._fail(failure_line(exc, timeout)))

    def _request(self, timeout: float) -> http.client.HTTPResponse:
        """GET the URL on a fresh connection; the 200 answer (headers read), or ConnectionFailed (DeviceTimeout when
        it timed out) in one line."""
        kind = http.client.HTTPSConnection if self.scheme == "https" else http.client.HTTPConnection
        connection = kind(self.host, self.port, timeout=timeout)
        try:
            connection.connect()
            self._socket = connection.sock  # getresponse() hands it to the response: close() shuts it from here
            connection.request("GET", self.path, headers={"Accept": "multipart/x-mixed-replace, image/*"})
            response = connection.getresponse()
        except (OSError, http.client.HTTPException) as exc:
            self._connection = connection
            self._close_connection()
            raise self._network_error(exc, timeout) from None
        self._connection, self._response = connection, response
        if response.status != 200:
            hint = {401: " (authentication is not supported)", 403: " (forbidden)",
                    404: " (wrong path? the server has no such page)"}.get(response.status, "")
            self._close_connection()
            raise ConnectionFailed(self._fail(f"HTTP {response.status} {response.reason}{hint}"))
        return response

    def _snapshot(self, timeout: float) -> tuple[Image, float, float]:
        """One snapshot: (image, middle of the request on the host clock, round trip s); ConnectionFailed or
        BadReading in one line."""
        sent = time.time()
        response = self._request(timeout)
        try:
            body = response.read()
        except (OSError, http.client.HTTPException) as exc:
            raise self._network_error(exc, timeout) from None
        finally:
            self._close_connection()
        received = time.time()
        self.last_round_trip = received - sent
        image = decode_jpeg(body)
        if image is None:
            kind = response.getheader("Content-Type", "no Content-Type")
            raise BadReading(self._fail(f"the answer ({kind}, {len(body)} bytes) is not a JPEG image"))
        return image, 0.5 * (sent + received), received - sent

    def _close_connection(self) -> None:
        if self._socket is not None:
            with contextlib.suppress(OSError):  # the response may still hold it: end the TCP connection itself
                self._socket.shutdown(socket.SHUT_RDWR)
            self._socket.close()
        for part in (self._response, self._connection):
            if part is not None:
                with contextlib.suppress(OSError, http.client.HTTPException):
                    part.close()
        self._connection = self._socket = self._response = None

    # --- the source interface (drivers/camera/sources.py) ---------------------------------------------------

    def open(self, timeout: float) -> None:
        self.close()
        self.timeout = timeout
        response = self._request(timeout)
        kind = (response.getheader("Content-Type") or "").strip()
        media = kind.partition(";")[0].strip().lower()
        self._running, self._probe, self._error, self._bad_parts = True, [], "", 0
        if media.startswith("multipart/"):
            boundary = boundary_of(kind)
            if not boundary:
                self.close()
                raise ConnectionFailed(self._fail(f"a multipart answer without a boundary ({kind})"))
            self.kind = "mjpeg"
            self._thread = threading.Thread(target=self._mjpeg_loop, args=(response, boundary), daemon=True,
                                            name=f"mjpeg-{self.host}")
            self._thread.start()
        elif media.startswith("image/"):
            self._close_connection()
            self.kind = "snapshot"
        else:
            self.close()
            raise ConnectionFailed(self._fail(f"serves {kind or 'no Content-Type'}, neither an MJPEG stream "
                                              "(multipart/x-mixed-replace) nor an image"))
        try:
            self._measure_timing(timeout)
        except BadReading as exc:
            self.close()
            raise ConnectionFailed(str(exc)) from None
        except (DeviceTimeout, ConnectionFailed):
            self.close()
            raise

    def _measure_timing(self, timeout: float) -> None:
        """Frame rate, frame times and latency from the first PROBE_FRAMES frames (module docstring)."""
        if self.kind == "snapshot":
            started = time.monotonic()
            for _ in range(PROBE_FRAMES):
                _, middle, trip = self._snapshot(timeout)
                self._probe.append((middle, trip))
                if time.monotonic() - started > timeout and len(self._probe) >= 3:
                    break
            trips = np.array([trip for _, trip in self._probe])
            self.rate = min(MAX_SNAPSHOT_RATE, 1.0 / max(PACE_TRIPS * float(np.median(trips)), 1e-6))
            self.measured_latency, self.latency_spread = float(np.median(trips)) / 2, float(np.std(trips)) / 2
            self.stamps = "host time at the middle of each request (uncertain by half its round trip)"
            self.latency, self.latency_basis = 0.0, "a snapshot is taken while it is asked for"
            return
        deadline = time.monotonic() + timeout
        with self._lock:
            while len(self._probe) < PROBE_FRAMES:
                if self._bad_parts >= PROBE_FRAMES // 2 and not self._probe:
                    raise BadReading(self._fail(f"its first {self._bad_parts} parts are not JPEG images"))
                left = deadline - time.monotonic()
                if left <= 0:
                    silent = time.monotonic() - self._last_arrival
                    why = (f"stalled: no frame for {silent:.1f} s" if self._probe else
                           self._error or "no frame at all")
                    raise DeviceTimeout(self._fail(f"delivered {len(self._probe)} of {PROBE_FRAMES} frames within "
                                                   f"{timeout:g} s ({why})"))
                self._lock.wait(left)
            host, device = (np.array(v) for v in zip(*self._probe, strict=True))
        usable, why = device_stamps_usable(host, device * 1e3, STAMP_RATE_TOLERANCE)
        self._device_stamps = usable
        self.rate = 1.0 / max(float(np.median(np.diff(device if usable else host))), 1e-6)
        if usable:
            delay = host - device
            self.measured_latency, self.latency_spread = float(np.median(delay)), float(np.std(delay))
            self.stamps = "camera clock (the parts' X-Timestamp header)"
            latency = 0 <= self.measured_latency < MAX_MEASURED_LATENCY
            self.latency = self.measured_latency if latency else 0.0
            self.latency_basis = ("measured" if latency else f"measured {self.measured_latency:.6g} s: the camera "
                                  "clock's offset, not a latency")
        else:
            self.latency_spread = float(np.std(np.diff(host)))
            self.latency, self.latency_basis = 0.0, "not measurable without frame times"
            self.stamps = ("host time at each part's arrival (" + ("no X-Timestamp header" if np.all(np.isnan(device))
                                                                   else f"X-Timestamp not usable: {why}") + ")")

    def _mjpeg_loop(self, response: http.client.HTTPResponse, boundary: str) -> None:
        """The reader thread: every part of the stream, reconnecting when it breaks (module docstring)."""
        while self._running:
            # a server may draw a new boundary for each connection
            reader = MultipartReader(response, boundary_of(response.getheader("Content-Type") or "") or boundary)
            try:
                while self._running:
                    headers, body, arrived = reader.next_part()
                    self._deliver(decode_jpeg(body), arrived, part_stamp(headers))
            except (OSError, ValueError, http.client.HTTPException, StreamBroken) as exc:
                with self._lock:
                    self._error = failure_line(exc, self.timeout)
            self._close_connection()
            while self._running:
                try:
                    response = self._request(self.timeout)
                    break
                except (ConnectionFailed, DeviceTimeout) as exc:
                    with self._lock:
                        self._error = str(exc).removeprefix(self._fail(""))
                    time.sleep(RETRY_WAIT)
        self._close_connection()  # closed while reconnecting

    def _snapshot_loop(self) -> None:
        """The poller thread of a streamed snapshot camera: a snapshot every ``1 / rate`` s while streaming (at once
        after one that took longer)."""
        period, due = 1.0 / self.rate, time.monotonic()
        while self._running and self._sink is not None:
            wait = due - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            due = max(due + period, time.monotonic())
            try:
                image, middle, _ = self._snapshot(self.timeout)
            except (ConnectionFailed, DeviceTimeout, BadReading) as exc:
                with self._lock:
                    self._error = str(exc).removeprefix(self._fail(""))
                    self._seq += 1  # a lost frame: its number is skipped
                continue
            self._deliver(image, middle, math.nan)

    def _deliver(self, image: Image | None, host: float, device: float) -> None:
        """Hand a frame to ``grab`` and, while streaming, to the queue (a frame that is not an image is lost)."""
        with self._lock:
            if image is None:
                self._error = "a part that is not a JPEG image"
                self._seq, self._bad_parts = self._seq + 1, self._bad_parts + 1
                self._lock.notify_all()
                return
            self._frame = (image, host)
            self._last_arrival = time.monotonic()
            if len(self._probe) < PROBE_FRAMES and self.kind == "mjpeg":
                self._probe.append((host, device))
            if self._sink is not None:
                self._sink.offer(Frame(self._seq, device if self._device_stamps else host, image))
            self._seq += 1
            self._lock.notify_all()

    def start_measurement(self) -> None:
        """Nothing to do: ``grab`` waits for a frame that arrived after it was called."""

    def grab(self, timeout: float) -> tuple[Image, float]:
        """A frame that arrived after this call (an MJPEG part, or a fresh snapshot) and its host time (s)."""
        if not self._running:
            raise ConnectionFailed(self._fail("not open (connect first)"))
        if self.kind == "snapshot":
            image, middle, _ = self._snapshot(timeout)
            return image, middle

        def why() -> str:
            last = f" (last failure: {self._error})" if self._error else ""
            return self._fail(f"no frame within {timeout:g} s{last}")

        return wait_for_frame(self._lock, lambda: self._frame, timeout, why)

    def start_frames(self, timeout: float) -> tuple[FrameQueue, float]:
        """Hand every frame from now on to a new queue (room for QUEUE_SECONDS of frames); returns it and the
        frame rate (Hz). A snapshot camera is polled back to back by a thread meanwhile."""
        if not self._running:
            raise ConnectionFailed(self._fail("not open (connect first)"))
        queue = FrameQueue(min(math.ceil(self.rate * QUEUE_SECONDS), MAX_QUEUE))
        with self._lock:
            self._sink, self._seq, self._last_arrival = queue, 0, time.monotonic()
        if self.kind == "snapshot":
            self._thread = threading.Thread(target=self._snapshot_loop, daemon=True, name=f"snapshots-{self.host}")
            self._thread.start()
        return queue, self.rate

    def capture(self, timeout: float) -> None:
        """The reader thread captures; DeviceTimeout when no frame has come for ``timeout`` s."""
        with self._lock:
            silent, error = time.monotonic() - self._last_arrival, self._error
        if silent > timeout:
            last = f" (last failure: {error})" if error else ""
            raise DeviceTimeout(self._fail(f"no frame for {silent:.1f} s while streaming{last}"))

    def stop_frames(self) -> None:
        with self._lock:
            self._sink = None
        if self.kind == "snapshot" and self._thread is not None:
            self._thread.join(timeout=self.timeout + 1.0)
            self._thread = None

    def close(self) -> None:
        self._running = False
        with self._lock:
            self._sink = None
        if self._socket is not None:
            with contextlib.suppress(OSError):  # wakes the reader thread blocked in a read
                self._socket.shutdown(socket.SHUT_RDWR)
        if self._thread is not None:
            self._thread.join(timeout=self.timeout + 1.0)
        self._close_connection()
        self._thread, self._frame = None, None
