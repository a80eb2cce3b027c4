"""A robot model from a file wherever a model is named: ``mock:PATH.yaml``, ``PATH.yaml@HOST`` for a real arm,
``identify --robot PATH``; validated as the bundled models are; ``--robot ''`` refused, never the mock UR5e."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from acquire.commands.cli import main
from acquire.running.session import Session
from config.robots import ROBOTS_DIR
from drivers.errors import SpecError
from drivers.spec import RobotSpec
from identify.commands.cli import main as identify_main

SMALL = ["--steps", "8", "--samples", "2", "--free-poses", "4", "--quiet"]
SAMPLE = Path(__file__).resolve().parents[2] / "identify" / "data" / "sample_ur5e.csv"


def _arm(folder: Path, **changes) -> Path:
    """A copy of the bundled UR5e under another name (a cell's own model file), with ``changes`` to its YAML."""
    doc = yaml.safe_load((ROBOTS_DIR / "ur5e.yaml").read_text())
    doc.update(name="cell7_arm", **changes)
    path = folder / "cell7_arm.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


@pytest.mark.parametrize(("text", "backend", "model", "host"), [
    ("mock:my_arm.yaml", "mock", "my_arm.yaml", None),
    ("mock:arms/cell7.yml?seed=3", "mock", "arms/cell7.yml", None),
    ("arms/cell7.yaml@192.168.1.10", "ur", "arms/cell7.yaml", "192.168.1.10"),
    ("ur:/opt/arms/cell7.yaml@10.0.0.2:30004", "ur", "/opt/arms/cell7.yaml", "10.0.0.2"),
])
def test_a_robot_spec_names_a_model_file(text, backend, model, host):
    spec = RobotSpec.parse(text)
    assert (spec.backend, spec.model, spec.host) == (backend, model, host)
    assert spec.model_is_file and Path(spec.resolved().model).is_absolute()


@pytest.mark.parametrize("text", ["mock:my arm.yaml", "mock:bad!name", "", "  "])
def test_a_bad_model_or_an_empty_spec_is_refused(text):
    with pytest.raises(SpecError):
        RobotSpec.parse(text)


@pytest.mark.slow
def test_a_mock_session_of_a_model_file_records_it_and_resumes_from_another_folder(tmp_path, monkeypatch, capsys):
    """Named relative to the working folder; the session keeps the absolute path, so a dry-run resume from another
    folder plans with the same model."""
    cell = tmp_path / "cell"
    cell.mkdir()
    _arm(cell)
    monkeypatch.chdir(cell)
    path = tmp_path / "s.session"
    assert main(["--robot", "mock:cell7_arm.yaml", "--tracker", "mock", "--session", str(path), *SMALL]) == 0
    assert "cell7_arm" in capsys.readouterr().out
    with Session.open(path) as session:
        spec = RobotSpec.parse(session.header["config"]["robot_spec"])
        assert session.outcome() == "complete"
        assert session.header["config"]["robot_model"]["name"] == "cell7_arm"  # the model itself (issue 39)
    assert spec.model == str(cell / "cell7_arm.yaml")
    monkeypatch.chdir(tmp_path)
    assert main(["--resume", str(path), "--dry-run"]) == 0
    assert "Plan for cell7_arm" in capsys.readouterr().out
    (cell / "cell7_arm.yaml").rename(tmp_path / "moved.yaml")  # the session still reads offline: its own model
    assert identify_main([str(path)]) == 0
    assert "cell7_arm" in capsys.readouterr().out


@pytest.mark.slow
def test_a_resume_uses_the_model_the_session_records_when_the_file_has_moved_or_changed(tmp_path, capsys):
    """The plan was checked with the recorded model: a resume drives with it, saying why in one line."""
    arm = _arm(tmp_path)
    path = tmp_path / "s.session"
    assert main(["--robot", f"mock:{arm}?fault=protective_stop@5", "--tracker", "mock", "--session", str(path),
                 *SMALL]) == 1
    capsys.readouterr()
    arm.write_text(arm.read_text().replace("cell7_arm", "cell7_arm_v2"))  # edited since: not the session's model
    assert main(["--resume", str(path), "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert f"robot: {arm} has changed since the session was planned; the resume uses the model the session " \
           "records (cell7_arm)" in out.splitlines() and "Plan for cell7_arm (" in out
    arm.rename(tmp_path / "moved.yaml")
    assert main(["--resume", str(path), "--quiet"]) == 0
    out, err = capsys.readouterr()
    assert f"robot: {arm} is not there; the resume uses the model the session records (cell7_arm)" \
           in out.splitlines() and err == ""
    with Session.open(path) as session:
        assert session.outcome() == "complete"
        assert [s.plan_index for s in session.steps()] == list(range(len(session.plan.steps)))


def test_a_model_file_is_validated_as_the_bundled_ones_are(tmp_path, capsys):
    arm = _arm(tmp_path, joints="RRRRR")  # five joint types for six DH rows
    assert main(["--robot", f"mock:{arm}", "--dry-run"]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and "cell7_arm.yaml" in err
    assert main(["--robot", f"mock:{tmp_path / 'missing.yaml'}", "--dry-run"]) == 2
    assert "missing.yaml" in capsys.readouterr().err


def test_a_real_arm_takes_a_model_file_with_its_address(tmp_path, capsys):
    """The dry run of ``PATH.yaml@HOST`` plans with the file's model (nothing connects)."""
    arm = _arm(tmp_path)
    assert main(["--robot", f"{arm}@192.168.1.10", "--tracker", "mock", "--dry-run"]) == 0
    assert "Plan for cell7_arm" in capsys.readouterr().out


@pytest.mark.parametrize("command", [
    lambda: main(["--robot", "", "--dry-run"]),
    lambda: identify_main([str(SAMPLE), "--robot", ""]),
])
def test_an_empty_robot_is_refused_not_replaced_by_a_default(command, capsys):
    assert command() == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and "robot" in err and "Plan for" not in err
