"""Compensation against simulated truths: targets reached at the accuracy the result's covariance predicts, the
nominal model's miss is the truth's deviation, the controller-pose round trip, and the command's rows and errors.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml

from config.robots import load_robot
from identify.applications.calibrated import CalibratedModel, ResultError
from identify.applications.compensate import compensate, parse_ur_pose, pose_matrices, solve_ik
from identify.commands.cli import main
from identify.estimator.poe import lines_from_model
from identify.io.result_io import result_to_dict
from identify.results.pipeline import identify
from identify.simulators.simulate import random_poses, simulate
from kinematics.dh import points_from_joints
from kinematics.truth import random_truth

NOISE = 5e-5
ROBOT = load_robot("ur5e")


def _identified(seed: int):
    rng = np.random.default_rng(seed)
    truth = random_truth(ROBOT.nominal, ROBOT.home, rng)
    meas, _ = simulate(truth, ROBOT.home, ROBOT.limits, rng, noise=NOISE, free_poses=20, check_poses=10)
    return truth, identify(meas, ROBOT.nominal), rng


@pytest.fixture(scope="module")
def case():
    return _identified(11)


@pytest.fixture(scope="module")
def result_file(case, tmp_path_factory):
    _, ident, _ = case
    path = tmp_path_factory.mktemp("result") / "result.yaml"
    path.write_text(yaml.safe_dump(result_to_dict(ident, ROBOT.nominal, "ur5e"), sort_keys=False))
    return path


def _nominal_in_cell(model: CalibratedModel) -> CalibratedModel:
    return CalibratedModel.exact(replace(ROBOT.nominal, base=model.base, tool=model.tool()))


def test_the_result_document_gives_the_identification_s_predictions_and_covariances(case) -> None:
    _, ident, rng = case
    doc = yaml.safe_load(yaml.safe_dump(result_to_dict(ident, ROBOT.nominal, "ur5e")))
    model = CalibratedModel.from_document(doc)
    q = random_poses(ROBOT.limits, 30, rng)
    np.testing.assert_allclose(model.points(q), ident.predict(q), atol=1e-12)
    np.testing.assert_allclose(model.point_covariances(q), ident.prediction_covariances(q), rtol=1e-9, atol=1e-20)
    # the frames along the predictor's axis lines are the DH model's for the same robot (the IK's Jacobian, tool poses)
    from identify.estimator.extensions import TermSet
    from identify.results.predict import Predictor

    exact = CalibratedModel.exact(ident.model)
    by_lines = replace(exact, predictor=Predictor(lines_from_model(ident.model, ROBOT.home), np.eye(27),
                                                  TermSet((), ROBOT.home, None), np.zeros(0), None, (1,)))
    np.testing.assert_allclose(by_lines.flanges(q), exact.flanges(q), atol=1e-12)
    np.testing.assert_allclose(by_lines.axes(q)[0], exact.axes(q)[0], atol=1e-12)
    np.testing.assert_allclose(np.cross(by_lines.axes(q)[1] - exact.axes(q)[1], exact.axes(q)[0]), 0.0, atol=1e-12)
    with pytest.raises(ResultError, match="no parameter covariance"):
        CalibratedModel.from_document({k: v for k, v in doc.items() if k != "covariance"})


def _joint_error_result(tmp_path):
    """A UR10e whose joints bend under gravity (1e-6 rad/(N m): 0.1 mm at the TP) and a FANUC whose controller
    reads J3 against the horizontal, each identified (compliance selected; coupling declared) and written."""
    from identify.simulators.simulate import sweep_readings
    from identify.simulators.simulate_joints import RealArm, measure
    from kinematics.joint_errors import JointErrors

    out = []
    for name, errors in (("ur10e", JointErrors(np.zeros(6), np.zeros(6), np.zeros(6), np.full(6, 1e-6))),
                         ("fanuc_lrmate200id", None)):
        robot = load_robot(name)
        rng = np.random.default_rng(150)
        truth = random_truth(robot.nominal, robot.home, rng)
        q, sweep, joint = sweep_readings(robot.joint_types, robot.home, robot.limits, 24)
        extra = random_poses(robot.limits, 50, rng)
        q = np.vstack([q, extra])
        sweep = np.concatenate([sweep, 100 + np.arange(50)])
        joint = np.concatenate([joint, np.zeros(50, dtype=np.int64)])
        held = np.zeros(len(q), dtype=bool)
        held[-20:] = True
        coupling = robot.coupling
        readings = q if coupling is None else coupling.readings_from_dh(q)
        arm = RealArm(truth, coupling, errors, robot.links)
        meas = measure(arm, readings, sweep, joint, 2e-5, np.random.default_rng(1), held)
        ident = identify(meas, robot.nominal, noise=2e-5, links=robot.links)
        path = tmp_path / f"{name}.yaml"
        path.write_text(yaml.safe_dump(result_to_dict(ident, robot.nominal, name)))
        out.append((robot, arm, ident, path))
    return out


def test_coupled_readings_and_joint_errors_are_compensated_through_the_result(tmp_path) -> None:
    """The result's coupling and joint errors (its extensions) predict through the document exactly as in the
    identification; compensated readings put the real arm on the targets within what the covariance predicts."""
    for robot, arm, ident, path in _joint_error_result(tmp_path):
        doc = yaml.safe_load(path.read_text())
        model = CalibratedModel.from_document(doc)
        rng = np.random.default_rng(7)
        readings = random_poses(robot.limits, 100, rng)
        if robot.coupling is not None:
            readings = robot.coupling.readings_from_dh(readings)
            assert doc.get("coupling")
        else:
            assert [t["name"] for t in doc["extensions"]["terms"]], "compliance should be selected"
        np.testing.assert_allclose(model.points(readings), ident.predict(readings), atol=1e-12)
        np.testing.assert_allclose(model.point_covariances(readings), ident.prediction_covariances(readings),
                                   rtol=1e-9, atol=1e-20)
        targets = arm.points(readings)
        start = readings + rng.normal(0, 0.01, readings.shape)
        result = compensate(model, targets, start, robot.limits)
        ok = result.solution.reached
        assert ok.sum() >= 95, result.solution.status
        np.testing.assert_allclose(model.points(result.solution.q[ok]), targets[ok], atol=1e-9)
        err = np.linalg.norm(arm.points(result.solution.q[ok]) - targets[ok], axis=1)
        assert np.sqrt(np.mean(err**2)) < 2.0 * np.sqrt(np.mean(result.expected[ok] ** 2))


def compensation_draws(seeds: list[int]) -> list[tuple[float, float, float, int]]:
    """Per draw (seed): a truth, a calibration, 200 random reachable targets (the truth's TP at random poses,
    tracker frame) compensated. Returns per draw the RMS real error of the reached targets over the RMS the
    covariance predicts, that prediction (m), the RMS miss of the nominal model's own solutions (m), and the
    number of targets reached; asserts along the way what holds per target."""
    out = []
    for seed in seeds:
        truth, ident, rng = _identified(seed)
        model = CalibratedModel.from_identification(ident)
        q_true = random_poses(ROBOT.limits, 200, rng)
        targets = points_from_joints(truth, q_true)
        result = compensate(model, targets, q_true, ROBOT.limits, nominal=_nominal_in_cell(model))
        sol = result.solution
        ok = sol.reached
        np.testing.assert_array_less(sol.position_error[ok], 1e-9)  # the identified model is on the target
        err = np.linalg.norm(points_from_joints(truth, sol.q[ok]) - targets[ok], axis=1)
        predicted = np.sqrt(np.mean(result.expected[ok] ** 2))
        # the nominal model's own solution: the real TP misses the target by the truth's deviation
        nominal_q = result.nominal.q[ok]
        nominal_err = np.linalg.norm(points_from_joints(truth, nominal_q) - targets[ok], axis=1)
        deviation = np.linalg.norm(points_from_joints(truth, nominal_q)
                                   - _nominal_in_cell(model).points(nominal_q), axis=1)
        np.testing.assert_allclose(nominal_err, deviation, atol=1e-9)
        out.append((float(np.sqrt(np.mean(err**2)) / predicted), float(predicted),
                    float(np.sqrt(np.mean(nominal_err**2))), int(ok.sum())))
    return out


@pytest.mark.slow
def test_compensated_targets_are_reached_at_the_predicted_accuracy_and_nominal_misses_by_the_truth() -> None:
    """With the identified model the real TP lands within 1.2x the RMS the covariance predicts (pooled over 3
    draws of 200 targets; no single draw beyond 1.5x); with the nominal model it misses by the truth's deviation
    from it, millimetres."""
    draws = compensation_draws([21, 22, 23])
    ratios = np.array([d[0] for d in draws])
    for ratio, predicted, nominal_rms, reached in draws:
        assert reached >= 195  # a few random poses sit at a singularity
        assert ratio < 1.5
        assert 0.5 * NOISE < predicted < 2 * NOISE  # 0.03 mm for this plan and noise
        assert nominal_rms > 0.5e-3  # millimetres
        assert nominal_rms > 10 * ratio * predicted
    assert np.sqrt(np.mean(ratios**2)) < 1.2


def test_controller_pose_round_trip(case) -> None:
    """The pose written for the controller, solved with the nominal model as the controller would, gives joint
    values at which the identified model reaches the target: to 1e-9 m."""
    _, ident, rng = case
    model = CalibratedModel.from_identification(ident).with_base(np.eye(4))
    nominal = CalibratedModel.exact(replace(ROBOT.nominal, tool=model.tool()))
    q_plan = random_poses(ROBOT.limits, 50, rng)
    flange = nominal.flanges(q_plan)
    targets, rotations = flange[:, :3, :3] @ model.tool() + flange[:, :3, 3], flange[:, :3, :3]
    result = compensate(model, targets, q_plan, ROBOT.limits, rotations, nominal=nominal, frame="base")
    ok = result.solution.status == "ok"
    assert ok.sum() >= 45
    from identify.applications.compensate import controller_poses, ur_pose

    written = [ur_pose(p) for p in controller_poses(nominal, result.solution.q[ok], model.tool())]
    poses = np.array([parse_ur_pose(text) for text in written])
    controller = solve_ik(nominal, poses[:, :3, 3], q_plan[ok], ROBOT.limits, poses[:, :3, :3], model.tool())
    assert np.all(controller.status == "ok")
    reached = model.points(controller.q)
    assert np.max(np.linalg.norm(reached - targets[ok], axis=1)) < 1e-9


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def test_compensate_command_rows_statuses_and_exit_codes(case, result_file, tmp_path, capsys) -> None:
    truth, ident, rng = case
    model = CalibratedModel.from_identification(ident)
    q = random_poses(ROBOT.limits, 5, rng)
    pts = points_from_joints(truth, q)
    rows = [f"{p[0]},{p[1]},{p[2]}," + ",".join(map(str, qq)) for p, qq in zip(pts, q, strict=True)]
    rows.append("3.0,3.0,3.0," + ",".join(map(str, q[0])))  # far beyond the arm's reach
    targets = _write(tmp_path / "t.csv", "# cell targets\nx,y,z,q1,q2,q3,q4,q5,q6\n" + "\n".join(rows) + "\n")
    out = tmp_path / "o.csv"
    assert main(["compensate", str(result_file), "--targets", str(targets), "--out", str(out)]) == 3
    text = capsys.readouterr().out
    # the far target is not reached; whether the solver stops at a joint limit or short of it ("limit" or
    # "unreachable") turns on the model's last bits there (a micrometre's change of the target flips it): either is a
    # refusal
    far = "unreachable" if "5 ok, 1 unreachable" in text else "limit"
    assert f"5 ok, 1 {far}" in text and "1 target(s) NOT reached" in text
    lines = [ln for ln in out.read_text().splitlines() if not ln.startswith("#")]
    assert [ln.split(",")[1] for ln in lines[1:]] == ["ok"] * 5 + [far]
    q_out = np.array([[float(v) for v in ln.split(",")[2:8]] for ln in lines[1:6]])
    np.testing.assert_allclose(model.points(q_out), pts, atol=1e-9)
    # never overwritten without --force, never an input
    assert main(["compensate", str(result_file), "--targets", str(targets), "--out", str(out)]) == 2
    assert "already exists" in capsys.readouterr().err
    assert main(["compensate", str(result_file), "--targets", str(targets), "--out", str(targets), "--force"]) == 2
    assert "is the input" in capsys.readouterr().err


def test_compensate_command_limits_and_bad_input(result_file, tmp_path, capsys) -> None:
    narrow = yaml.safe_load(Path(ROBOT.path).read_text())
    narrow["limits"][0] = [-0.1, 0.1]
    robot_file = _write(tmp_path / "narrow.yaml", yaml.safe_dump(narrow))
    targets = _write(tmp_path / "q.csv", "q1,q2,q3,q4,q5,q6\n0.05,-1.2,1.3,-1.5,-1.4,0.2\n0.8,-1.2,1.3,-1.5,-1.4,0.2\n")
    out = tmp_path / "o.csv"
    code = main(["compensate", str(result_file), "--targets", str(targets), "--joints-from", "nominal", "--out",
                 str(out), "--robot", str(robot_file)])
    assert code == 3
    lines = [ln for ln in out.read_text().splitlines() if not ln.startswith("#")]
    assert [ln.split(",")[1] for ln in lines[1:]] == ["ok", "limit"]
    capsys.readouterr()
    bad = [
        (_write(tmp_path / "a.csv", "x,y\n1,2\n"), [], "needs the columns x,y,z"),
        (_write(tmp_path / "b.csv", "x,y,z\n450,120,300\n"), [], "millimetres"),
        (_write(tmp_path / "c.csv", "x,y,z\n0.4,abc,0.3\n"), [], "line 2: y = 'abc' is not a number"),
        (_write(tmp_path / "d.csv", "x,y,z\n"), [], "no targets"),
        (tmp_path / "missing.csv", [], "no such targets file"),
        (targets, ["--as", "controller-pose", "--robot", str(tmp_path / "none.yaml")], "no such file"),
        (targets, ["--tool", "0.1,0.2"], "--tool needs 3 or 6"),
    ]
    for path, extra, message in bad:
        code = main(["compensate", str(result_file), "--targets", str(path), "--out", str(tmp_path / "x.csv"), *extra])
        err = capsys.readouterr().err
        assert code == 2 and message in err and len(err.strip().splitlines()) == 1, err
    old = {k: v for k, v in yaml.safe_load(result_file.read_text()).items() if k != "covariance"}
    no_cov = _write(tmp_path / "old.yaml", yaml.safe_dump(old))
    assert main(["compensate", str(no_cov), "--targets", str(targets), "--out", str(tmp_path / "y.csv")]) == 2
    assert "no parameter covariance" in capsys.readouterr().err
    assert not (tmp_path / "x.csv").exists() and not (tmp_path / "y.csv").exists()


def test_pose_targets_in_the_base_frame_with_a_tool(case, result_file, tmp_path, capsys) -> None:
    """x,y,z,rx,ry,rz of a tool 0.1 m along the flange's z: the identified model reaches position and orientation."""
    _, ident, rng = case
    model = CalibratedModel.from_identification(ident).with_base(np.eye(4))
    q = random_poses(ROBOT.limits, 4, rng)
    tcp = np.array([0.0, 0.0, 0.1])
    flange = model.flanges(q)
    pos = flange[:, :3, :3] @ tcp + flange[:, :3, 3]
    from identify.applications.compensate import rotvecs

    rv = rotvecs(flange)
    body = "\n".join(",".join(map(str, [*p, *r])) for p, r in zip(pos, rv, strict=True))
    targets = _write(tmp_path / "p.csv", "x,y,z,rx,ry,rz\n" + body + "\n")
    out = tmp_path / "o.csv"
    # seeds from home: the nominal solution first, then the identified one (the branch of the seed)
    code = main(["compensate", str(result_file), "--targets", str(targets), "--frame", "base", "--tool", "0,0,0.1",
                 "--out", str(out)])
    lines = [ln for ln in out.read_text().splitlines() if not ln.startswith("#")]
    statuses = [ln.split(",")[1] for ln in lines[1:]]
    q_out = np.array([[float(v) for v in ln.split(",")[2:8]] for ln in lines[1:]])
    ok = np.array(statuses) == "ok"
    assert code == (0 if ok.all() else 3) and ok.sum() >= 2, statuses
    f_out = model.flanges(q_out[ok])
    np.testing.assert_allclose(f_out[:, :3, :3] @ tcp + f_out[:, :3, 3], pos[ok], atol=1e-9)
    np.testing.assert_allclose(f_out[:, :3, :3], pose_matrices(pos[ok], rv[ok])[:, :3, :3], atol=1e-9)


def test_a_result_that_records_no_robot_is_refused_with_another_models_nominal(case, result_file, tmp_path,
                                                                                capsys) -> None:
    """Identified without --robot, the result names no model: --robot ur10e (another arm's nominal, joint changes
    of radians) is refused in one line, --robot ur5e is taken and the summary says so."""
    truth, _, _ = case
    doc = yaml.safe_load(result_file.read_text())
    doc.pop("nominal")
    unnamed = _write(tmp_path / "unnamed.yaml", yaml.safe_dump(doc, sort_keys=False))
    q = random_poses(ROBOT.limits, 3, np.random.default_rng(4))
    pts = points_from_joints(truth, q)
    targets = _write(tmp_path / "t.csv", "x,y,z\n" + "\n".join(",".join(map(str, p)) for p in pts) + "\n")
    out = tmp_path / "o.csv"
    argv = ["compensate", str(unnamed), "--targets", str(targets), "--out", str(out)]
    assert main([*argv, "--robot", "ur10e"]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and "records no robot model" in err and "ur10e" in err, err
    assert not out.exists()
    assert main([*argv, "--robot", "ur5e"]) == 0
    assert "taken as its nominal" in capsys.readouterr().out
