"""Issue 14: coupled joints, several tracked points, and the joint errors a DH table cannot hold.

Simulated arms (identify.simulators.simulate_joints) write readings as their controller reports them; tolerances come
from the tracker noise (0.02 mm per axis) through the fit's own reported uncertainty.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import yaml

from common.errors import InputError
from config.robots import load_robot
from identify.commands.cli import main
from identify.io.csvio import format_measurements, parse_measurements
from identify.results.pipeline import identify
from identify.simulators.simulate import random_poses
from identify.simulators.simulate_joints import RealArm, measure, reflector_plate, sweeps_and_poses
from kinematics.joint_errors import JointErrors
from kinematics.truth import random_truth

NOISE = 2e-5
ERROR_FACTOR = 2.0  # RMS error vs reported accuracy over 200 poses: chi-square(600) stays far below 2x


def _poses(robot, rng: np.random.Generator, steps: int, free: int, check: int):
    return sweeps_and_poses(robot.joint_types, robot.home, robot.limits, rng, steps, free, check)


def _error(ident, arm: RealArm, readings, tp=None) -> float:
    index = None if tp is None else np.full(len(readings), tp - 1)
    err = ident.predict(readings, tp) - arm.points(readings, index)
    return float(np.sqrt(np.mean(np.sum(err**2, axis=1))))


def test_fanuc_readings_with_their_coupling_identify_exactly_as_dh_values():
    """FANUC J3 is read against the horizontal (q3 = J2 + J3): the same poses and noise written as controller
    readings with '# coupling:' give the model found from DH values, to numerical precision."""
    robot = load_robot("fanuc_lrmate200id")
    rng = np.random.default_rng(140)
    truth = random_truth(robot.nominal, robot.home, rng)
    q_dh, sweep, joint, held = _poses(robot, rng, 24, 30, 20)
    readings = robot.coupling.readings_from_dh(q_dh)
    assert np.ptp(readings[joint == 2][:, 2]) > 1.0  # a DH joint-2 sweep moves two readings on the controller
    coupled = measure(RealArm(truth, robot.coupling), readings, sweep, joint, NOISE, np.random.default_rng(1), held)
    plain = measure(RealArm(truth), q_dh, sweep, joint, NOISE, np.random.default_rng(1), held)
    np.testing.assert_allclose(coupled.points, plain.points, atol=1e-12)
    text = format_measurements(coupled)
    assert "# coupling: [[1.0, 0.0" in text
    back = parse_measurements(text.splitlines()).measurements
    a, b = identify(back, robot.nominal), identify(plain, robot.nominal)
    assert a.verdict.status == "pass"
    q_check = random_poses(robot.limits, 100, rng)
    np.testing.assert_allclose(a.predict(robot.coupling.readings_from_dh(q_check)), b.predict(q_check), atol=1e-9)
    assert a.validation.rms == pytest.approx(b.validation.rms, rel=1e-6)
    # without the declaration the sweep moving J2 and J3 together is named, in one line
    with pytest.raises(InputError, match=r"sweep \d+ \(joint 2\): the readings of joints 2 and 3 move together"):
        identify(replace(back, coupling=None), robot.nominal)


def test_a_sweep_of_one_controller_reading_moves_two_dh_joints_and_counts_as_free_poses():
    robot = load_robot("fanuc_lrmate200id")
    rng = np.random.default_rng(141)
    truth = random_truth(robot.nominal, robot.home, rng)
    q_dh, sweep, joint, held = _poses(robot, rng, 24, 30, 10)
    readings = robot.coupling.readings_from_dh(q_dh)
    extra = np.tile(robot.coupling.readings_from_dh(robot.home[None])[0], (12, 1))
    extra[:, 1] += np.linspace(-0.4, 0.4, 12)  # J2 jogged on the controller: DH joints 2 and 3 move
    readings = np.vstack([readings, extra])
    sweep = np.concatenate([sweep, np.full(12, 99)])
    joint = np.concatenate([joint, np.full(12, 2)])
    meas = measure(RealArm(truth, robot.coupling), readings, sweep, joint, NOISE, rng, np.append(held, [False] * 12))
    ident = identify(meas, robot.nominal)
    assert any("sweep 99 moves DH joints 2 and 3 together (coupling): used as free poses" in w for w in ident.warnings)
    assert ident.verdict.status == "pass"


def test_three_reflectors_shrink_the_uncertainty_as_predicted_and_survive_occlusion():
    """Three reflectors 150-250 mm apart: the reported accuracy at held-out poses drops, the achieved error
    stays within it, and a point missing at some poses (line of sight) is simply absent."""
    robot = load_robot("ur5e")
    rng = np.random.default_rng(142)
    truth = random_truth(robot.nominal, robot.home, rng)
    tools = reflector_plate(rng)
    arm = RealArm(truth, tools=tools)
    q, sweep, joint, held = _poses(robot, rng, 12, 20, 0)
    visible = rng.random((len(q), 3)) > 0.15
    visible[:, 0] = True  # the first reflector is always seen (it names the tool of the DH contract)
    many = measure(arm, q, sweep, joint, NOISE, rng, held, visible)
    one = many.subset(many.tp == 1)
    q_check = random_poses(robot.limits, 200, rng)
    single, triple = identify(one, robot.nominal), identify(many, robot.nominal)
    assert triple.tp_ids == (1, 2, 3) and triple.verdict.status in ("pass", "warn")
    reported_1, reported_3 = single.prediction_rms(q_check), triple.prediction_rms(q_check)
    assert reported_3 < 0.8 * reported_1
    for ident, reported in ((single, reported_1), (triple, reported_3)):
        assert _error(ident, arm, q_check, 1) < ERROR_FACTOR * reported
    for tp in (2, 3):
        assert _error(triple, arm, q_check, tp) < ERROR_FACTOR * triple.prediction_rms(q_check, tp)
    np.testing.assert_allclose(triple.tools[0], triple.model.tool)
    with pytest.raises(ValueError, match="not in the model"):
        triple.predict(q_check[:2], 4)


def _ur10e_arm(seed: int, errors: JointErrors | None):
    robot = load_robot("ur10e")
    rng = np.random.default_rng(seed)
    truth = random_truth(robot.nominal, robot.home, rng)
    arm = RealArm(truth, errors=errors, links=robot.links)
    q, sweep, joint, held = _poses(robot, rng, 36, 40, 20)
    return robot, arm, measure(arm, q, sweep, joint, NOISE, rng, held), rng


def test_compliance_under_gravity_is_selected_and_sized():
    """1e-6 rad/(N m) on every joint of a UR10e (0.1 mm at the TP): compliance of joints 2 and 3 is found,
    its size within 5 sigma, and predictions reach the extended model's accuracy."""
    robot = load_robot("ur10e")
    errors = JointErrors(np.zeros(6), np.zeros(6), np.zeros(6), np.full(6, 1e-6))
    robot, arm, meas, rng = _ur10e_arm(143, errors)
    ident = identify(meas, robot.nominal, noise=NOISE, links=robot.links)
    found = {name: (value, std) for name, value, std in ident.extensions}
    for j in (2, 3):
        value, std = found[f"compliance_{j}"]
        assert abs(value - 1e-6) < 5 * std
    assert not any(name.startswith(("scale", "ecc")) for name in found)
    q_check = random_poses(robot.limits, 200, rng)
    assert _error(ident, arm, q_check) < ERROR_FACTOR * ident.prediction_rms(q_check)
    plain = identify(meas, robot.nominal, noise=NOISE, links=robot.links, extensions=False)
    assert _error(ident, arm, q_check) < 0.5 * _error(plain, arm, q_check)


def test_no_joint_error_selects_nothing_and_changes_nothing():
    robot, _, meas, rng = _ur10e_arm(144, None)
    ident = identify(meas, robot.nominal, noise=NOISE, links=robot.links)
    assert ident.extensions == [] and len(ident.decisions) == 16
    assert all(not d.selected for d in ident.decisions)
    plain = identify(meas, robot.nominal, noise=NOISE, links=robot.links, extensions=False)
    q_check = random_poses(robot.limits, 50, rng)
    np.testing.assert_allclose(ident.predict(q_check), plain.predict(q_check), atol=1e-12)


def test_cli_records_coupling_tools_and_extensions_and_exports_say_what_they_lack(tmp_path, capsys):
    robot = load_robot("fanuc_lrmate200id")
    rng = np.random.default_rng(145)
    truth = random_truth(robot.nominal, robot.home, rng)
    q_dh, sweep, joint, held = _poses(robot, rng, 24, 30, 10)
    arm = RealArm(truth, robot.coupling, JointErrors(np.full(6, 2e-4), np.zeros(6), np.zeros(6), np.zeros(6)),
                  tools=reflector_plate(rng, 2))
    meas = measure(arm, robot.coupling.readings_from_dh(q_dh), sweep, joint, NOISE, rng, held)
    csv_path = tmp_path / "fanuc.csv"
    csv_path.write_text(format_measurements(replace(meas, coupling=None)))  # the file does not say
    coupling = tmp_path / "coupling.yaml"
    coupling.write_text(yaml.safe_dump({"matrix": robot.coupling.matrix.tolist()}))
    out, urdf = tmp_path / "result.yaml", tmp_path / "robot.urdf"
    assert main([str(csv_path), "--coupling", str(coupling), "--out", str(out), "--urdf", str(urdf)]) == 0
    doc = yaml.safe_load(out.read_text())
    assert doc["coupling"]["matrix"][2] == [0.0, 1.0, 1.0, 0.0, 0.0, 0.0]
    assert set(doc["tools"]) == {1, 2} and doc["tools"][1] == doc["tool"]
    names = {t["name"] for t in doc["extensions"]["terms"]}
    assert {"scale_1", "scale_2", "scale_3"} <= names
    assert "scale" in doc["extensions"]["equations"]
    text = urdf.read_text()
    assert "NOT carried: the extended model's joint errors" in text and "q_dh = C . readings" in text
    capsys.readouterr()
    assert main([str(csv_path), "--extensions", "none", "--json"]) == 2  # the missing coupling, in one line
    assert "move together" in capsys.readouterr().err


@pytest.mark.slow
def test_report_shows_every_tracked_point_the_coupling_and_the_joint_error_decisions(tmp_path):
    robot = load_robot("fanuc_lrmate200id")
    rng = np.random.default_rng(146)
    truth = random_truth(robot.nominal, robot.home, rng)
    q_dh, sweep, joint, held = _poses(robot, rng, 24, 30, 10)
    arm = RealArm(truth, robot.coupling, JointErrors(np.full(6, 2e-4), np.zeros(6), np.zeros(6), np.zeros(6)),
                  tools=reflector_plate(rng, 2))
    csv_path, report = tmp_path / "fanuc.csv", tmp_path / "report.html"
    csv_path.write_text(format_measurements(measure(arm, robot.coupling.readings_from_dh(q_dh), sweep, joint, NOISE,
                                                    rng, held)))
    assert main([str(csv_path), "--report", str(report)]) == 0
    html = report.read_text()
    section = html[html.index('id="beyond-dh"'):]
    section = section[:section.index("</section>")]
    assert section.count("<tr>") >= 2 + 1 + 12  # two tracked points, the terms, every candidate's decision
    assert "q_dh = C · readings + offset" in section and "scale_3" in section
