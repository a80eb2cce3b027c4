"""``acquire verify`` beyond AP/RP on the simulated rig against its truth: vAP from three approach directions on an
arm with backlash, orientation AP from three reflectors and from one 6-DoF target, every figure's stated
uncertainty, and what is said when something is not measured."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from acquire.commands.cli import main as acquire
from acquire.running.session import Session
from drivers.sim.rig import SimulatedRig
from drivers.sim.world import backlash_play
from identify.applications.iso9283 import deviation_angles
from kinematics.dh import flange_frames, points_from_joints

LASH = 2e-4  # rad on every joint: 0.1-0.2 mm at the TP between two approach directions
CYCLES = 4
ROBOT = "mock:ur5e?points=3"


def _truth_implied(info: dict, steps: list, rig: SimulatedRig, mode: str) -> tuple[np.ndarray, np.ndarray]:
    """What a noise-free test would measure on the rig's truth (``rig``, backlash ``LASH``) through the calibration's
    base: vAP per pose, and the orientation deviation (a, b, c) of the first direction's visits. The backlash is
    replayed over the joints read at every step, in order, from home (the gap centred)."""
    base = np.array(info["base"])
    rb, shift = base[:3, :3], base[:3, 3]
    rotation = np.array(info["rotation"])
    tools = {int(k): np.array(v) for k, v in info["tools"].items()}
    tool = np.array(info["tool"])
    lash, last = np.zeros(6), np.array(rig.model.home)
    reached: dict[tuple[int, int], list[np.ndarray]] = {}
    for record in steps:
        q = np.array(record.q_act)
        lash, last = backlash_play(lash, q - last, LASH), q
        label = info["steps"][record.plan_index]
        if label[0] == mode:
            points = np.array([points_from_joints(replace(rig.truth, tool=t), (q + lash)[None])[0]
                               for t in rig.tools])
            reached.setdefault((label[2], label[3]), []).append((points - shift) @ rb)
    vap, angles = [], []
    for k in range(1, 6):
        bary = [np.mean([p[0] for p in reached[(k, h)]], axis=0) for h in (1, 2, 3)]
        vap.append(max(np.linalg.norm(a - b) for a in bary for b in bary))
        flange = np.array(info["targets"][k - 1]) - rotation @ tool
        commanded = np.array([flange + rotation @ tools[t] for t in sorted(tools)])
        angles.append(np.mean([deviation_angles(commanded, p) for p in reached[(k, 1)]], axis=0))
    return np.array(vap), np.array(angles)


@pytest.mark.slow
def test_vap_of_an_arm_with_backlash_and_orientation_from_three_reflectors(tmp_path: Path, capsys) -> None:
    """A calibration with three reflectors, verified on the same arm with 0.2 mrad of backlash per joint: vAP and the
    orientation AP of every pose, before and after, agree with what the truth implies within 4 of their stated
    uncertainties (plus 5 µm / 20 µrad for the arm's 2 µrad repeatability); vAP is far above what the noise alone
    gives (4 stated uncertainties)."""
    session = tmp_path / "cal.session"
    assert acquire(["--robot", ROBOT, "--tracker", "mock", "--session", str(session), "--quiet"]) == 0
    result = session.with_suffix(".result.yaml")
    verify = tmp_path / "v.session"
    capsys.readouterr()
    assert acquire(["verify", "--result", str(result), "--robot", f"{ROBOT}&backlash={LASH}", "--tracker", "mock",
                    "--session", str(verify), "--cycles", str(CYCLES)]) == 0
    out = capsys.readouterr().out
    assert "orientation [mrad]" in out and "vAP P1 (7.2)" in out and "within this run of" in out
    with Session.open(verify) as s:
        info = s.header["config"]["verification"]
        steps = s.steps()
    assert sum(info["steps"][r.plan_index][0] == "approach" for r in steps) == 2 * 5 * 3 * CYCLES
    summary = yaml.safe_load(verify.with_suffix(".verify.yaml").read_text())
    rig = SimulatedRig.from_spec(ROBOT, "mock")
    for mode in ("before", "after"):
        run = summary["runs"][mode]
        figures, u = run["figures"], run["uncertainty"]
        vap, angles = _truth_implied(info, steps, rig, mode)
        for k in range(5):
            name = f"vap P{k + 1}"
            assert abs(figures[name] - vap[k]) <= 4 * u[name] + 5e-6, (mode, name, figures[name], vap[k], u[name])
            assert vap[k] > 4 * u[name]  # backlash, not noise
            for j, axis in enumerate("abc"):
                name = f"ap_{axis} P{k + 1}"
                assert abs(figures[name] - angles[k, j]) <= 4 * u[name] + 2e-5, (mode, name, figures[name], angles[k])
    assert summary["orientation"] == {"measured": True, "reason": None, "source": "rigid fit of the tracked points"}
    before = np.array([[summary["runs"]["before"]["figures"][f"ap_{a} P{k}"] for a in "abc"] for k in range(1, 6)])
    assert np.abs(before).max() > 1e-3  # the nominal model turns the tool by about a milliradian
    report = verify.with_suffix(".report.html").read_text()
    assert "Orientation accuracy AP" in report and "vAP P5 (7.2)" in report and "AP c P5" in report
    # the same calibration, a tracker that sees one of the reflectors: not measured, and why
    one = tmp_path / "one.session"
    assert acquire(["verify", "--result", str(result), "--robot", "mock:ur5e", "--tracker", "mock", "--session",
                    str(one), "--cycles", "2", "--quiet"]) == 0
    assert "orientation not measured: the tracker saw 1 tracked point per visit" in " ".join(
        capsys.readouterr().out.split())


@pytest.mark.slow
def test_one_tracked_point_says_orientation_was_not_measured(tmp_path: Path, capsys, monkeypatch) -> None:
    """The tracker sees one point: the terminal, the summary and the report say orientation was not measured, and
    why; the drift is labelled as within the run, with its duration; the dry run shows the approach poses."""
    session = tmp_path / "cal.session"
    assert acquire(["--robot", "mock:ur5e", "--tracker", "mock", "--session", str(session), "--quiet",
                    "--free-poses", "10"]) == 0
    result = session.with_suffix(".result.yaml")
    capsys.readouterr()
    assert acquire(["verify", "--result", str(result), "--dry-run", "--cycles", "4"]) == 0
    dry = capsys.readouterr().out
    assert "each pose visited from 3 directions" in dry and "248 steps" in dry  # 8 + 2 x 5 x 4 x 3 x 2
    assert "4 cycles per pose; ISO 9283 asks for 30" in dry  # issue 39, item 13
    verify = tmp_path / "v.session"
    monkeypatch.setenv("COLUMNS", "80")
    assert acquire(["verify", "--result", str(result), "--session", str(verify), "--cycles", "4", "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "orientation not measured: the result knows 1 tracked point" in " ".join(out.split())
    assert "ISO 9283 measures it over 8 h" in " ".join(out.split())
    summary = yaml.safe_load(verify.with_suffix(".verify.yaml").read_text())
    assert summary["orientation"]["measured"] is False and "1 tracked point" in summary["orientation"]["reason"]
    assert 60 < summary["duration_s"] < 3600
    assert f"within this run of {round(summary['duration_s'] / 60)} min" in summary["drift_note"]
    assert "Orientation was not measured" in verify.with_suffix(".report.html").read_text()
    wide = [line for line in out.splitlines() if len(line) > 80 and str(tmp_path) not in line]  # paths stay whole
    assert not wide, "the terminal must fit 80 columns"


def test_approach_poses_are_planned_and_checked_like_every_step(tmp_path: Path) -> None:
    """Every approach pose (three per pose and run) is a step of the plan the checks see (limits, cell), lies 20 % of
    the edge from its pose along +x, +y, +z on the model that commands it, and a check that fails on them refuses
    the test with its reason."""
    from acquire.verification.verify import APPROACH_SHARE, VerifyError, build, design, problems
    from config.robots import load_robot
    from config.site import SiteConfig
    from identify.applications.calibrated import CalibratedModel
    from identify.io.result_io import load_result
    from tests.acquire.test_verify import _result

    robot, site = load_robot("ur5e"), SiteConfig.default()
    model, _ = load_result(str(_result(SimulatedRig("ur5e", seed=0).truth, tmp_path)))
    checked = []

    def plan_ok(q: dict, approach: dict, register) -> list[str]:
        plan = build(robot, site, q, 2, register, approach)[0]
        checked.append({s.q for s in plan.steps})
        return problems(plan, robot, site)

    d = design(model, robot, site, plan_ok)
    last = checked[-1]
    for mode in ("before", "after"):
        assert all(tuple(map(float, q)) in last for q in d.approach[mode].reshape(-1, 6))
    ident = model.with_base(np.eye(4))
    reached = ident.points(ident.readings(d.approach["after"].reshape(-1, 6))).reshape(5, 3, 3)
    offsets = reached - d.targets[:, None, :]
    np.testing.assert_allclose(offsets, np.broadcast_to(APPROACH_SHARE * d.edge * np.eye(3), (5, 3, 3)), atol=1e-6)
    nominal = CalibratedModel.exact(replace(robot.nominal, tool=ident.tool()), "ur5e")
    np.testing.assert_allclose(nominal.points(d.approach["before"][:, 2]) - d.targets,
                               np.tile([0, 0, APPROACH_SHARE * d.edge], (5, 1)), atol=1e-6)

    def no_high_approach(q: dict, approach: dict, register) -> list[str]:
        return ["P4's approach from z meets the cell's roof"] if approach else []

    with pytest.raises(VerifyError, match="approach from z meets the cell's roof"):
        design(model, robot, site, no_high_approach)


def _truth_turns(info: dict, steps: list, rig: SimulatedRig, mode: str) -> np.ndarray:
    """The orientation deviation (a, b, c) per pose, mean of the first direction's visits, that a noise-free test
    would measure of the target frame on the rig's truth (backlash ``LASH`` replayed as in :func:`_truth_implied`),
    taken into the base frame through the calibration's base and compared with the commanded flange orientation
    times the result's tool_frame."""
    base = np.array(info["base"])
    commanded = np.array(info["rotation"]) @ np.array(info["tool_frame"])
    lash, last = np.zeros(6), np.array(rig.model.home)
    turns: dict[int, list[np.ndarray]] = {}
    for record in steps:
        q = np.array(record.q_act)
        lash, last = backlash_play(lash, q - last, LASH), q
        label = info["steps"][record.plan_index]
        if label[0] == mode and label[3] == 1:
            rotation, _ = flange_frames(rig.truth, (q + lash)[None])
            attained = base[:3, :3].T @ rotation[0] @ rig.target_frames[0]
            turns.setdefault(label[2], []).append(Rotation.from_matrix(attained @ commanded.T).as_euler("xyz"))
    return np.array([np.mean(turns[k], axis=0) for k in range(1, 6)])


@pytest.mark.slow
def test_orientation_ap_rp_from_six_dof_readings_of_one_target(tmp_path: Path, capsys) -> None:
    """Issue 35: a calibration with one 6-DoF target (mock tracker, 0.2 mrad per reading) and its verification with
    the same target, on an arm with 0.2 mrad of backlash: orientation AP of every pose, before and after, comes from
    the 6-DoF readings alone (no three reflectors) and agrees with what the truth implies within 4 of its stated
    uncertainties (plus 20 µrad for the arm's repeatability); RP is a few times the per-visit noise, not zero."""
    tracker = "mock?orientation=0.0002"
    session = tmp_path / "cal.session"
    assert acquire(["--robot", "mock:ur5e", "--tracker", tracker, "--session", str(session), "--quiet"]) == 0
    result = session.with_suffix(".result.yaml")
    assert "tool_frame" in yaml.safe_load(result.read_text())
    verify = tmp_path / "v.session"
    capsys.readouterr()
    assert acquire(["verify", "--result", str(result), "--robot", f"mock:ur5e?backlash={LASH}", "--tracker", tracker,
                    "--session", str(verify), "--cycles", "3"]) == 0
    out = " ".join(capsys.readouterr().out.split())
    assert "orientation [mrad]" in out and "orientation from 6-DoF readings of the target frame" in out
    with Session.open(verify) as s:
        info = s.header["config"]["verification"]
        steps = s.steps()
    summary = yaml.safe_load(verify.with_suffix(".verify.yaml").read_text())
    assert summary["orientation"] == {"measured": True, "reason": None, "source": "6-DoF readings of the target frame"}
    rig = SimulatedRig.from_spec("mock:ur5e", tracker)
    for mode in ("before", "after"):
        figures, u = summary["runs"][mode]["figures"], summary["runs"][mode]["uncertainty"]
        truth = _truth_turns(info, steps, rig, mode)
        for k in range(5):
            for j, axis in enumerate("abc"):
                name = f"ap_{axis} P{k + 1}"
                assert 0 < u[name] < 2e-4, (mode, name, u[name])
                assert abs(figures[name] - truth[k, j]) <= 4 * u[name] + 2e-5, (mode, name, figures[name], truth[k])
                assert figures[f"rp_{axis} P{k + 1}"] > 0
    before = np.array([[summary["runs"]["before"]["figures"][f"ap_{a} P{k}"] for a in "abc"] for k in range(1, 6)])
    assert np.abs(before).max() > 1e-3  # the nominal model turns the target by about a milliradian
    assert "6-DoF readings" in verify.with_suffix(".report.html").read_text()
