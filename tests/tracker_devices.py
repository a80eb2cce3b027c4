"""Simulated measuring devices for tests: an ASCII device (any profile of ``config/trackers/``) on a real
pseudo-terminal or a loopback TCP socket, and an I++ DME server on loopback. Both answer from a simulated
rig's true TP (``rig.true_point()``) plus Gaussian noise.

ASCII device: the profile's ``simulation`` block says how it formats replies (``reply``, ``payload`` for a
checksum, ``identity``, ``banner``, ``lost``/``lost_status``, ``init_reply``, ``needs_init``, ``period`` of a
streaming device). Faults, each for the next ``count`` replies (``device.inject(name, count)``):

- ``target_lost``: the profile's target-lost reply; ``garbage``: a line of random bytes instead of the reply;
- ``noise``: non-printable noise bytes before the reply (the reply must still parse);
- ``partial``: the reply arrives in two pieces 20 ms apart (must still parse); ``truncated``: half a line;
- ``bad_checksum``: a wrong checksum; ``out_of_range``: coordinates of 1e6 m;
- ``reset``: the device prints its banner, forgets its initialisation (answers not_ready until
  initialised again) and drops the request; ``silence``: no answer.

Streaming (a profile with ``mode: streaming``): a line every ``period`` s of physical time, numbered (``seq``, every
line counts, lost ones too) and stamped with the device's own clock ``t`` = ``clock_offset`` + (1 + ``drift``) × τ
(s), τ the physical time the reading was taken, the point being the rig's true TP at τ; each line leaves
``latency`` s after τ. ``stamp_on_send=True``: the device stamps a line when it sends it (τ + ``latency``), as a
tracker that does not take its own latency out of its timestamps (the mock tracker's model), so a reading stamped
``t`` was taken at τ = (t - clock_offset) / (1 + drift) - latency. Physical time is ``clock`` (default the host's
wall clock, ``time.time()``; the UR emulator passes its rig's scaled clock, so that device and controller share one
time base and the period runs on it); when it is the rig's clock, the rig is sampled at τ itself.
``lose_target(seconds)`` makes the streamed lines of the next ``seconds`` the ``lost`` reply (the target out of the
beam), ``skip_lines(n)``: the next n lines are never sent (lost on the wire).

``echo=True`` echoes every command line back first. ``mixed_endings=True`` ends each line with a random one
of CRLF, LF and CR. A profile with ``points: N`` answers each trigger with N lines (reflector k at
``rig.true_points()[k-1]``, written in one piece); ids in ``device.hidden`` answer the ``lost`` reply (out of
sight); a fault spoils the first line (``target_lost``: every line).
"""

from __future__ import annotations

import contextlib
import os
import random
import re
import select
import socket
import threading
import time
import tty

import numpy as np

from drivers.clock import Clock, WallClock
from drivers.sim.rig import SimulatedRig
from drivers.trackers.ascii_profile import Profile, checksum_of, load_profile
from tests._served import _Served

ASCII_FAULTS = ("target_lost", "garbage", "noise", "partial", "truncated", "bad_checksum", "out_of_range", "reset",
                "silence")


class AsciiDevice(_Served):
    """An ASCII tracker speaking ``profile`` (name or Profile) on a pty (``transport="pty"``, then ``port``
    is the slave's path) or on loopback TCP (``transport="tcp"``, then ``port`` is ``socket://127.0.0.1:N``)."""

    def __init__(self, profile: str | Profile, rig: SimulatedRig | None = None, *, noise: float = 2e-5,
                 seed: int = 0, transport: str = "pty", mixed_endings: bool = False, latency: float = 0.0,
                 echo: bool = False, clock_offset: float = 0.0, drift: float = 0.0,
                 period: float | None = None, clock: Clock | None = None, stamp_on_send: bool = False) -> None:
        super().__init__()
        self.profile = profile if isinstance(profile, Profile) else load_profile(profile)
        self.sim = self.profile.simulation
        self.rig = rig if rig is not None else SimulatedRig("ur5e", seed=seed)
        self.noise, self.latency, self.mixed, self.echo = noise, latency, mixed_endings, echo
        self.clock_offset, self.drift, self.stamp_on_send = clock_offset, drift, stamp_on_send
        self.clock: Clock = WallClock() if clock is None else clock
        self._scale = float(getattr(self.clock, "scale", 1.0))  # physical s per wall s (a ScaledClock's scale)
        self.period = float(self.sim.get("period", 0.0)) if period is None else float(period)
        self.seq = 0  # streamed lines so far (sent or not)
        self.lost_until = 0.0  # physical time (the clock's) until which streamed lines say target lost
        self.skip = 0  # streamed lines still to leave out
        self._due: list[tuple[float, bytes]] = []  # streamed lines waiting for their latency to pass
        self.rng = np.random.default_rng(seed)
        self._random = random.Random(seed)
        self.faults: list[str] = []
        self.hidden: set[int] = set()  # tracked point ids out of sight (profiles with several points)
        self.initialised = not self.sim.get("needs_init", False)
        self.streaming = not self.sim.get("needs_start", False)
        self.replies = 0
        self.commands: list[str] = []
        self.busy: list[float] = []  # s the device spent answering each trigger (its own response time)
        self._inbuf = b""
        self._lock = threading.Lock()
        self.transport = transport
        if transport == "pty":
            self.fd, self._slave = os.openpty()
            tty.setraw(self._slave)
            self.port = os.ttyname(self._slave)
            self._start()
        else:
            self._server = socket.create_server(("127.0.0.1", 0))
            self.port = f"socket://127.0.0.1:{self._server.getsockname()[1]}"
            self._start()

    def inject(self, fault: str, count: int = 1) -> None:
        if fault not in ASCII_FAULTS:
            raise ValueError(f"unknown fault {fault!r} (known: {', '.join(ASCII_FAULTS)})")
        with self._lock:
            self.faults.extend([fault] * count)

    def device_time(self, tau: float | None = None) -> float:
        """The device's clock (s) at physical time ``tau`` (s on ``clock``, default now)."""
        return self.clock_offset + (1.0 + self.drift) * (self.clock.now() if tau is None else tau)

    def lose_target(self, seconds: float) -> tuple[float, float]:
        """Streamed lines of the next ``seconds`` (physical time) say target lost; returns that span on the device's
        clock as the lines' stamps give it (with ``stamp_on_send``, ``latency`` later)."""
        now = self.clock.now()
        self.lost_until = now + seconds
        shift = self.latency if self.stamp_on_send else 0.0
        return self.device_time(now + shift), self.device_time(self.lost_until + shift)

    def skip_lines(self, count: int) -> None:
        self.skip += int(count)

    def reset(self) -> None:
        """Reboot now (unprompted): banner, initialisation lost, streaming stopped."""
        self._write_line(self.sim.get("banner", "RESET"))
        self.initialised = not self.sim.get("needs_init", False)
        self.streaming = not self.sim.get("needs_start", False)

    # --- serving ------------------------------------------------------------------------------------------

    def _serve(self) -> None:
        if self.transport == "tcp":
            self._accept_each(self._server, self._serve_connection)
        else:
            try:
                self._loop()
            finally:
                os.close(self.fd)
                os.close(self._slave)

    def _serve_connection(self, conn: socket.socket) -> None:
        self.fd = conn.fileno()
        self._loop()

    def _loop(self) -> None:
        period = self.period if self.profile.mode == "streaming" else 0.0
        clock = self.clock
        next_emit = clock.now()
        while not self._stop.is_set():
            due = [next_emit] if period and self.streaming else []
            due += [self._due[0][0]] if self._due else []
            wait = max(0.0, min([0.01, *((d - clock.now()) / self._scale for d in due)]))
            ready, _, _ = select.select([self.fd], [], [], wait)
            if ready:
                try:
                    data = os.read(self.fd, 4096)
                except OSError:
                    data = b""
                if not data:
                    if self.transport == "tcp":
                        return
                    time.sleep(0.01)  # pty: the other side is closed for now
                    continue
                self.received += data
                self._inbuf += data
                *lines, self._inbuf = re.split(rb"\r\n|\r|\n", self._inbuf)
                for raw in lines:
                    if raw.strip():
                        self._command(raw.decode("ascii", "replace").strip())
            if period and self.streaming and clock.now() >= next_emit:
                self._stream_line()
                next_emit = max(next_emit + period, clock.now() - period)
            while self._due and self._due[0][0] <= clock.now():
                self._write(self._due.pop(0)[1])

    def _stream_line(self) -> None:
        """One streamed line (module docstring); a pending fault spoils it as a polled reply's."""
        self.seq += 1
        if self.faults or not self.initialised:
            self._reply()
            return
        if self.skip:
            self.skip -= 1
            return
        now = self.clock.now()
        self.replies += 1
        stamp = self.device_time(now + self.latency if self.stamp_on_send else now)
        line = self._format(lost=now < self.lost_until, t=stamp, tau=now)
        data = line.encode() + self._eol()
        if self.latency:
            self._due.append((now + self.latency, data))
        else:
            self._write(data)

    def _command(self, text: str) -> None:
        self.commands.append(text)
        if self.echo:
            self._write_line(text)
        p = self.profile
        if p.identify is not None and text == p.identify[0]:
            self._write_line(self.sim.get("identity", "SIM"))
        elif any(text == c.send for c in p.init):
            self.initialised = True
            expects = [c for c in p.init if c.send == text and c.expect is not None]
            if expects:
                self._write_line(self.sim.get("init_reply", "OK"))
        elif p.start is not None and text == p.start:
            self.streaming = True
        elif p.stop is not None and text == p.stop:
            self.streaming = False
        elif p.trigger is not None and text == p.trigger:
            started = time.perf_counter()
            if self.latency:
                self.clock.sleep(self.latency)
            self._reply()
            self.busy.append(time.perf_counter() - started)

    def _next_fault(self) -> str | None:
        with self._lock:
            return self.faults.pop(0) if self.faults else None

    def _reply(self) -> None:
        if not self.initialised:
            self._write_line(self.sim.get("not_ready", "E07 NOT READY"))
            return
        self.replies += 1
        fault = self._next_fault()
        if fault == "silence":
            return
        if fault == "reset":
            self.reset()
            return
        if fault == "garbage":
            junk = bytes(self._random.randrange(256) for _ in range(24)).replace(b"\r", b"").replace(b"\n", b"")
            self._write(junk + b"\r\n")
            return
        line = self._format(lost=fault == "target_lost", far=fault == "out_of_range")
        if fault == "bad_checksum":
            line = line[:-1] + ("0" if line[-1] != "0" else "1")
        if fault == "truncated":
            line = line[: len(line) // 2]
        eol = self._eol()
        for tp in range(2, self.profile.points + 1):  # the other points' lines follow in the same write
            line += eol.decode() + self._format(lost=fault == "target_lost" or tp in self.hidden, tp=tp)
        if fault == "noise":
            self._write(b"\x00\x13\xfe\x7f" + line.encode() + b"\x01" + eol)
        elif fault == "partial":
            half = len(line) // 2
            self._write(line[:half].encode())
            time.sleep(0.02)
            self._write(line[half:].encode() + eol)
        else:
            self._write(line.encode() + eol)

    def _format(self, lost: bool = False, far: bool = False, tp: int = 1, t: float | None = None,
                tau: float | None = None) -> str:
        """One reply line; ``t`` its device time (default now), ``tau`` the physical time of the reading (the
        rig is sampled at it when the device runs on the rig's clock, else at the rig's now)."""
        sim = self.sim
        lost = lost or (self.profile.points > 1 and tp in self.hidden)
        if lost and "lost" in sim:
            return str(sim["lost"]).format(tp=tp)
        at = tau if self.clock is self.rig.clock else None
        true = self.rig.true_points(at)[tp - 1] if self.profile.points > 1 else self.rig.true_point(at)
        point = np.asarray(true, dtype=float) + self.rng.normal(0.0, self.noise, 3)
        if far:
            point = np.full(3, 1e6)
        x, y, z = point / self.profile.scale
        status = sim.get("lost_status", "TL") if lost else sim.get("ok", "OK")
        values = {"x": x, "y": y, "z": z, "status": status, "tp": tp, "seq": self.seq,
                  "t": self.device_time() if t is None else t}
        if "payload" in sim:
            payload = str(sim["payload"]).format(**values)
            algorithm = self.profile.checksum or "xor"
            return str(sim["reply"]).format(payload=payload, checksum=checksum_of(payload, algorithm))
        return str(sim["reply"]).format(**values)

    def _eol(self) -> bytes:
        if self.mixed:
            return self._random.choice([b"\r\n", b"\n", b"\r"])
        return self.profile.line_ending.encode()

    def _write_line(self, text: str) -> None:
        self._write(text.encode() + self._eol())

    def _write(self, data: bytes) -> None:
        with contextlib.suppress(OSError):
            os.write(self.fd, data)


# the I++ DME server lives in tests/ipp_device.py (kept importable from here)
from tests.ipp_device import IPP_FAULTS, IPP_TOOL_PROPERTIES, IppServer, free_port, open_ipp  # noqa: E402

__all__ = ["ASCII_FAULTS", "IPP_FAULTS", "IPP_TOOL_PROPERTIES", "AsciiDevice", "IppServer", "_Served", "free_port",
           "open_ipp"]
