"""The simulated robot of mock mode (``--robot mock:MODEL?...``): a view of the simulated rig's arm.

The rig (drivers/sim/rig.py) holds the world: the true robot, the arm's actual state, the clock and the fault
schedule; its docstring describes the physics (synchronised trapezoidal moves, repeatability, ringing, coupled
readings, joint errors) and the faults a move can meet. The streams of continuous motion: drivers/sim/stream.py.
Units: rad (revolute) / m (prismatic), rad/s (m/s), rad/s² (m/s²), seconds on the rig's clock.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from config.robots import RobotModel
from drivers.base import Array, DeviceIdentity, RobotState
from drivers.clock import Clock
from drivers.errors import ConnectionFailed, DeviceTimeout, EmergencyStop, ProtectiveStop, RobotFault, SpecError
from drivers.motion import move_duration
from drivers.sim.rig import SimulatedRig
from drivers.sim.stream import JointStreaming
from drivers.sim.world import errors_as_dict, has_errors
from drivers.spec import RobotSpec

POLL_PERIOD = 0.01  # s between joint readings in wait_until_still
STILL_TOLERANCE = 1e-6  # rad (m): joints within this of each other count as still
_EPS = 1e-6  # s: time comparisons on the clock (epoch values near 1.8e9 s are only resolved to 2.4e-7 s)


class SimulatedRobot(JointStreaming):
    """The simulated robot arm (implements :class:`drivers.base.Robot` and ``StreamingRobot``: the streams are in
    drivers/sim/stream.py); a view of ``rig``'s arm."""

    def __init__(self, rig: SimulatedRig) -> None:
        self.rig, self.joint_types = rig, rig.model.joint_types
        self.poll_period, self.still_tolerance = POLL_PERIOD, STILL_TOLERANCE  # s, rad (m)

    @property
    def n_joints(self) -> int:
        return len(self.joint_types)

    def connect(self, timeout: float) -> None:
        if not timeout > 0:
            raise ValueError(f"timeout must be > 0 s, got {timeout!r}")
        self.rig.robot_connected = True

    def close(self) -> None:
        self.rig.robot_connected = False

    def identity(self) -> DeviceIdentity:
        rig = self.rig
        details = {"truth_seed": str(rig.seed), "repeatability": f"{rig.repeatability:g}", "ring": f"{rig.ring:g}",
                   "ring_tau": f"{rig.ring_tau:g}"}
        if rig.arm != rig.seed:
            details["arm_seed"] = str(rig.arm)
        if has_errors(rig.joint_errors):  # the truth of the joint errors, for benchmarks to compare with
            details["joint_errors"] = json.dumps(errors_as_dict(rig.joint_errors))
        if rig.points > 1:
            details["tools"] = json.dumps(rig.tools.tolist())  # the reflectors' true tool vectors, flange frame
        return DeviceIdentity("robot", f"simulated {rig.model.name}", serial=f"SIM-R{rig.seed}", firmware="sim",
                              details=details)

    def state(self) -> RobotState:
        return self.rig.robot_state

    def read_joints(self) -> Array:
        """Actual joint readings (n,), rad / m, including the repeatability error and any ringing (the
        controller's readings: with a coupled model not the DH values)."""
        self._require_link()
        return self.rig.actual_joints()

    def move_joints(self, q: Sequence[float], speed: Sequence[float], acceleration: Sequence[float],
                    timeout: float) -> None:
        """Move to the readings ``q`` (blocking; the clock advances by the move's duration). ValueError for a
        target whose DH values are out of the limits or a speed above the model's maximum; faults as in the
        module docstring."""
        rig = self.rig
        self._require_link()
        if rig._latched is not None:
            error = ProtectiveStop if rig._latched is RobotState.PROTECTIVE_STOP else EmergencyStop
            raise error(f"the simulated robot is in {rig._latched.value}: clear it (rig.clear_faults()), then resume")
        target, v, a = self._checked(q, speed, acceleration, timeout)
        number = rig.moves = rig.moves + 1
        fault = rig._take("robot", number)
        start = rig.rest_joints
        duration = move_duration(start, target, v, a)
        if fault == "disconnect":
            rig.robot_connected = False
            raise ConnectionFailed(f"lost the connection to the simulated robot at move {number}")
        if fault == "slow":
            rig.clock.sleep(timeout)
            raise DeviceTimeout(f"move {number} did not finish within its timeout of {timeout:g} s")
        stops = fault in ("protective_stop", "emergency_stop")
        stopped = rig._run(start, target, v, a, min(duration / 2 if stops else duration, timeout))
        if stops and duration / 2 <= timeout:
            rig._latched = RobotState.PROTECTIVE_STOP if fault == "protective_stop" else RobotState.EMERGENCY_STOP
            error = ProtectiveStop if fault == "protective_stop" else EmergencyStop
            raise error(f"simulated {rig._latched.value} during move {number}: clear it (rig.clear_faults()), "
                        "then resume")
        if stopped:
            raise RobotFault(f"move {number} was stopped (stop()) before it reached its target")
        if duration > timeout:
            raise DeviceTimeout(f"move {number} needs {duration:.3f} s, more than its timeout of {timeout:g} s; "
                                "the robot was stopped")
        if fault == "unsettled":
            rig._ring_decays = False

    def wait_until_still(self, settle_time: float, timeout: float) -> None:
        """Poll the joints every ``poll_period`` s until they have stayed within ``still_tolerance`` for
        ``settle_time`` s; DeviceTimeout once ``timeout`` s have passed (the clock advanced by the timeout)."""
        clock = self.rig.clock
        since = clock.now()
        deadline, anchor = since + timeout, self.read_joints()
        while True:
            now = clock.now()
            if now - since >= settle_time - _EPS:
                return
            if now >= deadline - _EPS:
                raise DeviceTimeout(f"the simulated robot did not settle ({settle_time:g} s still) within "
                                    f"{timeout:g} s")
            clock.sleep(min(self.poll_period, deadline - now, since + settle_time - now))
            q = self.read_joints()
            if np.max(np.abs(q - anchor), initial=0.0) > self.still_tolerance:
                anchor, since = q, clock.now()

    def stop(self) -> None:
        """Stop a move in progress (from another thread or a signal handler). Never raises."""
        self.rig._stop_requested = self.rig._moving  # a plain assignment: cannot fail

    def _require_link(self) -> None:
        if not self.rig.robot_connected:
            raise ConnectionFailed("the simulated robot is not connected (call connect(); after a lost link, "
                                   "connect again)")

    def _checked(self, q: Sequence[float], speed: Sequence[float], acceleration: Sequence[float],
                 timeout: float) -> tuple[Array, Array, Array]:
        model, n = self.rig.model, self.n_joints
        target, v, a = (np.asarray(x, dtype=float).reshape(-1) for x in (q, speed, acceleration))
        for name, values in (("target", target), ("speed", v), ("acceleration", a)):
            if values.shape != (n,) or not np.all(np.isfinite(values)):
                raise ValueError(f"{name} must be {n} finite numbers, got {values.tolist()}")
        dh = target if self.rig.coupling is None else self.rig.coupling.dh_from_readings(target[None, :])[0]
        for i, (value, (lo, hi)) in enumerate(zip(dh, model.limits, strict=True)):
            if not lo <= value <= hi:
                raise ValueError(f"joint {i + 1} target {value:.6g} is outside its limits [{lo:.6g}, {hi:.6g}] "
                                 "(the plan should have caught it)")
        for i, (value, top, acc) in enumerate(zip(v, model.max_speed, a, strict=True)):
            if not 0 < value <= top * (1 + 1e-9) or not acc > 0:
                raise ValueError(f"joint {i + 1}: speed {value:.6g} must be in (0, {top:.6g}] and acceleration "
                                 f"{acc:.6g} > 0")
        if not timeout > 0:
            raise ValueError(f"timeout must be > 0 s, got {timeout!r}")
        return target, v, a


def open_robot(spec: RobotSpec | str, *, rig: SimulatedRig | None = None, clock: Clock | None = None,
               site: object = None, model: RobotModel | None = None) -> SimulatedRobot:
    """The simulated robot of ``mock:MODEL?...`` on ``rig`` (made from the spec, with ``clock`` and ``model``, when
    None; ``model`` None: the one MODEL names). ``site`` (the site configuration every factory is given) is not
    needed by a simulated device."""
    spec = spec if isinstance(spec, RobotSpec) else RobotSpec.parse(spec)
    if not spec.is_mock:
        raise SpecError(f"drivers.sim opens mock robots only (mock:MODEL), got {str(spec)!r}")
    if rig is None:
        return SimulatedRobot(SimulatedRig.from_spec(spec, None, clock, model))
    if clock is not None and clock is not rig.clock:
        raise ValueError("the clock belongs to the rig: give it to SimulatedRig.from_spec, not open_robot")
    same = (Path(spec.model).resolve() == Path(rig.model.path).resolve() if spec.model_is_file
            else spec.model.lower() == rig.model.name.lower())
    if not same:
        raise ValueError(f"spec {str(spec)!r} names model {spec.model!r} but the rig simulates {rig.model.name!r}")
    ours = {key: getattr(rig, key) for key in ("seed", "repeatability", "ring", "ring_tau", "scale", "eccentricity",
                                                "compliance", "backlash")}
    ours.update({key: getattr(rig, key) for key in ("points", "occlusion") if key in spec.options})
    ours.update(rig.stream.robot_options())
    given = spec.mock_settings()
    ours["arm"], given["arm"] = rig.arm, rig.seed if given["arm"] is None else given["arm"]
    rig._check_settings(spec, ours, given, rig.robot_spec)
    return SimulatedRobot(rig)
