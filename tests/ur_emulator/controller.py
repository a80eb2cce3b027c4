"""The emulated controller (threads on one loopback address); see tests/ur_emulator/__init__.py."""

from __future__ import annotations

import contextlib
import socket
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from drivers.errors import ConnectionFailed, EmergencyStop, ProtectiveStop, RobotFault
from drivers.motion import joint_durations as _durations
from drivers.sim.rig import SimulatedRig
from drivers.sim.robot import SimulatedRobot
from tests.ur_emulator.protocol import (
    CMD_MOVEJ,
    CMD_NONE,
    CMD_STOP_SCRIPT,
    CMD_STOPJ,
    CMD_STOPL,
    DASHBOARD_PORT,
    ROBOT_MODE_POWER_OFF,
    ROBOT_MODE_RUNNING,
    RTDE_PORT,
    RUNTIME_PLAYING,
    RUNTIME_STOPPED,
    SAFETY_BIT_ESTOP,
    SAFETY_BIT_NORMAL,
    SAFETY_BIT_PROTECTIVE,
    SAFETY_BIT_ROBOT_ESTOP,
    SAFETY_NORMAL,
    SAFETY_PROTECTIVE_STOP,
    SAFETY_ROBOT_EMERGENCY_STOP,
    SCRIPT_BUSY,
    SCRIPT_DONE,
    SCRIPT_PORTS,
    SCRIPT_READY,
    STATUS_POWER_ON,
    STATUS_PROGRAM_RUNNING,
)
from tests.ur_emulator.servers import ControllerServers


class ScaledClock:
    """Simulated time running ``scale`` times faster than the wall clock: ``now()`` s since the epoch,
    ``sleep(s)`` waits s / scale wall seconds. An emulated move of 1 s takes 1 / scale s."""

    def __init__(self, scale: float = 1.0) -> None:
        if not scale > 0:
            raise ValueError(f"time scale must be > 0, got {scale!r}")
        self.scale = float(scale)
        self._epoch, self._mono = time.time(), time.monotonic()

    def now(self) -> float:
        return self._epoch + self.scale * (time.monotonic() - self._mono)

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            time.sleep(seconds / self.scale)


@dataclass
class _Motion:
    start: np.ndarray
    target: np.ndarray
    speed: float
    acceleration: float
    t0: float
    duration: float
    thread: threading.Thread | None = None
    done: bool = False


@dataclass
class _Log:
    """What the clients did, for tests: commands executed, scripts received, dashboard lines."""

    commands: list[int] = field(default_factory=list)
    scripts: list[str] = field(default_factory=list)
    dashboard: list[str] = field(default_factory=list)
    unknown_variables: list[str] = field(default_factory=list)


class UREmulator(ControllerServers):
    """The emulated controller of ``model`` at ``host`` (a loopback address). See the module docstring."""

    def __init__(self, host: str = "127.0.0.1", model: str = "ur5e", *, rig: SimulatedRig | None = None,
                 version: tuple[int, int, int, int] = (5, 11, 1, 108318), serial: str = "20205500001",
                 remote_control: bool = True, rate: float = 125.0, stall: bool = False,
                 kinematics: bool = True, time_scale: float = 1.0, native_rate: bool = False) -> None:
        self.host, self.model, self.version, self.serial = host, model, version, serial
        clock = ScaledClock(time_scale)
        self.rig = rig if rig is not None else SimulatedRig(model, clock=clock, ring=1e-5, ring_tau=0.05)
        self.robot = SimulatedRobot(self.rig)
        self.robot.connect(1.0)
        self.remote_control, self.rate, self.stall, self.kinematics = remote_control, rate, stall, kinematics
        self.native_rate = native_rate
        self.late_packages = 0  # native rate: packages sent over half a period after their tick (all connections)
        self._dropped: tuple[float, float] = (0.0, 0.0)  # [start, end) controller s: RTDE packages not sent
        self.log = _Log()
        self._lock = threading.RLock()
        self._inputs: dict[str, Any] = {}  # input registers, shared by all RTDE clients as on a controller
        self._outputs: dict[str, Any] = {"output_int_register_0": SCRIPT_BUSY, "output_int_register_2": -1}
        self.robot_mode, self.safety_mode = ROBOT_MODE_RUNNING, SAFETY_NORMAL
        self._program_running, self._program_starts_at = False, 0.0
        self._motion: _Motion | None = None
        self._async_token = -1
        self._prev_q, self._prev_t = self.rig.actual_joints(), time.monotonic()
        self._servers: list[socket.socket] = []
        self._connections: set[socket.socket] = set()
        self._threads: list[threading.Thread] = []
        self._running = False
        self._frozen: dict[str, Any] | None = None  # the state the stream repeats while frozen
        self._trackers: list[Any] = []
        self._emscon: list[Any] = []  # simulated emScon servers (serve_emscon)
        self._ipp: list[Any] = []  # simulated I++ servers (serve_ipp)

    # --- lifecycle ------------------------------------------------------------------------------------------

    def start(self) -> UREmulator:
        self._running = True
        handlers = {RTDE_PORT: self._serve_rtde, DASHBOARD_PORT: self._serve_dashboard,
                    **{p: self._serve_script for p in SCRIPT_PORTS}}
        try:
            for port, handler in handlers.items():
                server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
                server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                server.bind((self.host, port))
                server.listen(8)
                server.settimeout(0.1)
                self._servers.append(server)
                self._spawn(self._accept_loop, server, handler)
        except OSError:
            self.close()
            raise
        self._spawn(self._tick_loop)
        return self

    def close(self) -> None:
        self._running = False
        self.rig._stop_requested = True
        for tracker in [*self._trackers, *self._emscon, *self._ipp]:
            tracker.stop()
        for s in [*self._servers, *list(self._connections)]:
            with contextlib.suppress(OSError):
                s.shutdown(socket.SHUT_RDWR)  # wakes a thread blocked in recv (close alone does not)
            with contextlib.suppress(OSError):
                s.close()
        for t in self._threads:
            t.join(timeout=2.0)
        self._servers.clear()

    def __enter__(self) -> UREmulator:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _spawn(self, target: Any, *args: Any) -> threading.Thread:
        thread = threading.Thread(target=target, args=args, daemon=True, name=f"ur-emulator-{target.__name__}")
        thread.start()
        self._threads.append(thread)
        return thread

    # --- faults ---------------------------------------------------------------------------------------------

    def protective_stop(self) -> None:
        """A protective stop now: motion stops, the program stops, safety mode PROTECTIVE_STOP."""
        self._latch(SAFETY_PROTECTIVE_STOP)

    def emergency_stop(self) -> None:
        self._latch(SAFETY_ROBOT_EMERGENCY_STOP)

    def clear_stop(self) -> None:
        """What the operator does on the teach pendant (unlock protective stop / release the e-stop)."""
        with self._lock:
            self.safety_mode, self.robot_mode = SAFETY_NORMAL, ROBOT_MODE_RUNNING
            self.rig.clear_faults()

    def drop_connections(self) -> None:
        """Close every client connection (the servers keep listening)."""
        for s in list(self._connections):
            with contextlib.suppress(OSError):
                s.shutdown(socket.SHUT_RDWR)
                s.close()

    def freeze_stream(self, frozen: bool = True) -> None:
        """Frozen: every RTDE stream keeps sending the same state (the timestamp stands still), the links stay
        up. ``False`` thaws it."""
        with self._lock:
            self._frozen = self._state() if frozen else None

    def drop_packets(self, count: int = 1) -> float:
        """Native rate only: the next ``count`` RTDE packages (ticks) are not sent on any connection, as a network
        that loses them would; returns the controller time (s) of the first one lost."""
        if not self.native_rate:
            raise RuntimeError("drop_packets needs native_rate=True (packages on the emulated clock's ticks)")
        period = 1.0 / self.rate
        with self._lock:
            first = (int(self.rig.clock.now() / period) + 2) * period
            self._dropped = (first - period / 2, first + (int(count) - 0.5) * period)
        return first

    def _dropped_at(self, t: float) -> bool:
        """True if the package of controller time ``t`` is lost (drop_packets)."""
        start, end = self._dropped
        return start <= t < end

    def truth(self) -> Any:
        """The emulated arm's true DHModel (base, tool: the simulated tracker's view); also its factory calibration."""
        return self.rig.truth

    def serve_tracker(self, profile: str = "polled-xyz", noise: float = 2e-5, seed: int = 0, *,
                      latency: float = 0.0, clock_offset: float = 0.0, drift: float = 0.0,
                      period: float | None = None) -> str:
        """Start a simulated ASCII tracker (tests/tracker_devices.py, loopback TCP) that measures this
        emulator's true TP (noise m per axis); returns its pyserial URL ``socket://127.0.0.1:PORT``.

        The device runs on the emulator's clock (emulated time: a streaming profile's ``period``, default the
        profile's, is in emulated seconds). A streamed reading taken at emulated time τ leaves ``latency`` s
        later stamped with the device time of leaving, ``clock_offset + (1 + drift)·(τ + latency)``, as the mock
        tracker stamps: the clock offset a session should find is ``-(latency + clock_offset)`` when drift is 0.
        A polled reply comes ``latency`` s after its trigger."""
        from tests.tracker_devices import AsciiDevice

        device = AsciiDevice(profile, self.rig, noise=noise, seed=seed, transport="tcp", latency=latency,
                             clock_offset=clock_offset, drift=drift, period=period, clock=self.rig.clock,
                             stamp_on_send=True)
        self._trackers.append(device)
        return str(device.port)

    def serve_emscon(self, noise: float = 2e-5, seed: int = 0, faults: str = "", angle_noise: float = 2e-5) -> int:
        """Start a simulated Leica emScon server (drivers/trackers/emscon_sim.py, loopback TCP) measuring this
        emulator's true TP (noise m per axis; its measurement time passes on the emulator's clock) and, for a 6-DoF
        probe, the rig's first target frame (``angle_noise`` rad per axis); ``faults``: ``NAME[@N][xK],...`` as
        ``emscon:sim?fault=``. Returns its port (``emscon:127.0.0.1:PORT``)."""
        from drivers.trackers.emscon_server import parse_faults
        from drivers.trackers.emscon_sim import EmsconSimServer

        server = EmsconSimServer(self.rig, noise=noise, seed=seed, faults=parse_faults(faults) if faults else (),
                                 angle_noise=angle_noise)
        self._emscon.append(server)
        return int(server.port)

    def serve_ipp(self, noise: float = 2e-5, seed: int = 0) -> int:
        """Start a simulated I++ DME server (tests/ipp_device.py, loopback TCP, with ``OnMoveReportE`` reports at the
        rate asked) measuring this emulator's true TP (noise m per axis). Its reports run on the wall clock and are
        stamped by the client on arrival: stream with it at time scale 1 only. Returns its port
        (``ipp://127.0.0.1:PORT``)."""
        from tests.ipp_device import IppServer

        server = IppServer(self.rig, noise=noise, seed=seed, move_reports=True)
        self._ipp.append(server)
        return int(server.port)

    def inject_emscon(self, fault: str, count: int = 1) -> None:
        """The last simulated emScon server's ``inject`` (drivers/trackers/emscon_sim.py): a fault on its next
        measurement, or for a ``stream_`` fault its next continuous packet."""
        self._emscon[-1].inject(fault, count)

    def emscon_boot(self) -> float:
        """The emulated time (s) at which the last simulated emScon tracker's clock read 0: a continuous point stamped
        ``t`` by it was taken at controller time ``t + emscon_boot()`` (its drift is 0)."""
        return float(self._emscon[-1].boot)

    def emscon_connections(self) -> int:
        """Connections the simulated emScon servers accepted so far (one per link the client opened)."""
        return sum(server.connections for server in self._emscon)

    def last_motion(self) -> tuple[float, float] | None:
        """(start, duration) of the latest move on the emulator's clock (s since the epoch, s), or None."""
        motion = self._motion
        return None if motion is None else (motion.t0, motion.duration)

    def lose_tracker_target(self, seconds: float) -> tuple[float, float]:
        """The simulated streaming tracker loses its target for the next ``seconds`` (emulated s); returns that span
        on its clock, as its lines' stamps give it (tests/tracker_devices.py, ``AsciiDevice.lose_target``)."""
        if not self._trackers:
            raise RuntimeError("no simulated tracker: call serve_tracker first")
        return self._trackers[-1].lose_target(seconds)

    def tracker_replies(self) -> int:
        """Measurements the simulated trackers answered so far."""
        return sum(t.replies for t in self._trackers)

    def _latch(self, mode: int) -> None:
        with self._lock:
            self.safety_mode = mode
            if mode == SAFETY_ROBOT_EMERGENCY_STOP:
                self.robot_mode = ROBOT_MODE_POWER_OFF
            self.rig._stop_requested = True
            self._stop_program()

    def _stop_program(self) -> None:
        self._program_running = False
        self._outputs["output_int_register_0"] = SCRIPT_BUSY

    # --- state ----------------------------------------------------------------------------------------------

    @property
    def program_running(self) -> bool:
        return self._program_running

    def actual_q(self, t: float | None = None) -> np.ndarray:
        """The arm's joints (6,) rad at emulated time ``t`` (default now): the rig's, which follow a running move's
        profile on the clock, so the RTDE stream and the simulated tracker see one arm."""
        return np.asarray(self.rig.actual_joints(self.rig.clock.now() if t is None else t), dtype=float)

    def _state(self, t: float | None = None) -> dict[str, Any]:
        now = self.rig.clock.now() if t is None else t
        q = self.actual_q(now)
        qd = (self.actual_q(now + 1e-3) - q) / 1e-3
        motion = self._motion
        target = motion.target if motion is not None and not motion.done else q
        status = STATUS_POWER_ON if self.robot_mode == ROBOT_MODE_RUNNING else 0
        status |= STATUS_PROGRAM_RUNNING if self._program_running else 0
        bits = {SAFETY_NORMAL: SAFETY_BIT_NORMAL, SAFETY_PROTECTIVE_STOP: SAFETY_BIT_PROTECTIVE,
                SAFETY_ROBOT_EMERGENCY_STOP: SAFETY_BIT_ROBOT_ESTOP | SAFETY_BIT_ESTOP}[self.safety_mode]
        return {"timestamp": now, "actual_q": tuple(q), "actual_qd": tuple(qd), "target_q": tuple(target),
                "target_qd": tuple(qd), "robot_mode": self.robot_mode, "safety_mode": self.safety_mode,
                "safety_status": self.safety_mode, "robot_status_bits": status, "safety_status_bits": bits,
                "runtime_state": RUNTIME_PLAYING if self._program_running else RUNTIME_STOPPED,
                "speed_scaling": 1.0, "target_speed_fraction": 1.0, "joint_mode": (253,) * 6,
                "joint_temperatures": (30.0,) * 6, "actual_main_voltage": 48.0, "actual_robot_voltage": 48.0,
                **self._outputs}

    # --- the control script (register handshake) -------------------------------------------------------------

    def _tick_loop(self) -> None:
        while self._running:
            time.sleep(0.002)
            with self._lock:
                self._tick()

    def _tick(self) -> None:
        if self._program_starts_at and time.monotonic() >= self._program_starts_at:
            self._program_starts_at = 0.0
            if self.safety_mode == SAFETY_NORMAL:
                self._program_running = True
                self._outputs["output_int_register_0"] = SCRIPT_READY
        if not self._program_running:
            return
        cmd = int(self._inputs.get("input_int_register_0", 0))
        state = self._outputs["output_int_register_0"]
        if state == SCRIPT_DONE and cmd == CMD_NONE:
            self._outputs["output_int_register_0"] = SCRIPT_READY
        elif state == SCRIPT_READY and cmd != CMD_NONE:
            self.log.commands.append(cmd)
            self._outputs["output_int_register_0"] = SCRIPT_BUSY
            self._execute(cmd)

    def _execute(self, cmd: int) -> None:
        regs = self._inputs
        doubles = [float(regs.get(f"input_double_register_{k}", 0.0)) for k in range(8)]
        if cmd == CMD_STOP_SCRIPT:
            self._stop_program()
            return
        if cmd == CMD_MOVEJ:
            asynchronous = int(regs.get("input_int_register_1", 0)) == 1
            self._start_move(np.array(doubles[:6]), doubles[6], doubles[7], asynchronous)
            return
        if cmd in (CMD_STOPJ, CMD_STOPL):
            self._halt()
        self._outputs["output_int_register_0"] = SCRIPT_DONE

    def _halt(self) -> None:
        """Stop the running move (if any) and wait until the arm rests (called with the lock held)."""
        motion = self._motion
        if motion is None or motion.thread is None or not motion.thread.is_alive():
            return
        self.rig._stop_requested = True
        if motion.thread is not threading.current_thread():
            self._lock.release()
            try:
                motion.thread.join(timeout=5.0)
            finally:
                self._lock.acquire()

    def _start_move(self, target: np.ndarray, speed: float, acceleration: float, asynchronous: bool) -> None:
        self._halt()  # a new moveJ replaces the running one (the arm stops, then goes to the new target)
        start = self.rig.rest_joints
        duration = float(np.max(_durations(start, target, [speed] * 6, [acceleration] * 6), initial=0.0))
        motion = _Motion(start, target, speed, acceleration, self.rig.clock.now(), duration)
        if asynchronous:
            self._outputs["output_int_register_2"] = 0
            self._outputs["output_int_register_0"] = SCRIPT_DONE
        motion.thread = threading.Thread(target=self._run_move, args=(motion, asynchronous), daemon=True)
        self._motion = motion
        motion.thread.start()

    def _run_move(self, motion: _Motion, asynchronous: bool) -> None:
        n = len(motion.target)
        motion.t0 = self.rig.clock.now()  # the rig's move starts now: last_motion() reports when the arm moved
        try:
            if self.stall:  # a move that never finishes: the arm stays put, the script never reports done
                motion.target, motion.duration = motion.start.copy(), float("inf")
                while self._running and not self.rig._stop_requested:
                    time.sleep(0.01)
                return
            self.robot.move_joints(motion.target, [motion.speed] * n, [motion.acceleration] * n,
                                   timeout=max(motion.duration * 2 + 1.0, 1.0))
        except ProtectiveStop:
            self._latch(SAFETY_PROTECTIVE_STOP)
        except EmergencyStop:
            self._latch(SAFETY_ROBOT_EMERGENCY_STOP)
        except ConnectionFailed:  # the rig's "disconnect" fault: the network drops, the arm stays put
            self.rig.robot_connected = True
            self.drop_connections()
        except (RobotFault, ValueError):
            pass  # stopped by stopJ, or a target the script refuses: the move just ends
        finally:
            with self._lock:
                motion.done = True
                if asynchronous:
                    self._async_token = -2 if self._async_token == -1 else -1
                    self._outputs["output_int_register_2"] = self._async_token
                elif self._program_running:
                    self._outputs["output_int_register_0"] = SCRIPT_DONE
