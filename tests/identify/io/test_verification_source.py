"""``identify --report --verification`` compares what the files are, not how their paths were spelled (issue 39,
item 5): a result whose ``source`` was typed relative to the folder identify ran in is recognised from any other
folder; a copy of the data elsewhere is still another file."""

from __future__ import annotations

import hashlib
import os

import pytest
import yaml

from common.errors import InputError
from identify.io.verification_io import load_verification


def _verified(project, source_typed: str, **extra):
    """sessions/m.csv, its result (``source`` as typed in ``project``) and the verification of that result."""
    folder = project / "sessions"
    folder.mkdir(parents=True)
    data = folder / "m.csv"
    data.write_text("sweep,joint,q1,x,y,z\n")
    result = folder / "m.result.yaml"
    result.write_text(yaml.safe_dump({"source": source_typed, **extra}))
    summary = folder / "m.verify.yaml"
    summary.write_text(yaml.safe_dump({"verdict": {"status": "pass"}, "runs": {}, "result": "sessions/m.result.yaml",
                                       "result_sha256": hashlib.sha256(result.read_bytes()).hexdigest()}))
    return data, summary


def test_the_right_verification_is_taken_from_another_folder(tmp_path, monkeypatch):
    data, summary = _verified(tmp_path / "project", "sessions/m.csv")  # an older result: no source_path
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    assert load_verification(str(summary), str(data))["verdict"]["status"] == "pass"
    assert load_verification(str(summary), os.path.relpath(data))["verdict"]["status"] == "pass"
    copy = elsewhere / "m.csv"
    copy.write_text(data.read_text())
    with pytest.raises(InputError, match="not a calibration of"):
        load_verification(str(summary), str(copy))


def test_a_results_source_path_names_its_data_wherever_both_are_read_from(tmp_path, monkeypatch):
    """The data in another folder than the result, its ``source`` typed relative to a folder that is no ancestor:
    the result's ``source_path`` (absolute, written by result_to_dict) still finds it."""
    data = tmp_path / "measured" / "m.csv"
    data.parent.mkdir()
    data.write_text("sweep,joint,q1,x,y,z\n")
    folder = tmp_path / "results"
    folder.mkdir()
    result = folder / "m.result.yaml"
    result.write_text(yaml.safe_dump({"source": "m.csv", "source_path": str(data)}))  # typed in measured/
    summary = folder / "m.verify.yaml"
    summary.write_text(yaml.safe_dump({"verdict": {"status": "pass"}, "runs": {}, "result": str(result),
                                       "result_sha256": hashlib.sha256(result.read_bytes()).hexdigest()}))
    monkeypatch.chdir(tmp_path)
    assert load_verification(str(summary), "measured/m.csv")["verdict"]["status"] == "pass"
