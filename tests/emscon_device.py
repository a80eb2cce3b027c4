"""The emScon emulator of the tests: drivers/trackers/emscon_sim.py's simulated server (also behind ``emscon:sim``),
on a rig of its own unless given one, and the driver connected to it."""

from __future__ import annotations

from typing import Any

from drivers.sim.rig import SimulatedRig
from drivers.trackers.emscon_server import EMSCON_FAULTS
from drivers.trackers.emscon_sim import REFLECTORS, SHIFT, EmsconSimServer

__all__ = ["EMSCON_FAULTS", "REFLECTORS", "SHIFT", "EmsconServer", "open_emscon"]


class EmsconServer(EmsconSimServer):
    """The simulated emScon server on loopback (``host``, ``port``), answering from ``rig`` (default: a UR5e rig of
    seed ``seed``); faults with ``inject(name, count)`` (drivers/trackers/emscon_sim.py)."""

    def __init__(self, rig: SimulatedRig | None = None, *, noise: float = 2e-5, seed: int = 0, **options: Any) -> None:
        super().__init__(rig if rig is not None else SimulatedRig("ur5e", seed=seed), noise=noise, seed=seed,
                         **options)


def open_emscon(server: EmsconServer, **options: str) -> object:
    """The emScon driver connected to ``server`` (options as in the spec; answer timeout 0.5 s, measurement time
    0.002 s by default)."""
    from drivers.registry import open_tracker

    query = "&".join(f"{k}={v}" for k, v in {"timeout": "0.5", "meas_time": "0.002", **options}.items())
    tracker = open_tracker(f"emscon:{server.host}:{server.port}?{query}")
    tracker.connect(3.0)
    return tracker
