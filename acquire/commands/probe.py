"""``acquire --probe``: the operator's first check of a tracker on site (readings and their spread)."""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from acquire.commands.prepare import UsageError, open_traced_tracker, site_from_args
from drivers.clock import VirtualClock
from drivers.errors import DeviceTimeout, MeasurementError
from drivers.spec import RobotSpec, TrackerSpec


def probe(args: argparse.Namespace) -> int:
    """The operator's first check on site: open the tracker, take readings, show them and their spread.

    Exit 0 when every reading worked, 1 when any failed (each failure is one line), 2 for bad input. A tracker
    that sees several points shows each (``point N``); the spread is point 1's."""
    if args.count < 1:
        raise UsageError(f"--count must be at least 1, got {args.count}")
    site = site_from_args(args)
    tracker_spec = TrackerSpec.parse(args.tracker or "mock")
    rig = None
    simulated = tracker_spec.backend in ("aruco", "emscon") and tracker_spec.target == "sim"
    if tracker_spec.backend == "mock" or simulated:  # a simulated tracker
        # looks at a simulated robot standing at home
        from drivers.sim.rig import SimulatedRig

        robot_spec = RobotSpec.parse(args.robot if args.robot is not None else "mock:ur5e")
        robot_spec = robot_spec if robot_spec.backend == "mock" else RobotSpec.parse(f"mock:{robot_spec.model}")
        rig = SimulatedRig.from_spec(robot_spec, tracker_spec, VirtualClock())
    tracker = open_traced_tracker(tracker_spec, rig, site, args.trace_io)
    tracker.connect(site.timeouts.connect)
    points, failed, several = [], 0, False
    try:
        identity = tracker.identity()
        if not args.json:
            print(f"tracker: {identity.model}" + (f", serial {identity.serial}" if identity.serial else ""))
            if timing := camera_timing(identity.details):
                print(timing)
        for k in range(1, args.count + 1):
            try:
                readings = tracker.measure(1, site.timeouts.measure)
            except (MeasurementError, DeviceTimeout) as exc:
                failed += 1
                print(f"reading {k}: failed: {type(exc).__name__}: {exc}", file=sys.stderr)
                continue
            several = several or any(r.tp != 1 for r in readings)
            for reading in readings:  # one per tracked point in sight
                p = np.asarray(reading.position, dtype=float)
                if reading.tp == 1:
                    points.append(p)
                if args.json:
                    extra = {} if reading.tp == 1 else {"tp": reading.tp}
                    print(json.dumps({"x": p[0], "y": p[1], "z": p[2], "timestamp": reading.timestamp,
                                      "sigma": reading.sigma, "status": reading.status, **extra}))
                else:
                    point = "" if reading.tp == 1 and len(readings) == 1 else f" point {reading.tp}"
                    print(f"reading {k}{point}: x {p[0] * 1e3:.4f}  y {p[1] * 1e3:.4f}  z {p[2] * 1e3:.4f} mm  "
                          f"({reading.status})")
    finally:
        tracker.close()
    if points and not args.json:
        pts = np.array(points)
        spread = np.std(pts, axis=0, ddof=1) if len(pts) > 1 else np.zeros(3)
        worst = np.linalg.norm(pts - pts.mean(axis=0), axis=1).max()
        which = " (point 1)" if several else ""
        print(f"{len(pts)} of {args.count} readings{which}; spread (std) x {spread[0] * 1e3:.4f}, "
              f"y {spread[1] * 1e3:.4f}, z {spread[2] * 1e3:.4f} mm; largest distance from the mean "
              f"{worst * 1e3:.4f} mm")
    return 1 if failed else 0


def camera_timing(details: dict[str, str]) -> str:
    """A camera's frame rate, what its frames' times are, its measured latency and the latency its stop-and-go readings
    allow for (s in ``details``, printed in ms), in one line; "" for a tracker without a frame rate."""
    if "frame_rate" not in details:
        return ""
    line = f"frames: {float(details['frame_rate']):.1f} Hz; frame times: {details.get('stream_timestamps', '?')}"
    if "latency_measured" in details:
        line += (f"; latency {float(details['latency_measured']) * 1e3:.1f} ms measured "
                 f"(spread {float(details.get('latency_spread', 'nan')) * 1e3:.2f} ms)")
    elif "latency_spread" in details:
        line += (f"; latency not measurable (no frame times; arrival jitter "
                 f"{float(details['latency_spread']) * 1e3:.2f} ms)")
    if "latency" in details:  # drivers/camera/latency.py
        line += (f"; readings skip frames delivered within {float(details['latency']) * 1e3:.1f} ms of the request "
                 f"(latency: {details.get('latency_basis', '?')})")
    return line
