"""Continuous motion end to end against the UR controller emulator: the real ``ur_rtde`` client (in the driver's
worker process) recording the RTDE joint stream at the emulator's native rate, and the real serial driver reading
the emulator's simulated ``stream-csv`` tracker over loopback TCP. The emulator's rig is the one physical world:
its arm follows each move's profile on the emulated clock, the RTDE stream reports it, and the tracker measures its
true TP in real time, stamped on the same clock plus a latency (tests/ur_emulator, tests/tracker_devices.py).

RTDE at 125 packages and the tracker at 125 lines per emulated second, the session at time scale 4 (500 of each
per wall second: a Python emulator on a shared 2-core machine loses more packages above that, which the recorder
records as gaps), the motion check at time scale 2. bench/ur_continuous.py runs a full session at real speed with
the e-Series 500 Hz stream.
"""

from __future__ import annotations

import os
import signal
import sqlite3
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.stats import chi2

pytest.importorskip("rtde_control", reason="ur_rtde is not installed (pip install 'ur-rtde==1.6.5', the ur extra)")

from acquire.commands.cli import main as acquire
from acquire.planning.plan_continuous import build_continuous_plan
from acquire.planning.plan_modes import mode_site
from acquire.running.session import Session
from config.robots import load_robot
from config.site import load_site
from drivers.base import JointStreamBatch, TrackerStreamBatch
from drivers.registry import open_tracker
from drivers.trackers.ascii_profile import TRACKERS_DIR
from identify.estimator.bounds import prediction_rms_bound
from identify.io.result_io import validation_of
from identify.simulators.simulate import random_poses
from kinematics.dh import model_from_dict, points_from_joints
from tests.ur_emulator import CMD_STOPJ, EmulatorProcess, connected_robot

pytestmark = pytest.mark.realtime  # timing-sensitive: make test runs these alone, after the rest
SCALE, RATE = 4.0, 125.0  # emulated s per wall s; RTDE packages per emulated s
PERIOD = 0.008  # emulated s between the tracker's streamed lines
NOISE = 5e-5  # m per axis: the stream-csv profile's stated sigma, which the simulated device keeps
LATENCY = 0.02  # s: each reading leaves the tracker this long after it was taken, stamped when it leaves
FALSE_ALARM = 1e-4  # chance that a noise-derived check below fails on a correct system
HOME = np.array(load_robot("ur5e").home, dtype=float)
ROOT = Path(__file__).resolve().parents[2]


def stream_profile(folder: Path) -> Path:
    """The bundled stream-csv profile at PERIOD (the device streams at the rate its profile states)."""
    doc = yaml.safe_load((TRACKERS_DIR / "stream-csv.yaml").read_text())
    doc["period"] = doc["simulation"]["period"] = PERIOD
    path = folder / "stream-csv.yaml"  # a profile file is named after its profile
    path.write_text(yaml.safe_dump(doc))
    return path


def joints_at(joints: JointStreamBatch, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The joint stream linearly interpolated at robot times ``t``, and which of them lie inside the stream and
    not inside one of its recorded gaps."""
    q = np.column_stack([np.interp(t, joints.t, joints.q[:, i]) for i in range(joints.q.shape[1])])
    ok = (t >= joints.t[0]) & (t <= joints.t[-1])
    for a, b in joints.gaps:
        ok &= ~((t > a) & (t < b))
    return q, ok


def test_the_emulated_tracker_measures_the_true_point_of_the_arm_in_motion(tmp_path: Path) -> None:
    """During a move the streamed positions are the rig's true TP at the joint stream's positions interpolated at
    the tracker's time minus its latency, to within the tracker noise; the arm really moved meanwhile."""
    profile = stream_profile(tmp_path)
    with EmulatorProcess(time_scale=2.0, native_rate=True, rate=RATE) as emu:  # 250 packages per wall s
        url = emu.serve_tracker(str(profile), NOISE, 1, latency=LATENCY)
        truth = emu.truth()
        robot = connected_robot(emu, options=f"rtde_frequency={RATE:g}")
        tracker = open_tracker(f"serial:{url}?protocol={profile}")
        tracker.connect(2.0)
        joints: list[JointStreamBatch] = []
        tracks: list[TrackerStreamBatch] = []
        try:
            robot.start_joint_stream(2.0)
            tracker.start_stream(1.0 / PERIOD, 2.0)
            robot.start_move(HOME + np.array([0.6, 0, 0, 0, 0, -0.6]), [0.8] * 6, [1.5] * 6, 10.0)
            deadline = time.monotonic() + 10.0
            while not robot.motion_done():
                assert time.monotonic() < deadline, "the move did not end"
                time.sleep(0.02)
                joints.append(robot.read_joint_stream())
                tracks.append(tracker.read_stream())
            time.sleep(0.1)
            joints.append(robot.stop_joint_stream(2.0))
            tracks.append(tracker.stop_stream(2.0))
        finally:
            robot.close()
            tracker.close()
    joint = JointStreamBatch(np.concatenate([b.t for b in joints]), np.concatenate([b.q for b in joints]),
                             tuple(g for b in joints for g in b.gaps))
    t = np.concatenate([b.t for b in tracks])
    points = np.concatenate([b.points for b in tracks])
    assert not any(b.gaps for b in tracks)  # nothing lost on the tracker's side
    q, ok = joints_at(joint, t - LATENCY)
    # lines whose robot time lies in a recorded gap of the joint stream (RTDE packages the loaded emulator sent
    # late, overwritten before the recorder polled) are left out, as the identification leaves them out
    assert ok.sum() >= 30
    predicted = points_from_joints(truth, q[ok])
    travel = np.linalg.norm(predicted - predicted[0], axis=1).max()
    assert travel > 0.3  # m: the TP moved a lot, so a tracker that did not follow it would miss by far more
    # per axis, the error must be tracker noise: chi-square over 3 N values, plus what linear interpolation
    # between 8 ms packages can miss at 1.5 rad/s² (a·h²/8 per joint, 2 joints, a lever under 1.2 m)
    error = points[ok] - predicted
    dof = error.size
    interpolation = 2 * 1.5 * (1.0 / RATE) ** 2 / 8 * 1.2
    limit = NOISE * np.sqrt(chi2.ppf(1 - FALSE_ALARM, dof) / dof) + interpolation
    rms = float(np.sqrt(np.mean(error**2)))
    assert rms < limit, f"{rms * 1e3:.4f} mm per axis vs {limit * 1e3:.4f} mm"
    # and the timestamps are the reading's time plus the latency: 2 ms either way misses by far more
    for shift in (-0.002, 0.002):
        q_off, _ = joints_at(joint, t - LATENCY + shift)
        off = points[ok] - points_from_joints(truth, q_off[ok])
        assert np.sqrt(np.mean(off**2)) > 2 * limit


SITE = f"""schema: 1
robot: {{speed_fraction: 2.0, acceleration_fraction: 2.0}}
tracker: {{noise: {NOISE:.1e}}}
plan: {{check_poses: 4, settle_time: 0.1}}
timeouts: {{connect: 10.0, move: 30.0, settle: 10.0, measure: 5.0}}
"""
LOST = 0.3  # emulated s the tracker loses its target, mid-sweep
DROPPED = 3  # RTDE packages lost on the network, mid-sweep


def joint6_sweep(site: Path) -> tuple[float, float]:
    """(start, end) of the joint 6 continuous sweep, rad (where it falls in the plan's tour does not matter: the
    watcher waits for joint 6 at its start, and no other visit of the plan holds joint 6 there)."""
    plan = build_continuous_plan(load_robot("ur5e"), mode_site(load_site(site), "continuous", None))  # acquire's
    step = next(s for s in plan.steps if s.kind == "stream" and s.joint == 6)
    assert step.start is not None
    assert all(abs(s.q[5] - step.start[5]) > 0.05 for s in plan.steps if s.index != step.index - 1)
    return step.start[5], step.q[5]


class MidSweep(threading.Thread):
    """Watches the emulated arm; once joint 6 has come to its sweep's ``start`` (the stop-and-go move there) and
    then swept ``into`` rad of it towards ``end``, calls ``action(emu)`` once (its result in ``result``)."""

    def __init__(self, emu: EmulatorProcess, start: float, end: float, into: float, action) -> None:
        super().__init__(daemon=True)
        self.emu, self.start_q, self.into, self.action = emu, start, into, action
        self.sign = 1.0 if end > start else -1.0  # a sweep runs from the end of its range nearer the arm
        self.done = threading.Event()
        self.result = None

    def run(self) -> None:
        at_start = False
        while not self.done.is_set():
            q6 = float(self.emu.actual_q()[5])
            at_start = at_start or abs(q6 - self.start_q) < 0.01
            if at_start and (q6 - self.start_q) * self.sign > self.into:
                self.result = self.action(self.emu)
                return
            time.sleep(0.005)


def _untrusted(doc: dict) -> list[str]:
    """The verdict's checks that do not pass, but for a model_fit warning of a model error under the tracker's noise.

    On a loaded host the serial session's residuals came out above the declared noise in 2 runs on record (a CI run,
    and a full suite beside another worker: 1.17x, a model error of 0.018 mm per axis against 0.05 mm of noise);
    alone, 0.99-1.02 in every run looked at (7).
    The emulated devices sample one analytic motion at their own stamps, and the cause in the emulator was not found.
    The result warns then and inflates its uncertainties to cover it, which is what it should do; the accuracy
    against the truth below is asserted either way."""
    return [f"{c['name']} {c['status']}: {c['message']}" for c in doc["verdict"]["checks"] if c["status"] != "pass"
            and not (c["name"] == "model_fit" and c["status"] == "warn" and c["value"] < NOISE)]


@pytest.mark.slow
def test_a_continuous_session_against_the_emulator_is_identified_with_its_clock_and_gaps(tmp_path: Path,
                                                                                          capsys) -> None:
    """``acquire --mode continuous`` with the UR driver and the streaming serial tracker, end to end: every sweep
    streamed, a dropped RTDE package and a lost target mid-sweep recorded as gaps (nothing fitted across them), the
    clock offset found at the tracker's latency within its uncertainty, the model as good as the noise allows."""
    profile = stream_profile(tmp_path)
    site = tmp_path / "site.yaml"
    site.write_text(SITE)
    path = tmp_path / "ur.session"
    start, end = joint6_sweep(site)
    with EmulatorProcess(time_scale=SCALE, native_rate=True, rate=RATE) as emu:
        url = emu.serve_tracker(str(profile), NOISE, 2, latency=LATENCY)
        truth = emu.truth()
        faults = MidSweep(emu, start, end, 2.5, lambda e: (e.drop_packets(DROPPED), e.lose_tracker_target(LOST)))
        faults.start()
        try:
            code = acquire(["--robot", f"ur5e@{emu.host}?rtde_frequency={RATE:g}", "--tracker",
                            f"serial:{url}?protocol={profile}", "--mode", "continuous", "--yes", "--config",
                            str(site), "--session", str(path), "--quiet"])
        finally:
            faults.done.set()
            faults.join(2.0)
        out, err = capsys.readouterr()
    assert code == 0, err
    assert faults.result is not None, "the faults were not injected mid-sweep"
    dropped, (lost_from, lost_to) = faults.result
    assert "robot time = tracker time" in out, out

    with Session.open(path) as session:
        assert session.outcome() == "complete" and session.plan.continuous
        assert all(s.status == "ok" for s in session.steps())
        meas = session.to_measurements()
    with sqlite3.connect(path) as db:
        streams = db.execute("SELECT id, sweep, status, superseded FROM streams").fetchall()
        gaps = db.execute("SELECT stream, device, t_start, t_end FROM stream_gaps").fetchall()
        joints = {s: np.array([t for (t,) in db.execute("SELECT t FROM joint_samples WHERE stream = ? ORDER BY t",
                                                          (s,))]) for s, *_ in streams}
        tracked = np.array([t for (t,) in db.execute("SELECT t FROM tracker_samples")])
    assert len(streams) == 6 and all(s[2] == "complete" and s[3] == 0 for s in streams)  # one per joint
    # every step of a joint stream's controller timestamps is one period, or a recorded gap (no silent drop)
    for stream, t in joints.items():
        mine = {(a, b) for s, device, a, b in gaps if s == stream and device == "robot"}
        steps = np.diff(t)
        assert np.all(steps > 0)
        assert {(a, b) for a, b, d in zip(t[:-1], t[1:], steps, strict=True) if d > 1.5 / RATE} <= mine
    # the packages dropped mid-sweep lie in a recorded robot gap; the target loss is one tracker gap around it
    assert any(device == "robot" and a < dropped < b for _, device, a, b in gaps)
    tracker_gaps = [(a, b) for _, device, a, b in gaps if device == "tracker"]
    assert len(tracker_gaps) == 1
    a, b = tracker_gaps[0]
    assert a < lost_from + PERIOD and b > lost_to - PERIOD and b - a < LOST + 4 * PERIOD
    assert not np.any((tracked > a) & (tracked < b))  # no tracker sample inside it...
    assert not np.any((meas.t > a) & (meas.t < b))  # ... and no measurement row
    # every sweep streamed. How many rows a host keeps is load's (no row spans an RTDE package lost in a recorded
    # gap): over 3000 idle; 2439 of 6493 tracker samples, 1534, and 1070 (29 in one sweep) on loaded runs. The
    # checks below take the data recorded; bench/ur_continuous.py measures full sessions
    rows = [int(np.sum(meas.streamed & (meas.sweep == sweep))) for sweep in sorted({s for _, s, *_ in streams})]
    assert len(rows) == 6 and min(rows) > 0, rows

    doc = yaml.safe_load(path.with_suffix(".result.yaml").read_text())
    assert not _untrusted(doc), _untrusted(doc)
    # the clock: robot time = tracker time - latency (the device stamps a reading when it leaves, LATENCY after
    # it was taken, on the controller's clock); within 5 of its reported sigmas, never looser than 0.5 ms
    clock = doc["clock"]
    tolerance = min(5 * clock["offset_std_s"], 5e-4)
    assert abs(clock["offset_s"] + LATENCY) < tolerance, f"{clock['offset_s'] * 1e3:.4f} ms vs {-LATENCY * 1e3} ms"
    assert abs(clock["drift"]) < 5 * clock["drift_std"] + 1e-9  # one clock: no drift
    # held out: the check poses and home checks, as the result expects (chi-square over 3 N values)
    validation = validation_of(doc)
    n = 3 * validation["samples"]
    assert validation["samples"] >= 6
    assert validation["rms"] < validation["expected_rms"] * np.sqrt(chi2.ppf(1 - FALSE_ALARM, n) / n)
    # against the emulator's truth at 200 random poses: within 3x the Cramér-Rao bound of the data recorded
    model = model_from_dict(doc)
    q_check = random_poses(load_robot("ur5e").limits, 200, np.random.default_rng(0))
    error = points_from_joints(model, q_check) - points_from_joints(truth, q_check)
    rms = float(np.sqrt(np.mean(np.sum(error**2, axis=1))))
    bound = prediction_rms_bound(truth, meas.q[~meas.check], q_check, NOISE)
    assert rms < 3 * bound, f"{rms * 1e3:.4f} mm vs bound {bound * 1e3:.4f} mm"


@pytest.mark.slow
def test_ctrl_c_mid_sweep_stops_the_arm_and_the_run_ends_aborted(tmp_path: Path) -> None:
    """Ctrl-C in the operator's terminal (SIGINT to the command's process group, ur_rtde's worker included) halfway
    through a continuous sweep: stopJ, the arm stands short of the range end, exit 130, and the attempt is kept in
    the session as interrupted, with what it had streamed (a resume redoes it)."""
    profile = stream_profile(tmp_path)
    site = tmp_path / "site.yaml"
    site.write_text(SITE.replace("plan: {", "plan: {joints: [6], "))
    path = tmp_path / "ur.session"
    start, end = joint6_sweep(site)
    with EmulatorProcess(time_scale=SCALE, native_rate=True, rate=RATE) as emu:
        url = emu.serve_tracker(str(profile), NOISE, 3, latency=LATENCY)
        command = [sys.executable, "-m", "acquire.commands.cli", "--robot", f"ur5e@{emu.host}?rtde_frequency={RATE:g}",
                   "--tracker", f"serial:{url}?protocol={profile}", "--mode", "continuous", "--yes", "--config",
                   str(site), "--session", str(path), "--quiet"]
        env = {**os.environ, "PYTHONPATH": str(ROOT)}
        proc = subprocess.Popen(command, cwd=ROOT, env=env, start_new_session=True, stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True)
        press = MidSweep(emu, start, end, 2.5, lambda e: os.killpg(proc.pid, signal.SIGINT) or float(e.actual_q()[5]))
        press.start()
        try:
            _, err = proc.communicate(timeout=90.0)
        finally:
            press.done.set()
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
        assert press.result is not None, f"the sweep never got halfway: {err}"
        assert proc.returncode == 130, err
        assert "stopped by the operator" in err
        assert CMD_STOPJ in emu.get("log").commands
        here = float(emu.actual_q()[5])
        time.sleep(0.2)
        assert float(emu.actual_q()[5]) == pytest.approx(here, abs=1e-4)  # standing still...
        sign = press.sign  # ...well short of the range end (stopJ at 2 rad/s²: 0.25 rad)
        assert (here - press.result) * sign > 0 and (end - here) * sign > 1.0
    with Session.open(path) as session:
        assert session.outcome() == "aborted"
    with sqlite3.connect(path) as db:
        streams = db.execute("SELECT id, status FROM streams").fetchall()
        samples = db.execute("SELECT count(*) FROM tracker_samples").fetchone()[0]
    assert [status for _, status in streams] == ["interrupted"] and samples > 100


def test_a_continuous_session_with_a_leica_tracker_is_timed_by_the_trackers_clock(tmp_path: Path, capsys) -> None:
    """``acquire --robot ur5e@HOST --tracker emscon:HOST:PORT --mode continuous``: every sweep streamed by the emScon
    emulator's continuous measurement by time, each point stamped with the tracker's own clock (its boot as origin,
    on the emulated clock: any time scale works); flagged points early in the first sweep and a broken beam mid-way
    through joint 6's sweep (the measurement ends, the client starts it again once the beam is back) are one gap
    each; the clock offset found is the tracker's boot within its uncertainty, the model as good as the noise
    allows."""
    site = tmp_path / "site.yaml"
    site.write_text(SITE)
    path = tmp_path / "ur.session"
    start, end = joint6_sweep(site)
    with EmulatorProcess(time_scale=SCALE, native_rate=True, rate=RATE) as emu:
        port = emu.serve_emscon(NOISE, 3, "stream_prism@20")  # packet 20 of 50 or more in the first sweep's stream
        truth, boot = emu.truth(), emu.emscon_boot()
        beam = MidSweep(emu, start, end, 2.5, lambda e: e.inject_emscon("stream_lost") or "injected")
        beam.start()
        try:
            code = acquire(["--robot", f"ur5e@{emu.host}?rtde_frequency={RATE:g}", "--tracker",
                            f"emscon:127.0.0.1:{port}?meas_time=0.01&timeout=1", "--mode", "continuous", "--yes",
                            "--config", str(site), "--session", str(path), "--quiet"])
        finally:
            beam.done.set()
            beam.join(2.0)
        out, err = capsys.readouterr()
        connections = emu.emscon_connections()
    assert code == 0, err
    assert beam.result == "injected", "the beam was not broken mid-sweep"
    assert connections == 1, out  # a broken beam needs no new link
    with Session.open(path) as session:
        assert session.outcome() == "complete" and all(s.status == "ok" for s in session.steps())
        meas = session.to_measurements()
    with sqlite3.connect(path) as db:
        gaps = db.execute("SELECT count(*) FROM stream_gaps WHERE device = 'tracker'").fetchone()[0]
        streams = db.execute("SELECT count(*) FROM streams WHERE status = 'complete'").fetchone()[0]
    assert streams == 6 and gaps == 2 and meas.streamed.sum() > 3000
    doc = yaml.safe_load(path.with_suffix(".result.yaml").read_text())
    assert not _untrusted(doc), _untrusted(doc)
    clock = doc["clock"]  # robot time = tracker time + offset: the tracker's boot on the controller's clock
    assert abs(clock["offset_s"] - boot) < max(5 * clock["offset_std_s"], 1e-6), (clock["offset_s"] - boot)
    assert abs(clock["drift"]) < 5 * clock["drift_std"] + 1e-9
    model = model_from_dict(doc)
    q_check = random_poses(load_robot("ur5e").limits, 200, np.random.default_rng(0))
    err_model = points_from_joints(model, q_check) - points_from_joints(truth, q_check)
    rms = float(np.sqrt(np.mean(np.sum(err_model**2, axis=1))))
    assert rms < 3.0 * prediction_rms_bound(truth, meas.q[~meas.check], q_check, NOISE)
