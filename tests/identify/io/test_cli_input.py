"""``identify INPUT``: every bad input gets one clear line on stderr and exit code 2, never a traceback; good input
(including awkward but valid files) identifies a model that reproduces the data.

Input files are a valid simulated UR5e session written with ``format_measurements`` and then corrupted.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from config.robots import load_robot
from identify.commands.cli import main
from identify.estimator.measurements import Measurements
from identify.io.csvio import format_measurements
from identify.io.result_io import validation_of
from identify.simulators.simulate import simulate
from kinematics.dh import DHModel, points_from_joints
from kinematics.truth import random_truth

NOISE = 5e-5  # m per axis
STEPS = 12  # samples per sweep
FREE = 10  # free poses
ROBOT = load_robot("ur5e")
HEADER_LINE = 3  # 1-based: '# joints', '# units', then the header row
ROOT = Path(__file__).resolve().parents[3]


# --- data and corruption helpers ----------------------------------------------------------------------------------


def _session(noise: float = NOISE, seed: int = 3, tool=None) -> tuple[DHModel, Measurements]:
    rng = np.random.default_rng(seed)
    truth = random_truth(ROBOT.nominal, ROBOT.home, rng)
    if tool is not None:
        truth = DHModel(truth.joint_types, truth.theta, truth.d, truth.a, truth.alpha, truth.base, tool)
    meas, _ = simulate(truth, ROBOT.home, ROBOT.limits, rng, noise=noise, steps=STEPS, free_poses=FREE)
    return truth, meas


@pytest.fixture(scope="module")
def session() -> tuple[DHModel, Measurements]:
    return _session()


@pytest.fixture
def lines(session) -> list[str]:
    """The valid CSV as a list of lines: line k of the file is ``lines[k - 1]``."""
    return format_measurements(session[1]).splitlines()


def write(tmp_path: Path, content: list[str] | str | bytes, name: str = "session.csv") -> Path:
    path = tmp_path / name
    if isinstance(content, bytes):
        path.write_bytes(content)
    else:
        path.write_text(content if isinstance(content, str) else "\n".join(content) + "\n", encoding="utf-8")
    return path


def column(lines: list[str], name: str) -> int:
    return lines[HEADER_LINE - 1].split(",").index(name)


def set_field(lines: list[str], line: int, name: str, value: str) -> list[str]:
    """Set column ``name`` of file line ``line`` (1-based) to ``value``."""
    out = list(lines)
    fields = out[line - 1].split(",")
    fields[column(lines, name)] = value
    out[line - 1] = ",".join(fields)
    return out


def map_rows(lines: list[str], fn) -> list[str]:
    """Apply ``fn(fields, is_header)`` to every non-comment line (header and data)."""
    out = []
    for text in lines:
        if text.startswith("#"):
            out.append(text)
            continue
        fields = text.split(",")
        out.append(",".join(fn(fields, text is lines[HEADER_LINE - 1])))
    return out


def drop_column(lines: list[str], name: str) -> list[str]:
    index = column(lines, name)
    return map_rows(lines, lambda f, _: f[:index] + f[index + 1:])


def add_column(lines: list[str], name: str, value) -> list[str]:
    """Append a column; ``value`` is a string or a function of the data fields."""
    return map_rows(lines, lambda f, header: [*f, name if header else (value(f) if callable(value) else value)])


def data_lines(lines: list[str], sweep: int) -> list[int]:
    """1-based file line numbers of the rows of ``sweep``."""
    return [k + 1 for k in range(HEADER_LINE, len(lines)) if lines[k].split(",")[0] == str(sweep)]


def keep_rows_of_sweep(lines: list[str], sweep: int, count: int) -> list[str]:
    drop = set(data_lines(lines, sweep)[count:])
    return [text for k, text in enumerate(lines, start=1) if k not in drop]


def invoke(argv: list[str], capsys) -> tuple[int, str, str]:
    try:
        code = main([str(a) for a in argv])
    except SystemExit as exc:  # argparse usage errors exit through SystemExit
        code = exc.code
    out, err = capsys.readouterr()
    return code, out, err


def assert_one_line_error(code: int, out: str, err: str, *needles: str) -> None:
    assert code == 2, f"exit code {code}, stderr {err!r}"
    assert out == ""
    assert err.endswith("\n") and err.count("\n") == 1, f"not one line: {err!r}"
    assert err.startswith("identify: error: ")
    assert "Traceback" not in err
    for needle in needles:
        assert needle in err, f"{needle!r} not in {err!r}"


def model_from_yaml(doc: dict) -> DHModel:
    """The forward model (README.md, File contracts) from the contract keys only (independent of result_io)."""
    joints = doc["joints"]
    return DHModel(
        "".join(j["type"] for j in joints),
        [j["theta"] for j in joints],
        [j["d"] for j in joints],
        [j["a"] for j in joints],
        [j["alpha"] for j in joints],
        np.array(doc["base"]),
        np.array(doc["tool"]),
    )


def fit_residuals(model: DHModel, meas: Measurements) -> np.ndarray:
    """3D distance (m) between measured and predicted TP at the rows with all joint readings."""
    rows = np.all(np.isfinite(meas.q), axis=1)
    return np.linalg.norm(meas.points[rows] - points_from_joints(model, meas.q[rows]), axis=1)


# --- bad input: one line, exit code 2 ---------------------------------------------------------------------------


def test_missing_column(tmp_path, lines, capsys):
    path = write(tmp_path, drop_column(lines, "y"))
    assert_one_line_error(*invoke([path], capsys), "line 3", "missing column(s) y", "sweep,joint,q1..q6,x,y,z")


def test_missing_q_column_is_a_gap(tmp_path, lines, capsys):
    path = write(tmp_path, drop_column(lines, "q3"))
    assert_one_line_error(*invoke([path], capsys), "line 3", "without gaps", "q1, q2, q4, q5, q6")


def test_q_column_gap(tmp_path, lines, capsys):
    text = list(lines)
    text[HEADER_LINE - 1] = text[HEADER_LINE - 1].replace("q4", "q7")
    assert_one_line_error(*invoke([write(tmp_path, text)], capsys), "line 3", "without gaps", "q7")


def test_extra_q_column(tmp_path, lines, capsys):
    path = write(tmp_path, add_column(lines, "q7", "0.0"))
    assert_one_line_error(*invoke([path], capsys), "inconsistent joint counts", "6 joints", "q1..q7")


def test_joint_count_comment_disagrees_with_q_columns(tmp_path, lines, capsys):
    text = [t.replace("# joints: RRRRRR", "# joints: RRRRR") for t in lines]
    assert_one_line_error(*invoke([write(tmp_path, text)], capsys), "inconsistent joint counts", "RRRRR", "q1..q6")


def test_joints_option_disagrees_with_q_columns(tmp_path, lines, capsys):
    path = write(tmp_path, lines)
    assert_one_line_error(*invoke([path, "--joints", "RRRRRRR"], capsys), "inconsistent joint counts", "7 joints")


@pytest.mark.parametrize(
    ("name", "value", "needle"),
    [
        ("x", "nan", "column x: 'nan' is not a finite number"),
        ("z", "NaN", "column z: 'NaN' is not a finite number"),
        ("y", "inf", "column y: 'inf' is not a finite number"),
        ("q2", "-inf", "column q2: '-inf' is not a finite number"),
        ("q6", "nan", "column q6: 'nan' is not a finite number"),
        ("x", "1.2.3", "column x: '1.2.3' is not a number"),
        ("x", "", "column x is empty"),
        ("sweep", "1.5", "column sweep: '1.5' is not an integer"),
        ("joint", "two", "column joint: 'two' is not an integer"),
    ],
)
def test_bad_values_name_line_and_column(tmp_path, lines, capsys, name, value, needle):
    line = HEADER_LINE + 5
    path = write(tmp_path, set_field(lines, line, name, value))
    assert_one_line_error(*invoke([path], capsys), f"line {line}: {needle}")


def test_field_count_differs_from_header(tmp_path, lines, capsys):
    line = HEADER_LINE + 7
    text = list(lines)
    text[line - 1] += ",0.5"
    assert_one_line_error(*invoke([write(tmp_path, text)], capsys), f"line {line}: 12 fields, the header has 11")
    text = list(lines)
    text[line - 1] = text[line - 1].rsplit(",", 1)[0]
    assert_one_line_error(*invoke([write(tmp_path, text)], capsys), f"line {line}: 10 fields, the header has 11")


def test_empty_reading_of_a_joint_that_did_not_move(tmp_path, lines, capsys):
    line = data_lines(lines, 1)[3]  # sweep 1 moves joint 6; blank joint 2
    path = write(tmp_path, set_field(lines, line, "q2", ""))
    assert_one_line_error(*invoke([path], capsys),
                          f"line {line}: in a sweep, leave either the moved joint's reading or every reading empty")


def test_joint_index_out_of_range(tmp_path, lines, capsys):
    line = data_lines(lines, 2)[0]
    path = write(tmp_path, set_field(lines, line, "joint", "9"))
    assert_one_line_error(*invoke([path], capsys), f"line {line}: joint must be 0 (free pose) or 1..6")


def test_sweep_that_mixes_joints(tmp_path, lines, capsys):
    path = write(tmp_path, set_field(lines, data_lines(lines, 2)[4], "joint", "4"))
    assert_one_line_error(*invoke([path], capsys), "sweep 2 mixes joints [4, 5]")


def test_sweep_with_fewer_than_three_samples(tmp_path, lines, capsys):
    path = write(tmp_path, keep_rows_of_sweep(lines, 1, 2))
    assert_one_line_error(*invoke([path], capsys), "sweep 1 (joint 6) has 2 samples; at least 3 needed")


def test_joint_never_swept(tmp_path, lines, capsys):
    path = write(tmp_path, keep_rows_of_sweep(lines, 6, 0))  # sweep 6 moves joint 1
    assert_one_line_error(*invoke([path], capsys), "joint 1 is never swept")


def test_tp_on_a_joint_axis(tmp_path, capsys):
    """The TP on joint 6's axis (frame 6's z: tool = (0, 0, 0.05) with a6 = alpha6 = 0) does not move in sweep 1."""
    truth, meas = _session(noise=2e-5, tool=[0.0, 0.0, 0.05])
    truth_exact = DHModel(truth.joint_types, truth.theta, truth.d, np.r_[truth.a[:5], 0.0],
                          np.r_[truth.alpha[:5], 0.0], truth.base, truth.tool)
    rng = np.random.default_rng(1)
    points = points_from_joints(truth_exact, meas.q) + rng.normal(0.0, 2e-5, meas.points.shape)
    bad = Measurements(meas.joint_types, meas.q, points, meas.sweep, meas.joint)
    path = write(tmp_path, format_measurements(bad))
    assert_one_line_error(*invoke([path], capsys), "joint 6", "sweep 1", "sits on the joint's axis")


def test_arc_too_short_to_define_an_axis(tmp_path, session, capsys):
    """Joint 3 (sweep 4) turned through 1 degree only."""
    truth, meas = session
    q, points = meas.q.copy(), meas.points.copy()
    rows = meas.sweep == 4
    assert np.all(meas.joint[rows] == 3)
    q[rows, 2] = ROBOT.home[2] + np.radians(np.linspace(-0.5, 0.5, rows.sum()))
    points[rows] = points_from_joints(truth, q[rows]) + np.random.default_rng(2).normal(0, 1e-6, (rows.sum(), 3))
    short = Measurements(meas.joint_types, q, points, meas.sweep, meas.joint)
    path = write(tmp_path, format_measurements(short))
    code, out, err = invoke([path], capsys)
    assert_one_line_error(code, out, err, "joint 3: sweep 4 covers", "too short an arc to define an axis")


def test_positions_in_millimetres_need_units_mm(tmp_path, session, capsys):
    meas = session[1]
    mm = Measurements(meas.joint_types, meas.q, meas.points * 1e3, meas.sweep, meas.joint)
    text = format_measurements(mm).replace("# units: m, rad\n", "")
    path = write(tmp_path, text)
    assert_one_line_error(*invoke([path], capsys), "look like millimetres", "--units mm")
    code, out, err = invoke([path, "--units", "mm", "--json"], capsys)
    assert code == 0, err
    model = model_from_yaml(json.loads(out))
    assert np.max(fit_residuals(model, meas)) < 5 * NOISE * np.sqrt(3)  # same data, read in metres


def test_unknown_units_comment(tmp_path, lines, capsys):
    text = [t.replace("# units: m, rad", "# units: inch, rad") for t in lines]
    assert_one_line_error(*invoke([write(tmp_path, text)], capsys), "unknown position unit 'inch'")


def test_empty_file(tmp_path, capsys):
    assert_one_line_error(*invoke([write(tmp_path, "")], capsys), "the file is empty")
    assert_one_line_error(*invoke([write(tmp_path, "\n  \n", "blank.csv")], capsys), "the file is empty")


def test_comments_only_and_header_only(tmp_path, lines, capsys):
    assert_one_line_error(*invoke([write(tmp_path, lines[:2])], capsys), "no header row and no data")
    assert_one_line_error(*invoke([write(tmp_path, lines[:3], "h.csv")], capsys), "no data rows")


def test_binary_file(tmp_path, capsys):
    path = write(tmp_path, bytes(range(256)) * 4, "session.bin")
    assert_one_line_error(*invoke([path], capsys), "binary data, not a measurement CSV")


def test_non_utf8_file(tmp_path, lines, capsys):
    text = "\n".join(lines).replace("# units: m, rad", "# units: m, rad; Müller") + "\n"
    path = write(tmp_path, text.encode("latin-1"))
    assert_one_line_error(*invoke([path], capsys), "not UTF-8")


def test_missing_joint_types(tmp_path, lines, capsys):
    text = [t for t in lines if not t.startswith("# joints")]
    assert_one_line_error(*invoke([write(tmp_path, text)], capsys), "joint types unknown", "--joints")


def test_invalid_joint_types(tmp_path, lines, capsys):
    assert_one_line_error(*invoke([write(tmp_path, lines), "--joints", "RRXRRR"], capsys), "R and P", "'RRXRRR'")


def test_unknown_robot(tmp_path, lines, capsys):
    path = write(tmp_path, lines)
    assert_one_line_error(*invoke([path, "--robot", "ur99"], capsys), "'ur99'", "ur5e")


def test_robot_with_other_joint_types(tmp_path, lines, capsys):
    path = write(tmp_path, lines)
    assert_one_line_error(*invoke([path, "--robot", "scara"], capsys), "--robot scara has joints RRPR",
                          "the data have RRRRRR")


@pytest.mark.parametrize("value", ["1.5", "1", "-0.1", "nan"])
def test_bad_holdout(tmp_path, lines, capsys, value):
    path = write(tmp_path, lines)
    assert_one_line_error(*invoke([path, "--holdout", value], capsys), "--holdout must be in [0, 1)")


def test_holdout_not_a_number(tmp_path, lines, capsys):
    path = write(tmp_path, lines)
    assert_one_line_error(*invoke([path, "--holdout", "a third"], capsys), "--holdout", "invalid float value")


def test_nonexistent_file(tmp_path, capsys):
    assert_one_line_error(*invoke([tmp_path / "nope.csv"], capsys), "nope.csv: no such file")


def test_invalid_role(tmp_path, lines, capsys):
    text = add_column(lines, "role", "fit")
    line = HEADER_LINE + 4
    path = write(tmp_path, set_field(text, line, "role", "maybe"))
    assert_one_line_error(*invoke([path], capsys), f"line {line}: role must be 'fit' or 'check', got 'maybe'")


def test_duplicate_column(tmp_path, lines, capsys):
    path = write(tmp_path, add_column(lines, "x", "0.0"))
    assert_one_line_error(*invoke([path], capsys), "column 'x' appears twice")


# --- through a real process ---------------------------------------------------------------------------------------


def _process(*args) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "identify.commands.cli", *map(str, args)],
        capture_output=True, text=True, timeout=60, cwd=ROOT, check=False,
    )


@pytest.mark.slow
@pytest.mark.parametrize(
    ("case", "needle"),
    [
        ("missing", "no such file"),
        ("binary", "binary data"),
        ("mm", "look like millimetres"),
        ("holdout", "invalid float value"),
    ],
)
def test_bad_input_in_a_real_process(tmp_path, session, case, needle):
    args: list = []
    if case == "missing":
        args = [tmp_path / "missing.csv"]
    elif case == "binary":
        args = [write(tmp_path, b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR", "image.csv")]
    elif case == "mm":
        meas = session[1]
        mm = Measurements(meas.joint_types, meas.q, meas.points * 1e3, meas.sweep, meas.joint)
        args = [write(tmp_path, format_measurements(mm).replace("# units: m, rad\n", ""))]
    else:
        args = [write(tmp_path, format_measurements(session[1])), "--holdout", "half"]
    result = _process(*args)
    assert result.returncode == 2, result.stderr
    assert result.stdout == ""
    assert result.stderr.count("\n") == 1 and result.stderr.endswith("\n"), result.stderr
    assert "Traceback" not in result.stderr
    assert needle in result.stderr


def test_good_input_in_a_real_process(tmp_path, session):
    result = _process(write(tmp_path, format_measurements(session[1])), "--json")
    assert result.returncode == 0, result.stderr
    assert set(json.loads(result.stdout)) >= {"joints", "base", "tool"}


# --- good input ------------------------------------------------------------------------------------------------------


def test_json_output(tmp_path, session, capsys):
    truth, meas = session
    code, out, err = invoke([write(tmp_path, format_measurements(meas)), "--json"], capsys)
    assert code == 0, err
    doc = json.loads(out)
    assert {"joints", "base", "tool"} <= set(doc)
    assert [j["type"] for j in doc["joints"]] == list("RRRRRR")
    assert np.array(doc["base"]).shape == (4, 4)
    np.testing.assert_allclose(np.array(doc["base"])[3], [0, 0, 0, 1])
    assert len(doc["tool"]) == 3
    # predictions of the JSON model at the truth's poses: within a few noise levels of the truth
    q = np.vstack([meas.q, ROBOT.home])
    err_truth = np.linalg.norm(points_from_joints(model_from_yaml(doc), q) - points_from_joints(truth, q), axis=1)
    assert np.sqrt(np.mean(err_truth**2)) < 3 * NOISE


def test_out_writes_the_result_yaml(tmp_path, session, capsys):
    meas = session[1]
    out_path = tmp_path / "results" / "result.yaml"
    out_path.parent.mkdir()  # a missing folder is an error (issue 13), never made
    code, out, err = invoke([write(tmp_path, format_measurements(meas)), "--out", out_path], capsys)
    assert code == 0, err
    assert f"{out_path}: the result (use: its plain model, held-out " in out
    doc = yaml.safe_load(out_path.read_text(encoding="utf-8"))
    assert list(doc)[:3] == ["joints", "base", "tool"]
    model = model_from_yaml(doc)
    residuals = fit_residuals(model, meas)
    noise_rms = NOISE * np.sqrt(3)  # 3D
    assert np.max(residuals) < 5 * noise_rms
    assert np.sqrt(np.mean(residuals**2)) < 1.5 * noise_rms
    assert not list(out_path.parent.glob(".result.yaml.*"))  # no temporary file left behind


def test_joints_option_overrides_the_file(tmp_path, session, lines, capsys):
    text = [t.replace("# joints: RRRRRR", "# joints: RRRRRP") for t in lines]
    code, out, err = invoke([write(tmp_path, text), "--joints", "rrrrrr", "--json"], capsys)
    assert code == 0, err
    doc = json.loads(out)
    assert [j["type"] for j in doc["joints"]] == list("RRRRRR")
    assert any("--joints RRRRRR overrides the file's '# joints: RRRRRP'" in w for w in doc["warnings"])
    assert np.max(fit_residuals(model_from_yaml(doc), session[1])) < 5 * NOISE * np.sqrt(3)


def test_joints_option_supplies_missing_types(tmp_path, lines, capsys):
    text = [t for t in lines if not t.startswith("# joints")]
    code, _, err = invoke([write(tmp_path, text), "--joints", "RRRRRR"], capsys)
    assert code == 0, err


def test_sweep_with_few_samples_warns(tmp_path, session, lines, capsys):
    path = write(tmp_path, keep_rows_of_sweep(lines, 1, 5))
    code, out, err = invoke([path], capsys)
    assert code == 0, err
    assert "sweep 1 (joint 6) has only 5 samples" in out
    code, out, err = invoke([path, "--json"], capsys)
    doc = json.loads(out)
    assert any("sweep 1 (joint 6) has only 5 samples" in w for w in doc["warnings"])
    assert np.max(fit_residuals(model_from_yaml(doc), session[1])) < 5 * NOISE * np.sqrt(3)


def test_hand_jogged_sweep(tmp_path, session, lines, capsys):
    """Sweep 2 moves joint 5 by hand: its q5 readings are empty. The axis comes from the positions alone."""
    text = list(lines)
    for line in data_lines(lines, 2):
        text = set_field(text, line, "q5", "")
    code, out, err = invoke([write(tmp_path, text), "--json"], capsys)
    assert code == 0, err
    doc = json.loads(out)
    axis5 = next(ax for ax in doc["geometric_step"]["axes"] if ax["joint"] == 5)
    assert axis5["samples"] == STEPS and axis5["sweep"] == 2
    meas = session[1]
    assert np.max(fit_residuals(model_from_yaml(doc), meas)) < 5 * NOISE * np.sqrt(3)


def test_check_rows_are_reported_under_validation(tmp_path, session, lines, capsys):
    meas = session[1]
    free_lines = [k + 1 for k in range(HEADER_LINE, len(lines)) if lines[k].split(",")[1] == "0"]
    assert len(free_lines) == FREE
    check = set(free_lines[:4])
    text = [
        (t + ("," + ("check" if k in check else "fit")) if k > HEADER_LINE else t + ",role" if k == HEADER_LINE else t)
        for k, t in enumerate(lines, start=1)
    ]
    code, out, err = invoke([write(tmp_path, text), "--json"], capsys)
    assert code == 0, err
    doc = json.loads(out)
    validation = validation_of(doc)
    assert validation["samples"] == 4
    assert validation["rms"] < 3 * NOISE * np.sqrt(3)
    assert validation["max"] >= validation["rms"]
    # check rows are never fitted: the fit counts all rows but the 4 (no hold-out draw with a role column)
    assert doc["residuals"]["samples"] == len(meas) - 4
    code, out, _ = invoke([write(tmp_path, text, "again.csv")], capsys)
    assert "validation of the plain model on 4 held-out poses" in out


def test_ignored_extra_columns_are_noted(tmp_path, session, lines, capsys):
    text = add_column(lines, "step", "12")
    code, out, err = invoke([write(tmp_path, text), "--json"], capsys)
    assert code == 0, err
    assert any("ignored column(s): step" in w for w in json.loads(out)["warnings"])
