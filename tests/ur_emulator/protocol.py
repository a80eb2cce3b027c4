"""The wire formats the UR controller emulator speaks: RTDE packages and variables, ur_rtde's register codes,
the robot / safety mode values, and script-program framing (see tests/ur_emulator/__init__.py)."""

from __future__ import annotations

import socket
import struct

RTDE_PORT, DASHBOARD_PORT, SCRIPT_PORTS = 30004, 29999, (30001, 30002, 30003)

# RTDE package types
V, v, M, U, O, I, S, P = (ord(c) for c in "VvMUOISP")
# ur_rtde control-script states in output_int_register_0 and command codes in input_int_register_0
SCRIPT_BUSY, SCRIPT_READY, SCRIPT_DONE = 0, 1, 2
CMD_NONE, CMD_MOVEJ, CMD_STOPL, CMD_STOPJ, CMD_STOP_SCRIPT = 0, 1, 33, 34, 255
# robot_mode, safety_mode, runtime_state values; bits of robot_status_bits and safety_status_bits
ROBOT_MODE_RUNNING, ROBOT_MODE_POWER_OFF = 7, 3
SAFETY_NORMAL, SAFETY_PROTECTIVE_STOP, SAFETY_ROBOT_EMERGENCY_STOP = 1, 3, 7
RUNTIME_STOPPED, RUNTIME_PLAYING = 1, 2
STATUS_POWER_ON, STATUS_PROGRAM_RUNNING = 1 << 0, 1 << 1
SAFETY_BIT_NORMAL, SAFETY_BIT_PROTECTIVE, SAFETY_BIT_ROBOT_ESTOP, SAFETY_BIT_ESTOP = 1 << 0, 1 << 2, 1 << 6, 1 << 7

def _words(text: str) -> list[str]:
    return text.split()


_FORMATS = {"BOOL": "?", "UINT8": "B", "UINT32": "I", "UINT64": "Q", "INT32": "i", "DOUBLE": "d",
            "VECTOR3D": "3d", "VECTOR6D": "6d", "VECTOR6INT32": "6i", "VECTOR6UINT32": "6I"}
_V6 = _words("target_q target_qd target_qdd target_current target_moment actual_q actual_qd actual_current "
             "joint_control_output actual_TCP_pose actual_TCP_speed actual_TCP_force target_TCP_pose "
             "target_TCP_speed joint_temperatures actual_joint_voltage payload_inertia ft_raw_wrench "
             "joint_position_deviation_ratio actual_current_window actual_current_as_torque target_current_window "
             "external_force_torque")
_DOUBLES = _words("timestamp actual_execution_time speed_scaling target_speed_fraction actual_momentum "
                  "actual_main_voltage actual_robot_voltage actual_robot_current standard_analog_input0 "
                  "standard_analog_input1 standard_analog_output0 standard_analog_output1 io_current "
                  "euromap67_24V_voltage euromap67_24V_current tool_analog_input0 tool_analog_input1 "
                  "tool_output_current tool_temperature tcp_force_scalar payload collision_detection_ratio "
                  "speed_slider_fraction standard_analog_output_0 standard_analog_output_1")
_UINT32 = _words("runtime_state robot_status_bits safety_status_bits analog_io_types euromap67_input_bits "
                 "euromap67_output_bits tool_mode tool_analog_input_types output_bit_registers0_to_31 "
                 "output_bit_registers32_to_63 input_bit_registers0_to_31 input_bit_registers32_to_63 "
                 "script_control_line speed_slider_mask")
_UINT8 = _words("tool_output_mode tool_digital_output0_mode tool_digital_output1_mode standard_digital_output_mask "
                "standard_digital_output configurable_digital_output_mask configurable_digital_output "
                "tool_digital_output_mask tool_digital_output standard_analog_output_mask standard_analog_output_type")
VARIABLES: dict[str, str] = {
    **{n: "VECTOR6D" for n in _V6}, **{n: "DOUBLE" for n in _DOUBLES}, **{n: "UINT32" for n in _UINT32},
    **{n: "UINT8" for n in _UINT8},
    "actual_digital_input_bits": "UINT64", "actual_digital_output_bits": "UINT64", "robot_mode": "INT32",
    "joint_mode": "VECTOR6INT32", "safety_mode": "INT32", "safety_status": "INT32", "tool_output_voltage": "INT32",
    "time_scale_source": "INT32", "actual_tool_accelerometer": "VECTOR3D", "elbow_position": "VECTOR3D",
    "elbow_velocity": "VECTOR3D", "payload_cog": "VECTOR3D",
    **{f"{d}_int_register_{k}": "INT32" for d in ("input", "output") for k in range(48)},
    **{f"{d}_double_register_{k}": "DOUBLE" for d in ("input", "output") for k in range(48)},
    **{f"{d}_bit_register_{k}": "BOOL" for d in ("input", "output") for k in range(64, 128)},
}
_ZERO = {"VECTOR6D": (0.0,) * 6, "VECTOR3D": (0.0,) * 3, "VECTOR6INT32": (0,) * 6, "VECTOR6UINT32": (0,) * 6,
         "DOUBLE": 0.0, "BOOL": False}

# the dashboard's "get robot model" answer (it does not tell e-Series from CB3: the major version does)
DASHBOARD_MODEL = {"ur3": "UR3", "ur3e": "UR3", "ur5": "UR5", "ur5e": "UR5", "ur10": "UR10", "ur10e": "UR10",
                   "ur16e": "UR16", "ur20": "UR20", "ur30": "UR30"}


def _packet(kind: int, payload: bytes = b"") -> bytes:
    return struct.pack(">HB", len(payload) + 3, kind) + payload


def _recv_exact(sock: socket.socket, n: int) -> bytes:
    data = b""
    while len(data) < n:
        chunk = sock.recv(n - len(data))
        if not chunk:
            raise ConnectionError("peer closed")
        data += chunk
    return data


def _take_program(buffer: str) -> tuple[str | None, str]:
    """The first complete top-level program (``def``/``sec`` NAME ... ``end`` at column 0) in ``buffer``."""
    lines = buffer.split("\n")
    start = next((i for i, line in enumerate(lines) if line.startswith(("def ", "sec "))), None)
    if start is None:
        return None, buffer if len(buffer) < 1_000_000 else ""
    for i in range(start + 1, len(lines) - 1):  # the last element has no newline yet
        if lines[i].rstrip() == "end":
            return "\n".join(lines[start:i + 1]) + "\n", "\n".join(lines[i + 1:])
    return None, buffer
