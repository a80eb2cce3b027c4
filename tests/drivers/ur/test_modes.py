"""What the UR controller's robot and safety modes mean (drivers/ur/modes.py), without a controller: the state
reported for each mode and the fault raised (with the teach-pendant help) when the arm cannot be commanded."""

from __future__ import annotations

import pytest

from drivers.base import RobotState
from drivers.errors import EmergencyStop, ProtectiveStop, RobotFault
from drivers.ur.modes import check_modes, robot_state

RUNNING, POWER_OFF = 7, 3
STILL = 2e-3  # rad/s


@pytest.mark.parametrize(("robot_mode", "safety_mode", "qd", "state"), [
    (RUNNING, 1, [0.0] * 6, RobotState.READY),
    (RUNNING, 2, [0.0] * 5 + [0.9 * STILL], RobotState.READY),  # reduced mode, below the still speed
    (RUNNING, 1, [0.0] * 5 + [-1.1 * STILL], RobotState.MOVING),
    (RUNNING, 3, [0.0] * 6, RobotState.PROTECTIVE_STOP),
    (RUNNING, 5, [0.0] * 6, RobotState.PROTECTIVE_STOP),  # safeguard stop
    (RUNNING, 7, [0.0] * 6, RobotState.EMERGENCY_STOP),
    (RUNNING, 9, [0.0] * 6, RobotState.FAULT),
    (POWER_OFF, 1, [0.0] * 6, RobotState.FAULT),
])
def test_the_state_of_each_mode(robot_mode: int, safety_mode: int, qd: list[float], state: RobotState) -> None:
    assert robot_state(robot_mode, safety_mode, qd, STILL) is state


@pytest.mark.parametrize(("robot_mode", "safety_mode", "error", "words"), [
    (RUNNING, 5, ProtectiveStop, "safeguard stop (SAFEGUARD_STOP) at ur.local: the safeguard input is open"),
    (RUNNING, 12, ProtectiveStop, "safeguard stop (AUTOMATIC_MODE_SAFEGUARD_STOP)"),
    (RUNNING, 3, ProtectiveStop, "UR protective stop at ur.local: on the teach pendant"),
    (RUNNING, 6, EmergencyStop, "UR emergency stop (SYSTEM_EMERGENCY_STOP) at ur.local: release the"),
    (RUNNING, 9, RobotFault, "UR safety mode FAULT at ur.local"),
    (RUNNING, 42, RobotFault, "UR safety mode 42 at ur.local"),
    (POWER_OFF, 1, RobotFault, "not running (robot mode POWER_OFF): on the teach pendant: power on"),
])
def test_a_mode_that_stops_the_run_raises_with_what_to_do(robot_mode: int, safety_mode: int,
                                                          error: type[RobotFault], words: str) -> None:
    with pytest.raises(error) as info:
        check_modes(robot_mode, safety_mode, "ur.local")
    assert type(info.value) is error and words in str(info.value)


def test_a_running_arm_in_normal_or_reduced_mode_can_be_commanded() -> None:
    for safety_mode in (1, 2):
        check_modes(RUNNING, safety_mode, "ur.local")  # raises nothing
