"""What a user gets besides this repository (issue 39, item 13): the wheel carries every data file the README uses,
no shipped file sends the reader to a design document they do not have, the README says how to install (dh-calib is
not on PyPI) and writes down the robot YAML format with an example that loads, and a result given to ``identify``
as measurements is named for what it is."""

from __future__ import annotations

import fnmatch
import re
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text(encoding="utf-8")
#: modules another change owns at the time of writing (issue 39 leaves their docstrings to it)
def test_the_wheel_carries_every_data_file_of_the_packages():
    data = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]
    for package, patterns in data.items():
        for folder in {Path(p).parent for p in patterns}:
            for path in (ROOT / package / folder).iterdir():
                if path.is_file() and not path.name.startswith(".") and path.suffix not in (".py", ".pyc"):
                    relative = str(path.relative_to(ROOT / package))
                    assert any(fnmatch.fnmatch(relative, p) for p in patterns), relative
    assert {"data/example_ur5e.script", "data/sample_ur5e_truth.yaml"} <= {
        str(p.relative_to(ROOT / "identify")) for p in (ROOT / "identify" / "data").iterdir()}


def test_no_shipped_file_cites_the_design_document():
    cited = [str(p.relative_to(ROOT)) for package in ("common", "kinematics", "config", "drivers", "session",
                                                      "identify", "acquire", "bench")
             for p in (ROOT / package).rglob("*") if p.suffix in (".py", ".yaml")
             and any(cited in p.read_text(encoding="utf-8") for cited in ("DESIGN", "../shared"))]
    assert cited == []


def test_the_readme_says_how_to_install_what_is_not_published():
    assert "pip install 'dh-calib" not in README  # no such package on PyPI
    assert "not published on\nPyPI" in README or "not published on PyPI" in README


def test_the_readme_robot_yaml_example_loads():
    from config.robots import KEYS, robot_from_document

    example = re.search(r"```yaml\n(schema: 1\nname: lab_3r\n.*?)```", README, re.S)
    assert example
    import yaml

    robot = robot_from_document(yaml.safe_load(example.group(1)), "README")
    assert robot.name == "lab_3r" and robot.joint_types == "RRR"
    assert all(f"`{key}" in README for key in KEYS)  # every key written down


@pytest.mark.parametrize(("name", "says"), [("r.yaml", "this is a result"), ("m.yaml", "this is a robot model")])
def test_a_yaml_given_as_measurements_is_named(tmp_path, capsys, name, says):
    from identify.commands.cli import main

    doc = ("joints:\n- {type: R, a: 0.0, alpha: 0.0, d: 0.0, theta: 0.0}\nbase: [[1, 0, 0, 0]]\nverdict: {}\n"
           if name == "r.yaml" else (ROOT / "config" / "robots" / "ur5e.yaml").read_text())
    (tmp_path / name).write_text(doc)
    assert main([str(tmp_path / name)]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and says in err, err


def test_every_install_hint_names_a_requirement_of_its_extra():
    """Messages say what to install (``pip install 'matplotlib>=3.8,<4' (the report extra)``), not a package name
    that no index has (``pip install 'dh-calib[report]'``)."""
    from common.errors import EXTRAS

    extras = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]
    assert all(requirement in extras[extra] for extra, requirement in EXTRAS.items())
    shipped = [p for package in ("common", "config", "drivers", "session", "identify", "acquire")
               for p in (ROOT / package).rglob("*.py") if "dh-calib[" in p.read_text(encoding="utf-8")]
    assert shipped == []
