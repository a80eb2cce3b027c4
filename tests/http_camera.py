"""A network camera on loopback for the tests and bench/network_camera.py: a real HTTP server (``http.server`` in a
thread) that serves the frames it is given (grey images, JPEG-encoded once) as real cameras do.

Paths:

- ``/stream``: ``multipart/x-mixed-replace; boundary=frame``, the frames in a loop at ``fps``; each part has
  ``Content-Type: image/jpeg``, ``Content-Length`` and, with ``stamps``, ``X-Timestamp: S.US`` (as mjpg-streamer and
  the ESP32 camera web server write it): the frame's exposure, taken as its send time minus ``latency`` s (the
  injected latency), plus ``clock_offset`` s (the camera's clock against the host's);
- ``/nolength``: the same stream without ``Content-Length`` (a part ends at the next boundary);
- ``/snapshot``: one JPEG per GET, exposed when the request arrives and sent ``delay`` s later;
- ``/stall``: a stream that stops once ``stall_after`` parts were streamed in all (this and every later connection
  then gets nothing more, and stays open);
- ``/garbage``: a stream whose parts are not images; ``/page``: an HTML page; anything else: 404.

``sent``: (exposure host time, send time) of every frame served, for the bench to compare with what the client
stamped. ``stop()`` ends every connection.
"""

from __future__ import annotations

import http.server
import threading
import time
from collections.abc import Sequence

import cv2
import numpy as np


class HttpCamera:
    """The server (``url(path)`` gives a path's URL); ``frames`` grey images, served in turn."""

    def __init__(self, frames: Sequence[np.ndarray], fps: float = 30.0, stamps: bool = True, latency: float = 0.0,
                 clock_offset: float = 0.0, delay: float = 0.0, stall_after: int = 2, quality: int = 95) -> None:
        self.fps, self.stamps, self.latency, self.clock_offset = fps, stamps, latency, clock_offset
        self.delay, self.stall_after, self.quality = delay, stall_after, quality
        self.sent: list[tuple[float, float]] = []
        self.requests = self.streamed = 0  # GET requests; stream parts sent over every connection
        self.paths: list[str] = []  # every request's path, with its query
        self.stopping = threading.Event()
        self._lock = threading.Lock()
        self.show(frames)
        camera = self

        class Handler(http.server.BaseHTTPRequestHandler):
            def log_message(self, *args: object) -> None:  # quiet
                pass

            def do_GET(self) -> None:
                camera.requests += 1
                camera.paths.append(self.path)
                camera.serve(self)

        self.server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.server.daemon_threads = True
        self._thread = threading.Thread(target=self.server.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
        self._thread.start()

    def url(self, path: str) -> str:
        return f"http://127.0.0.1:{self.server.server_address[1]}{path}"

    def show(self, frames: Sequence[np.ndarray]) -> None:
        """Serve these frames from now on (JPEG-encoded at ``quality``)."""
        jpegs = [cv2.imencode(".jpg", f, [cv2.IMWRITE_JPEG_QUALITY, self.quality])[1].tobytes() for f in frames]
        with self._lock:
            self._jpegs, self._next = jpegs, 0

    def _frame(self) -> bytes:
        with self._lock:
            jpeg = self._jpegs[self._next % len(self._jpegs)]
            self._next += 1
            return jpeg

    def serve(self, handler: http.server.BaseHTTPRequestHandler) -> None:
        path = handler.path.split("?")[0]
        try:
            if path == "/snapshot":
                exposed = time.time()
                jpeg = self._frame()
                time.sleep(self.delay)
                handler.send_response(200)
                handler.send_header("Content-Type", "image/jpeg")
                handler.send_header("Content-Length", str(len(jpeg)))
                handler.end_headers()
                self.sent.append((exposed, time.time()))  # before the client can hold the image
                handler.wfile.write(jpeg)
            elif path in ("/stream", "/nolength", "/stall", "/garbage"):
                self._stream(handler, path)
            elif path == "/page":
                body = b"<html><body>camera settings</body></html>"
                handler.send_response(200)
                handler.send_header("Content-Type", "text/html")
                handler.send_header("Content-Length", str(len(body)))
                handler.end_headers()
                handler.wfile.write(body)
            else:
                handler.send_error(404, "Not Found")
        except (BrokenPipeError, ConnectionResetError):
            pass  # the client went away

    def _stream(self, handler: http.server.BaseHTTPRequestHandler, path: str) -> None:
        handler.send_response(200)
        handler.send_header("Content-Type", "multipart/x-mixed-replace; boundary=frame")
        handler.end_headers()
        start, k = time.monotonic(), 0
        while not self.stopping.is_set():
            if path == "/stall" and self.streamed >= self.stall_after:
                self.stopping.wait(60.0)
                return
            wait = start + k / self.fps - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            jpeg = b"this is not an image" if path == "/garbage" else self._frame()
            now = time.time()
            head = ["--frame", "Content-Type: image/jpeg"]
            if path != "/nolength":
                head.append(f"Content-Length: {len(jpeg)}")
            if self.stamps:
                head.append(f"X-Timestamp: {now - self.latency + self.clock_offset:.6f}")
            self.sent.append((now - self.latency, now))  # before the client can hold the frame
            handler.wfile.write(("\r\n".join(head) + "\r\n\r\n").encode() + jpeg + b"\r\n")
            handler.wfile.flush()
            k, self.streamed = k + 1, self.streamed + 1

    def stop(self) -> None:
        self.stopping.set()
        self.server.shutdown()
        self.server.server_close()
        self._thread.join(timeout=2.0)
