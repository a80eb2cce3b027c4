"""Which simulated devices make one simulated world (drivers/sim/rig.py): a simulated robot pairs with the mock tracker
or the simulated camera, never with a real device; and where the rig's reflector settings come from."""

from __future__ import annotations

from typing import Any

from drivers.errors import SpecError
from drivers.spec import RobotSpec, TrackerSpec


def is_simulated_camera(spec: TrackerSpec) -> bool:
    """True for ``aruco:sim?...``: real detection on images rendered from the rig (drivers/camera/renderer.py)."""
    return spec.backend == "aruco" and spec.target == "sim"


def is_simulated_emscon(spec: TrackerSpec) -> bool:
    """True for ``emscon:sim?...``: the emScon client against a simulated server on the rig (drivers/trackers/)."""
    return spec.backend == "emscon" and spec.target == "sim"


def check_pairing(robot: RobotSpec, tracker: TrackerSpec) -> None:
    """SpecError unless the two devices are both simulated or both real: a simulated tracker cannot see a real
    arm, nor a real tracker a simulated one (one simulated world, :class:`SimulatedRig`)."""
    simulated = (robot.is_mock, tracker.is_mock or is_simulated_camera(tracker) or is_simulated_emscon(tracker))
    if simulated[0] != simulated[1]:
        raise unpaired(robot, tracker)


def points_settings(robot: RobotSpec, tracker: TrackerSpec | None, r: dict[str, Any],
                    t: dict[str, Any]) -> dict[str, Any]:
    """The rig's ``points`` and ``occlusion``: given on the robot spec (the reflectors on its flange) or on the
    tracker spec (what it sees), the robot's default otherwise; SpecError when the two specs disagree."""
    out = {}
    for key in ("points", "occlusion"):
        value = r[key]
        if t[key] is not None:
            if key in robot.options and t[key] != r[key]:
                raise SpecError(f"{key}= is {r[key]:g} in {str(robot)!r} but {t[key]:g} in {str(tracker)!r}; give "
                                "it once (either spec) or the same on both")
            value = t[key]
        out[key] = value
    return out


def unpaired(robot: RobotSpec, tracker: TrackerSpec | None) -> SpecError:
    """The error for a simulated device paired with a real one."""
    return SpecError(f"a simulated rig needs mock devices on both sides (mock:MODEL with mock, aruco:sim or "
                     f"emscon:sim), got {str(robot)!r} and {str(tracker)!r}")
