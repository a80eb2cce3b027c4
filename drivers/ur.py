"""Universal Robots arms (CB3 and e-Series, UR3 to UR30) over RTDE with the ``ur_rtde`` package.

Spec form (see drivers/spec.py)::

    ur5e@192.168.1.10[?key=value&...]     or  ur5e  (host from the site file: robot.hosts / robot.host)

Options (unknown ones are refused): ``reconnects`` (int >= 0, default 3: attempts after a lost link),
``still_speed`` (rad/s, default 2e-3: joints slower than this count as still), ``max_speed`` (rad/s, default
1.0: the highest joint speed a move may ask for, at most the model's maximum), ``max_acceleration`` (rad/s²,
default 2.0), ``remote_check`` (``on``/``off``, default on: refuse a controller not in remote control).
The port cannot be chosen: ur_rtde uses the controller's fixed ports (30004 RTDE, 29999 dashboard, 30003 script).

How it drives the arm:

- ``connect`` first probes the dashboard server (a plain socket, a few seconds at most), so a wrong or
  unreachable host fails fast with one line; there it checks the model (``get robot model`` and the PolyScope
  major version: 5 = e-Series, 3 = CB3) and, on e-Series, remote control. Then it opens
  ``RTDEReceiveInterface`` (state stream) and ``RTDEControlInterface`` (which uploads ur_rtde's control script).
- ``move_joints`` sends ``moveJ(q, speed, acceleration, asynchronous=True)`` and watches the state stream until
  the arm is at the target and still, so that a timeout, ``stop()`` or Ctrl-C can cut in with ``stopJ`` (a
  blocking moveJ holds the control interface, and a stopJ from elsewhere would wait for it to finish). UR's
  moveJ takes one speed for the leading joint: the smallest of the per-joint values is used.
- readings are ``getActualQ`` (encoder values); ``wait_until_still`` watches ``getActualQd``.
- robot mode and safety mode are checked before every move and while moving and settling; a protective stop,
  emergency stop, safeguard stop or a powered-off arm raises with what to do on the teach pendant.
- a lost link is retried ``reconnects`` times, then ConnectionFailed.

The ur_rtde import happens in :func:`open_robot` (BackendUnavailable with the pip command without it).
"""

from __future__ import annotations

import contextlib
import json
import math
import socket
import struct
import threading
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from config.robots import ConfigError, RobotModel, load_robot
from drivers.base import Array, DeviceIdentity, RobotState
from drivers.errors import (
    BackendUnavailable,
    ConnectionFailed,
    DeviceTimeout,
    EmergencyStop,
    ProtectiveStop,
    RobotFault,
    SpecError,
)
from drivers.spec import ROBOT_FORMS, RobotSpec

RTDE_PORT, DASHBOARD_PORT, PRIMARY_PORT = 30004, 29999, 30001
CALIBRATION_TIMEOUT = 1.5  # s, at most, to read the kinematics info on the primary interface
INSTALL_HINT = "pip install 'dh-calib[ur]'"
PROBE_TIMEOUT = 3.0  # s, at most, for the first contact with the controller
POLL_PERIOD = 0.008  # s, about one RTDE package at 125 Hz
POSITION_TOLERANCE = 1e-3  # rad: a move has arrived when every joint is this close to its target
STOP_DECELERATION = 2.0  # rad/s², stopJ

#: Option -> (default, meaning).
OPTIONS: dict[str, tuple[object, str]] = {
    "reconnects": (3, "attempts to reconnect after a lost link (integer >= 0)"),
    "still_speed": (2e-3, "joint speed below which the arm counts as still, rad/s"),
    "max_speed": (1.0, "highest joint speed a move may ask for, rad/s"),
    "max_acceleration": (2.0, "highest joint acceleration a move may ask for, rad/s^2"),
    "remote_check": ("on", "refuse a controller that is not in remote control (on/off)"),
}

# RTDE robot_mode and safety_mode values (UR's RTDE guide)
ROBOT_MODES = {-1: "NO_CONTROLLER", 0: "DISCONNECTED", 1: "CONFIRM_SAFETY", 2: "BOOTING", 3: "POWER_OFF",
               4: "POWER_ON", 5: "IDLE", 6: "BACKDRIVE", 7: "RUNNING", 8: "UPDATING_FIRMWARE"}
SAFETY_MODES = {1: "NORMAL", 2: "REDUCED", 3: "PROTECTIVE_STOP", 4: "RECOVERY", 5: "SAFEGUARD_STOP",
                6: "SYSTEM_EMERGENCY_STOP", 7: "ROBOT_EMERGENCY_STOP", 8: "VIOLATION", 9: "FAULT",
                10: "VALIDATE_JOINT_ID", 11: "UNDEFINED", 12: "AUTOMATIC_MODE_SAFEGUARD_STOP",
                13: "SYSTEM_THREE_POSITION_ENABLING_STOP"}
ROBOT_MODE_RUNNING = 7
SAFETY_OK = (1, 2)  # normal, reduced
SAFETY_PROTECTIVE = (3, 5, 12, 13)
SAFETY_EMERGENCY = (6, 7)

PROTECTIVE_HELP = ("on the teach pendant: find and remove the cause (collision, obstacle, limit), press 'Unlock' "
                   "(e-Series: 'Enable') in the protective-stop dialog, switch back to Remote Control, then "
                   "resume the run")
SAFEGUARD_HELP = ("the safeguard input is open: close the guard door / reset the light curtain, then resume "
                  "the run")
EMERGENCY_HELP = ("release the emergency-stop button, on the teach pendant confirm the dialog, power on and "
                  "release the brakes (Initialize screen), switch back to Remote Control, then resume the run")
POWER_HELP = ("on the teach pendant: power on and release the brakes (Initialize screen), switch back to "
              "Remote Control, then resume the run")


def _rtde_modules() -> tuple[Any, Any]:
    """(rtde_control, rtde_receive), imported now; BackendUnavailable without ur_rtde."""
    try:
        import rtde_control
        import rtde_receive
    except ImportError as exc:
        raise BackendUnavailable(f"the 'ur' robot backend needs the ur_rtde package, which is not installed: "
                                 f"{INSTALL_HINT}") from exc
    return rtde_control, rtde_receive


def _options(spec: RobotSpec) -> dict[str, Any]:
    text = str(spec)
    out: dict[str, Any] = {key: default for key, (default, _) in OPTIONS.items()}
    for key, value in spec.options.items():
        if key not in OPTIONS:
            raise SpecError(f"unknown option {key!r} of a UR robot in {text!r} (known: {', '.join(OPTIONS)}); "
                            f"expected {ROBOT_FORMS}")
        try:
            if key == "reconnects":
                if not value.isdigit():
                    raise ValueError
                out[key] = int(value)
            elif key == "remote_check":
                if value not in ("on", "off"):
                    raise ValueError
                out[key] = value
            else:
                number = float(value)
                if not (math.isfinite(number) and number > 0):
                    raise ValueError
                out[key] = number
        except ValueError:
            raise SpecError(f"option {key}={value} in {text!r} must be {OPTIONS[key][1]}") from None
    return out


def open_robot(spec: RobotSpec | str, rig: object = None, site: Any = None) -> URRobot:
    """The UR robot of ``spec`` (unconnected). The host is the spec's, else the site configuration's."""
    spec = spec if isinstance(spec, RobotSpec) else RobotSpec.parse(spec)
    if spec.backend != "ur":
        raise SpecError(f"drivers.ur opens real UR robots (MODEL@HOST), got {str(spec)!r}")
    if rig is not None:
        raise SpecError(f"a real UR robot ({spec}) cannot be used with a simulated rig; use mock:{spec.model}")
    if spec.port is not None:
        raise SpecError(f"{str(spec)!r}: a UR robot takes no port (ur_rtde uses the controller's fixed ports); "
                        f"write {spec.model}@HOST")
    options = _options(spec)
    host = spec.host or (site.host_for(spec.model) if site is not None else None)
    if not host:
        raise SpecError(f"no address for robot {str(spec)!r}: write {spec.model}@HOST or set robot.hosts."
                        f"{spec.model.lower()} (or robot.host) in the site file")
    try:
        model = load_robot(spec.model)
    except ConfigError as exc:
        raise SpecError(f"robot spec {str(spec)!r}: {exc}") from exc
    if not model.vendor.lower().startswith("universal"):
        raise SpecError(f"robot spec {str(spec)!r}: {model.name} is not a Universal Robots model")
    modules = _rtde_modules()
    return URRobot(model, host, options, modules)


class _Dashboard:
    """A minimal dashboard-server client (port 29999): one command, one reply line."""

    def __init__(self, host: str, timeout: float) -> None:
        self.sock = socket.create_connection((host, DASHBOARD_PORT), timeout=timeout)
        self.file = self.sock.makefile("rb")
        self.greeting = self._line()

    def _line(self) -> str:
        line = self.file.readline()
        if not line:
            raise ConnectionError("the dashboard server closed the connection")
        return line.decode(errors="replace").strip()

    def ask(self, command: str) -> str:
        self.sock.sendall(command.encode() + b"\n")
        return self._line()

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self.sock.sendall(b"quit\n")
        with contextlib.suppress(OSError):
            self.file.close()
            self.sock.close()


def _dashboard_model(name: str) -> str:
    """ur5e -> UR5 (what ``get robot model`` answers; e-Series and CB3 alike)."""
    name = name.upper()
    return name[:-1] if name.endswith("E") else name


def _polyscope_major(text: str) -> int | None:
    for word in text.split():
        head = word.split(".")[0]
        if "." in word and head.isdigit():
            return int(head)
    return None


def read_factory_calibration(host: str, timeout: float) -> dict[str, Any]:
    """The controller's own calibrated DH values, from the kinematics info (robot state sub-package 5) that the
    primary client interface (port 30001) sends after connecting: ``{"theta": [6], "a": [6], "d": [6],
    "alpha": [6], "checksum": [6], "status": int}`` in UR's convention (rad, m). OSError / ValueError when it
    cannot be read within ``timeout`` s."""
    deadline = time.monotonic() + timeout
    with socket.create_connection((host, PRIMARY_PORT), timeout=timeout) as sock:
        buffer = b""
        while time.monotonic() < deadline:
            sock.settimeout(max(deadline - time.monotonic(), 0.01))
            chunk = sock.recv(65536)
            if not chunk:
                break
            buffer += chunk
            while len(buffer) >= 5:
                size, kind = struct.unpack_from(">iB", buffer)
                if size < 5 or size > 1 << 20:
                    raise ValueError(f"garbled primary-interface message (length {size})")
                if len(buffer) < size:
                    break
                message, buffer = buffer[5:size], buffer[size:]
                if kind == 16 and (found := _kinematics_info(message)) is not None:
                    return found
    raise ValueError(f"no kinematics info from port {PRIMARY_PORT} within {timeout:g} s")


def _kinematics_info(message: bytes) -> dict[str, Any] | None:
    offset = 0
    while offset + 5 <= len(message):
        size, kind = struct.unpack_from(">iB", message, offset)
        if size < 5:
            return None
        if kind == 5 and size >= 5 + 24 + 192:
            body = message[offset + 5:offset + size]
            checksum = list(struct.unpack_from(">6I", body))
            values = struct.unpack_from(">24d", body, 24)
            status = struct.unpack_from(">I", body, 216)[0] if len(body) >= 220 else -1
            keys = ("theta", "a", "d", "alpha")
            return {**{key: list(values[6 * i:6 * i + 6]) for i, key in enumerate(keys)}, "checksum": checksum,
                    "status": status}
        offset += size
    return None


class URRobot:
    """A UR arm through ur_rtde (implements :class:`drivers.base.Robot`). See the module docstring."""

    def __init__(self, model: RobotModel, host: str, options: dict[str, Any], modules: tuple[Any, Any]) -> None:
        self.model, self.host, self.options = model, host, options
        self.joint_types = model.joint_types
        self._control_module, self._receive_module = modules
        self._control: Any = None
        self._receive: Any = None
        self._identity = DeviceIdentity("robot", model.name, details={"host": host})
        self._stop = threading.Event()
        self.factory_calibration: dict[str, Any] | None = None  # by connect(): theta, a, d, alpha, ... or None
        self.still_speed = float(options["still_speed"])
        self.poll_period = POLL_PERIOD

    # --- connection -------------------------------------------------------------------------------------------

    def connect(self, timeout: float) -> None:
        if not timeout > 0:
            raise ValueError(f"timeout must be > 0 s, got {timeout!r}")
        self.close()
        identity = self._check_dashboard(min(timeout, PROBE_TIMEOUT))
        try:
            self.factory_calibration = read_factory_calibration(self.host, min(timeout, CALIBRATION_TIMEOUT))
            calibration = json.dumps(self.factory_calibration, separators=(",", ":"))
        except (OSError, ValueError) as exc:
            self.factory_calibration = None
            calibration = f"unavailable ({' '.join(str(exc).split()) or type(exc).__name__})"
        self._identity = DeviceIdentity(identity.kind, identity.model, identity.serial, identity.firmware,
                                        {**identity.details, "factory_calibration": calibration})
        try:
            self._receive = self._receive_module.RTDEReceiveInterface(self.host)
            self._control = self._control_module.RTDEControlInterface(self.host)
        except (RuntimeError, ValueError, OSError) as exc:
            self.close()
            raise ConnectionFailed(f"the UR controller at {self.host} refused the RTDE connection: "
                                   f"{' '.join(str(exc).split())}") from exc

    def _check_dashboard(self, timeout: float) -> DeviceIdentity:
        where = f"the UR controller at {self.host}"
        try:
            dashboard = _Dashboard(self.host, timeout)
        except OSError as exc:
            reason = "no answer" if isinstance(exc, TimeoutError) else (exc.strerror or str(exc))
            raise ConnectionFailed(f"cannot reach {where} (dashboard port {DASHBOARD_PORT}: {reason}); check the "
                                   "address, the network cable and that the controller is switched on") from None
        try:
            answers = {key: dashboard.ask(command) for key, command in (
                ("version", "PolyscopeVersion"), ("model", "get robot model"), ("serial", "get serial number"))}
            major = _polyscope_major(answers["version"])
            if major is not None and major >= 5 and self.options["remote_check"] == "on":
                answers["remote"] = dashboard.ask("is in remote control")
        except OSError as exc:
            raise ConnectionFailed(f"{where} stopped answering on the dashboard port: {exc}") from None
        finally:
            dashboard.close()
        self._check_model(answers["model"], major)
        if answers.get("remote", "true").strip().lower() != "true":
            raise ConnectionFailed(f"{where} is not in remote control: on the teach pendant tap the Local/Remote "
                                   "switch (top right) and choose Remote Control, then connect again")
        details = {"host": self.host, "dashboard_model": answers["model"], "polyscope": answers["version"]}
        firmware = answers["version"].removeprefix("URSoftware").strip()
        return DeviceIdentity("robot", self.model.name, serial=answers["serial"], firmware=firmware,
                              details=details)

    def _check_model(self, reported: str, major: int | None) -> None:
        expected = _dashboard_model(self.model.name)
        reported_name = reported.strip().upper()
        if not reported_name.startswith("UR"):
            return  # an old controller without "get robot model": it cannot tell
        e_series = self.model.name.lower().endswith("e") or expected in ("UR20", "UR30")
        series_ok = major is None or (major >= 5) == e_series
        if reported_name != expected or not series_ok:
            series = "" if major is None else (" (PolyScope 5+)" if major >= 5 else " (CB3)")
            newer = major is not None and major >= 5 and reported_name not in ("UR20", "UR30")
            suggestion = reported_name.lower() + ("e" if newer else "")
            raise ConnectionFailed(f"refusing {self.host}: the controller reports a {reported_name}{series} but the "
                                   f"spec says {self.model.name}; give the right model (e.g. {suggestion}@{self.host})")

    def close(self) -> None:
        control, receive = self._control, self._receive
        self._control = self._receive = None
        with contextlib.suppress(Exception):
            if control is not None:
                control.stopScript()
        for device in (control, receive):
            with contextlib.suppress(Exception):
                if device is not None:
                    device.disconnect()

    def identity(self) -> DeviceIdentity:
        return self._identity

    # --- state ------------------------------------------------------------------------------------------------

    def state(self) -> RobotState:
        receive = self._receive
        if receive is None or self._control is None:
            return RobotState.DISCONNECTED
        try:
            if not receive.isConnected():
                return RobotState.DISCONNECTED
            robot_mode, safety_mode = int(receive.getRobotMode()), int(receive.getSafetyMode())
            qd = np.asarray(receive.getActualQd(), dtype=float)
        except RuntimeError:
            return RobotState.DISCONNECTED
        if safety_mode in SAFETY_PROTECTIVE:
            return RobotState.PROTECTIVE_STOP
        if safety_mode in SAFETY_EMERGENCY:
            return RobotState.EMERGENCY_STOP
        if safety_mode not in SAFETY_OK or robot_mode != ROBOT_MODE_RUNNING:
            return RobotState.FAULT
        return RobotState.MOVING if np.max(np.abs(qd), initial=0.0) > self.still_speed else RobotState.READY

    def _check(self) -> None:
        """Raise the RobotFault that fits the controller's state (nothing when it can be commanded)."""
        receive = self._require_link()
        robot_mode, safety_mode = int(receive.getRobotMode()), int(receive.getSafetyMode())
        mode = SAFETY_MODES.get(safety_mode, str(safety_mode))
        if safety_mode in (5, 12):
            raise ProtectiveStop(f"UR safeguard stop ({mode}) at {self.host}: {SAFEGUARD_HELP}")
        if safety_mode in SAFETY_PROTECTIVE:
            raise ProtectiveStop(f"UR protective stop at {self.host}: {PROTECTIVE_HELP}")
        if safety_mode in SAFETY_EMERGENCY:
            raise EmergencyStop(f"UR emergency stop ({mode}) at {self.host}: {EMERGENCY_HELP}")
        if safety_mode not in SAFETY_OK:
            raise RobotFault(f"UR safety mode {mode} at {self.host}: read the message on the teach pendant, "
                             "clear it (restart the controller after a FAULT or VIOLATION), then resume the run")
        if robot_mode != ROBOT_MODE_RUNNING:
            name = ROBOT_MODES.get(robot_mode, str(robot_mode))
            raise RobotFault(f"the UR arm at {self.host} is not running (robot mode {name}): {POWER_HELP}")

    def _require_link(self) -> Any:
        receive = self._receive
        if receive is None or self._control is None:
            raise ConnectionFailed(f"the UR robot at {self.host} is not connected (call connect())")
        if not receive.isConnected() or not self._control.isConnected():
            self._reconnect()
        return self._receive

    def _reconnect(self) -> None:
        attempts = int(self.options["reconnects"])
        for attempt in range(attempts):
            time.sleep(min(0.5 * (attempt + 1), 2.0))
            with contextlib.suppress(RuntimeError):
                if not self._receive.isConnected():
                    self._receive.reconnect()
                if not self._control.isConnected():
                    self._control.reconnect()
                if self._receive.isConnected() and self._control.isConnected():
                    return
        raise ConnectionFailed(f"lost the connection to the UR controller at {self.host} and {attempts} "
                               "reconnection attempts failed: check the network, then resume the run")

    # --- motion -----------------------------------------------------------------------------------------------

    def read_joints(self) -> Array:
        """Actual joint positions (6,), rad: the encoder values of the last RTDE package."""
        receive = self._require_link()
        try:
            return np.asarray(receive.getActualQ(), dtype=float)
        except RuntimeError as exc:
            raise ConnectionFailed(f"cannot read the joints of the UR robot at {self.host}: {exc}") from exc

    def move_joints(self, q: Sequence[float], speed: Sequence[float], acceleration: Sequence[float],
                    timeout: float) -> None:
        target, v, a = self._checked(q, speed, acceleration, timeout)
        self._check()
        control = self._control
        if not control.isProgramRunning():  # e.g. after a cleared protective stop
            control.reuploadScript()
            self._wait(lambda: control.isProgramRunning(), 2.0, "the ur_rtde control script did not start")
        self._stop.clear()
        started = time.monotonic()
        try:
            if not control.moveJ(target.tolist(), v, a, True):
                self._check()
                raise RobotFault(f"the UR controller at {self.host} refused the move (moveJ returned false); "
                                 "check the teach pendant for a message")
            self._watch_move(target, started + timeout, timeout)
        except KeyboardInterrupt:
            self.stop()
            raise

    def _watch_move(self, target: Array, deadline: float, timeout: float) -> None:
        receive = self._receive
        while True:
            self._check()
            if self._stop.is_set():
                raise RobotFault(f"the move of the UR robot at {self.host} was stopped (stop()) before it arrived")
            q = np.asarray(receive.getActualQ(), dtype=float)
            qd = np.asarray(receive.getActualQd(), dtype=float)
            if np.max(np.abs(q - target)) < POSITION_TOLERANCE and np.max(np.abs(qd)) < self.still_speed:
                return
            if time.monotonic() >= deadline:
                self.stop()
                raise DeviceTimeout(f"the UR robot at {self.host} did not reach its target within {timeout:g} s; "
                                    "it was stopped (stopJ)")
            time.sleep(self.poll_period)

    def wait_until_still(self, settle_time: float, timeout: float) -> None:
        """Return once every actual joint speed has stayed below ``still_speed`` for ``settle_time`` s."""
        start = time.monotonic()
        since: float | None = None
        receive = self._receive
        while True:
            self._check()
            now = time.monotonic()
            qd = np.asarray(receive.getActualQd(), dtype=float)
            if np.max(np.abs(qd), initial=0.0) < self.still_speed:
                since = now if since is None else since
                if now - since >= settle_time:
                    return
            else:
                since = None
            if now - start >= timeout:
                raise DeviceTimeout(f"the UR robot at {self.host} did not settle ({settle_time:g} s with joint "
                                    f"speeds below {self.still_speed:g} rad/s) within {timeout:g} s")
            time.sleep(self.poll_period)

    def stop(self) -> None:
        """Stop any motion now (stopJ); never raises."""
        self._stop.set()
        control = self._control
        with contextlib.suppress(Exception):
            if control is not None:
                control.stopJ(STOP_DECELERATION, False)

    def _wait(self, condition: Any, timeout: float, message: str) -> None:
        deadline = time.monotonic() + timeout
        while not condition():
            if time.monotonic() > deadline:
                raise RobotFault(f"{message} on the UR controller at {self.host} within {timeout:g} s")
            time.sleep(0.01)

    def _checked(self, q: Sequence[float], speed: Sequence[float], acceleration: Sequence[float],
                 timeout: float) -> tuple[Array, float, float]:
        model, n = self.model, len(self.joint_types)
        target, vs, accs = (np.asarray(x, dtype=float).reshape(-1) for x in (q, speed, acceleration))
        for name, values in (("target", target), ("speed", vs), ("acceleration", accs)):
            if values.shape != (n,) or not np.all(np.isfinite(values)):
                raise ValueError(f"{name} must be {n} finite numbers, got {values.tolist()}")
        for i, (value, (lo, hi)) in enumerate(zip(target, model.limits, strict=True)):
            if not lo <= value <= hi:
                raise ValueError(f"joint {i + 1} target {value:.6g} is outside its limits [{lo:.6g}, {hi:.6g}]")
        v, a = float(np.min(vs)), float(np.min(accs))
        top = min(float(self.options["max_speed"]), float(np.min(model.max_speed)))
        if not 0 < v <= top * (1 + 1e-9):
            raise ValueError(f"joint speed {v:.6g} rad/s must be in (0, {top:.6g}] (option max_speed)")
        if not 0 < a <= float(self.options["max_acceleration"]) * (1 + 1e-9):
            raise ValueError(f"joint acceleration {a:.6g} rad/s² must be in (0, {self.options['max_acceleration']:g}]"
                             " (option max_acceleration)")
        if not timeout > 0:
            raise ValueError(f"timeout must be > 0 s, got {timeout!r}")
        return target, v, a
