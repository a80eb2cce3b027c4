"""ArUco camera stream: delivered rate, per-frame noise, detection time per frame, and a continuous mock session.

    .venv/bin/python -m bench.camera_stream [--width 1280 --height 720 --fps 30] [--no-sessions]

Stream (``drivers/camera/stream.py`` on ``aruco:sim``: images rendered from the simulated UR5e, read by OpenCV):
a 2x2 grid board of 50 mm markers at 0.8 m facing the camera (60 deg horizontal field of view, noise 2 grey
levels, blur 0.5 px), 40 ms from exposure to stamp. "still": 2 s with the arm at rest; "moving": joint 1 turning
0.5 rad at up to 1 rad/s (the TP at up to 0.4 m/s). Per stream: the rate delivered (rows per second of stamps),
frames lost, the per-frame error against the true TP at each stamp minus the latency (RMS per camera axis: x, y
across the line of sight, z along it; m -> mm), the median reported sigma (per axis), the worker's detection time
per frame (detection, edge refinement, pose) and the wall time per frame (rendering included).

Sessions: ``acquire --robot mock:ur5e?seed=3 --tracker aruco:sim?... --mode step|continuous`` as fresh processes
(virtual clock) with sweeps of +-0.3 rad around the UR5e's home so the board stays in view (SITE). Robot time =
first step's start to last step's end on the rig's clock; held-out RMS from the session's own identification; the
fitted clock offset against the camera's latency; the identified model's RMS error against the simulated truth at
200 random poses within the sweep ranges, next to the result's own bound for its held-out poses (validation
``bound``: the model's share of the expected held-out error); wall time of the whole run.

Targets: the still stream delivers every frame (rate >= 0.99 x fps), detection keeps up with the frame rate
(detection time per frame < 1 / fps), the continuous session's clock offset is -latency within 3 of its reported
standard uncertainties. Exit status 1 when one is missed.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

from bench.continuous import held_out, robot_time
from drivers.camera.tracker import open_tracker
from drivers.clock import VirtualClock
from drivers.sim.rig import SimulatedRig
from drivers.sim.robot import SimulatedRobot
from drivers.spec import RobotSpec, TrackerSpec
from identify.io.result_io import validation_of
from kinematics.dh import model_from_dict, points_from_joints

ROBOT = "mock:ur5e?seed=3"
LATENCY = 0.04  # s
TARGET = "board=grid&cols=2&rows=2&size=0.05&gap=0.01&tilt=0&distance=0.8"
SITE = """schema: 1
plan:
  sweep_ranges: [[-0.3, 0.3], [-1.87, -1.27], [1.27, 1.87], [-1.87, -1.27], [-1.87, -1.27], [-0.3, 0.3]]
  check_poses: 6
  home_check_every: 0
"""


def camera_spec(width: int, height: int, fps: float) -> str:
    return f"aruco:sim?{TARGET}&width={width}&height={height}&fps={fps:g}&latency={LATENCY:g}"


def stream(spec: str, seconds: float, turn: float) -> dict[str, float]:
    """One stream of ``seconds`` (rig clock), joint 1 turning by ``turn`` rad meanwhile; the numbers of the
    module docstring."""
    tracker_spec = TrackerSpec.parse(spec)
    rig = SimulatedRig.from_spec(RobotSpec.parse(ROBOT), tracker_spec, VirtualClock())
    tracker = open_tracker(tracker_spec, rig=rig)
    tracker.connect(5.0)
    robot = SimulatedRobot(rig)
    robot.connect(5.0)
    started = time.perf_counter()
    t0 = rig.clock.now()
    rate = tracker.start_stream(250.0, 5.0)
    if turn:
        target = rig.rest_joints
        target[0] += turn
        robot.start_move(target, [1.0] * 6, [2.0] * 6, 10.0)
    batches = []
    while rig.clock.now() - t0 < seconds:
        rig.clock.sleep(0.02)
        batches.append(tracker.read_stream())
        if turn:
            robot.motion_done()
    batches.append(tracker.stop_stream(10.0))
    wall = time.perf_counter() - started
    t = np.concatenate([b.t for b in batches])
    points = np.vstack([b.points for b in batches])
    sigma = np.concatenate([b.sigma for b in batches])
    err = points - rig.true_points(t - LATENCY)[:, 0]
    counts = tracker.stream_counts
    speed = np.linalg.norm(np.diff(rig.true_points(t)[:, 0], axis=0), axis=1) / np.diff(t)
    tracker.close()
    return {"rate": rate, "delivered": (len(t) - 1) / (t[-1] - t[0]), "frames": counts["frames"], "rows": len(t),
            "gaps": counts["gaps"], "rms": np.sqrt(np.mean(err**2, axis=0)), "sigma": float(np.median(sigma)),
            "detect": tracker.detect_seconds / max(counts["frames"], 1), "wall": wall / max(counts["frames"], 1),
            "speed": float(speed.max())}


def session(mode: str, tracker: str, folder: Path) -> dict[str, object]:
    """A mock session of ``mode`` measured by ``tracker`` (module docstring)."""
    path = folder / f"{mode}.session"
    (folder / "site.yaml").write_text(SITE)
    started = time.perf_counter()
    subprocess.run([sys.executable, "-m", "acquire.commands.launch", "--robot", ROBOT, "--tracker", tracker,
                    "--mode", mode, "--config", str(folder / "site.yaml"), "--session", str(path), "--quiet"],
                   check=False, stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - started
    seconds, samples = robot_time(path)
    result_path = path.with_suffix(".result.yaml")
    result = yaml.safe_load(result_path.read_text())
    truth = SimulatedRig.from_spec(RobotSpec.parse(ROBOT), TrackerSpec.parse(tracker), VirtualClock()).truth
    lo, hi = np.array(yaml.safe_load(SITE)["plan"]["sweep_ranges"]).T
    q = np.random.default_rng(0).uniform(lo, hi, (200, len(lo)))
    err = points_from_joints(model_from_dict(result), q) - points_from_joints(truth, q)
    terms = [t.get("name", str(t)) if isinstance(t, dict) else str(t)
             for t in (result.get("extensions") or {}).get("terms", [])]
    bound = (validation_of(result, "plain") or {}).get("bound")
    return {"robot": seconds, "samples": samples, "held_out": held_out(result_path), "wall": wall, "bound": bound,
            "verdict": result["verdict"]["status"], "clock": result.get("clock"), "terms": terms,
            "truth": float(np.sqrt(np.mean(np.sum(err**2, axis=1))))}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--width", type=int, default=1280)
    p.add_argument("--height", type=int, default=720)
    p.add_argument("--fps", type=float, default=30.0)
    p.add_argument("--no-sessions", action="store_true", help="only the streams")
    args = p.parse_args(argv)
    spec = camera_spec(args.width, args.height, args.fps)
    print(f"camera {args.width}x{args.height} at {args.fps:g} Hz, latency {LATENCY * 1e3:g} ms; load average "
          f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    print(f"{'stream':<8} {'rate':>5} {'delivered':>9} {'frames':>6} {'gaps':>4} {'err x,y,z RMS [mm]':>24} "
          f"{'sigma [mm]':>10} {'detect [ms]':>11} {'wall [ms]':>9} {'TP speed [m/s]':>14}")
    ok = True
    for name, seconds, turn in (("still", 2.0, 0.0), ("moving", 1.6, 0.5)):
        s = stream(spec, seconds, turn)
        rms = ", ".join(f"{v * 1e3:.4f}" for v in s["rms"])
        print(f"{name:<8} {s['rate']:>5g} {s['delivered']:>9.2f} {s['frames']:>6} {s['gaps']:>4} {rms:>24} "
              f"{s['sigma'] * 1e3:>10.4f} {s['detect'] * 1e3:>11.2f} {s['wall'] * 1e3:>9.1f} {s['speed']:>14.3f}")
        if name == "still":
            ok &= s["delivered"] >= 0.99 * args.fps and s["rows"] == s["frames"]
        ok &= s["detect"] < 1.0 / args.fps
    if args.no_sessions:
        return 0 if ok else 1
    tracker = camera_spec(args.width, args.height, args.fps) + "&frames=3"
    with tempfile.TemporaryDirectory() as tmp:
        rows = {mode: session(mode, tracker, Path(tmp)) for mode in ("step", "continuous")}
    print(f"\nsessions: {ROBOT}, {tracker}, sweeps +-0.3 rad about home")
    print(f"{'mode':<11} {'robot time [s]':>14} {'samples':>8} {'held-out RMS [mm]':>18} {'vs truth [mm]':>13} "
          f"{'bound [mm]':>10} {'verdict':>7} {'wall [s]':>8}")
    for mode, r in rows.items():
        shown = "n/a" if r["held_out"] is None else f"{r['held_out'] * 1e3:.4f}"
        bound = "n/a" if r["bound"] is None else f"{r['bound'] * 1e3:.4f}"
        print(f"{mode:<11} {r['robot']:>14.1f} {r['samples']:>8} {shown:>18} {r['truth'] * 1e3:>13.4f} {bound:>10} "
              f"{r['verdict']:>7} {r['wall']:>8.1f}")
        if r["terms"]:
            print(f"  {mode}: joint errors selected: {', '.join(r['terms'])}")
    clock = rows["continuous"]["clock"] or {}
    offset, std = clock.get("offset_s", np.nan), clock.get("offset_std_s", np.nan)
    print(f"continuous clock offset {offset * 1e3:.3f} +- {std * 1e3:.3f} ms (latency {LATENCY * 1e3:g} ms), "
          f"{clock.get('streamed_rows')} streamed rows; robot time continuous / step "
          f"{rows['continuous']['robot'] / rows['step']['robot']:.2f}")
    ok &= bool(abs(offset + LATENCY) < 3 * std)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
