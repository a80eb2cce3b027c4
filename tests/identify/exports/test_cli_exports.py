"""The export options of `identify` and the report at the end of `acquire`, through the commands."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from identify.commands.cli import main
from identify.io.csvio import format_measurements, read_measurements
from kinematics.dh import model_from_dict

ROOT = Path(__file__).resolve().parents[3]
SAMPLE = ROOT / "identify" / "data" / "sample_ur5e.csv"


@pytest.mark.slow
def test_every_export_is_written_and_consistent(tmp_path, capsys):
    pytest.importorskip("matplotlib")
    out = {k: tmp_path / f"r.{k}" for k in ("yaml", "html", "urdf", "cal", "py", "json", "csv")}
    code = main([str(SAMPLE), "--robot", "ur5e", "--out", str(out["yaml"]), "--report", str(out["html"]),
                 "--urdf", str(out["urdf"]), "--ur-calibration", str(out["cal"]), "--rtb", str(out["py"]),
                 "--json-out", str(out["json"]), "--csv", str(out["csv"])])
    assert code == 0
    assert out["html"].read_text().count("<img") >= 6
    assert "<robot" in out["urdf"].read_text() and "kinematics:" in out["cal"].read_text()
    assert "DHRobot" in out["py"].read_text()
    doc = yaml.safe_load(out["yaml"].read_text())
    import json

    assert json.loads(out["json"].read_text())["joints"] == doc["joints"]
    again = read_measurements(out["csv"]).measurements
    original = read_measurements(SAMPLE).measurements
    assert np.array_equal(again.points, original.points)
    assert out["yaml"].stat().st_mode & 0o044  # an ordinary, readable result file


def test_ur_calibration_of_a_non_ur_robot_is_refused_before_identifying(tmp_path, capsys):
    from config.robots import load_robot
    from identify.simulators.simulate import simulate
    from kinematics.truth import random_truth

    robot = load_robot("scara")
    rng = np.random.default_rng(1)
    meas, _ = simulate(random_truth(robot.nominal, robot.home, rng), robot.home, robot.limits, rng, noise=5e-5)
    path = tmp_path / "scara.csv"
    path.write_text(format_measurements(meas))
    assert main([str(path), "--ur-calibration", str(tmp_path / "c.yaml")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "6R UR arm" in err
    assert not (tmp_path / "c.yaml").exists()


@pytest.mark.slow
def test_acquire_writes_the_report_beside_the_session(tmp_path):
    pytest.importorskip("matplotlib")
    from acquire.commands.cli import main as acquire_main

    session = tmp_path / "s.session"
    assert acquire_main(["--robot", "mock:ur5e?seed=2", "--tracker", "mock", "--session", str(session), "--steps",
                         "12", "--samples", "3", "--free-poses", "6", "--quiet"]) == 0
    page = session.with_suffix(".report.html").read_text()
    assert "Acquisition" in page or "acquisition" in page
    model = model_from_dict(yaml.safe_load(session.with_suffix(".result.yaml").read_text()))
    assert model.joint_types == "RRRRRR"
