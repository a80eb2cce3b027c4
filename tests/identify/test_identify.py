"""End-to-end identification on simulated robots: exactness, accuracy against the Cramér-Rao bound,
outliers, conventions, uncertainties and the result contract.

Tolerances come from the noise: a single data set lands within about 0.5-1.8 times the bound for an
ideal estimator, so one draw must stay below ACCURACY_FACTOR times it.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml

from config.robots import load_robot
from identify.commands.cli import main
from identify.estimator.bounds import prediction_rms_bound
from identify.io.csvio import format_measurements, read_measurements
from identify.io.result_io import result_to_dict
from identify.results.pipeline import identify, split_holdout
from identify.simulators.simulate import random_poses, simulate
from kinematics.dh import model_from_dict, model_to_dict, points_from_joints
from kinematics.truth import random_truth

FAMILIES = ["ur5e", "scara", "iiwa7", "track_ur5e", "gantry"]
ACCURACY_FACTOR = 2.5
ROOT = Path(__file__).resolve().parents[2]


def _case(name: str, seed: int):
    robot = load_robot(name)
    rng = np.random.default_rng(seed)
    truth = random_truth(robot.nominal, robot.home, rng)
    q_check = random_poses(robot.limits, 200, rng)
    return robot, rng, truth, q_check


def _rms_error(model, truth, q):
    return float(np.sqrt(np.mean(np.sum((points_from_joints(model, q) - points_from_joints(truth, q)) ** 2, axis=1))))


@pytest.mark.slow
@pytest.mark.parametrize("name", FAMILIES)
@pytest.mark.parametrize("with_nominal", [True, False])
def test_zero_noise_reproduces_truth(name, with_nominal):
    robot, rng, truth, q_check = _case(name, seed=3)
    meas, _ = simulate(truth, robot.home, robot.limits, rng, noise=0.0)
    ident = identify(meas, robot.nominal if with_nominal else None)
    err = np.abs(points_from_joints(ident.model, q_check) - points_from_joints(truth, q_check)).max()
    assert err < 1e-9


@pytest.mark.slow
@pytest.mark.parametrize("name", FAMILIES)
@pytest.mark.parametrize(("noise", "arc"), [(1e-5, None), (5e-5, np.radians(20)), (5e-4, None)])
def test_noisy_accuracy_within_bound(name, noise, arc):
    robot, rng, truth, q_check = _case(name, seed=5)
    meas, _ = simulate(truth, robot.home, robot.limits, rng, noise=noise, arc=arc)
    ident = identify(meas, robot.nominal)
    bound = prediction_rms_bound(truth, meas.q, q_check, noise)
    assert _rms_error(ident.model, truth, q_check) < ACCURACY_FACTOR * bound
    # the residuals imply the simulated noise (per axis), within the spread of its estimate
    assert ident.refinement.noise == pytest.approx(noise, rel=0.2)


@pytest.mark.parametrize("name", ["ur5e", "scara"])
def test_gross_outliers_are_rejected_and_do_not_spoil_the_fit(name):
    robot, rng, truth, q_check = _case(name, seed=8)
    meas, bad = simulate(truth, robot.home, robot.limits, rng, noise=5e-5, outliers=4)
    ident = identify(meas, robot.nominal)
    assert sorted(ident.rejected_rows) == sorted(int(meas.row[b]) for b in bad)
    clean_q = np.delete(meas.q, bad, axis=0)
    assert _rms_error(ident.model, truth, q_check) < ACCURACY_FACTOR * prediction_rms_bound(
        truth, clean_q, q_check, 5e-5
    )


def test_refinement_beats_the_papers_geometric_step_on_partial_arcs():
    robot, rng, truth, q_check = _case("ur5e", seed=9)
    meas, _ = simulate(truth, robot.home, robot.limits, rng, noise=5e-5, arc=np.radians(20))
    ident = identify(meas, robot.nominal)
    assert _rms_error(ident.model, truth, q_check) < 0.7 * _rms_error(ident.geometric.model, truth, q_check)


def test_parallel_axes_keep_conventional_d_and_no_d_blows_up():
    """UR joints 2-4 are parallel: d2, d3 stay at the nominal 0 and every d stays near nominal, even with
    short noisy arcs where exact DH would put the common normal metres away."""
    robot, rng, truth, _ = _case("ur5e", seed=12)
    for _ in range(8):
        meas, _ = simulate(truth, robot.home, robot.limits, rng, noise=5e-4, arc=np.radians(20))
        ident = identify(meas, robot.nominal)
        assert {2, 3} <= set(ident.parallel)
        fixed = {f.name: f.value for f in ident.fixed}
        assert fixed["d2"] == 0.0 and fixed["d3"] == 0.0
        assert np.abs(ident.model.d - robot.nominal.d).max() < 0.05


def test_fixed_parameters_take_nominal_values_and_are_explained():
    robot, rng, truth, _ = _case("ur5e", seed=4)
    meas, _ = simulate(truth, robot.home, robot.limits, rng, noise=5e-5)
    ident = identify(meas, robot.nominal)
    fixed = {f.name: f for f in ident.fixed}
    assert set(fixed) == {"theta1", "d1", "d2", "d3", "theta6", "d6", "a6", "alpha6"}
    assert fixed["d1"].value == pytest.approx(robot.nominal.d[0])
    assert fixed["d6"].value == pytest.approx(robot.nominal.d[5])
    assert "base" in fixed["theta1"].reason and "tool" in fixed["alpha6"].reason
    assert all(ident.std[ident.refinement.free] > 0)


@pytest.mark.slow
def test_reported_uncertainty_matches_monte_carlo_spread():
    """30 repetitions: the mean reported standard uncertainty of a few DH values matches their empirical
    spread within 35 % (the sampling error of a 30-draw standard deviation is about 13 %)."""
    robot, rng, truth, _ = _case("ur5e", seed=21)
    picks = [9 + 4 * 1 + 2, 9 + 4 * 3 + 1, 9 + 4 * 4 + 3]  # a2, d4, alpha5
    estimates, reported = [], []
    for _ in range(30):
        meas, _ = simulate(truth, robot.home, robot.limits, rng, noise=5e-5)
        ident = identify(meas, robot.nominal)
        table = ident.model.dh_table().ravel()
        estimates.append(table[[p - 9 for p in picks]])
        reported.append(ident.std[picks])
    ratio = np.mean(reported, axis=0) / np.std(estimates, axis=0, ddof=1)
    assert np.all((ratio > 0.65) & (ratio < 1.35)), ratio


def test_held_out_poses_are_validated_against_their_expected_error():
    robot, rng, truth, _ = _case("ur5e", seed=6)
    meas, _ = simulate(truth, robot.home, robot.limits, rng, noise=5e-5, free_poses=20, check_poses=15)
    ident = identify(meas, robot.nominal)
    v = ident.validation
    assert v.samples == 15
    assert 0.5 * v.expected < v.rms < 1.6 * v.expected
    assert v.max >= v.rms


def test_holdout_split_is_seeded_and_only_takes_free_poses():
    robot, rng, truth, _ = _case("ur5e", seed=6)
    meas, _ = simulate(truth, robot.home, robot.limits, rng, noise=5e-5, free_poses=20)
    a, b = split_holdout(meas, 0.3, seed=1), split_holdout(meas, 0.3, seed=1)
    assert np.array_equal(a.check, b.check) and a.check.sum() == 6
    assert np.all(a.joint[a.check] == 0)


def test_hand_jogged_sweep_without_readings_still_identifies():
    robot, rng, truth, q_check = _case("ur5e", seed=7)
    meas, _ = simulate(truth, robot.home, robot.limits, rng, noise=5e-5, free_poses=30)
    q = meas.q.copy()
    q[meas.joint == 4, 3] = np.nan  # joint 4 jogged by hand: its readings were not logged
    ident = identify(replace(meas, q=q), robot.nominal)
    free_only = meas.q[(meas.joint != 4)]
    assert _rms_error(ident.model, truth, q_check) < ACCURACY_FACTOR * prediction_rms_bound(
        truth, free_only, q_check, 5e-5
    )


def test_per_sample_sigma_weights_give_unit_reduced_chi_square():
    robot, rng, truth, _ = _case("ur5e", seed=10)
    meas, _ = simulate(truth, robot.home, robot.limits, rng, noise=0.0)
    sigma = rng.choice([2e-5, 2e-4], size=len(meas))
    noisy = replace(meas, points=meas.points + rng.normal(size=meas.points.shape) * sigma[:, None], sigma=sigma)
    ident = identify(noisy, robot.nominal)
    note = next(n for n in ident.refinement.notes if "chi-square" in n)
    assert 0.8 < float(note.split()[2]) < 1.2


def test_result_document_round_trips_and_keeps_the_contract(tmp_path):
    robot, rng, truth, q_check = _case("scara", seed=2)
    meas, _ = simulate(truth, robot.home, robot.limits, rng, noise=5e-5)
    ident = identify(meas, robot.nominal)
    doc = yaml.safe_load(yaml.safe_dump(result_to_dict(ident, robot.nominal, robot.name), sort_keys=False))
    assert list(doc)[:3] == ["joints", "base", "tool"]
    assert set(doc["joints"][0]) == {"type", "a", "alpha", "d", "theta"}
    model = model_from_dict(doc)
    assert np.allclose(points_from_joints(model, q_check), points_from_joints(ident.model, q_check), atol=1e-12)
    assert model_from_dict(model_to_dict(truth)).dh_table() == pytest.approx(truth.dh_table())
    assert doc["software"]["version"]


def test_csv_round_trip_preserves_measurements(tmp_path):
    robot, rng, truth, _ = _case("track_ur5e", seed=2)
    meas, _ = simulate(truth, robot.home, robot.limits, rng, noise=5e-5, check_poses=5)
    path = tmp_path / "m.csv"
    path.write_text(format_measurements(meas))
    again = read_measurements(path).measurements
    assert again.joint_types == meas.joint_types
    assert np.array_equal(again.q, meas.q) and np.array_equal(again.points, meas.points)
    assert np.array_equal(again.check, meas.check) and np.array_equal(again.sweep, meas.sweep)


def test_bundled_sample_identifies_to_its_truth(tmp_path, capsys):
    sample = ROOT / "identify" / "data" / "sample_ur5e.csv"
    truth = model_from_dict(yaml.safe_load((sample.with_name("sample_ur5e_truth.yaml")).read_text()))
    out = tmp_path / "result.yaml"
    assert main([str(sample), "--robot", "ur5e", "--out", str(out)]) == 0
    assert "validation of the plain model on 9 held-out poses" in capsys.readouterr().out
    model = model_from_dict(yaml.safe_load(out.read_text()))
    robot = load_robot("ur5e")
    meas = read_measurements(sample).measurements
    q_check = random_poses(robot.limits, 200, np.random.default_rng(0))
    bound = prediction_rms_bound(truth, meas.q, q_check, 5e-5)
    assert _rms_error(model, truth, q_check) < ACCURACY_FACTOR * bound
