"""identify says every file it wrote (it announced --out only), and --json keeps stdout one JSON document."""

from __future__ import annotations

import json
from pathlib import Path

from identify.cli import main

SAMPLE = Path(__file__).resolve().parents[2] / "identify" / "data" / "sample_ur5e.csv"


def test_every_written_file_is_announced(tmp_path, capsys):
    files = {"--out": "r.yaml", "--urdf": "r.urdf", "--rtb": "r.py", "--json-out": "r.json", "--csv": "m.csv"}
    argv = [str(SAMPLE)] + [x for option, name in files.items() for x in (option, str(tmp_path / name))]
    assert main(argv) == 0
    out = capsys.readouterr().out
    for what, name in zip(("result", "URDF", "Robotics Toolbox script", "JSON result", "measurement CSV"),
                          files.values(), strict=True):
        assert f"{what} written to {tmp_path / name}" in out and (tmp_path / name).is_file()
    assert main([*argv, "--json", "--force"]) == 0
    json.loads(capsys.readouterr().out)  # nothing but the document
