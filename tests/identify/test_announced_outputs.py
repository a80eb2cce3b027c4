"""identify says every file it wrote (it announced --out only), and --json keeps stdout one JSON document."""

from __future__ import annotations

import json
from pathlib import Path

from identify.commands.cli import main

SAMPLE = Path(__file__).resolve().parents[2] / "identify" / "data" / "sample_ur5e.csv"


def test_every_written_file_is_announced(tmp_path, capsys):
    files = {"--out": "r.yaml", "--urdf": "r.urdf", "--rtb": "r.py", "--json-out": "r.json", "--csv": "m.csv"}
    argv = [str(SAMPLE)] + [x for option, name in files.items() for x in (option, str(tmp_path / name))]
    assert main(argv) == 0
    out = capsys.readouterr().out.splitlines()
    # the model files say which model they carry and its held-out figure; the others that they were written
    expected = {"r.yaml": "the result (use: its plain model, held-out ",
                "r.urdf": "plain model (exact axes), held-out ", "r.py": "plain model (DH table), held-out ",
                "r.json": None, "m.csv": None}
    for name, carries in expected.items():
        path = tmp_path / name
        said = f"{path}: {carries}" if carries else f"written to {path}"
        assert any(said in line for line in out), (name, out[-6:])
        assert path.is_file()
    assert main([*argv, "--json", "--force"]) == 0
    streams = capsys.readouterr()
    json.loads(streams.out)  # nothing but the document; the model files are announced on stderr
    assert f"{tmp_path / 'r.urdf'}: plain model (exact axes)" in streams.err
