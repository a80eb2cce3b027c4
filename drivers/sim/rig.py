"""The simulated rig (mock mode): a simulated robot and a simulated tracker that see one simulated world.

Units and frames: joint values rad (revolute) / m (prismatic); speeds rad/s (m/s), accelerations rad/s²
(m/s²); TP positions metres in the tracker frame; times seconds on the rig's clock (a ``VirtualClock``
advances at once when a device "sleeps", so a whole session runs in seconds with the timestamps and
durations of a real one; a ``WallClock`` plays it at real speed for ``--realtime``).

The world (:class:`SimulatedRig`):

- the true robot: ``random_truth(nominal, home, default_rng(seed))`` of the model's nominal DH table (seeded
  perturbations, a random base pose in the tracker frame, a random TP off every axis); the tracker sees
  ``kinematics.dh.points_from_joints(truth, q)`` at the joints' true DH values ``q``, never its own model;
- ``arm=N`` swaps the arm: the DH table of ``random_truth`` with seed N, at the placement and with the TP of
  ``seed`` (another arm of the same model, where the first one stood); ``moved``/``turned`` (tracker options) move
  the tracker: the base is placed at ``T @ base``, T the rotation vector ``turned`` (degrees) then the shift
  ``moved`` (m), as a tracker put back on its tripod elsewhere sees it;
- the robot's readings are the controller's: with a coupled model (``coupling:`` in its YAML, e.g. FANUC J2/J3)
  ``move_joints`` takes and ``read_joints`` gives readings, and the true DH values are
  ``coupling.dh_from_readings(readings)``; joint limits are checked on those DH values;
- joint errors (options ``scale``, ``eccentricity``, ``compliance``; drivers/sim/world.py): the joints really
  stand at ``q + Δq(q)`` of those DH values (``rig.joint_errors``, recorded in the robot's identity);
- ``backlash`` (rad or m, every joint): the play of a gear train (:func:`~drivers.sim.world.backlash_play`): the
  joint (link) follows the readings (motor) only once the gap is taken up, so after a move longer than the gap it
  rests half of it short of its target, behind it in the direction of the move, and the same command reached from
  either side lands ``backlash`` apart; a shorter move leaves it in the gap; centred at the start;
- ``points=N`` reflectors on the flange (``rig.tools``, (N, 3) in the flange frame; the first is the truth's
  TP), 150-250 mm apart on a plate: the tracker reports each one (``tp`` 1..N) with its own noise; with
  ``occlusion=P`` each point is out of sight at a measurement with probability P (all out of sight: TargetLost);
- a move is synchronised: every joint follows the trapezoidal profile of the slowest one
  (:func:`move_duration`); the arm comes to rest at the target plus a repeatability error
  N(0, ``repeatability``) per joint, then rings: ``q(t) = rest + A·exp(-Δt/ring_tau)·cos(2π·f·Δt)`` with
  ``|A_i|`` in [0.5, 1]·``ring`` and f = :data:`RING_FREQUENCY`; the joint readings are the actual values; a time
  during the last move (a camera frame exposed before its delivery) sees the arm on that move's profile;
- with ``aruco:sim?...`` as the tracker (drivers/camera/tracker.py) the rig takes that spec's faults and seed, and
  :meth:`SimulatedRig.face_tracker` re-places the true base in front of the camera; the camera renders the
  target at :meth:`SimulatedRig.flange_pose` and OpenCV detects it (only the pixels are simulated);
- the tracker's ``k``-th reading of a ``measure`` call is sampled at ``t0 + k·latency`` and delivered
  ``latency`` later, with isotropic Gaussian noise ``noise`` (m per axis, reported as ``sigma``); a reading
  is lost with probability ``dropout`` (the call raises TargetLost).

Faults (spec option ``fault=NAME[@N][xK],...`` or :meth:`SimulatedRig.inject`), counted per ``move_joints``
call (robot) or ``measure`` call (tracker), 1-based from the rig's creation:

- ``protective_stop`` / ``emergency_stop``: move N stops halfway; state PROTECTIVE_STOP / EMERGENCY_STOP;
  ProtectiveStop / EmergencyStop now and on every move until ``rig.clear_faults()``;
- ``disconnect``: move / measurement N raises ConnectionFailed, and so does every call until ``connect()``;
- ``slow``: move N never finishes, measurement N takes longer than its timeout: DeviceTimeout once the
  timeout has passed on the clock (a VirtualClock advances by it; nothing sleeps for real);
- ``unsettled``: after move N the arm keeps ringing, so ``wait_until_still`` raises DeviceTimeout (until the
  next move or ``rig.clear_faults()``);
- ``target_lost`` / ``bad_reading``: measurements N to N+K-1 raise TargetLost / BadReading (garbage reply).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from common.errors import install_hint
from config.robots import ConfigError, RobotModel, load_robot
from drivers.base import Array, RobotState
from drivers.clock import Clock, VirtualClock
from drivers.errors import (
    BackendUnavailable,
    SpecError,
)
from drivers.motion import joint_durations as _durations
from drivers.motion import profile_fraction as _fraction
from drivers.sim.pairing import check_pairing, is_simulated_camera, is_simulated_emscon, points_settings, unpaired
from drivers.sim.stream_model import StreamedMove, StreamSettings
from drivers.sim.world import backlash_play, joint_errors_for, reflector_tools, true_joints
from drivers.spec import PERSISTENT_FAULTS, ROBOT_FAULTS, TRACKER_FAULTS, FaultSpec, RobotSpec, TrackerSpec
from kinematics.dh import flange_frames, frames_from_joints, points_from_joints
from kinematics.truth import random_truth

RING_FREQUENCY = 8.0  # Hz, of the oscillation after a move
MOTION_CHUNK = 0.05  # s of motion between checks for stop()
# When several faults fall on one move / measurement, the first of these happens (the others are dropped).
_PRIORITY = ("disconnect", "emergency_stop", "protective_stop", "slow", "unsettled", "target_lost", "bad_reading")


@dataclass
class _Fault:
    device: str  # "robot" or "tracker"
    name: str
    numbers: list[int]  # the moves / measurements it still affects
    started: bool = False


def _vector(name: str, value: Iterable[float]) -> tuple[float, float, float]:
    out = tuple(float(v) for v in value)
    if len(out) != 3 or not all(math.isfinite(v) for v in out):
        raise ValueError(f"simulated rig: {name} must be three finite numbers")
    return out  # type: ignore[return-value]


def _setting(name: str, value: float, upper: float = math.inf) -> float:
    if not (math.isfinite(value := float(value)) and 0 <= value < upper):
        raise ValueError(f"simulated rig: {name} must be a finite number in [0, {upper:g})")
    return value


class SimulatedRig:
    """One simulated world: the true robot, the arm's actual state, the clock and the fault schedule.

    ``model``: a bundled robot name or a RobotModel; ``seed`` seeds the truth (``random_truth``), the
    reflectors, the joint errors and the robot's random errors, ``tracker_seed`` (default: ``seed``) the tracker's
    noise, dropouts and occlusions. The other settings are those of :data:`drivers.spec.MOCK_ROBOT_OPTIONS` and
    ``MOCK_TRACKER_OPTIONS`` (``eccentricity`` in degrees, as in the spec).
    Attributes: ``model``, ``truth`` (DHModel), ``tools`` (points, 3), ``joint_errors`` (JointErrors),
    ``coupling`` (the model's, or None), ``clock``, ``moves`` and ``measurements`` (calls so far).
    """

    def __init__(self, model: str | RobotModel = "ur5e", *, clock: Clock | None = None, seed: int = 0,
                 repeatability: float = 2e-6, ring: float = 1e-5, ring_tau: float = 0.1,
                 noise: float = 5e-5, latency: float = 0.002, dropout: float = 0.0, tracker_seed: int | None = None,
                 robot_faults: Iterable[FaultSpec] = (), tracker_faults: Iterable[FaultSpec] = (),
                 points: int = 1, occlusion: float = 0.0, scale: float = 0.0, eccentricity: float = 0.0,
                 compliance: float = 0.0, backlash: float = 0.0, stream: StreamSettings | None = None,
                 arm: int | None = None,
                 moved: Iterable[float] = (0.0, 0.0, 0.0), turned: Iterable[float] = (0.0, 0.0, 0.0),
                 orientation: float = 0.0) -> None:
        self.model = model if isinstance(model, RobotModel) else load_robot(model)
        self.clock: Clock = VirtualClock() if clock is None else clock
        self.seed = int(seed)
        self.tracker_seed = self.seed if tracker_seed is None else int(tracker_seed)
        self.repeatability = _setting("repeatability", repeatability)
        self.ring = _setting("ring", ring)
        self.ring_tau = _setting("ring_tau", ring_tau)
        self.noise = _setting("noise", noise)
        self.latency = _setting("latency", latency)
        self.dropout = _setting("dropout", dropout, upper=1.0)
        self.occlusion = _setting("occlusion", occlusion, upper=1.0)
        self.scale, self.eccentricity = _setting("scale", scale), _setting("eccentricity", eccentricity)
        self.compliance = _setting("compliance", compliance)
        self.backlash = _setting("backlash", backlash)
        if int(points) != points or points < 1:
            raise ValueError(f"simulated rig: points must be an integer >= 1, got {points!r}")
        self.points = int(points)
        self.orientation = _setting("orientation", orientation)  # rad per axis; 0: the tracker sees positions only
        home = np.array(self.model.home, dtype=float)
        self.truth = random_truth(self.model.nominal, home, np.random.default_rng(self.seed))
        self.arm = self.seed if arm is None else int(arm)
        if self.arm != self.seed:  # another arm of the model, where the first one stood, with its TP
            other = random_truth(self.model.nominal, home, np.random.default_rng(self.arm))
            self.truth = replace(other, base=self.truth.base, tool=self.truth.tool)
        self.moved, self.turned = _vector("moved", moved), _vector("turned", turned)
        move = np.eye(4)
        move[:3, :3] = Rotation.from_rotvec(np.radians(self.turned)).as_matrix()
        move[:3, 3] = self.moved
        self.truth = replace(self.truth, base=move @ self.truth.base)
        self.coupling = self.model.coupling
        # the world's extras have generators of their own: a rig without them is the rig of before
        self.joint_errors = joint_errors_for(self.model, self.scale, math.radians(self.eccentricity),
                                             self.compliance, np.random.default_rng([self.seed, 5]))
        self.tools = reflector_tools(self.truth, home, self.points, np.random.default_rng([self.seed, 4]))
        # each tracked point's target frame in the flange frame (a 6-DoF probe's axes: seeded, any orientation)
        frames = Rotation.random(self.points, random_state=np.random.default_rng([self.seed, 6]))
        self.target_frames = frames.as_matrix()
        self._robot_rng = np.random.default_rng([self.seed, 1])
        self._tracker_rng = np.random.default_rng([self.tracker_seed, 2])
        self._occlusion_rng = np.random.default_rng([self.tracker_seed, 3])
        self._orientation_rng = np.random.default_rng([self.tracker_seed, 8])
        self._rest = self.readings_of(home)  # where the arm came to rest (actual readings)
        self._lash = np.zeros(self.model.n_joints)  # each joint's offset from its readings in the gap (backlash)
        self._ring_amp, self._ring_start, self._ring_decays = np.zeros(self.model.n_joints), self.clock.now(), True
        self.moves = self.measurements = 0  # move_joints / measure calls so far
        self.robot_connected = self.tracker_connected = False
        self._latched: RobotState | None = None  # PROTECTIVE_STOP / EMERGENCY_STOP until clear_faults()
        self._moving = self._stop_requested = False
        self._faults: list[_Fault] = []
        self.robot_spec: RobotSpec | None = None
        self.tracker_spec: TrackerSpec | None = None
        self.stream, self.stream_epoch = stream or StreamSettings(), self.clock.now()  # drivers/sim/stream.py
        self._stream_rng = np.random.default_rng([self.tracker_seed, 16])
        self._path: Any = None  # a streamed move (drivers/sim/stream.py), overlaid on the rest-and-ring model
        self._past: Any = None  # the last finished stop-and-go move: where the arm was during it (a late camera frame)
        for fault in robot_faults:
            self.inject(fault.name, at_move=fault.at, count=fault.count, device="robot")
        for fault in tracker_faults:
            self.inject(fault.name, at_measure=fault.at, count=fault.count, device="tracker")

    @classmethod
    def from_spec(cls, robot: RobotSpec | str, tracker: TrackerSpec | str | None = None,
                  clock: Clock | None = None, model: RobotModel | None = None) -> SimulatedRig:
        """The rig of ``mock:MODEL?...`` and ``mock?...`` (options, faults included); clock default VirtualClock.
        ``model``: the robot model to simulate (a resumed session's recorded one), None for the one MODEL names."""
        robot = robot if isinstance(robot, RobotSpec) else RobotSpec.parse(robot)
        tracker = tracker if tracker is None or isinstance(tracker, TrackerSpec) else TrackerSpec.parse(tracker)
        if not robot.is_mock:
            raise unpaired(robot, tracker)
        if tracker is not None:
            check_pairing(robot, tracker)
        camera = tracker is not None and is_simulated_camera(tracker)
        r = robot.mock_settings()
        served = tracker is not None and is_simulated_emscon(tracker)  # its simulated server takes its own options
        t = (tracker.mock_settings() if tracker is not None and not camera and not served
             else TrackerSpec("mock").mock_settings())
        world = points_settings(robot, tracker, r, t)
        view = None
        if camera:  # only the camera's pixels are simulated: the rig takes its faults, seed and placement
            assert tracker is not None
            try:
                from drivers.camera.tracker import rig_settings
            except ImportError as exc:
                raise BackendUnavailable(f"the simulated camera needs OpenCV: {install_hint('vision')}") from exc
            t["fault"], t["seed"], view = rig_settings(tracker)
        try:
            model = model if model is not None else load_robot(robot.model)
        except ConfigError as exc:
            raise SpecError(f"robot spec {str(robot)!r}: {exc}") from exc
        if camera and world["points"] > 1:
            raise SpecError(f"{str(robot)!r} with {str(tracker)!r}: the simulated camera sees one target; "
                            "points=N needs the mock tracker")
        try:
            rig = cls(model, clock=clock, seed=r["seed"], repeatability=r["repeatability"], ring=r["ring"],
                      ring_tau=r["ring_tau"], noise=t["noise"], latency=t["latency"], dropout=t["dropout"],
                      tracker_seed=t["seed"], robot_faults=r["fault"], tracker_faults=t["fault"], scale=r["scale"],
                      eccentricity=r["eccentricity"], compliance=r["compliance"], backlash=r["backlash"],
                      stream=StreamSettings.from_settings(r, t), arm=r["arm"], moved=t["moved"],
                      turned=t["turned"], orientation=t["orientation"], **world)
        except ValueError as exc:
            raise SpecError(f"robot spec {str(robot)!r}: {exc}") from None
        rig.robot_spec, rig.tracker_spec = robot, tracker
        if view is not None and tracker is not None and tracker.options.get("mount") == "flange":
            from drivers.camera.flange_camera import CAMERA_MOUNT, facing_board

            rig.face_board(CAMERA_MOUNT, facing_board(*view))  # the camera on the flange, the board before it at home
        elif view is not None:
            rig.face_tracker(*view)
        return rig

    # --- the physical world -------------------------------------------------------------------------------

    def actual_joints(self, t: float | Array | None = None) -> Array:
        """The arm's actual joint values at clock time ``t`` (default now): (n,), or (m, n) for m times."""
        path = self._path  # read once: a move's thread may end it meanwhile (the emulator's tracker reads here)
        if path is not None and np.ndim(t) == 0:
            held = path.at(self.clock.now() if t is None else float(np.asarray(t)))
            if held is not None:
                return held
        dt = np.maximum(np.asarray(self.clock.now() if t is None else t, dtype=float) - self._ring_start, 0.0)
        if not self._ring_decays:
            envelope = np.ones_like(dt)
        elif self.ring_tau > 0:
            envelope = np.exp(-dt / self.ring_tau)
        else:
            envelope = np.zeros_like(dt)
        wave = envelope * np.cos(2 * np.pi * RING_FREQUENCY * dt)
        out = self._rest + np.multiply.outer(wave, self._ring_amp)
        if path is None and self._past is not None and t is not None:
            return self._past.overlay(t, out)  # a time during the last move (a camera's latency looks back)
        return out if path is None else path.overlay(self.clock.now() if t is None else t, out)

    def readings_of(self, q: Array) -> Array:
        """The controller's readings (n,) or (m, n) that give the DH joint values ``q`` (the same without a
        coupling)."""
        q = np.asarray(q, dtype=float)
        return q.copy() if self.coupling is None else self.coupling.readings_from_dh(np.atleast_2d(q)).reshape(q.shape)

    def true_joints(self, t: float | Array | None = None) -> Array:
        """Where the joints really stand at clock time ``t`` (default now), DH values: the DH values of the
        actual readings plus the joint errors (drivers/sim/world.py) and the backlash: (n,), or (m, n) for m times."""
        q = true_joints(self.actual_joints(t), self.coupling, self.joint_errors, self.truth, self.model.links)
        return q + self._lash if self.backlash else q

    def true_points(self, t: float | Array | None = None) -> Array:
        """The true positions of every reflector, m in the tracker frame, at clock time ``t`` (default now):
        (points, 3), or (m, points, 3) for m times; reflector k is ``tools[k]`` on the flange."""
        q = np.atleast_2d(self.true_joints(t))
        out = np.stack([points_from_joints(replace(self.truth, tool=tool), q) for tool in self.tools], axis=1)
        return out if np.ndim(t) else out[0]

    def true_frames(self, t: float | Array | None = None) -> Array:
        """The true orientation of every tracked point's target frame, tracker frame <- target frame, at clock time
        ``t`` (default now): (points, 3, 3), or (m, points, 3, 3) for m times (``target_frames[k]`` on the flange)."""
        rotation, _ = flange_frames(self.truth, np.atleast_2d(self.true_joints(t)))
        out = np.einsum("mij,kjl->mkil", rotation, self.target_frames)
        return out if np.ndim(t) else out[0]

    def true_point(self, t: float | None = None) -> Array:
        """The true TP (3,) (the first reflector), m in the tracker frame, at clock time ``t`` (default now)."""
        return points_from_joints(self.truth, self.true_joints(t))[0]

    def flange_pose(self, t: float | None = None) -> Array:
        """The true last DH frame (the flange; the TP is ``truth.tool`` in it) at clock time ``t`` (default
        now): 4x4, tracker frame <- flange frame, metres."""
        return frames_from_joints(self.truth, self.true_joints(t))[0, -1]

    def face_tracker(self, distance: float, tilt: float = 0.0, roll: float = 0.0) -> None:
        """Re-place the true robot's base for a camera tracker: at home the TP lies ``distance`` m down the
        tracker's z axis and the flange's z axis points back at the tracker, turned by ``tilt`` rad about
        the tracker's x axis and then by ``roll`` rad about its z axis (a marker on the flange faces the
        camera). The DH table and the TP stay as they were."""
        home = true_joints(self.readings_of(self.model.home), self.coupling, self.joint_errors, self.truth,
                           self.model.links)
        at_home = frames_from_joints(replace(self.truth, base=np.eye(4)), home)[0, -1]  # base <- flange
        facing = facing_flange(self.truth.tool, distance, tilt, roll)
        self.truth = replace(self.truth, base=facing @ np.linalg.inv(at_home))

    def face_board(self, mount: Array, facing: Array) -> None:
        """Re-place the true base for a camera on the flange at ``mount`` (flange <- camera) seeing a fixed board:
        at home the board is at ``facing`` (camera <- board) and the tracker frame is the board's. DH table kept."""
        home = true_joints(self.readings_of(self.model.home), self.coupling, self.joint_errors, self.truth,
                           self.model.links)
        at_home = frames_from_joints(replace(self.truth, base=np.eye(4)), home)[0, -1]  # base <- flange
        self.truth = replace(self.truth, base=np.linalg.inv(at_home @ mount @ facing))

    @property
    def rest_joints(self) -> Array:
        """Where the arm comes to rest once it stops ringing (n,): the last target plus repeatability error."""
        return self._rest.copy()

    @property
    def robot_state(self) -> RobotState:
        if not self.robot_connected:
            return RobotState.DISCONNECTED
        if self._latched is not None:
            return self._latched
        return RobotState.MOVING if self._moving else RobotState.READY

    def _run(self, start: Array, target: Array, speed: Array, acceleration: Array, until: float) -> bool:
        """Move from ``start`` towards ``target`` for ``until`` s of the move's profile (clock advanced in
        chunks so that ``stop()`` can cut in), then let the arm come to rest. Returns True if stopped early.

        While it runs, the arm follows the profile on the clock (a :class:`StreamedMove` overlaid on the rest
        model, held where the move ends): what a tracker measuring in real time (the UR emulator's) sees."""
        durations = _durations(start, target, speed, acceleration)
        k = int(np.argmax(durations))
        duration, distance = float(durations[k]), abs(float(target[k] - start[k]))
        elapsed, remaining = 0.0, until
        t0 = self.clock.now()
        path = StreamedMove(start, target, speed, acceleration, t0)
        if until < path.duration:
            path.t_stop = t0 + until
        self._moving, self._stop_requested, self._path = True, False, path
        try:
            while remaining > 0 and not self._stop_requested:
                step = min(MOTION_CHUNK, remaining)
                self.clock.sleep(step)
                elapsed, remaining = elapsed + step, remaining - step
        finally:  # also on KeyboardInterrupt: the arm stops where it is
            self._moving = False
            if self._stop_requested:  # where the profile has got to on the clock (a real-time clock runs on
                elapsed = min(until, max(elapsed, self.clock.now() - t0))  # while a chunk's sleep ends)
            share = _fraction(elapsed, duration, float(speed[k]), float(acceleration[k]), distance)
            if duration > 0:
                n = len(start)
                reached = start + share * (target - start)
                self._rest = reached + self._robot_rng.normal(0.0, self.repeatability, n)
                signs = self._robot_rng.choice([-1.0, 1.0], n)
                self._ring_amp = self.ring * self._robot_rng.uniform(0.5, 1.0, n) * signs
                self._ring_start = self.clock.now()
                self._ring_decays = True
                self._lash = backlash_play(self._lash, reached - start, self.backlash)
            if self._stop_requested:  # cut short: the profile ends where the arm stopped
                path.t_stop = min(path.t_stop, t0 + elapsed)
            path.finished, self._past = True, path  # times before the move's end still see it
            self._path = None  # last: until now the move's profile holds the arm (no glitch for a reader)
        return self._stop_requested

    # --- faults ---------------------------------------------------------------------------------------------

    def inject(self, fault: str, *, at_move: int | None = None, at_measure: int | None = None, count: int = 1,
               device: str | None = None) -> None:
        """Schedule ``fault`` at move ``at_move`` (robot) or measurement ``at_measure`` (tracker), 1-based and
        counted from the rig's creation; without either, at the next one of ``device`` (needed only for the
        names both devices have: disconnect, slow). ``count``: how many moves / measurements a transient
        fault lasts. E.g. ``rig.inject("protective_stop", at_move=40)``, ``rig.inject("target_lost", count=3)``.
        """
        if device is None:
            if at_move is None and at_measure is None and fault in ROBOT_FAULTS and fault in TRACKER_FAULTS:
                raise ValueError(f"fault {fault!r} exists for both devices: say device='robot' or 'tracker'")
            device = "robot" if at_move is not None or fault not in TRACKER_FAULTS else "tracker"
        dev = device
        if dev not in ("robot", "tracker") or (at_measure if dev == "robot" else at_move) is not None:
            raise ValueError(f"at_move is for the robot and at_measure for the tracker (device {dev!r})")
        known = ROBOT_FAULTS if dev == "robot" else TRACKER_FAULTS
        if fault not in known:
            raise ValueError(f"unknown {dev} fault {fault!r} (known: {', '.join(known)})")
        if count < 1 or (count != 1 and fault in PERSISTENT_FAULTS):
            raise ValueError(f"count must be >= 1, and 1 for {', '.join(PERSISTENT_FAULTS)}; got {count}")
        done = self.moves if dev == "robot" else self.measurements
        at = at_move if dev == "robot" else at_measure
        at = done + 1 if at is None else int(at)
        if at <= done:
            raise ValueError(f"{dev} {'move' if dev == 'robot' else 'measurement'} {at} has already happened")
        self._faults.append(_Fault(dev, fault, list(range(at, at + count))))

    def clear_faults(self, pending: bool = False) -> None:
        """Recover: release a protective or emergency stop, end a persistent ringing and the rest of a running
        transient fault (``pending=True``: drop the scheduled ones too). A lost link needs ``connect()``."""
        self._latched = None
        if not self._ring_decays:
            self._ring_decays, self._ring_start = True, self.clock.now()
        self._faults = [] if pending else [f for f in self._faults if not f.started]

    def pending_faults(self) -> list[str]:
        """The scheduled faults, e.g. ``["robot: protective_stop@40", "tracker: target_lost@10x3"]``."""
        return [f"{f.device}: {FaultSpec(f.name, f.numbers[0], len(f.numbers))}" for f in self._faults]

    def _take(self, device: str, number: int) -> str | None:
        """The fault (if any) of ``device`` at move / measurement ``number``; consumes it."""
        hits = []
        for fault in self._faults:
            if fault.device == device and number in fault.numbers:
                fault.numbers.remove(number)
                fault.started = True
                hits.append(fault.name)
        self._faults = [f for f in self._faults if f.numbers]
        return min(hits, key=_PRIORITY.index) if hits else None

    def _check_settings(self, spec: RobotSpec | TrackerSpec, ours: dict[str, Any], given: dict[str, Any],
                        made_from: RobotSpec | TrackerSpec | None) -> None:
        if given["fault"] and spec != made_from:
            raise ValueError(f"the faults of {str(spec)!r} must be given to SimulatedRig.from_spec, not open_*")
        differ = [key for key in ours if ours[key] != given[key]]
        if differ:
            raise ValueError(f"spec {str(spec)!r} disagrees with the simulated rig on {', '.join(differ)}; "
                             "open the devices with the specs the rig was made from")


def facing_flange(tool: Array, distance: float, tilt: float = 0.0, roll: float = 0.0) -> Array:
    """Tracker frame <- flange frame (4x4, m) of :meth:`SimulatedRig.face_tracker`'s placement: the TP (``tool``, m
    in the flange frame) ``distance`` m down the tracker's z axis, the flange's z axis pointing back at the
    tracker, turned by ``tilt`` rad about the tracker's x axis and then by ``roll`` rad about its z axis."""
    cr, sr, ct, st = math.cos(roll), math.sin(roll), math.cos(tilt), math.sin(tilt)
    facing = np.array([[1.0, 0, 0], [0, -1, 0], [0, 0, -1]])  # flange z towards the tracker
    rotation = np.array([[cr, -sr, 0], [sr, cr, 0], [0, 0, 1]]) @ np.array(
        [[1, 0, 0], [0, ct, -st], [0, st, ct]]) @ facing
    out = np.eye(4)
    out[:3, :3] = rotation
    out[:3, 3] = np.array([0.0, 0.0, distance]) - rotation @ np.asarray(tool, dtype=float)
    return out
