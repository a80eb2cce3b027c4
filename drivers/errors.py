"""Exceptions of the device layer. Every message is one line an operator can act on.

DriverError
├── SpecError            a device string that does not parse (also a ValueError)
├── BackendUnavailable   the backend's package is not installed ("install X")
├── ConnectionFailed     cannot connect, or the link was lost
├── DeviceTimeout        a device did not answer in time
├── RobotFault           the robot stopped itself; the run must pause
│   ├── ProtectiveStop
│   └── EmergencyStop
└── MeasurementError     one measurement failed; retrying may help
    ├── TargetLost       line of sight lost / marker not visible
    └── BadReading       garbage or out-of-range reply
"""

from __future__ import annotations


class DriverError(Exception):
    """Base of all device errors."""


class SpecError(DriverError, ValueError):
    """A device spec string that does not parse; the message shows the expected form."""


class BackendUnavailable(DriverError):
    """The backend's Python package is missing; the message says what to install."""


class ConnectionFailed(DriverError):
    """Cannot connect to the device, or the connection was lost."""


class DeviceTimeout(DriverError):
    """The device did not answer within its timeout."""


class RobotFault(DriverError):
    """The robot is in a state where it must not be commanded (protective or emergency stop, fault)."""


class ProtectiveStop(RobotFault):
    """Protective stop: clear it on the teach pendant, then resume."""


class EmergencyStop(RobotFault):
    """Emergency stop pressed: release it and re-enable the robot, then resume."""


class MeasurementError(DriverError):
    """One tracker measurement failed; the orchestrator may retry."""


class TargetLost(MeasurementError):
    """The tracker cannot see the target (beam broken, marker out of view)."""


class BadReading(MeasurementError):
    """The device answered with something unparseable or out of range."""
