"""Continuous against stop-and-go against the UR controller emulator: robot time and held-out accuracy of a full
default UR5e session in each mode (issue 16).

    python -m bench.ur_continuous [--time-scale 1] [--latency 0.02] [--keep DIR]

One emulator (tests/ur_emulator, its rig's arm at emulated real speed for ``--time-scale 1``) with RTDE at the
e-Series native 500 Hz on its own clock (``native_rate``), and its simulated ``stream-csv`` tracker (500 lines per
emulated s, noise 0.05 mm per axis: the profile's stated sigma; each reading stamped ``--latency`` s after it was
taken). Both sessions run ``acquire --robot ur5e@HOST?rtde_frequency=500 --tracker serial:socket://...?protocol=
stream-csv --mode MODE --yes`` as a fresh process with the default plan and site (the real ur_rtde client in the
driver's worker, the real serial driver); step mode reads the same device's lines, 5 per step. Each session is
identified by ``acquire`` itself.

Robot time: from the first step's start to the last step's end (host clock, times the time scale: the
controller's seconds). Held-out RMS: the identification's own (check poses and home re-measurements, ``validation``
in the result YAML), beside the expected value it states; "truth": the RMS error of the identified model against
the emulator's true robot at 200 random poses. Targets: continuous robot time <= 1/4 of stop-and-go's, held-out
RMS <= 1.1x. ``--time-scale K`` runs the emulated arm K times faster (RTDE and tracker at 500/K Hz emulated, so
the wall rates stay at 500 per second) for a quick look; the robot times then include host-side waits (settle,
stream slack) multiplied by K, so only time scale 1 measures the targets.
"""

from __future__ import annotations

import argparse
import os
import platform
import sqlite3
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

from config.robots import load_robot
from drivers.trackers.ascii_profile import TRACKERS_DIR
from identify.io.result_io import validation_of
from identify.simulate import random_poses
from kinematics.dh import model_from_dict, points_from_joints
from tests.ur_emulator import EmulatorProcess

NATIVE = 500.0  # Hz: e-Series RTDE, and the stream-csv device's line rate
NOISE = 5e-5  # m per axis: the stream-csv profile's sigma
ROBOT_TIME_TARGET, ACCURACY_TARGET = 0.25, 1.1
ROOT = Path(__file__).resolve().parent.parent


def tracker_profile(folder: Path, scale: float) -> str:
    """The stream-csv profile (its name), or at time scale ``scale`` != 1 a copy whose period is ``scale`` times
    the profile's (emulated s), so the wall rate stays the device's."""
    if scale == 1.0:
        return "stream-csv"
    doc = yaml.safe_load((TRACKERS_DIR / "stream-csv.yaml").read_text())
    doc["period"] = doc["simulation"]["period"] = float(doc["period"]) * scale
    path = folder / "stream-csv.yaml"
    path.write_text(yaml.safe_dump(doc))
    return str(path)


def session_numbers(session: Path, scale: float) -> dict[str, float]:
    """Robot time (controller s), steps, tracker samples, and for streams: joint samples, gaps, packages lost."""
    with sqlite3.connect(session) as db:
        start, end, steps = db.execute("SELECT min(t_start), max(t_end), count(*) FROM steps").fetchone()
        samples = db.execute("SELECT count(*) FROM readings").fetchone()[0]
        out = {"robot_time": float(end - start) * scale, "steps": steps, "samples": samples}
        tables = {r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
        if "streams" in tables:
            current = "SELECT id FROM streams WHERE superseded = 0 AND status = 'complete'"
            count = "SELECT count(*) FROM {} WHERE stream IN (" + current + ")"
            out["samples"] += db.execute(count.format("tracker_samples")).fetchone()[0]
            out["joint_samples"] = db.execute(count.format("joint_samples")).fetchone()[0]
            rate = db.execute("SELECT max(joint_rate) FROM streams").fetchone()[0] or NATIVE / scale
            for device in ("robot", "tracker"):
                gaps = db.execute(f"SELECT t_start, t_end FROM stream_gaps WHERE device = ? AND stream IN ({current})",
                                  (device,)).fetchall()
                out[f"{device}_gaps"] = len(gaps)
                if device == "robot":
                    out["packages_lost"] = sum(max(0, round((b - a) * rate) - 1) for a, b in gaps)
            span = db.execute(f"SELECT sum(mx - mn) FROM (SELECT max(t) AS mx, min(t) AS mn FROM joint_samples "
                              f"WHERE stream IN ({current}) GROUP BY stream)").fetchone()[0]
            out["joint_expected"] = float(span or 0.0) * rate + len(db.execute(current).fetchall())
    return out


def run_session(mode: str, emu: EmulatorProcess, tracker: str, rate: float, folder: Path, scale: float) -> dict:
    """One ``acquire`` session as a fresh process; its numbers, result YAML and error against the truth."""
    session = folder / f"{mode}.session"
    command = [sys.executable, "-m", "acquire.launch", "--robot", f"ur5e@{emu.host}?rtde_frequency={rate:g}",
               "--tracker", tracker, "--mode", mode, "--yes", "--session", str(session), "--quiet"]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    load = os.getloadavg()
    started = time.perf_counter()
    done = subprocess.run(command, cwd=folder, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - started
    if done.returncode != 0:
        raise SystemExit(f"bench.ur_continuous: {mode} session exited {done.returncode}: "
                         f"{done.stderr.strip().splitlines()[-1:] or done.stdout[-300:]}")
    numbers = session_numbers(session, scale)
    doc = yaml.safe_load(session.with_suffix(".result.yaml").read_text())
    model = model_from_dict(doc)
    truth = emu.truth()
    q = random_poses(load_robot("ur5e").limits, 200, np.random.default_rng(0))
    error = points_from_joints(model, q) - points_from_joints(truth, q)
    return {**numbers, "doc": doc, "wall": wall, "load": (load, os.getloadavg()),
            "truth_rms": float(np.sqrt(np.mean(np.sum(error**2, axis=1))))}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.ur_continuous", description=__doc__.splitlines()[0])
    p.add_argument("--time-scale", type=float, default=1.0, help="emulated s per wall s (1: real speed)")
    p.add_argument("--latency", type=float, default=0.02, help="s between a reading and its timestamp")
    p.add_argument("--keep", type=Path, help="keep the sessions, results and reports in this (new) folder")
    args = p.parse_args(argv)
    if not args.time_scale > 0 or not 0 <= args.latency < 1:
        print("bench.ur_continuous: --time-scale must be > 0 and --latency in [0, 1) s", file=sys.stderr)
        return 2
    if args.keep is not None and args.keep.exists():
        print(f"bench.ur_continuous: --keep {args.keep} exists; give a new folder", file=sys.stderr)
        return 2
    scale, rate = args.time_scale, NATIVE / args.time_scale
    print(f"python {platform.python_version()}, ur_rtde client, {os.cpu_count()} cores, {time.strftime('%Y-%m-%d')}; "
          f"emulator at time scale {scale:g}, RTDE {rate:g} Hz native (rtde_frequency={rate:g}), tracker stream-csv "
          f"{rate:g} Hz, noise {NOISE * 1e3:g} mm per axis, latency {args.latency * 1e3:g} ms")
    rows = {}
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.keep or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        profile = tracker_profile(folder, scale)
        with EmulatorProcess(time_scale=scale, native_rate=True, rate=rate) as emu:
            url = emu.serve_tracker(profile, NOISE, 1, latency=args.latency)
            tracker = f"serial:{url}?protocol={profile}"
            for mode in ("step", "continuous"):
                rows[mode] = run_session(mode, emu, tracker, rate, folder, scale)
            late = emu.get("late_packages")
    print(f"{'mode':<11} {'robot time [s]':>14} {'steps':>6} {'samples':>8} {'held-out RMS [mm]':>18} "
          f"{'(expected)':>10} {'vs truth [mm]':>14} {'wall [s]':>9}  load before / after")
    for mode, r in rows.items():
        v = validation_of(r["doc"])
        (a, b, c), (d, e, f) = r["load"]
        print(f"{mode:<11} {r['robot_time']:>14.1f} {r['steps']:>6} {r['samples']:>8} {v['rms'] * 1e3:>18.4f} "
              f"{v['expected_rms'] * 1e3:>10.4f} {r['truth_rms'] * 1e3:>14.4f} {r['wall']:>9.1f}  "
              f"{a:.1f} {b:.1f} {c:.1f} / {d:.1f} {e:.1f} {f:.1f}")
    step, cont = rows["step"], rows["continuous"]
    time_ratio = cont["robot_time"] / step["robot_time"]
    rms_ratio = validation_of(cont["doc"])["rms"] / validation_of(step["doc"])["rms"]
    truth_ratio = cont["truth_rms"] / step["truth_rms"]
    verdicts = ", ".join(f"{m} {r['doc']['verdict']['status']}" for m, r in rows.items())
    print(f"verdicts: {verdicts}; held-out poses: step {step['doc']['validation']['samples']}, continuous "
          f"{cont['doc']['validation']['samples']}")
    time_ok, rms_ok = time_ratio <= ROBOT_TIME_TARGET, rms_ratio <= ACCURACY_TARGET
    print(f"continuous / step robot time: {time_ratio:.3f} (target <= {ROBOT_TIME_TARGET}): "
          f"{'met' if time_ok else 'MISSED'}")
    print(f"continuous / step held-out RMS: {rms_ratio:.3f} (target <= {ACCURACY_TARGET}): "
          f"{'met' if rms_ok else 'MISSED'}; against the truth {truth_ratio:.3f}")
    clock = cont["doc"].get("clock") or {}
    if clock:
        offset, sigma = clock["offset_s"] * 1e3, clock["offset_std_s"] * 1e3
        print(f"clock: robot time = tracker time {offset:+.4f} ± {sigma:.4f} ms, "
              f"drift {clock['drift'] * 1e6:+.2f} ± {clock['drift_std'] * 1e6:.2f} ppm over {clock['streamed_rows']} "
              f"streamed rows (true: {-args.latency * 1e3:+g} ms, 0 ppm)")
    lost = cont["packages_lost"]
    print(f"joint stream: {cont['joint_samples']} samples kept of about {cont['joint_expected']:.0f}, "
          f"{cont['robot_gaps']} recorded gap(s) holding {lost} lost package(s); tracker gaps {cont['tracker_gaps']}; "
          f"emulator packages sent late (both RTDE connections, both sessions): {late}")
    return 0 if time_ok and rms_ok else 1


if __name__ == "__main__":
    sys.exit(main())
