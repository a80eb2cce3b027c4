"""What a UR controller's robot mode and safety mode (RTDE, UR's RTDE guide) mean for a run: the state of the
arm (:func:`robot_state`) and, when it cannot be commanded, the fault to raise with what to do on the teach
pendant (:func:`check_modes`). Used by the UR driver (drivers/ur/driver.py) on every snapshot of the state stream.
"""

from __future__ import annotations

from collections.abc import Sequence

from drivers.base import RobotState
from drivers.errors import EmergencyStop, ProtectiveStop, RobotFault

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


def robot_state(robot_mode: int, safety_mode: int, qd: Sequence[float], still_speed: float) -> RobotState:
    """The arm's state from the controller's modes and the joint speeds ``qd`` (rad/s): moving when one is above
    ``still_speed`` (rad/s)."""
    if safety_mode in SAFETY_PROTECTIVE:
        return RobotState.PROTECTIVE_STOP
    if safety_mode in SAFETY_EMERGENCY:
        return RobotState.EMERGENCY_STOP
    if safety_mode not in SAFETY_OK or robot_mode != ROBOT_MODE_RUNNING:
        return RobotState.FAULT
    return RobotState.MOVING if max(map(abs, qd), default=0.0) > still_speed else RobotState.READY


def check_modes(robot_mode: int, safety_mode: int, host: str) -> None:
    """Raise the RobotFault that fits the controller's modes (none when the arm can be commanded); the message
    names the controller at ``host`` and what to do on the teach pendant."""
    mode = SAFETY_MODES.get(safety_mode, str(safety_mode))
    if safety_mode in (5, 12):
        raise ProtectiveStop(f"UR safeguard stop ({mode}) at {host}: {SAFEGUARD_HELP}")
    if safety_mode in SAFETY_PROTECTIVE:
        raise ProtectiveStop(f"UR protective stop at {host}: {PROTECTIVE_HELP}")
    if safety_mode in SAFETY_EMERGENCY:
        raise EmergencyStop(f"UR emergency stop ({mode}) at {host}: {EMERGENCY_HELP}")
    if safety_mode not in SAFETY_OK:
        raise RobotFault(f"UR safety mode {mode} at {host}: read the message on the teach pendant, "
                         "clear it (restart the controller after a FAULT or VIOLATION), then resume the run")
    if robot_mode != ROBOT_MODE_RUNNING:
        name = ROBOT_MODES.get(robot_mode, str(robot_mode))
        raise RobotFault(f"the UR arm at {host} is not running (robot mode {name}): {POWER_HELP}")
