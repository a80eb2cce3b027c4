"""A Universal Robots controller emulator on loopback, for testing the UR driver with the real ``ur_rtde`` client.

It speaks just enough of the controller's interfaces for ``rtde_control.RTDEControlInterface(host)`` and
``rtde_receive.RTDEReceiveInterface(host)`` to connect and work:

- RTDE on port 30004: protocol version (V), controller version (v), output / input recipes (O / I), start /
  pause (S / P), data packages (U) both ways at up to ``rate`` Hz;
- the dashboard server on 29999 (greeting, ``PolyscopeVersion``, ``is in remote control``, ``get robot model``,
  ``get serial number``, ``robotmode``, ``safetystatus``, ``unlock protective stop``, ``stop``, ...);
- the primary / secondary interface (30001 / 30002) first sends a version message and a robot state message
  with the kinematics info (sub-package 5: checksums, DH theta, a, d, alpha, calibration status; here the rig's
  true robot plays the factory calibration; ``kinematics=False``: robot state messages without it);
- the script ports 30001 / 30002 / 30003: a program ``def rtde_control(): ... end`` sent there "runs": the
  emulator then plays the register handshake of ur_rtde's control script (below) instead of URScript.

Register handshake (ur_rtde 1.6.5, lower register range): the client writes the command code in
``input_int_register_0`` and its arguments in ``input_double_register_0..`` (``input_int_register_1``: async
flag); the script reports in ``output_int_register_0``: 1 = ready for a command, 2 = done with it; the client
then clears the command (writes 0) and the script goes back to 1. Codes used here: 1 moveJ (q in doubles 0-5,
speed 6, acceleration 7), 34 stopJ (deceleration in double 0), 255 stop the script. ``output_int_register_2``
is the async progress: 0 while an async move runs, then -1 / -2 alternately. Other codes are acknowledged
(done) without effect. The client also reads ``robot_status_bits`` (bit 1: program running),
``safety_status_bits`` (bit 2: protective stop, bit 7: emergency stop) and ``runtime_state`` (2 playing).

Motion: the arm is a :class:`drivers.sim.rig.SimulatedRig` on a :class:`ScaledClock` (``time_scale``: emulated
seconds per wall second, default 1; the tests run at 10 to 100, so a move of seconds takes a fraction of a
second while the RTDE stream keeps its wall-clock rate); a moveJ is the rig's synchronised trapezoidal move
(``SimulatedRobot.move_joints`` with the commanded speed / acceleration on every joint). The streamed
``actual_q`` is the rig's arm at the package's time: the move's profile on the emulated clock while it runs
(the rig holds it at the target until its move has ended), then the rig's resting / ringing arm; the simulated
tracker measures the same arm, so streams and tracker see one world.

Native rate (``native_rate=True``): every RTDE stream sends one package per period (1 / ``rate``) of EMULATED
time, stamped with that tick's controller time and carrying the state at it, as a controller does on its own
clock; at ``time_scale`` k that is k × ``rate`` packages per wall second (keep k × rate at 1 kHz or so). The
default sends ``rate`` packages per WALL second stamped with the emulated time of sending (the steps of the
timestamp are then k / rate: fine for stop-and-go, not for recording a stream at its native rate).
:meth:`UREmulator.drop_packets` (native rate) loses the next packages on every connection (a dropped RTDE
package for the stream recorder to find).

Faults: :meth:`UREmulator.protective_stop`, :meth:`emergency_stop`, :meth:`clear_stop`, :meth:`drop_connections`,
:meth:`freeze_stream` (the stream repeats one state: the timestamp stands still), ``remote_control=False``,
``stall=True`` (a moveJ that never finishes), ``kinematics=False`` (the primary interface sends robot state
messages without the kinematics info: no factory calibration), or the rig's own fault schedule, counted in
moves: ``EmulatorProcess(rig=SimulatedRig("ur5e", clock=ScaledClock(10), robot_faults=parse_faults(
"protective_stop@2", "robot")))``: move 2 stops halfway in a protective stop; ``disconnect@N``: the network
drops every client connection at move N, which does not start. Tests trigger the others at a position of the
emulated arm, not after a wall-clock delay, so that a loaded machine cannot move them.

Tracker: :meth:`UREmulator.serve_tracker` starts a simulated ASCII tracker (``tests/tracker_devices.py``,
loopback TCP) measuring this emulator's true TP, for whole acquisitions with the real serial driver
(``serial:socket://127.0.0.1:PORT?protocol=polled-xyz``, or a streaming profile such as ``stream-csv`` for
continuous motion: its lines run on the emulated clock, with a ``latency``, ``clock_offset`` and ``drift`` of
their own; :meth:`lose_tracker_target` blinds it for a while); :meth:`truth` is the true robot (DH, base, tool),
which the primary interface also reports as the controller's factory calibration.

Each emulator binds its own loopback address (127.x.y.z), since the ports are fixed. Run it in a child process
(:class:`EmulatorProcess`): the ur_rtde client holds the GIL while it connects, so an emulator in threads of the
client's process starves and the connection hangs::

    with EmulatorProcess() as emu:                       # a fresh 127.a.b.c, see free_loopback_address()
        rtde_c = rtde_control.RTDEControlInterface(emu.host)
        emu.protective_stop()                            # calls go to the UREmulator in the child
        emu.get("log").commands                          # [1, 34, ...]: command codes the script executed

Layout: ``protocol.py`` (RTDE packages, variables and their types, register codes, mode values),
``controller.py`` (:class:`UREmulator`: servers, control-script handshake, motion), ``process.py``.
"""

from tests.ur_emulator.controller import ScaledClock, UREmulator
from tests.ur_emulator.process import EmulatorProcess, connected_robot, free_loopback_address
from tests.ur_emulator.protocol import (
    CMD_MOVEJ,
    CMD_NONE,
    CMD_STOP_SCRIPT,
    CMD_STOPJ,
    CMD_STOPL,
    SAFETY_NORMAL,
    SAFETY_PROTECTIVE_STOP,
    SAFETY_ROBOT_EMERGENCY_STOP,
    SCRIPT_DONE,
    SCRIPT_READY,
    VARIABLES,
)

__all__ = [
    "CMD_MOVEJ",
    "CMD_NONE",
    "CMD_STOPJ",
    "CMD_STOPL",
    "CMD_STOP_SCRIPT",
    "SAFETY_NORMAL",
    "SAFETY_PROTECTIVE_STOP",
    "SAFETY_ROBOT_EMERGENCY_STOP",
    "SCRIPT_DONE",
    "SCRIPT_READY",
    "VARIABLES",
    "EmulatorProcess",
    "ScaledClock",
    "UREmulator",
    "connected_robot",
    "free_loopback_address",
]
