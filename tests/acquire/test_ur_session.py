"""A whole acquisition against the UR controller emulator with the real command (``acquire``), the real
ur_rtde client (in the driver's worker process) and the real serial tracker driver: the emulator process also
serves a simulated polled-xyz tracker over loopback TCP that measures the emulated arm's true TP (or a simulated
Leica emScon server, for the emScon client). The session
is identified end to end and compared with the emulator's true robot, which is also the factory calibration
its controller reports."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

pytest.importorskip("rtde_control", reason="ur_rtde is not installed (pip install 'ur-rtde==1.6.5', the ur extra)")

from acquire.commands.cli import main as acquire
from acquire.running.session import Session
from config.robots import load_robot
from drivers.sim.rig import SimulatedRig
from drivers.spec import parse_faults
from identify.commands.cli import main as identify
from identify.estimator.bounds import prediction_rms_bound
from identify.simulators.simulate import random_poses
from kinematics.dh import model_from_dict, points_from_joints
from session.rows import factory_calibration
from tests.ur_emulator import CMD_MOVEJ, CMD_STOPJ, EmulatorProcess, ScaledClock

SCALE = 100.0  # emulated seconds per wall second: a sweep move of a few seconds takes a few hundredths
NOISE, SAMPLES = 2e-5, 3  # the simulated tracker's noise (m per axis) and readings per step
SITE = f"""schema: 1
tracker: {{noise: {NOISE:.1e}}}
plan: {{settle_time: 0.02, steps_per_sweep: 5, samples_per_step: {SAMPLES}, free_poses: 5, check_poses: 3,
        home_check_every: 20}}
timeouts: {{connect: 10.0, move: 30.0, settle: 10.0, measure: 5.0}}
"""
ROOT = Path(__file__).resolve().parents[2]


def _emulator(faults: str = "") -> EmulatorProcess:
    robot_faults = parse_faults(faults, "robot") if faults else ()
    rig = SimulatedRig("ur5e", clock=ScaledClock(SCALE), ring=1e-5, ring_tau=0.05, robot_faults=robot_faults)
    return EmulatorProcess(rig=rig)


def _args(emu: EmulatorProcess, tracker: str, tmp_path: Path) -> list[str]:
    site = tmp_path / "site.yaml"
    site.write_text(SITE)
    return ["--robot", f"ur5e@{emu.host}", "--tracker", f"serial:{tracker}?protocol=polled-xyz", "--yes",
            "--config", str(site), "--session", str(tmp_path / "ur.session"), "--quiet"]


@pytest.mark.slow
def test_acquire_against_the_emulator_identifies_its_true_robot(tmp_path, capsys) -> None:
    """A full session with a network drop at move 9 (mid-sweep): the driver reconnects, no step is lost, and
    the identified robot matches the emulated truth within what the tracker noise allows."""
    with _emulator("disconnect@9") as emu:
        tracker = emu.serve_tracker("polled-xyz", NOISE, 1)
        code = acquire(_args(emu, tracker, tmp_path))
        out, err = capsys.readouterr()
        assert code == 0, err
        truth = emu.truth()
        assert emu.get("log").commands.count(CMD_MOVEJ) > 1
    path = tmp_path / "ur.session"
    with Session.open(path) as session:
        steps, plan = session.steps(), session.plan
        assert session.outcome() == "complete"
        assert [s.plan_index for s in steps] == list(range(len(plan.steps)))  # every step, once
        assert all(s.status == "ok" and s.samples + s.rejected == SAMPLES and s.samples >= 2 for s in steps)
        for s in steps:  # the recorded joints are the encoder values at the commanded pose
            np.testing.assert_allclose(s.q_act, s.q_cmd, atol=1e-3)
        calibration, _ = factory_calibration(session.header)
        meas = session.to_measurements()
    for key in ("theta", "d", "a", "alpha"):  # the header holds the controller's calibration: the truth here
        np.testing.assert_allclose(calibration[key], getattr(truth, key), atol=1e-12)
    assert "Δ identified vs factory calibration" in out
    assert "vs factory calibration" in path.with_suffix(".report.html").read_text()

    doc = yaml.safe_load(path.with_suffix(".result.yaml").read_text())
    assert doc["controller"]["model"] == "factory calibration"  # "before" for compensation: what the arm runs
    np.testing.assert_allclose(doc["controller"]["dh"]["a"], truth.a, atol=1e-12)
    model = model_from_dict(doc)
    fit_q = meas.q[~meas.check]
    q_check = random_poses(load_robot("ur5e").limits, 200, np.random.default_rng(0))
    err = points_from_joints(model, q_check) - points_from_joints(truth, q_check)
    rms = float(np.sqrt(np.mean(np.sum(err**2, axis=1))))
    assert rms < 3.0 * prediction_rms_bound(truth, fit_q, q_check, NOISE / np.sqrt(SAMPLES))
    # DH values the data determine (not fixed, not placed by the parallel-axis convention): within 5 of the
    # result's own standard uncertainties of the truth, plus the noise-free rounding of the emulated arm
    fixed = {f["parameter"] for f in doc["fixed"]}
    parallel = set(doc["convention"]["parallel_links"])
    std = doc["uncertainty"]["joints"]
    identified = model.dh_table()
    checked = 0
    for i in range(6):
        for k, name in enumerate(("theta", "d", "a", "alpha")):
            joint = i + 1
            if f"{name}{joint}" in fixed or (name == "d" and (joint in parallel or joint - 1 in parallel)):
                continue
            delta = np.angle(np.exp(1j * (identified[i, k] - truth.dh_table()[i, k]))) if name in (
                "theta", "alpha") else identified[i, k] - truth.dh_table()[i, k]
            assert abs(delta) < 5 * std[i][name] + 1e-6, f"{name}{joint}: {delta:.3g} vs std {std[i][name]:.3g}"
            checked += 1
    assert checked >= 12


@pytest.mark.slow
def test_acquire_with_a_leica_tracker_against_both_emulators(tmp_path, capsys) -> None:
    """``acquire --robot ur5e@HOST --tracker emscon:HOST:PORT``: the emScon client against the simulated emScon
    server measuring the emulated arm, with a broken beam, a server restart, garbage and silence on the tracker and
    a network drop on the robot; no step lost, and the identification is as good as the noise allows."""
    with _emulator("disconnect@9") as emu:
        port = emu.serve_emscon(NOISE, 1, "beam_broken@12x2,drop@30,garbage@50,silence@70")
        args = _args(emu, "unused", tmp_path)
        args[args.index("--tracker") + 1] = f"emscon:127.0.0.1:{port}?meas_time=0.001&timeout=0.5"
        code = acquire(args)
        _, err = capsys.readouterr()
        assert code == 0, err
        truth, connections = emu.truth(), emu.emscon_connections()
    assert connections == 4  # the first link, then one after the restart, the garbage and the silence
    with Session.open(tmp_path / "ur.session") as session:
        steps, plan = session.steps(), session.plan
        retries = [e[3] for e in session.events() if e[2] == "retry"]
        meas = session.to_measurements()
        assert session.outcome() == "complete"
        assert [s.plan_index for s in steps] == list(range(len(plan.steps)))  # every step, once
        assert all(s.status == "ok" and s.samples + s.rejected == SAMPLES for s in steps)
        assert "emScon" in session.header["tracker"]["details"]["protocol"]
    assert len(retries) == 2 and all("BeamLost" in r for r in retries)
    model = model_from_dict(yaml.safe_load((tmp_path / "ur.result.yaml").read_text()))
    q_check = random_poses(load_robot("ur5e").limits, 200, np.random.default_rng(0))
    err = points_from_joints(model, q_check) - points_from_joints(truth, q_check)
    rms = float(np.sqrt(np.mean(np.sum(err**2, axis=1))))
    assert rms < 3.0 * prediction_rms_bound(truth, meas.q[~meas.check], q_check, NOISE / np.sqrt(SAMPLES))


@pytest.mark.slow
def test_ctrl_c_mid_run_stops_the_arm_resume_completes_and_the_report_says_no_factory_calibration(
        tmp_path, capsys) -> None:
    """Ctrl-C in the operator's terminal (SIGINT to the command's process group, ur_rtde's worker included)
    ends the run with stopJ and exit code 130; every step recorded stays, and --resume records the rest. This
    controller does not send its calibration: the run works, and both reports say so."""
    with EmulatorProcess(time_scale=SCALE, kinematics=False) as emu:
        tracker = emu.serve_tracker("polled-xyz", NOISE, 3)
        command = [sys.executable, "-m", "acquire.commands.cli", *_args(emu, tracker, tmp_path)]
        env = {**os.environ, "PYTHONPATH": str(ROOT)}
        proc = subprocess.Popen(command, cwd=ROOT, env=env, start_new_session=True, stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True)
        try:
            deadline = time.monotonic() + 60.0
            while emu.get("log").commands.count(CMD_MOVEJ) < 8 and proc.poll() is None:
                assert time.monotonic() < deadline, "the run did not start moving"
                time.sleep(0.01)
            os.killpg(proc.pid, signal.SIGINT)  # what the terminal does on Ctrl-C
            _, err = proc.communicate(timeout=60.0)
        finally:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
        assert proc.returncode == 130, err
        assert "stopped by the operator" in err
        assert CMD_STOPJ in emu.get("log").commands
        path = tmp_path / "ur.session"
        with Session.open(path) as session:
            before = {s.plan_index: s for s in session.steps()}
            assert session.outcome() == "aborted" and before
        code = acquire(["--resume", str(path), "--yes", "--quiet"])
        out, err = capsys.readouterr()
        assert code == 0, err
    assert "note: factory calibration: not available (the factory calibration could not be read" in out
    with Session.open(path) as session:
        after = session.steps()
        assert [s.plan_index for s in after] == list(range(len(session.plan.steps)))  # none lost, none twice
        assert all(after[i] == record for i, record in before.items())  # the steps before Ctrl-C, unchanged
    report = tmp_path / "again.html"
    assert identify([str(path), "--report", str(report)]) == 0
    out = capsys.readouterr().out
    assert "Δ: identified - ur5e" in out and "factory calibration: not available" in out
    text = report.read_text()
    assert "vs ur5e" in text and "factory calibration: not available" in text
