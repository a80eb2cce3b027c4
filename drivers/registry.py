"""Backend name -> driver module, imported only when a device of that backend is opened.

Importing this module imports no backend (no numpy, no simulator, no ``serial``, ``cv2`` or ``rtde_*``).
Each backend module exposes a factory ``open_robot(spec: RobotSpec, **kwargs) -> Robot`` or
``open_tracker(spec: TrackerSpec, **kwargs) -> Tracker``; the factory returns an unconnected device (call
``connect(timeout)`` next) and checks the backend's own options.

Mock mode: the simulated robot and tracker must see one simulated world (the same true robot, the same
clock), so their factories take it as ``rig=``::

    from drivers.clock import VirtualClock          # WallClock() for --realtime
    from drivers.registry import open_robot, open_tracker
    from drivers.sim.rig import SimulatedRig
    from drivers.spec import RobotSpec, TrackerSpec

    robot_spec, tracker_spec = RobotSpec.parse("mock:ur5e?seed=3"), TrackerSpec.parse("mock?noise=5e-5")
    rig = SimulatedRig.from_spec(robot_spec, tracker_spec, VirtualClock())
    robot = open_robot(robot_spec, rig=rig)
    tracker = open_tracker(tracker_spec, rig=rig)

The rig takes the options of both specs (truth seed, noise, faults...); ``open_*`` checks that the spec it is
given agrees with the rig. Without ``rig=``, ``open_robot`` builds a private rig from the spec (clock:
``clock=`` or a VirtualClock); a mock tracker always needs ``rig=``. A rig is only for mock devices on both
sides (``from_spec`` refuses a real one: a simulated tracker cannot see a real arm, nor a real tracker a
simulated one).

Keyword arguments every factory accepts, so that a caller can pass the same ones to any backend:
``rig`` (a SimulatedRig, or None for real backends) and ``site`` (the resolved site configuration, or None;
the mock backend ignores it). A real backend may take more of its own. A model-only robot spec (``ur5e``)
gets its host from the site configuration, or explicitly with ``spec.with_host(host)``.

Errors: a malformed spec raises SpecError; a backend that is not implemented in this installation, or whose
third-party package is missing, raises BackendUnavailable with one line saying what to do.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from common.errors import install_hint
from drivers.errors import BackendUnavailable
from drivers.spec import RobotSpec, TrackerSpec

if TYPE_CHECKING:
    from drivers.base import Robot, Tracker

#: Robot backend -> "module:factory".
ROBOT_BACKENDS: dict[str, str] = {
    "ur": "drivers.ur.driver:open_robot",
    "mock": "drivers.sim.robot:open_robot",
}
#: Tracker backend -> "module:factory".
TRACKER_BACKENDS: dict[str, str] = {
    "serial": "drivers.trackers.serial_tracker:open_tracker",
    "ipp": "drivers.trackers.ipp:open_tracker",
    "emscon": "drivers.trackers.emscon:open_tracker",
    "aruco": "drivers.camera.tracker:open_tracker",
    "mock": "drivers.sim.tracker:open_tracker",
}
#: Top-level third-party module -> the pyproject.toml extra that installs it.
EXTRAS: dict[str, str] = {
    "rtde_control": "ur",
    "rtde_receive": "ur",
    "rtde_io": "ur",
    "serial": "serial",
    "cv2": "vision",
}


def open_robot(spec: RobotSpec | str, **kwargs: Any) -> Robot:
    """Open (not yet connect) the robot described by ``spec`` (a RobotSpec or its string)."""
    if not isinstance(spec, RobotSpec):
        spec = RobotSpec.parse(spec)
    factory = load_factory("robot", spec.backend)
    return factory(spec, **kwargs)  # type: ignore[no-any-return]


def open_tracker(spec: TrackerSpec | str, **kwargs: Any) -> Tracker:
    """Open (not yet connect) the tracker described by ``spec`` (a TrackerSpec or its string)."""
    if not isinstance(spec, TrackerSpec):
        spec = TrackerSpec.parse(spec)
    factory = load_factory("tracker", spec.backend)
    return factory(spec, **kwargs)  # type: ignore[no-any-return]


def load_factory(kind: str, backend: str) -> Callable[..., Any]:
    """Import the factory of a ``kind`` ("robot" or "tracker") backend; BackendUnavailable if it cannot be."""
    table = ROBOT_BACKENDS if kind == "robot" else TRACKER_BACKENDS
    if backend not in table:
        raise BackendUnavailable(f"unknown {kind} backend {backend!r}; known: {', '.join(table)}")
    module_name, _, attribute = table[backend].partition(":")
    shown = module_name.replace(".", "/") + ".py"
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        missing = exc.name or ""
        if missing and (missing == module_name or module_name.startswith(missing + ".")):
            raise BackendUnavailable(f"the {backend!r} {kind} backend is not available in this installation "
                                     f"({shown} is not implemented yet)") from exc
        if not missing:
            raise BackendUnavailable(f"the {backend!r} {kind} backend cannot be imported ({shown}: "
                                     f"{' '.join(str(exc).split())})") from exc
        top = missing.partition(".")[0]
        extra = EXTRAS.get(top)
        hint = install_hint(extra) if extra else f"install the package that provides {top!r}"
        raise BackendUnavailable(f"the {backend!r} {kind} backend needs the Python module {top!r}, which is not "
                                 f"installed: {hint}") from exc
    factory = getattr(module, attribute, None)
    if not callable(factory):
        raise BackendUnavailable(f"the {backend!r} {kind} backend is broken: {shown} has no {attribute}()")
    return factory  # type: ignore[no-any-return]
