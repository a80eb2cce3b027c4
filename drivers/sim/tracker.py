"""The simulated tracker of the mock mode (``--tracker mock?...``): it sees the simulated rig's reflectors.

The rig (drivers/sim/rig.py) holds the world: the true robot, its reflectors (``points``), the clock and the fault
schedule. A ``measure(count)`` call samples reading ``k`` at ``t0 + k·latency`` and delivers it ``latency``
later, every reflector in sight at once, each with its own isotropic Gaussian noise ``noise`` (m per axis,
reported as ``sigma``) and its id ``tp`` (1..points). A measurement is lost as a whole with probability
``dropout`` (TargetLost); with ``occlusion`` each reflector is out of sight for the whole measurement with that
probability (no readings of it; all out of sight: TargetLost). Scheduled faults as in drivers/sim/rig.py.
6-DoF mode (``orientation=SIGMA_R``): each reading also gives its tracked point's target frame (the rig's
``target_frames`` on the flange) as a rotation vector, turned by isotropic Gaussian noise of ``SIGMA_R`` rad per axis
(reported as ``sigma_r``), from a generator of its own (the positions' draws are those of the mock without it).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial.transform import Rotation

from drivers.base import DeviceIdentity, TrackerReading, check_measure_request
from drivers.errors import BadReading, ConnectionFailed, DeviceTimeout, SpecError, TargetLost
from drivers.sim.stream import TrackerStreaming
from drivers.spec import TrackerSpec

if TYPE_CHECKING:
    from drivers.sim.rig import SimulatedRig


class SimulatedTracker(TrackerStreaming):
    """The simulated tracker (implements :class:`drivers.base.Tracker` and ``StreamingTracker``, the stream in
    drivers/sim/stream.py): sees the rig's true reflectors."""

    def __init__(self, rig: SimulatedRig) -> None:
        self.rig = rig

    @property
    def points(self) -> int:
        """How many tracked points (reflectors) it can see."""
        return self.rig.points

    def connect(self, timeout: float) -> None:
        if not timeout > 0:
            raise ValueError(f"timeout must be > 0 s, got {timeout!r}")
        self.rig.tracker_connected = True

    def close(self) -> None:
        self.rig.tracker_connected = False

    def identity(self) -> DeviceIdentity:
        rig = self.rig
        details = {"noise": f"{rig.noise:g}", "latency": f"{rig.latency:g}", "dropout": f"{rig.dropout:g}"}
        if rig.points > 1 or rig.occlusion > 0:
            details.update(points=str(rig.points), occlusion=f"{rig.occlusion:g}")
        if rig.orientation > 0:
            details.update(orientation=f"{rig.orientation:g}")
        if any(rig.moved) or any(rig.turned):
            details.update(moved=",".join(f"{v:g}" for v in rig.moved), turned=",".join(f"{v:g}" for v in rig.turned))
        s = rig.stream  # its streams' clock (drivers/sim/stream.py): what a session's clock fit should find
        details.update(clock_offset=f"{s.clock_offset!r}", drift=f"{s.drift!r}", stamp_jitter=f"{s.jitter!r}",
                       clock_epoch=f"{rig.stream_epoch!r}")
        return DeviceIdentity("tracker", "simulated tracker", serial=f"SIM-T{rig.tracker_seed}", firmware="sim",
                              details=details)

    def measure(self, count: int, timeout: float) -> list[TrackerReading]:
        """``count`` readings of each reflector in sight (m, tracker frame; ``sigma`` = the noise, ``tp`` its id),
        in time order, the reflectors of one reading in id order; the clock advances by ``count · latency``.
        Raises TargetLost, BadReading, DeviceTimeout, ConnectionFailed."""
        rig = self.rig
        if not rig.tracker_connected:
            raise ConnectionFailed("the simulated tracker is not connected (call connect(); after a lost link, "
                                   "connect again)")
        check_measure_request(count, timeout)
        number = rig.measurements = rig.measurements + 1
        fault = rig._take("tracker", number)
        clock, latency = rig.clock, rig.latency
        if fault == "disconnect":
            rig.tracker_connected = False
            raise ConnectionFailed(f"lost the connection to the simulated tracker at measurement {number}")
        if fault == "slow" or count * latency > timeout:
            clock.sleep(timeout)
            raise DeviceTimeout(f"measurement {number} ({count} readings) got no answer within {timeout:g} s")
        if fault == "target_lost":
            clock.sleep(latency)
            raise TargetLost(f"simulated tracker lost the target (line of sight) at measurement {number}")
        if fault == "bad_reading":
            clock.sleep(latency)
            raise BadReading(f"simulated tracker sent garbage at measurement {number}: '#?!\\x00 1.2e+9?'")
        t0 = clock.now()
        times = t0 + latency * np.arange(count)
        points = rig.true_points(times)  # (count, points, 3)
        points += rig._tracker_rng.normal(0.0, rig.noise, points.shape)
        if rig.dropout > 0:
            lost = np.flatnonzero(rig._tracker_rng.random(count) < rig.dropout)
            if lost.size:
                clock.sleep(latency * (lost[0] + 1))
                raise TargetLost(f"simulated tracker lost the target in reading {lost[0] + 1} of measurement "
                                 f"{number}")
        seen = np.arange(rig.points)
        if rig.occlusion > 0:
            seen = np.flatnonzero(rig._occlusion_rng.random(rig.points) >= rig.occlusion)
            if not seen.size:
                clock.sleep(latency)
                raise TargetLost(f"simulated tracker: every one of the {rig.points} point(s) is out of sight "
                                 f"(line of sight blocked) at measurement {number}")
        clock.sleep(latency * count)
        if rig.orientation > 0:
            frames = rig.true_frames(times)  # (count, points, 3, 3)
            turns = Rotation.from_rotvec(rig._orientation_rng.normal(0.0, rig.orientation, (count, rig.points, 3))
                                         .reshape(-1, 3)).as_matrix().reshape(frames.shape)
            rotvecs = Rotation.from_matrix((turns @ frames).reshape(-1, 3, 3)).as_rotvec().reshape(count, rig.points, 3)
            return [TrackerReading(points[i, k], float(times[i]), sigma=rig.noise, tp=int(k) + 1,
                                   rotvec=rotvecs[i, k], sigma_r=rig.orientation)
                    for i in range(count) for k in seen]
        return [TrackerReading(points[i, k], float(times[i]), sigma=rig.noise, tp=int(k) + 1)
                for i in range(count) for k in seen]


def open_tracker(spec: TrackerSpec | str, *, rig: SimulatedRig | None = None, site: object = None) -> SimulatedTracker:
    """The simulated tracker of ``mock?...``, looking at ``rig``'s robot (required); ``site`` is not needed."""
    spec = spec if isinstance(spec, TrackerSpec) else TrackerSpec.parse(spec)
    if not spec.is_mock:
        raise SpecError(f"drivers.sim opens the mock tracker only, got {str(spec)!r}")
    if rig is None:
        raise ValueError("a mock tracker needs the simulated robot it looks at: pass "
                         "rig=SimulatedRig.from_spec(robot_spec, tracker_spec, clock)")
    given = spec.mock_settings()
    given["seed"] = rig.seed if given["seed"] is None else given["seed"]
    ours = {"noise": rig.noise, "latency": rig.latency, "dropout": rig.dropout, "seed": rig.tracker_seed,
            "moved": rig.moved, "turned": rig.turned, "orientation": rig.orientation}
    ours.update({key: getattr(rig, key) for key in ("points", "occlusion") if given[key] is not None})
    ours.update(rig.stream.tracker_options())
    rig._check_settings(spec, ours, given, rig.tracker_spec)
    return SimulatedTracker(rig)
