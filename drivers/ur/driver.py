"""Universal Robots arms (CB3 and e-Series, UR3 to UR30) over RTDE with the ``ur_rtde`` package.

Spec form (see drivers/spec.py)::

    ur5e@192.168.1.10[?key=value&...]     or  ur5e  (host from the site file: robot.hosts / robot.host)

Options (unknown ones are refused): ``reconnects`` (int >= 0, default 3: fresh connections tried after a
lost link, per operation), ``still_speed`` (rad/s, default 2e-3: joints slower than this count as still),
``max_speed`` (rad/s, default 1.0: the highest joint speed a move may ask for, at most the model's maximum),
``max_acceleration`` (rad/s², default 2.0), ``remote_check`` (``on``/``off``, default on: refuse a controller
not in remote control), ``stream_timeout`` (s, default 1.0: a state stream whose timestamp stands still this
long is a lost link), ``rtde_frequency`` (Hz, default the controller's native rate: 500 on e-Series, 125 on
CB3; the rate of the state stream and of the recorded joint stream). The port cannot be chosen: the
controller's ports are fixed (30004 RTDE, 29999 dashboard, 30003 script, 30001 primary interface).

How it drives the arm:

- ``connect`` first probes the dashboard server (a plain socket, a few seconds at most), so a wrong or
  unreachable host fails fast with one line; there it checks the model (``get robot model`` and the PolyScope
  major version: 5 = e-Series, 3 = CB3) and, on e-Series, remote control. It reads the factory calibration
  (drivers/ur/info.py; ``factory_calibration``, None when the controller does not give it). Then it starts
  the ur_rtde worker process (drivers/ur/worker.py), which opens ``RTDEReceiveInterface`` (state stream) and
  ``RTDEControlInterface`` (which uploads ur_rtde's control script). ur_rtde never runs in this process: a
  crash or hang of ur_rtde is a lost link here, not a crash of the acquisition.
- every check reads one snapshot of the state stream (link, timestamp, robot and safety mode, actual q and qd,
  program running) in one request to the worker.
- ``move_joints`` sends ``moveJ(q, speed, acceleration, asynchronous=True)`` and watches the state stream until
  the arm is at the target and still, so that a timeout, ``stop()`` or Ctrl-C can cut in with ``stopJ``. UR's
  moveJ takes one speed and acceleration, the leading joint's (the largest travel): the largest that keeps every
  moving joint within its own value is sent (drivers/motion.py), so a move of one joint (a continuous sweep)
  runs at that joint's speed.
- readings are ``getActualQ`` (encoder values); ``wait_until_still`` watches ``getActualQd``.
- robot mode and safety mode are checked before every move and while moving and settling; a protective stop,
  emergency stop, safeguard stop or a powered-off arm raises with what to do on the teach pendant
  (drivers/ur/modes.py).
- a lost link (the worker died or hung, ur_rtde lost the connection, or the stream's timestamp stood still
  for ``stream_timeout`` s) is retried with a fresh worker ``reconnects`` times, then ConnectionFailed. A move
  cut by a lost link is commanded again to the same target after the reconnection.

- continuous motion (``start_move``, ``motion_done``, the joint stream recorded in the worker at the native rate
  with the controller's timestamps): drivers/ur/stream.py.

The ur_rtde import check happens in :func:`open_robot` (BackendUnavailable with the pip command without it).
"""

from __future__ import annotations

import contextlib
import json
import math
import threading
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from common.errors import install_hint
from config.robots import ConfigError, RobotModel, load_robot
from drivers.base import Array, DeviceIdentity, RobotState
from drivers.errors import (
    BackendUnavailable,
    ConnectionFailed,
    DeviceTimeout,
    RobotFault,
    SpecError,
)
from drivers.motion import leading_joint_limits
from drivers.spec import ROBOT_FORMS, RobotSpec
from drivers.ur.info import DASHBOARD_PORT, Dashboard, dashboard_model, polyscope_major, read_factory_calibration
from drivers.ur.modes import check_modes, robot_state
from drivers.ur.stream import JointStreaming
from drivers.ur.worker import CALL_TIMEOUT, LinkLost, Snapshot, Worker, WorkerError

CALIBRATION_TIMEOUT = 1.5  # s, at most, to read the kinematics info on the primary interface
INSTALL_HINT = install_hint("ur")
PROBE_TIMEOUT = 3.0  # s, at most, for the first contact with the controller
RECONNECT_TIMEOUT = 5.0  # s, at most, for a fresh worker to open the interfaces after a lost link
POLL_PERIOD = 0.008  # s, about one RTDE package at 125 Hz
POSITION_TOLERANCE = 1e-3  # rad: a move has arrived when every joint is this close to its target
STOP_DECELERATION = 2.0  # rad/s², stopJ
REFUSAL_WAIT = 0.05  # s after a refused moveJ before the state is judged (several RTDE packages)

#: Option -> (default, meaning).
OPTIONS: dict[str, tuple[object, str]] = {
    "reconnects": (3, "attempts to reconnect after a lost link (integer >= 0)"),
    "still_speed": (2e-3, "joint speed below which the arm counts as still, rad/s"),
    "max_speed": (1.0, "highest joint speed a move may ask for, rad/s"),
    "max_acceleration": (2.0, "highest joint acceleration a move may ask for, rad/s^2"),
    "remote_check": ("on", "refuse a controller that is not in remote control (on/off)"),
    "stream_timeout": (1.0, "seconds a standing state-stream timestamp may last before the link counts as lost"),
    "rtde_frequency": (None, "the RTDE rate in Hz, at most 500 (default: 500 on e-Series, 125 on CB3)"),
}
NATIVE_RATE = {True: 500.0, False: 125.0}  # Hz, e-Series / CB3


def _check_ur_rtde() -> None:
    """BackendUnavailable (with the pip command) unless ur_rtde can be imported; the worker process imports it."""
    try:
        import rtde_control  # noqa: F401
        import rtde_receive  # noqa: F401
    except ImportError as exc:
        raise BackendUnavailable(f"the 'ur' robot backend needs the ur_rtde package, which is not installed: "
                                 f"{INSTALL_HINT}") from exc


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
                if not (math.isfinite(number) and number > 0) or (key == "rtde_frequency" and number > 500):
                    raise ValueError
                out[key] = number
        except ValueError:
            raise SpecError(f"option {key}={value} in {text!r} must be {OPTIONS[key][1]}") from None
    return out


def open_robot(spec: RobotSpec | str, rig: object = None, site: Any = None, model: RobotModel | None = None) -> URRobot:
    """The UR robot of ``spec`` (unconnected). The host is the spec's, else the site configuration's. ``model``: the
    robot model (a resumed session's recorded one), None for the one ``spec`` names."""
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
        model = model if model is not None else load_robot(spec.model)
    except ConfigError as exc:
        raise SpecError(f"robot spec {str(spec)!r}: {exc}") from exc
    if not model.vendor.lower().startswith("universal"):
        raise SpecError(f"robot spec {str(spec)!r}: {model.name} is not a Universal Robots model")
    _check_ur_rtde()
    return URRobot(model, host, options)


class URRobot(JointStreaming):
    """A UR arm through ur_rtde in a worker process (implements :class:`drivers.base.Robot` and
    :class:`drivers.base.StreamingRobot`); see the module docstring. ``factory_calibration``: the controller's
    DH values read at connect (dict of UR's theta, a, d, alpha per joint, rad and m), or None when it could not
    be read."""

    def __init__(self, model: RobotModel, host: str, options: dict[str, Any]) -> None:
        self.model, self.host, self.options = model, host, options
        self.joint_types = model.joint_types
        self._worker: Worker | None = None
        self._identity = DeviceIdentity("robot", model.name, details={"host": host})
        self._stops = 0  # stop() calls so far; a move that sees the count change was stopped
        self._stops_lock = threading.Lock()
        self.factory_calibration: dict[str, Any] | None = None
        self.still_speed = float(options["still_speed"])
        self.stream_timeout = float(options["stream_timeout"])
        self.poll_period = POLL_PERIOD
        self.call_timeout = CALL_TIMEOUT  # s, for one request to the worker (a hung worker is killed after it)
        self.reconnections = 0  # fresh workers started after a lost link, since connect()
        self._stamp: tuple[float, float] = (math.nan, 0.0)  # last stream timestamp, when it was first seen
        e_series = model.name.lower().endswith("e") or dashboard_model(model.name) in ("UR20", "UR30")
        self.rtde_frequency = float(options.get("rtde_frequency") or NATIVE_RATE[e_series])  # Hz
        self._init_stream()

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
            self._start_worker(timeout)
        except LinkLost as exc:
            self._drop_worker(graceful=False)
            raise ConnectionFailed(f"the UR controller at {self.host} refused the RTDE connection: {exc}") from None
        self.reconnections = 0

    def _start_worker(self, timeout: float) -> None:
        """A fresh worker whose state stream is seen advancing; LinkLost if not."""
        self._drop_worker(graceful=False)
        self._worker = Worker(self.host, timeout, frequency=self.rtde_frequency)
        self._stamp = (math.nan, time.monotonic())
        deadline = time.monotonic() + self.stream_timeout + timeout
        first = self._snapshot()[1]
        while self._snapshot()[1] == first:
            if time.monotonic() > deadline:
                raise LinkLost(f"the state stream of {self.host} does not advance")
            time.sleep(self.poll_period)

    def _drop_worker(self, graceful: bool = True) -> None:
        """End the worker: ``graceful`` stops ur_rtde's control script first (bounded), else it is killed."""
        worker, self._worker = self._worker, None
        if worker is not None:
            worker.close() if graceful else worker.kill()

    def _check_dashboard(self, timeout: float) -> DeviceIdentity:
        where = f"the UR controller at {self.host}"
        try:
            dashboard = Dashboard(self.host, timeout)
        except OSError as exc:
            reason = "no answer" if isinstance(exc, TimeoutError) else (exc.strerror or str(exc))
            raise ConnectionFailed(f"cannot reach {where} (dashboard port {DASHBOARD_PORT}: {reason}); check the "
                                   "address, the network cable and that the controller is switched on") from None
        try:
            answers = {key: dashboard.ask(command) for key, command in (
                ("version", "PolyscopeVersion"), ("model", "get robot model"), ("serial", "get serial number"))}
            major = polyscope_major(answers["version"])
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
        expected = dashboard_model(self.model.name)
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
        """Stop ur_rtde's control script and end the worker (and a joint stream); never raises."""
        self._streaming, self._stream_worker, self._motion = False, None, None
        with contextlib.suppress(Exception):
            self._drop_worker()

    def identity(self) -> DeviceIdentity:
        return self._identity

    # --- the link ---------------------------------------------------------------------------------------------

    def _call(self, name: str, *args: Any) -> Any:
        worker = self._worker
        if worker is None:
            raise LinkLost("not connected")
        return worker.call(name, *args, timeout=self.call_timeout)

    def _snapshot(self) -> Snapshot:
        """One snapshot of the state stream; LinkLost when ur_rtde lost the link, the worker died or hung, or
        the stream's timestamp has stood still for ``stream_timeout`` s (a frozen controller stream)."""
        try:
            snap: Snapshot = self._call("snapshot")
        except WorkerError as exc:
            raise LinkLost(f"ur_rtde: {exc}") from None
        if not snap[0]:
            raise LinkLost("ur_rtde lost the connection")
        now = time.monotonic()
        stamp, seen = self._stamp
        if snap[1] != stamp:
            self._stamp = (snap[1], now)
        elif now - seen > self.stream_timeout:
            raise LinkLost(f"the state stream stopped: its timestamp has stood at {stamp:.3f} s for "
                           f"{now - seen:.1f} s")
        return snap

    def _linked(self, operation: Any) -> Any:
        """``operation()``, reconnecting with a fresh worker after a lost link (at most ``reconnects`` times
        for this operation), then ConnectionFailed."""
        if self._worker is None:
            raise ConnectionFailed(f"the UR robot at {self.host} is not connected (call connect())")
        attempts, budget = 0, int(self.options["reconnects"])
        while True:
            try:
                return operation()
            except LinkLost as exc:
                lost, reason = str(exc), ""
            while True:
                self._drop_worker(graceful=False)  # a worker on a lost link may hang in ur_rtde: no goodbyes
                if attempts >= budget:
                    last = f" (last: {reason})" if reason and reason != lost else ""
                    raise ConnectionFailed(
                        f"lost the connection to the UR controller at {self.host} ({lost}) and {budget} "
                        f"reconnection attempt(s) failed{last}: check the network and the controller, then "
                        "resume the run")
                attempts += 1
                time.sleep(min(0.2 * attempts, 1.0))
                try:
                    self._start_worker(RECONNECT_TIMEOUT)
                except LinkLost as exc:
                    reason = str(exc)
                    continue
                self.reconnections += 1
                break

    # --- state ------------------------------------------------------------------------------------------------

    def state(self) -> RobotState:
        try:
            _, _, robot_mode, safety_mode, _, qd, _ = self._snapshot()
        except LinkLost:
            return RobotState.DISCONNECTED
        return robot_state(robot_mode, safety_mode, qd, self.still_speed)

    def _checked_snapshot(self) -> Snapshot:
        """A snapshot; raises the RobotFault that fits the controller's state (none when it can be commanded)."""
        snap = self._snapshot()
        check_modes(snap[2], snap[3], self.host)
        return snap

    # --- motion -----------------------------------------------------------------------------------------------

    def read_joints(self) -> Array:
        """Actual joint positions (6,), rad: the encoder values of the latest RTDE package."""
        return np.asarray(self._linked(lambda: self._snapshot()[4]), dtype=float)

    def move_joints(self, q: Sequence[float], speed: Sequence[float], acceleration: Sequence[float],
                    timeout: float) -> None:
        stops = self._stops
        target, v, a = self._checked(q, speed, acceleration, timeout)
        deadline = time.monotonic() + timeout
        try:
            self._linked(lambda: self._move(target, v, a, deadline, timeout, stops))
        except KeyboardInterrupt:
            self.stop()
            raise

    def _move(self, target: Array, v: Array, a: Array, deadline: float, timeout: float, stops: int) -> None:
        """Command the move and watch it to the end (run again after a reconnection: same target)."""
        self._command_move(target, v, a, stops)
        while True:
            _, _, _, _, actual, qd, _ = self._checked_snapshot()
            self._raise_if_stopped(stops)
            if (np.max(np.abs(np.asarray(actual) - target)) < POSITION_TOLERANCE
                    and max(map(abs, qd)) < self.still_speed):
                return
            if time.monotonic() >= deadline:
                self.stop()
                raise DeviceTimeout(f"the UR robot at {self.host} did not reach its target within {timeout:g} s; "
                                    "it was stopped (stopJ)")
            time.sleep(self.poll_period)

    def _command_move(self, target: Array, speed: Array, acceleration: Array, stops: int) -> None:
        """Send the asynchronous moveJ (the control script started first if it is not running) with the leading
        joint's speed and acceleration from where the arm stands (per-joint ``speed`` rad/s, ``acceleration``
        rad/s²); RobotFault when the controller refuses it twice."""
        for attempt in (1, 2):
            snap = self._checked_snapshot()
            if not snap[6]:  # ur_rtde's control script is not running, e.g. after a
                with contextlib.suppress(WorkerError):  # cleared protective stop or another script
                    self._call("reupload")
                self._wait_program(2.0)
            self._raise_if_stopped(stops)
            v, a = leading_joint_limits(snap[4], target, speed, acceleration)
            try:
                accepted, why = self._call("move", target.tolist(), v, a), "moveJ returned false"
            except WorkerError as exc:
                accepted, why = False, str(exc)
            if accepted:
                break
            time.sleep(REFUSAL_WAIT)  # let the state stream catch up with what the controller did
            if max(map(abs, self._checked_snapshot()[5])) > self.still_speed:  # a fault explains the refusal,
                break  # or the arm runs the move after all (e.g. a fault is being latched): watch it
            if attempt == 2:
                raise RobotFault(f"the UR controller at {self.host} refused the move twice ({why}); check the "
                                 "teach pendant for a message")
            # the arm is still: once more, the script may have been replaced mid-command (a client reconnecting)

    def _raise_if_stopped(self, stops: int) -> None:
        if self._stops != stops:
            self._send_stop()  # a stop() from a signal handler may have found the worker busy
            raise RobotFault(f"the move of the UR robot at {self.host} was stopped (stop()) before it arrived")

    def _wait_program(self, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        while not self._checked_snapshot()[6]:
            if time.monotonic() > deadline:
                raise RobotFault(f"the ur_rtde control script did not start on the UR controller at {self.host} "
                                 f"within {timeout:g} s; check the teach pendant for a message")
            time.sleep(0.01)

    def wait_until_still(self, settle_time: float, timeout: float) -> None:
        """Return once every actual joint speed has stayed below ``still_speed`` for ``settle_time`` s."""
        start = time.monotonic()
        self._linked(lambda: self._settle(settle_time, timeout, start))

    def _settle(self, settle_time: float, timeout: float, start: float) -> None:
        since: float | None = None
        while True:
            qd = self._checked_snapshot()[5]
            now = time.monotonic()
            if max(map(abs, qd), default=0.0) < self.still_speed:
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
        """Stop any motion now (stopJ); never raises. Safe from a signal handler and from other threads."""
        with self._stops_lock:
            self._stops += 1
        self._send_stop()

    def _send_stop(self) -> None:
        with contextlib.suppress(Exception):
            self._call("stop", STOP_DECELERATION)

    def _checked(self, q: Sequence[float], speed: Sequence[float], acceleration: Sequence[float],
                 timeout: float) -> tuple[Array, Array, Array]:
        """Target (6,) rad, per-joint speeds rad/s and accelerations rad/s², each checked against the limits."""
        model, n = self.model, len(self.joint_types)
        target, vs, accs = (np.asarray(x, dtype=float).reshape(-1) for x in (q, speed, acceleration))
        for name, values in (("target", target), ("speed", vs), ("acceleration", accs)):
            if values.shape != (n,) or not np.all(np.isfinite(values)):
                raise ValueError(f"{name} must be {n} finite numbers, got {values.tolist()}")
        for i, (value, (lo, hi)) in enumerate(zip(target, model.limits, strict=True)):
            if not lo <= value <= hi:
                raise ValueError(f"joint {i + 1} target {value:.6g} is outside its limits [{lo:.6g}, {hi:.6g}]")
        top_a = float(self.options["max_acceleration"])
        for i, (v, a, limit) in enumerate(zip(vs, accs, model.max_speed, strict=True)):
            top = min(float(self.options["max_speed"]), float(limit))
            if not 0 < v <= top * (1 + 1e-9):
                raise ValueError(f"joint {i + 1} speed {v:.6g} rad/s must be in (0, {top:.6g}] (option max_speed)")
            if not 0 < a <= top_a * (1 + 1e-9):
                raise ValueError(f"joint {i + 1} acceleration {a:.6g} rad/s² must be in (0, {top_a:g}] (option "
                                 "max_acceleration)")
        if not timeout > 0:
            raise ValueError(f"timeout must be > 0 s, got {timeout!r}")
        return target, vs, accs
