"""``identify check RESULT DATA``: a second session of the same arm with the tracker moved holds, with the
held-out RMS of the first session within noise and the tracker's move recovered; another arm of the same model
fails (exit 3); gross errors are found and left out; a re-mounted reflector fails unless ``--refit-tool``; the
extended model is checked beside the plain one; bad inputs give one line and exit 2."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
import yaml

from config.robots import load_robot
from identify.applications.holds import check_models, pose_groups
from identify.applications.result_models import result_models
from identify.commands.cli import main
from identify.io.csvio import format_measurements
from identify.io.result_io import result_to_dict, validation_of
from identify.results.pipeline import identify
from identify.simulators.simulate import dh_truth, make_scenario, reading_error, simulate, transform_lines
from kinematics.truth import random_base, random_truth

ROBOT = load_robot("ur5e")
NOISE = 5e-5
CHECK_POSES = 30


def _session(truth, seed, steps=6, free=30, check=0):
    meas, _ = simulate(truth, ROBOT.home, ROBOT.limits, np.random.default_rng(seed), noise=NOISE, steps=steps,
                       free_poses=free, check_poses=check)
    return meas


def _moved(truth, seed):
    """The tracker moved: any rotation, up to 2.5 m away (new tracker <- old tracker)."""
    move = random_base(np.random.default_rng(seed), distance=1.0)
    return replace(truth, base=move @ truth.base), move


@pytest.fixture(scope="module")
def first():
    """Session 1 of a UR5e (sweeps, 15 free poses, 30 held-out): its result document and truth."""
    truth = random_truth(ROBOT.nominal, ROBOT.home, np.random.default_rng(1))
    meas = _session(truth, 2, steps=12, free=15, check=CHECK_POSES)
    doc = result_to_dict(identify(meas, ROBOT.nominal), ROBOT.nominal, ROBOT.name)
    return yaml.safe_load(yaml.safe_dump(doc)), truth


def _check(doc, meas, **kw):
    models = result_models(doc, meas.q, meas.tp)
    return check_models(meas.points, meas.q, meas.tp, models.models, models.use, **kw)


def test_same_arm_with_the_tracker_moved_holds_at_the_first_sessions_heldout_rms(first):
    """Five second sessions, the tracker moved anywhere: each passes; the registration is the move (to what the
    noise allows); the held-out RMS pooled over them matches session 1's held-out RMS within the two figures'
    chi-square spread (4 sigma)."""
    doc, truth = first
    square, count = 0.0, 0
    for seed in range(5):
        moved, move = _moved(truth, 10 + seed)
        meas = _session(moved, 20 + seed)
        check = _check(doc, meas)
        plain = check.chosen
        assert check.status == "pass" and plain.name == "plain" and not len(plain.gross)
        turn = plain.registration.rotation @ move[:3, :3].T
        assert np.degrees(np.arccos(np.clip((np.trace(turn) - 1) / 2, -1, 1))) < 0.01
        assert np.linalg.norm(plain.registration.translation - move[:3, 3]) < 1e-3
        assert plain.registration.moved == pytest.approx(np.linalg.norm(move[:3, 3]), abs=1e-3)
        square += plain.heldout.rms**2 * plain.heldout.samples
        count += plain.heldout.samples
    rms2, rms1 = np.sqrt(square / count), validation_of(doc, "plain")["rms"]
    spread = np.sqrt(1 / (2 * 3 * CHECK_POSES) + 1 / (2 * 3 * count))  # relative std of an RMS of k squares
    assert abs(rms2 / rms1 - 1) < 4 * spread


def test_another_arm_of_the_same_model_fails(first, tmp_path, capsys):
    doc, _ = first
    other = random_truth(ROBOT.nominal, ROBOT.home, np.random.default_rng(77))
    check = _check(doc, _session(other, 3))
    assert check.status == "fail" and check.chosen.ratio > 10
    result, data = tmp_path / "r.yaml", tmp_path / "other.csv"
    result.write_text(yaml.safe_dump(doc))
    data.write_text(format_measurements(_session(other, 3)))
    assert main(["check", str(result), str(data)]) == 3
    out = capsys.readouterr().out
    assert out.startswith("FAIL") and max(len(line) for line in out.splitlines()) <= 80


def test_a_noise_1000x_the_sigma_of_another_arms_data_is_refused(first, tmp_path, capsys):
    """Issue 39, item 1, with data the result does not fit (another arm: 100s of times the noise in-sample, which
    hides any slip): ``--noise 0.05`` (50 mm) turned its FAIL into a WARN, exit 0. Rows that state their sigma
    (a session's, a CSV ``sigma`` column) show the slip: refused, one line; in its unit the check fails as it
    should."""
    doc, _ = first
    other = _session(random_truth(ROBOT.nominal, ROBOT.home, np.random.default_rng(77)), 3)
    other = replace(other, sigma=np.full(len(other.row), NOISE))
    result, data = tmp_path / "r.yaml", tmp_path / "other.csv"
    result.write_text(yaml.safe_dump(doc))
    data.write_text(format_measurements(other))
    assert main(["check", str(result), str(data), "--noise", "0.05"]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and "--noise 0.05 is read as 50 mm; did you mean 0.05mm? (1000x the sigma" \
        in err, err
    assert main(["check", str(result), str(data), "--noise", "0.05mm"]) == 3
    assert capsys.readouterr().out.startswith("FAIL")


def test_gross_errors_are_found_and_do_not_break_the_registration(first):
    doc, truth = first
    meas = _session(_moved(truth, 5)[0], 6)
    clean = _check(doc, meas).chosen
    rng = np.random.default_rng(7)
    bad = rng.choice(len(meas.points), 4, replace=False)
    points = meas.points.copy()
    points[bad] += rng.normal(size=(4, 3)) / np.sqrt(3) * rng.uniform(5e-3, 20e-3, (4, 1))
    broken = _check(doc, replace(meas, points=points)).chosen
    assert broken.status == "pass" and set(broken.gross) == set(bad)
    assert broken.heldout.rms == pytest.approx(clean.heldout.rms, rel=0.1)  # the same rows but four
    assert np.allclose(broken.registration.translation, clean.registration.translation, atol=1e-4)


def test_a_remounted_reflector_fails_unless_the_tool_is_refitted(first):
    doc, truth = first
    moved, _ = _moved(truth, 8)
    shift = np.array([0.02, -0.01, 0.005])
    meas = _session(replace(moved, tool=moved.tool + shift), 9)
    assert _check(doc, meas).status == "fail"
    refit = _check(doc, meas, refit_tool=True)
    assert refit.status == "pass" and refit.chosen.parameters == 9
    assert np.linalg.norm(refit.chosen.registration.tools[1] - shift) < 2e-4


def test_the_extended_model_is_checked_beside_the_plain_one():
    """A result with joint errors (reading scale and once-per-turn terms simulated): both models are checked on
    a second session; the extended one holds at its stated figure, the DH table alone does not hold it."""
    rng = np.random.default_rng(3)
    truth = dh_truth(ROBOT.nominal, ROBOT.home, rng)
    errors = reading_error("RRRRRR", rng, scale=2e-4, amplitude=np.radians(0.02))
    s1 = make_scenario(truth, ROBOT.home, ROBOT.limits, rng, noise=2e-5, steps=18, free_poses=20, check_poses=20,
                       errors=errors)
    doc = result_to_dict(identify(s1.meas, ROBOT.nominal), ROBOT.nominal, ROBOT.name)
    assert doc["extensions"]["terms"]
    s2 = make_scenario(transform_lines(truth, random_base(rng)), ROBOT.home, ROBOT.limits, rng, noise=2e-5, steps=6,
                       free_poses=30, errors=errors)
    check = _check(doc, s2.meas)
    by_name = {m.name: m for m in check.models}
    assert check.use == "extended" and check.status == "pass"
    assert by_name["extended"].ratio < 1.5
    assert by_name["plain"].heldout.rms > 3 * by_name["extended"].heldout.rms


def test_two_model_results_are_read_by_their_stated_figures_and_use(first):
    """A result of the two-model form (validation.plain / validation.extended, use): each model's stated figure
    is its expected RMS, with the new tracker noise in place of the calibration's; ``use`` picks the verdict."""
    doc, truth = first
    doc = {**doc, "validation": {"plain": {"expected_rms": 2e-4}, "extended": {"expected_rms": 1e-4}}, "use": "plain"}
    meas = _session(_moved(truth, 11)[0], 12)
    old = doc["noise"]["tracker_per_axis"]
    models = result_models(doc, meas.q, meas.tp, noise=2 * old)
    assert [m.name for m in models.models] == ["plain"] and models.use == "plain"  # no terms: no extended model
    assert models.sources == {"plain": "stated"}
    assert models.models[0].expected == pytest.approx(np.sqrt(2e-4**2 + 9 * old**2), rel=1e-12)
    assert result_models(doc, meas.q, meas.tp).models[0].expected == pytest.approx(2e-4, rel=1e-12)


def test_undeclared_higher_noise_warns_and_declared_passes(first, tmp_path, capsys):
    """Today's tracker 2.2x noisier: the held-out RMS is about twice the stated figure (warn, exit 0); with that
    noise declared (--noise) the expectation follows and the check passes."""
    doc, truth = first
    meas, _ = simulate(_moved(truth, 13)[0], ROBOT.home, ROBOT.limits, np.random.default_rng(14), noise=2.2 * NOISE,
                       steps=6, free_poses=30)
    result, data = tmp_path / "r.yaml", tmp_path / "noisy.csv"
    result.write_text(yaml.safe_dump(doc))
    data.write_text(format_measurements(meas))
    assert main(["check", str(result), str(data), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["status"] == "warn"
    assert main(["check", str(result), str(data), "--json", "--noise", str(2.2 * NOISE)]) == 0
    assert json.loads(capsys.readouterr().out)["status"] == "pass"


def test_each_tracked_point_gets_its_own_figure():
    """Three reflectors, one of them knocked 1 mm off since the calibration: the pooled figure fails, and only
    that point's own held-out RMS is far beyond the noise."""
    from identify.applications.holds import Model
    from identify.estimator.poe import points_from_lines
    from identify.simulators.simulate import lines_from_model

    rng = np.random.default_rng(15)
    truth = random_truth(ROBOT.nominal, ROBOT.home, rng)
    lines = lines_from_model(truth, ROBOT.home)
    lines = replace(lines, extra_tps=lines.tp_home + rng.uniform(-0.1, 0.1, (2, 3)))
    q = np.repeat(rng.uniform(-2, 2, (20, 6)), 3, axis=0)
    tp = np.tile([1, 2, 3], 20)
    moved = replace(lines, extra_tps=lines.extra_tps + np.array([[1e-3, 0, 0], [0, 0, 0]]))
    points = points_from_lines(moved, q, tp - 1) + rng.normal(0, NOISE, (60, 3))
    model = Model("plain", lambda q, tp: points_from_lines(lines, q, tp - 1), np.sqrt(3) * NOISE)
    check = check_models(points, q, tp, [model])
    per_tp = check.chosen.per_tp
    assert per_tp[2].rms > 0.5e-3 and max(per_tp[1].rms, per_tp[3].rms) < 0.5 * per_tp[2].rms
    assert check.status == "fail" and not len(check.chosen.gross)  # a third of the rows: not beam breaks


def test_pose_groups_join_the_rows_of_one_pose():
    q = np.array([[1.0, 2.0], [0.0, 0.0], [1.0, 2.0], [3.0, 1.0]])
    assert pose_groups(q).tolist() == [0, 1, 0, 2]


def test_command_json_out_and_refusals(first, tmp_path, capsys):
    doc, truth = first
    result, data, out = tmp_path / "r.yaml", tmp_path / "today.csv", tmp_path / "check.yaml"
    result.write_text(yaml.safe_dump(doc))
    data.write_text(format_measurements(_session(_moved(truth, 4)[0], 4)))
    assert main(["check", str(result), str(data), "--json", "--out", str(out)]) == 0
    printed = json.loads(capsys.readouterr().out)
    written = yaml.safe_load(out.read_text())
    assert printed["status"] == written["status"] == "pass" and printed["models"]["plain"]["heldout"]["samples"] > 60
    assert main(["check", str(result), str(data)]) == 0
    text = capsys.readouterr().out
    assert text.startswith("PASS") and max(len(line) for line in text.splitlines()) <= 80
    few = tmp_path / "few.csv"
    meas = _session(truth, 4, steps=3, free=0)
    few.write_text(format_measurements(meas.subset(np.isin(meas.sweep, [1, 2]))))
    not_result = tmp_path / "not.yaml"
    not_result.write_text("a: 1\n")
    cases = [
        ([str(tmp_path / "none.yaml"), str(data)], "no such result file"),
        ([str(not_result), str(data)], "not a result file"),
        ([str(result), str(tmp_path / "none.csv")], "no such file"),
        ([str(result), str(data), "--out", str(out)], "exists"),
        ([str(result), str(data), "--noise", "-1"], "--noise"),
        ([str(result), str(few)], "at least 6 are needed"),
        ([str(result), str(data), "--joints", "RRRR"], ""),
    ]
    for argv, words in cases:
        try:
            code = main(["check", *argv])
        except SystemExit as exc:  # a value its option refuses (--noise -1): argparse's one line
            code = exc.code
        assert code == 2, argv
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and words in err and "Traceback" not in err, err


def _session_then_check(folder: str) -> tuple[int, int, str]:
    """A mock acquisition of a simulated UR5e (it writes its result beside the session), then that result checked
    on the session file itself: the session is read as DATA. Exit codes and the check's output."""
    import contextlib
    import io
    from pathlib import Path

    from acquire.commands.cli import main as acquire

    path, out = Path(folder) / "s.session", io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()):
        acquired = acquire(["--robot", "mock:ur5e", "--tracker", "mock?seed=1", "--steps", "6", "--free-poses", "6",
                            "--session", str(path), "--quiet"])
    with contextlib.redirect_stdout(out):
        code = main(["check", str(path.with_suffix(".result.yaml")), str(path)])
    return acquired, code, out.getvalue()


@pytest.mark.slow
def test_check_reads_a_session_file(tmp_path):
    acquired, code, out = _session_then_check(str(tmp_path))
    assert acquired == 0 and code == 0, out
    assert out.startswith("PASS") and "moved 0.0 mm" in out  # the mock tracker stayed where it was


def test_a_noise_1000x_off_against_what_the_data_show_is_refused(first, tmp_path, capsys):
    """``--noise 0.05`` (50 mm read for 0.05 mm) makes any data pass against a huge "expected" error: refused,
    repeating what was typed, since the data's own scatter (0.05 mm per axis) is 1000x below it; in its unit the
    check runs and passes."""
    doc, truth = first
    result, data = tmp_path / "r.yaml", tmp_path / "today.csv"
    result.write_text(yaml.safe_dump(doc))
    data.write_text(format_measurements(_session(_moved(truth, 4)[0], 4)))
    assert main(["check", str(result), str(data), "--noise", "0.05"]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and "--noise 0.05 is read as 50 mm; did you mean 0.05mm?" in err, err
    assert main(["check", str(result), str(data), "--noise", "0.05mm"]) == 0
    assert main(["check", str(result), str(data), "--noise", "0.4mm"]) == 0  # 8x: a pessimistic noise, not a slip
